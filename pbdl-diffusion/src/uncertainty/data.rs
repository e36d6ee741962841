//! The data: snapshots of an unsteady cylinder wake at several Reynolds numbers, simulated with
//! pbdl-grid, and their per-pixel mean and standard deviation (the ground truth).

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::scene::Scene;

/// Geometry and sampling of the wake simulations (lengths in cylinder diameters `D`, times in
/// `D / U` with inflow speed `U = 1`).
#[derive(Debug, Clone, PartialEq)]
pub struct WakeConfig {
    /// Grid cells per diameter (pbdl-grid's Karman tour uses 4-5).
    pub cells_per_d: usize,
    /// Channel length and height `[lx, ly]`; free-slip walls, uniform inflow at `x = 0`.
    pub domain: [f64; 2],
    /// Cylinder centre.
    pub center: [f64; 2],
    /// The output window `[x0, y0]` (lower-left corner); it spans `out_size * pool` grid cells.
    pub window_origin: [f64; 2],
    /// Output height and width (`[H, W]`).
    pub out_size: [usize; 2],
    /// Average pooling factor from grid cells to output pixels (1: none).
    pub pool: usize,
    /// Time before the first snapshot (the wake has to start shedding).
    pub warmup: f64,
    /// Number of snapshots per Reynolds number.
    pub snapshots: usize,
    /// Time between snapshots.
    pub interval: f64,
    /// Transverse kick that starts the shedding (pbdl-grid's `physics.kick`).
    pub kick: f64,
}

impl Default for WakeConfig {
    /// 16 D x 8 D channel at 4 cells/D (64 x 32 cells), cylinder 3 D behind the inflow, a 32 x 32
    /// window from 2 D to 10 D (the cylinder and 7 D of wake), 100 snapshots 1 D/U apart after
    /// 80 D/U of warm-up.
    fn default() -> Self {
        Self {
            cells_per_d: 4,
            domain: [16.0, 8.0],
            center: [3.0, 4.0],
            window_origin: [2.0, 0.0],
            out_size: [32, 32],
            pool: 1,
            warmup: 80.0,
            snapshots: 100,
            interval: 1.0,
            kick: 0.3,
        }
    }
}

impl WakeConfig {
    fn grid_cells(&self) -> [usize; 2] {
        let n = |l: f64| (l * self.cells_per_d as f64).round() as usize;
        [n(self.domain[0]), n(self.domain[1])]
    }

    fn window_start(&self) -> [usize; 2] {
        let n = |l: f64| (l * self.cells_per_d as f64).round() as usize;
        [n(self.window_origin[0]), n(self.window_origin[1])]
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        let [nx, ny] = self.grid_cells();
        let [x0, y0] = self.window_start();
        let [h, w] = self.out_size;
        let (h, w) = (h * self.pool, w * self.pool);
        if self.cells_per_d < 2 || self.pool == 0 {
            return bad(
                "WakeConfig.cells_per_d / pool",
                format!("{} / {}", self.cells_per_d, self.pool),
                "use at least 2 cells per diameter and a pooling factor of at least 1",
            );
        }
        if h == 0 || w == 0 || x0 + w > nx || y0 + h > ny {
            return bad(
                "WakeConfig window",
                format!("origin {:?}, size {:?} in a {nx} x {ny} grid", self.window_origin, self.out_size),
                "the output window must lie inside the channel",
            );
        }
        let positive = self.interval.is_finite() && self.interval > 0.0;
        if self.snapshots < 2 || !positive || !(self.warmup.is_finite() && self.warmup >= 0.0) {
            return bad(
                "WakeConfig snapshots",
                format!("{} every {} after {}", self.snapshots, self.interval, self.warmup),
                "use at least 2 snapshots, a positive interval and a non-negative warm-up",
            );
        }
        Ok(())
    }

    /// The obstacle mask on the output window, `[H, W]`: the fraction of the pooled grid cells
    /// whose centre is inside the cylinder (0 or 1 without pooling).
    pub fn mask(&self) -> Vec<f32> {
        let p = self.pool.max(1);
        let [ho, wo] = self.out_size;
        let fine = self.fine_mask();
        let w = wo * p;
        let mut m = vec![0.0; ho * wo];
        for j in 0..ho * p {
            for i in 0..w {
                m[(j / p) * wo + i / p] += fine[j * w + i] / (p * p) as f32;
            }
        }
        m
    }

    fn fine_mask(&self) -> Vec<f32> {
        let [h, w] = self.out_size;
        let (h, w) = (h * self.pool.max(1), w * self.pool.max(1));
        let [x0, y0] = self.window_start();
        let dx = 1.0 / self.cells_per_d as f64;
        let mut m = vec![0.0; h * w];
        for j in 0..h {
            for i in 0..w {
                let (x, y) = ((x0 + i) as f64 * dx + 0.5 * dx, (y0 + j) as f64 * dx + 0.5 * dx);
                let r2 = (x - self.center[0]).powi(2) + (y - self.center[1]).powi(2);
                m[j * w + i] = if r2 < 0.25 { 1.0 } else { 0.0 };
            }
        }
        m
    }
}

/// The snapshots of one Reynolds number.
#[derive(Debug, Clone)]
pub struct WakeCase {
    /// Reynolds number `U D / nu`.
    pub re: f64,
    /// Cell-centred velocity `(u, v)` on the output window, `[N, 2, H, W]` (`f32`).
    pub snapshots: Tensor,
}

/// Simulates the wake at Reynolds number `re` and returns the windowed snapshots.
pub fn simulate_wake(cfg: &WakeConfig, re: f64) -> Result<WakeCase> {
    cfg.validate()?;
    if !(re > 0.0 && re.is_finite()) {
        return Err(Error::InvalidConfig {
            name: "Reynolds number",
            value: re.to_string(),
            hint: "use a positive Reynolds number (the wake sheds above about 47)",
        });
    }
    let [nx, ny] = cfg.grid_cells();
    let t_end = cfg.warmup + (cfg.snapshots - 1) as f64 * cfg.interval;
    let text = format!(
        "name = \"wake_re{re}\"\n[grid]\nnx = {nx}\nny = {ny}\nlx = {lx}\nly = {ly}\n\
         [physics]\nkind = \"cylinder\"\nnu = {nu}\ninflow = 1.0\nadvection = \"central_rk4\"\nkick = {kick}\n\
         [[obstacles]]\nkind = \"circle\"\ncenter = [{cx}, {cy}]\nradius = 0.5\n\
         [time]\nt_end = {t_end}\ncfl = 0.7\nspeed = 1.5\nframes = 2\n",
        lx = cfg.domain[0],
        ly = cfg.domain[1],
        nu = 1.0 / re,
        kick = cfg.kick,
        cx = cfg.center[0],
        cy = cfg.center[1],
    );
    let scene_err = |e: pbdl_grid::scene::SceneError| Error::InvalidConfig {
        name: "wake scene",
        value: e.to_string(),
        hint: "check WakeConfig (domain, cylinder, resolution) and the Reynolds number",
    };
    let mut sim = Scene::from_toml_str(&text, "wake").map_err(scene_err)?.build().map_err(scene_err)?;
    let [h, w] = cfg.out_size;
    let (h, w) = (h * cfg.pool, w * cfg.pool);
    let [x0, y0] = cfg.window_start();
    let mut frames = Vec::with_capacity(cfg.snapshots);
    let mut next = 0;
    while next < cfg.snapshots {
        let target = cfg.warmup + next as f64 * cfg.interval;
        // Record at the first step at or past the target time (within half a step).
        if sim.time() >= target - 0.5 * sim.dt() {
            let fields = sim.fields().map_err(scene_err)?;
            let vel = fields
                .into_iter()
                .find(|(n, _)| n == "velocity")
                .map(|(_, t)| t)
                .ok_or_else(|| Error::shape("wake simulation output", "a `velocity` field", "none"))?;
            let window = vel.narrow(1, y0, h)?.narrow(2, x0, w)?.to_dtype(DType::F32)?;
            let window = if cfg.pool > 1 { window.unsqueeze(0)?.avg_pool2d(cfg.pool)?.squeeze(0)? } else { window };
            frames.push(window);
            next += 1;
            continue;
        }
        if sim.step_index() >= sim.steps() {
            break;
        }
        sim.step().map_err(scene_err)?;
    }
    if frames.len() != cfg.snapshots {
        return Err(Error::shape("number of wake snapshots", cfg.snapshots, frames.len()));
    }
    Ok(WakeCase { re, snapshots: Tensor::stack(&frames, 0)? })
}

/// Per-pixel mean and (population) standard deviation over snapshots or samples, `[C, H, W]` each.
#[derive(Debug, Clone)]
pub struct FieldStats {
    /// The mean field.
    pub mean: Tensor,
    /// The standard-deviation field.
    pub std: Tensor,
}

impl FieldStats {
    /// The statistics of `[N, C, H, W]` samples (`N >= 2`).
    pub fn of(samples: &Tensor) -> Result<Self> {
        let (n, ..) =
            samples.dims4().map_err(|_| Error::shape("samples (layout [N, C, H, W])", "rank 4", samples.dims()))?;
        if n < 2 {
            return Err(Error::shape("number of samples for a standard deviation", ">= 2", n));
        }
        let x = samples.to_dtype(DType::F64)?;
        let mean = x.mean(0)?;
        let var = x.broadcast_sub(&mean)?.sqr()?.mean(0)?;
        Ok(Self { mean, std: var.sqrt()? })
    }
}

/// The three condition channels `[3, H, W]` of one case: inflow speed field (1 everywhere: all
/// cases share `U = 1`), the obstacle mask, and `Re / re_scale` as a constant field.
pub fn condition(cfg: &WakeConfig, re: f64, re_scale: f64, device: &Device) -> Result<Tensor> {
    let [h, w] = cfg.out_size;
    let inflow = Tensor::ones((1, h, w), DType::F32, device)?;
    let mask = Tensor::from_vec(cfg.mask(), (1, h, w), device)?;
    let re_field = (Tensor::ones((1, h, w), DType::F32, device)? * (re / re_scale))?;
    Ok(Tensor::cat(&[&inflow, &mask, &re_field], 0)?)
}
