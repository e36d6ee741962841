//! Reference data: a scene ([`SilScene`]: the wake, the plume) simulated at the reference
//! resolution, each frame downsampled to the source grid (`T r_t`), for a set of values of the
//! scene's parameter (Reynolds numbers of the wake, buoyancy factors of the plume).
//!
//! The transfer `T` matches the MAC layout: a coarse `u` face (`x = (I+1) dX`, rows
//! `J dY .. (J+1) dY`) is the average of the `factor` fine `u` faces it covers (the fine faces
//! at `x = (factor (I+1)) dx`), and likewise for `v` along x. A face average keeps the flux
//! through every coarse face, so a divergence-free fine field stays divergence-free on the
//! coarse grid (where no obstacle cuts the cells differently). A cell-centred scalar (the
//! plume's density) is averaged over the `factor x factor` fine cells of each coarse cell
//! ([`downsample_cells`]), which keeps its total `sum rho dx dy` exactly.

use super::scene::{SilScene, WakeConfig};
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_grid::Grid;
use serde::{Deserialize, Serialize};

/// The integer factor between a fine and a coarse grid over the same extent (typed error for
/// different extents or a non-integer ratio).
pub fn downsample_factor(fine: &Grid, coarse: &Grid) -> Result<usize> {
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
    if !(same(fine.lx, coarse.lx) && same(fine.ly, coarse.ly)) {
        return Err(Error::invalid(
            "downsample_factor",
            "grid",
            format!("the grids cover different extents: {}x{} vs {}x{}", fine.lx, fine.ly, coarse.lx, coarse.ly),
        ));
    }
    if fine.nx % coarse.nx != 0 || fine.ny % coarse.ny != 0 || fine.nx / coarse.nx != fine.ny / coarse.ny {
        return Err(Error::invalid(
            "downsample_factor",
            "grid",
            format!(
                "{}x{} cells do not divide into {}x{} by one integer factor; pick a coarse grid that divides the fine one",
                fine.nx, fine.ny, coarse.nx, coarse.ny
            ),
        ));
    }
    Ok(fine.nx / coarse.nx)
}

/// Face-average of MAC velocities `[B, 2, ny f, nx f]` to `[B, 2, ny, nx]` (differentiable).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// // u = x-index of the face, v = 0: a coarse u face takes the fine face on its own plane.
/// let u = Tensor::arange(1f32, 17., &Device::Cpu)?.reshape((1, 1, 1, 16))?.repeat((1, 1, 8, 1))?;
/// let fine = Tensor::cat(&[&u, &u.zeros_like()?], 1)?;
/// let coarse = pbdl_sol::sil::downsample_mac(&fine, 4)?;
/// assert_eq!(coarse.dims(), &[1, 2, 2, 4]);
/// assert_eq!(coarse.narrow(1, 0, 1)?.flatten_all()?.to_vec1::<f32>()?, [4., 8., 12., 16., 4., 8., 12., 16.]);
/// # Ok::<(), pbdl_sol::Error>(())
/// ```
pub fn downsample_mac(fine: &Tensor, factor: usize) -> Result<Tensor> {
    let d = fine.dims();
    if d.len() != 4 || d[1] != 2 || factor == 0 || d[2] % factor != 0 || d[3] % factor != 0 {
        return Err(Error::Shape {
            context: "downsample_mac",
            expected: format!("[batch, 2, ny * {factor}, nx * {factor}] with factor >= 1"),
            got: d.to_vec(),
        });
    }
    let (b, ny, nx, f) = (d[0], d[2] / factor, d[3] / factor, factor);
    let u = fine.narrow(1, 0, 1)?.reshape((b, 1, ny * f, nx, f))?.narrow(4, f - 1, 1)?;
    let u = u.contiguous()?.reshape((b, 1, ny, f, nx))?.mean(3)?;
    let v = fine.narrow(1, 1, 1)?.reshape((b, 1, ny, f, nx * f))?.narrow(3, f - 1, 1)?;
    let v = v.contiguous()?.reshape((b, 1, ny, nx, f))?.mean(4)?;
    Ok(Tensor::cat(&[&u, &v], 1)?)
}

/// Cell average of cell-centred values `[B, C, ny f, nx f]` to `[B, C, ny, nx]`
/// (differentiable): each coarse cell is the mean of the `f x f` fine cells it covers, so
/// `sum q dX dY` on the coarse grid equals `sum q dx dy` on the fine one.
///
/// ```
/// use candle_core::{Device, Tensor};
/// let fine = Tensor::arange(0f64, 16., &Device::Cpu)?.reshape((1, 1, 4, 4))?;
/// let coarse = pbdl_sol::sil::downsample_cells(&fine, 2)?;
/// assert_eq!(coarse.flatten_all()?.to_vec1::<f64>()?, [2.5, 4.5, 10.5, 12.5]);
/// # Ok::<(), pbdl_sol::Error>(())
/// ```
pub fn downsample_cells(fine: &Tensor, factor: usize) -> Result<Tensor> {
    let d = fine.dims();
    if d.len() != 4 || factor == 0 || d[2] % factor != 0 || d[3] % factor != 0 {
        return Err(Error::Shape {
            context: "downsample_cells",
            expected: format!("[batch, channels, ny * {factor}, nx * {factor}] with factor >= 1"),
            got: d.to_vec(),
        });
    }
    let (b, c, ny, nx, f) = (d[0], d[1], d[2] / factor, d[3] / factor, factor);
    let x = fine.reshape((b * c, ny, f, nx, f))?.mean(4)?.mean(2)?;
    Ok(x.reshape((b, c, ny, nx))?)
}

/// Downsamples a reference state to the source grid: velocity by [`downsample_mac`], the
/// density (when there is one) by [`downsample_cells`], packed as `[B, 2 + 1, ny, nx]`.
pub fn downsample_state(state: &pbdl_grid::FluidState, factor: usize) -> Result<Tensor> {
    let u = downsample_mac(state.velocity.values(), factor)?;
    Ok(match &state.density {
        Some(rho) => Tensor::cat(&[&u, &downsample_cells(rho.values(), factor)?], 1)?,
        None => u,
    })
}

/// Parameter values and lengths of the data set. The fields are named for the wake
/// (`train_re`, `test_re`); for another scene they hold its parameter (the plume's buoyancy
/// factors, [`PlumeConfig::data`](super::plume::PlumeConfig::data)). The default follows the
/// paper's wake split: six training numbers a factor 2 apart, held-out numbers half-way between
/// them (geometrically).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataConfig {
    /// Training Reynolds numbers. Default `[97.66, 195.3, 390.6, 781.3, 1562.5, 3125]`.
    pub train_re: Vec<f64>,
    /// Held-out Reynolds numbers. Default `[146.5, 293, 585.9, 1171.9, 2343.8]`.
    pub test_re: Vec<f64>,
    /// Frames simulated before recording (the wake develops). Default 200.
    pub warmup: usize,
    /// Frames recorded per training simulation. Default 300.
    pub train_frames: usize,
    /// Frames recorded per held-out simulation. Default 150.
    pub test_frames: usize,
}

impl Default for DataConfig {
    fn default() -> Self {
        let base = 97.65625;
        Self {
            train_re: (0..6).map(|k| base * 2f64.powi(k)).collect(),
            test_re: (0..5).map(|k| 1.5 * base * 2f64.powi(k)).collect(),
            warmup: 200,
            train_frames: 300,
            test_frames: 150,
        }
    }
}

impl DataConfig {
    /// Checks the settings.
    pub fn validate(&self) -> Result<()> {
        if self.train_re.is_empty() {
            return Err(Error::invalid("DataConfig", "train_re", "give at least one training Reynolds number"));
        }
        if let Some(re) = self.train_re.iter().chain(&self.test_re).find(|r| !(**r > 0.0 && r.is_finite())) {
            return Err(Error::invalid("DataConfig", "train_re / test_re", format!("must be positive, got {re}")));
        }
        if self.train_frames < 2 || (!self.test_re.is_empty() && self.test_frames < 2) {
            return Err(Error::invalid("DataConfig", "train_frames / test_frames", "record at least 2 frames"));
        }
        Ok(())
    }
}

/// One reference simulation on the source grid.
#[derive(Clone, Debug)]
pub struct ReferenceSim {
    /// Its parameter: the Reynolds number of the wake, the buoyancy factor of the plume.
    pub re: f64,
    /// Downsampled frames `T r_t`, `[frames, 2 + scalars, ny, nx]` (velocity, then density).
    pub frames: Tensor,
    /// The uncorrected source trajectory from the first frame, `s^src_0 = T r_0`,
    /// `s^src_{t+1} = P_s(s^src_t)`, `[frames, 2, ny, nx]` (the paper's NON learns from these
    /// states). [`generate`] fills it for the training simulations; `None` elsewhere.
    pub source: Option<Tensor>,
}

impl ReferenceSim {
    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.dim(0).unwrap_or(0)
    }

    /// Whether it has no frames.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Training and held-out reference simulations of a scene (the wake by default).
#[derive(Clone, Debug)]
pub struct ReferenceSet<S = WakeConfig> {
    /// The scene they were made with (named `wake` from the first scene; the plume's
    /// [`PlumeConfig`](super::plume::PlumeConfig) in a plume set).
    pub wake: S,
    /// Training simulations.
    pub train: Vec<ReferenceSim>,
    /// Held-out simulations.
    pub test: Vec<ReferenceSim>,
}

/// Simulates one reference run of `scene` at parameter `re` and returns `frames` downsampled
/// frames after `warmup`.
pub fn reference_run<S: SilScene>(
    scene: &S,
    re: f64,
    warmup: usize,
    frames: usize,
    dtype: DType,
) -> Result<ReferenceSim> {
    scene.check_parameter(re)?;
    let fine = scene.fine_grid()?;
    let fluid = scene.fine_stepper(re)?;
    let mut s = scene.start(&fluid, fine, dtype)?;
    let rate = match scene.inflow_rate() {
        Some(r) => Some(Tensor::new(r, &candle_core::Device::Cpu)?.to_dtype(dtype)?),
        None => None,
    };
    let mut out = Vec::with_capacity(frames);
    for t in 0..warmup + frames {
        if t >= warmup {
            out.push(downsample_state(&s, scene.refinement())?);
        }
        for _ in 0..scene.substeps() {
            s = fluid.step(&s, rate.as_ref())?;
        }
        let m = s.velocity.max_abs()?;
        if !m.is_finite() {
            return Err(Error::NonFinite { context: "reference_run", step: t });
        }
    }
    Ok(ReferenceSim { re, frames: Tensor::cat(&out, 0)?, source: None })
}

/// The uncorrected source trajectory of `reference`: `frames` states from `s_0 = T r_0`, each
/// the source step `P_s` of the one before (no correction; detached), `[frames, C, ny, nx]`.
pub fn source_trajectory<S: SilScene>(scene: &S, reference: &ReferenceSim) -> Result<Tensor> {
    if reference.is_empty() {
        return Err(Error::invalid("source_trajectory", "frames", "the reference has no frames"));
    }
    let source = scene.source_solver(reference.re)?;
    let start = reference.frames.narrow(0, 0, 1)?;
    let mut states = vec![start.clone()];
    states.extend(super::eval::rollout(&source, &start, reference.len() - 1, None)?);
    Ok(Tensor::cat(&states, 0)?)
}

/// All reference runs of `data` for `scene` (sequential; each step is parallel inside
/// pbdl-grid), with a progress bar over the simulations. Each training simulation also gets its
/// uncorrected source trajectory ([`source_trajectory`], for NON).
pub fn generate<S: SilScene>(scene: &S, data: &DataConfig, dtype: DType) -> Result<ReferenceSet<S>> {
    scene.check()?;
    data.validate()?;
    for &p in data.train_re.iter().chain(&data.test_re) {
        scene.check_parameter(p)?;
    }
    let total = (data.train_re.len() + data.test_re.len()) as u64;
    let progress = pbdl_core::train::Progress::new(total);
    let run = |re: f64, frames: usize, k: u64| -> Result<ReferenceSim> {
        progress.set_message(format!("reference {} {re:.4}", scene.parameter_name()));
        let r = reference_run(scene, re, data.warmup, frames, dtype)?;
        progress.set_position(k + 1);
        Ok(r)
    };
    let mut k = 0;
    let mut train = Vec::new();
    for &re in &data.train_re {
        let mut r = run(re, data.train_frames, k)?;
        r.source = Some(source_trajectory(scene, &r)?);
        train.push(r);
        k += 1;
    }
    let mut test = Vec::new();
    for &re in &data.test_re {
        test.push(run(re, data.test_frames, k)?);
        k += 1;
    }
    progress.finish();
    Ok(ReferenceSet { wake: scene.clone(), train, test })
}
