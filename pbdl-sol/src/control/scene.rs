//! "Gaussian clash" scenes: initial state, constant Gaussian forcing, and the forced
//! ("natural") trajectory whose last state is the target.
//!
//! As in the paper's data (Holl et al. 2020, section 5.1), on unit coordinates `x` in `[0, 1)`:
//! - initial state: a positive bump on the left and a negative one on the right that run into
//!   each other, `u0 = A_l g(x; c_l, s_l) + A_r g(x; c_r, s_r)` with `g = exp(-(x - c)^2 / (2 s^2))`,
//!   `c_l ~ U(0.2, 0.4)`, `A_l ~ U(0, 3)`, `c_r ~ U(0.6, 0.8)`, `A_r ~ U(-3, 0)`,
//!   `s_l, s_r ~ U(0.05, 0.15)`;
//! - force: one Gaussian `F = A_f g(x; c_f, s_f)`, `c_f ~ U(0.4, 0.6)`, `A_f ~ 32 U(-0.05, 0.05)`,
//!   `s_f ~ U(0.1, 0.4)`, held constant for all steps;
//! - target: the last state of the forced trajectory `u_{t+1} = P(u_t) + dt F`.
//!
//! Scene `k` of a set depends only on `(seed, k)` (its own generator), so a range of scenes is
//! the same whichever other scenes are generated with it.

use super::config::BurgersControlConfig;
use super::physics::ForcedBurgers;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use rand::{Rng, SeedableRng};

/// A batch of scenes with their forced trajectories. All tensors `[batch, 1, 1, cells]`.
#[derive(Clone, Debug)]
pub struct ControlScenes {
    /// Initial states `u_0`.
    pub initial: Tensor,
    /// Target states `u*` (the last states of `trajectory`).
    pub target: Tensor,
    /// The constant force that produced the target.
    pub force: Tensor,
    /// `u_0 .. u_T` under `force` (the "natural" trajectory; `T + 1` entries).
    pub trajectory: Vec<Tensor>,
}

impl ControlScenes {
    /// Number of scenes.
    pub fn len(&self) -> usize {
        self.initial.dims()[0]
    }

    /// Whether there are no scenes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The scenes at `idx` (in that order).
    pub fn select(&self, idx: &[usize]) -> Result<Self> {
        let n = self.len();
        if let Some(&bad) = idx.iter().find(|&&i| i >= n) {
            return Err(Error::invalid("ControlScenes::select", "idx", format!("index {bad} out of {n} scenes")));
        }
        let ids = Tensor::new(idx.iter().map(|&i| i as u32).collect::<Vec<_>>(), self.initial.device())?;
        let pick = |t: &Tensor| t.index_select(&ids, 0);
        Ok(Self {
            initial: pick(&self.initial)?,
            target: pick(&self.target)?,
            force: pick(&self.force)?,
            trajectory: self.trajectory.iter().map(pick).collect::<candle_core::Result<_>>()?,
        })
    }
}

/// The generator of scene `k` of the set `seed` (a splitmix-style mix of both).
fn scene_rng(seed: u64, k: u64) -> rand::rngs::StdRng {
    let mut z = seed ^ k.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    rand::rngs::StdRng::seed_from_u64(z ^ (z >> 31))
}

/// Initial state and force of scene `k` of set `seed` on the unit cell centres `x`.
pub fn gaussian_clash(x: &[f64], seed: u64, k: u64) -> (Vec<f64>, Vec<f64>) {
    let mut r = scene_rng(seed, k);
    let g = |x: f64, c: f64, s: f64| (-(x - c).powi(2) / (2.0 * s * s)).exp();
    let (cl, al, sl) = (r.random_range(0.2..0.4), r.random_range(0.0..3.0), r.random_range(0.05..0.15));
    let (cr, ar, sr) = (r.random_range(0.6..0.8), r.random_range(-3.0..0.0), r.random_range(0.05..0.15));
    let (cf, af, sf) = (r.random_range(0.4..0.6), 32.0 * r.random_range(-0.05..0.05), r.random_range(0.1..0.4));
    let u0 = x.iter().map(|&x| al * g(x, cl, sl) + ar * g(x, cr, sr)).collect();
    let f = x.iter().map(|&x| af * g(x, cf, sf)).collect();
    (u0, f)
}

/// Scenes `range` of set `seed`: initial states, forces, and the forced trajectories simulated
/// with pbdl-grid's Burgers (batched), in `dtype` on `device`.
///
/// # Errors
/// [`Error::InvalidConfig`] for a bad config or an empty range; [`Error::NonFinite`] if a
/// trajectory blows up.
pub fn generate(
    cfg: &BurgersControlConfig,
    seed: u64,
    range: std::ops::Range<usize>,
    dtype: DType,
    device: &Device,
) -> Result<ControlScenes> {
    cfg.validate()?;
    if range.is_empty() {
        return Err(Error::invalid("control::scene::generate", "range", "is empty; ask for at least one scene"));
    }
    let x = cfg.unit_centres();
    let n = range.len();
    let (mut u0, mut f) = (Vec::with_capacity(n * cfg.cells), Vec::with_capacity(n * cfg.cells));
    for k in range {
        let (a, b) = gaussian_clash(&x, seed, k as u64);
        u0.extend(a);
        f.extend(b);
    }
    let shape = (n, 1, 1, cfg.cells);
    let initial = Tensor::from_vec(u0, shape, device)?.to_dtype(dtype)?;
    let force = Tensor::from_vec(f, shape, device)?.to_dtype(dtype)?;
    let physics = ForcedBurgers::new(cfg)?;
    let trajectory = physics.rollout(&initial, &vec![force.clone(); cfg.steps])?;
    for (t, s) in trajectory.iter().enumerate() {
        let m = s.abs()?.to_dtype(DType::F64)?.max_all()?.to_scalar::<f64>()?;
        if !m.is_finite() {
            return Err(Error::NonFinite { context: "control::scene::generate", step: t });
        }
    }
    let target = trajectory[cfg.steps].clone();
    Ok(ControlScenes { initial, target, force, trajectory })
}
