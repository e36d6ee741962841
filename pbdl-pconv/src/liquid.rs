//! CConv's liquid network (Ummenhofer et al. 2020, "Lagrangian fluid simulation with continuous
//! convolutions") in 2D at CPU size, trained on dam breaks of pbdl-particles' own WCSPH solver.
//!
//! * **Data** ([`LiquidDataset`]): water columns of different widths and heights collapsing in
//!   one closed tank (scene `dam_break`, WCSPH, wall particles), frames `frame_dt` apart; the
//!   train/test split is by scene. The particle spacing is 0.05 m and the frame step 1/50 s,
//!   CConv's own scale (`r_p = 0.025` m, spacing `2 r_p`, `dt = 1/50` s) under the same gravity,
//!   so a frame moves a particle at most about `sqrt(2 g H) dt ≈ 0.1` m, two spacings, as in
//!   CConv's data; our `dam_break` scene writes its frames at the same 0.02 s.
//! * **Network** ([`LiquidNet`]): layer 0 concatenates a CConv over the fluid particles on
//!   `[1, v*]`, a CConv from the wall particles on their inward normals and a dense layer on
//!   `[1, v*]`; then CConv + dense layers on the ReLU of the previous output, with a residual on
//!   the middle layer (equal widths), the last layer 2 channels, times 1/128: a position
//!   correction. Filters 4x4, bilinear, ball-to-cube map, poly6 window; support radius
//!   [`LiquidConfig::radius_in_spacings`] spacings.
//! * **Step** ([`LiquidNet::step`]): `v* = v + dt g`, `x* = x + dt (v* + v)/2`,
//!   `x' = x* + Δx(x*, v*)`, `v' = (x' - x)/dt`.
//! * **Loss** ([`train`]): CConv's `mean_i exp(-N_i/40) |x̂_i - x_i|^0.5` (`N_i`: fluid
//!   neighbours at `x*`), over a two-step rollout (weights 0.5 each), times 128; Adam 1e-3,
//!   eps 1e-6, the learning rate halved at 50, 60, 70, 80 and 90% of the steps (CConv: 25k..45k
//!   of 50k); mirror augmentation `x -> W - x` (2D's rotation about gravity), through
//!   [`pbdl_core::train::TrainLoop`] (checkpoints, exact resume).
//! * **Evaluation** ([`evaluate`]): the learned model rolled out from a test scene's first frame
//!   for [`LiquidConfig::eval_factor`] times the training horizon (the frames of a training
//!   sequence) against the SPH reference: mean particle distance per frame, finiteness,
//!   escapes from the tank, kinetic energy; [`write_gif`] draws learned | SPH side by side.
//!
//! The search radius: CConv's filter *extent* is `1.5 · 6 r_p = 4.5` spacings and its search
//! radius half of it; [`LiquidConfig::radius_in_spacings`] defaults to that radius, 2.25
//! spacings (about 15 neighbours in 2D).
//!
//! Status: at this CPU budget (12000 updates of batch 2, CConv: 50k of batch 16) the learned
//! liquid stays finite and in the tank for 5x its training horizon only with a raised learning
//! rate ([`LiquidTrainConfig::acceptance`]), and it spreads more than the SPH water settles;
//! see the notes of `tests/liquid_tests.rs`.
//!
//! ```no_run
//! use pbdl_pconv::liquid::{evaluate, train, LiquidConfig, LiquidDataset, LiquidTrainConfig};
//!
//! let data = LiquidDataset::generate(&LiquidConfig::default())?;
//! let trained = train(&data, &LiquidTrainConfig::default(), None)?;
//! let report = evaluate(&data, &trained.net, 0)?;
//! println!("mean distance at the end: {:.3} m", report.mean_distance.last().unwrap());
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::filter::FilterSpec;
use crate::graph::PairGraph;
use crate::layer::{insert, ContinuousConv};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use pbdl_particles::scene::Scene;
use pbdl_particles::Evolve;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

/// One water column in the tank (lengths in metres, lower left corner of the tank at 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Column {
    /// Column width.
    pub width: f64,
    /// Column height.
    pub height: f64,
}

/// The data set's geometry and split.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LiquidConfig {
    /// Particle spacing in m (CConv: `2 r_p = 0.05`).
    pub spacing: f64,
    /// Tank width in m (a multiple of the spacing).
    pub tank_width: f64,
    /// Tank height in m (closed tank).
    pub tank_height: f64,
    /// Gravity in m/s².
    pub g: f64,
    /// Time between frames in s (CConv: 1/50).
    pub frame_dt: f64,
    /// Frames of a training sequence, the initial one included: the training horizon.
    pub frames: usize,
    /// The test rollouts run `eval_factor * frames` frames.
    pub eval_factor: usize,
    /// Training scenes.
    pub train: Vec<Column>,
    /// Held-out scenes.
    pub test: Vec<Column>,
    /// Convolution support radius in particle spacings (CConv: 2.25, half its filter extent).
    pub radius_in_spacings: f64,
}

impl Default for LiquidConfig {
    /// The acceptance data: a 2 m x 1.6 m tank, spacing 0.05 m, six training columns of
    /// 300 to 400 particles, two test columns, 40 frames (0.8 s) per training sequence,
    /// 200-frame (4 s) test references.
    fn default() -> Self {
        let c = |width, height| Column { width, height };
        LiquidConfig {
            spacing: 0.05,
            tank_width: 2.0,
            tank_height: 1.6,
            g: 9.81,
            frame_dt: 0.02,
            frames: 40,
            eval_factor: 5,
            train: vec![c(0.8, 1.2), c(1.0, 0.8), c(0.6, 1.3), c(0.9, 1.0), c(0.7, 1.1), c(1.1, 0.7)],
            test: vec![c(0.75, 1.15), c(0.95, 0.9)],
            radius_in_spacings: 2.25,
        }
    }
}

impl LiquidConfig {
    /// A tiny data set for fast tests: spacing 0.1 m, a 1.2 m x 1 m tank, two training
    /// columns of 24-30 particles and one test column, 6 frames per sequence.
    pub fn tiny() -> Self {
        let c = |width, height| Column { width, height };
        LiquidConfig {
            spacing: 0.1,
            tank_width: 1.2,
            tank_height: 1.0,
            frames: 6,
            eval_factor: 5,
            train: vec![c(0.4, 0.6), c(0.5, 0.6)],
            test: vec![c(0.4, 0.7)],
            ..Self::default()
        }
    }

    /// The convolution radius in m.
    pub fn radius(&self) -> f64 {
        self.radius_in_spacings * self.spacing
    }

    /// Frames of the test references (initial frame included): `eval_factor * frames`.
    pub fn eval_frames(&self) -> usize {
        self.eval_factor * self.frames
    }

    fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(Error::Config { field, reason });
        let pos = |v: f64| v > 0.0 && v.is_finite();
        if !(pos(self.spacing) && pos(self.tank_width) && pos(self.tank_height) && pos(self.frame_dt)) {
            return bad("spacing", "spacing, tank size and frame_dt must be positive and finite".into());
        }
        if !(self.g.is_finite() && self.g >= 0.0) {
            return bad("g", format!("{}; must be finite and non-negative", self.g));
        }
        if self.frames < 3 {
            return bad("frames", format!("{}; the two-step loss needs at least 3", self.frames));
        }
        if self.eval_factor < 1 {
            return bad("eval_factor", "0; use at least 1".into());
        }
        if self.train.is_empty() || self.test.is_empty() {
            return bad("train", "give at least one training and one test column".into());
        }
        if !(self.radius_in_spacings >= 1.0 && self.radius_in_spacings.is_finite()) {
            return bad("radius_in_spacings", format!("{}; use at least 1", self.radius_in_spacings));
        }
        for c in self.train.iter().chain(&self.test) {
            if !(pos(c.width) && pos(c.height) && c.width <= self.tank_width && c.height <= self.tank_height) {
                return bad("train", format!("{c:?} must be positive and fit the tank"));
            }
        }
        Ok(())
    }
}

/// Positions and velocities of the fluid particles, `[n]` points.
#[derive(Clone, Debug, PartialEq)]
pub struct LiquidFrame {
    /// Positions in m.
    pub x: Vec<[f64; 2]>,
    /// Velocities in m/s.
    pub v: Vec<[f64; 2]>,
}

/// One simulated scene.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// The column it started from.
    pub column: Column,
    /// Frames `frame_dt` apart, the initial one first.
    pub frames: Vec<LiquidFrame>,
}

/// The tank's walls, shared by all scenes.
#[derive(Clone, Debug)]
pub struct Walls {
    /// Wall particle positions.
    pub x: Vec<[f64; 2]>,
    /// Inward unit normals (towards the nearest point of the tank's interior).
    pub normals: Vec<[f64; 2]>,
    /// The tank `[lo, hi]`.
    pub tank: [[f64; 2]; 2],
    /// `x` as an f32 tensor `[m, 2]`.
    positions: Tensor,
    /// `normals` as an f32 tensor `[m, 2]`.
    features: Tensor,
}

/// Training and test scenes.
#[derive(Clone, Debug)]
pub struct LiquidDataset {
    /// The configuration.
    pub config: LiquidConfig,
    /// Training sequences (`frames` frames each).
    pub train: Vec<Sequence>,
    /// Test sequences (`eval_factor * frames` frames each).
    pub test: Vec<Sequence>,
    /// The walls.
    pub walls: Walls,
    /// The SPH solver's time to produce the data, in s.
    pub seconds: f64,
}

fn dam_scene(cfg: &LiquidConfig, c: &Column) -> Result<Scene> {
    let mut scene = Scene::builtin("dam_break")?;
    let db = scene.dam_break.as_mut().ok_or_else(|| Error::Config {
        field: "scene",
        reason: "the built-in dam_break scene has no [dam_break] section".into(),
    })?;
    let g = &mut db.geometry;
    g.a = c.width;
    g.height_ratio = c.height / c.width;
    g.tank_width = cfg.tank_width / c.width;
    g.tank_height = cfg.tank_height / c.width;
    g.dx = cfg.spacing / c.width;
    g.g = cfg.g;
    Ok(scene)
}

/// A tank `[lo, hi]`.
type Tank = [[f64; 2]; 2];

fn points(flat: &[f64]) -> Vec<[f64; 2]> {
    flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect()
}

impl LiquidDataset {
    /// Runs the WCSPH dam break for every column.
    pub fn generate(cfg: &LiquidConfig) -> Result<Self> {
        cfg.validate()?;
        let start = std::time::Instant::now();
        let run = |c: &Column, frames: usize| -> Result<(Sequence, Vec<[f64; 2]>, Tank)> {
            let mut sim = dam_scene(cfg, c)?.build(0, None)?;
            let mut out = Vec::with_capacity(frames);
            for f in 0..frames {
                if f > 0 {
                    sim.run_until(f as f64 * cfg.frame_dt)?;
                }
                let fr = sim.frame()?;
                out.push(LiquidFrame { x: points(&fr.positions), v: points(&fr.velocities) });
            }
            let tank = match &sim {
                pbdl_particles::scene::Stepper::Wcsph(s) => s.container(),
                _ => [[0.0, 0.0], [cfg.tank_width, cfg.tank_height]],
            };
            Ok((Sequence { column: *c, frames: out }, points(&sim.fixed_positions()), tank))
        };
        let mut walls = None;
        let mut train = Vec::new();
        for c in &cfg.train {
            let (s, w, t) = run(c, cfg.frames)?;
            walls.get_or_insert((w, t));
            train.push(s);
        }
        let test = cfg.test.iter().map(|c| run(c, cfg.eval_frames()).map(|r| r.0)).collect::<Result<Vec<_>>>()?;
        let (wx, tank) = walls.expect("at least one training column");
        let normals: Vec<[f64; 2]> = wx
            .iter()
            .map(|p| {
                let q = [p[0].clamp(tank[0][0], tank[1][0]), p[1].clamp(tank[0][1], tank[1][1])];
                let d = [q[0] - p[0], q[1] - p[1]];
                let n = (d[0] * d[0] + d[1] * d[1]).sqrt().max(1e-12);
                [d[0] / n, d[1] / n]
            })
            .collect();
        let walls = Walls { positions: tensor(&wx)?, features: tensor(&normals)?, x: wx, normals, tank };
        Ok(LiquidDataset { config: cfg.clone(), train, test, walls, seconds: start.elapsed().as_secs_f64() })
    }

    /// Fluid particles of each training and test scene.
    pub fn particle_counts(&self) -> (Vec<usize>, Vec<usize>) {
        let n = |s: &[Sequence]| s.iter().map(|q| q.frames[0].x.len()).collect();
        (n(&self.train), n(&self.test))
    }
}

fn tensor(p: &[[f64; 2]]) -> Result<Tensor> {
    let flat: Vec<f32> = p.iter().flat_map(|q| [q[0] as f32, q[1] as f32]).collect();
    Ok(Tensor::from_vec(flat, (p.len(), 2), &Device::Cpu)?)
}

fn to_points(t: &Tensor) -> Result<Vec<[f64; 2]>> {
    let flat = t.flatten_all()?.to_vec1::<f32>()?;
    Ok(flat.chunks_exact(2).map(|c| [c[0] as f64, c[1] as f64]).collect())
}

/// Widths of a [`LiquidNet`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetShape {
    /// Channels of each of layer 0's three branches (CConv: 32).
    pub branch: usize,
    /// Widths of the later layers before the 2-channel output (CConv: `[64, 64]`); a layer
    /// with as many outputs as inputs adds its input (the residual).
    pub hidden: Vec<usize>,
    /// Basis functions per axis (CConv: 4).
    pub terms: usize,
}

impl Default for NetShape {
    /// CPU width: branches of 16 (48 channels), hidden `[32, 32]`, 4x4 filters.
    fn default() -> Self {
        NetShape { branch: 16, hidden: vec![32, 32], terms: 4 }
    }
}

#[derive(Clone, Debug)]
struct Dense {
    weight: Tensor,
    bias: Tensor,
}

impl Dense {
    fn new(varmap: &VarMap, name: &str, c_in: usize, c_out: usize, seed: u64) -> Result<Self> {
        let bound = 1.0 / (c_in as f64).sqrt();
        let w = pbdl_core::seed::rand_uniform((c_in, c_out), -bound, bound, DType::F32, &Device::Cpu, seed)?;
        Ok(Dense {
            weight: insert(varmap, &format!("{name}.weight"), w)?,
            bias: insert(varmap, &format!("{name}.bias"), Tensor::zeros(c_out, DType::F32, &Device::Cpu)?)?,
        })
    }

    fn forward(&self, h: &Tensor) -> Result<Tensor> {
        Ok(h.matmul(&self.weight)?.broadcast_add(&self.bias)?)
    }
}

/// CConv's fluid network at CPU width (see the module documentation).
#[derive(Clone, Debug)]
pub struct LiquidNet {
    shape: NetShape,
    radius: f64,
    fluid0: ContinuousConv,
    wall0: ContinuousConv,
    dense0: Dense,
    convs: Vec<ContinuousConv>,
    dense: Vec<Dense>,
}

/// Gravity, time step and walls for [`LiquidNet::step`].
#[derive(Clone, Copy, Debug)]
pub struct StepContext<'a> {
    /// Gravity magnitude (acting along -y).
    pub g: f64,
    /// Time step.
    pub dt: f64,
    /// The walls.
    pub walls: &'a Walls,
}

/// The output of one [`LiquidNet::step`].
#[derive(Clone, Debug)]
pub struct StepOutput {
    /// New positions `[n, 2]`.
    pub x: Tensor,
    /// New velocities `[n, 2]`.
    pub v: Tensor,
    /// Fluid neighbours of each particle at `x*`.
    pub neighbors: Vec<usize>,
}

impl LiquidNet {
    /// Creates the variables in `varmap` (f32) from `seed`.
    pub fn new(varmap: &VarMap, shape: NetShape, radius: f64, seed: u64) -> Result<Self> {
        if shape.branch == 0 || shape.hidden.contains(&0) || shape.terms < 2 {
            return Err(Error::Config {
                field: "shape",
                reason: format!("{shape:?}; widths must be positive, at least 2 terms"),
            });
        }
        let spec = FilterSpec::cconv(2, shape.terms, radius);
        let s = |k: u64| pbdl_core::noise::stream_seed(seed, k);
        let b = shape.branch;
        let fluid0 = ContinuousConv::new(varmap, "fluid0", spec, 3, b, true, s(0))?;
        let wall0 = ContinuousConv::new(varmap, "wall0", spec, 2, b, true, s(1))?;
        let dense0 = Dense::new(varmap, "dense0", 3, b, s(2))?;
        let mut convs = Vec::new();
        let mut dense = Vec::new();
        let mut c_in = 3 * b;
        for (l, &c_out) in shape.hidden.iter().chain(std::iter::once(&2)).enumerate() {
            let l = l + 1;
            convs.push(ContinuousConv::new(varmap, &format!("conv{l}"), spec, c_in, c_out, true, s(2 * l as u64 + 1))?);
            dense.push(Dense::new(varmap, &format!("dense{l}"), c_in, c_out, s(2 * l as u64 + 2))?);
            c_in = c_out;
        }
        Ok(LiquidNet { shape, radius, fluid0, wall0, dense0, convs, dense })
    }

    /// The widths.
    pub fn shape(&self) -> &NetShape {
        &self.shape
    }

    /// The support radius.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The position correction `[n, 2]` (already times 1/128) at positions `x` with velocities
    /// `v` (`[n, 2]` each), given the fluid self graph and the wall-to-fluid graph at `x`.
    pub fn correction(
        &self,
        fluid: &Arc<PairGraph>,
        wall: &Arc<PairGraph>,
        x: &Tensor,
        v: &Tensor,
        walls: &Walls,
    ) -> Result<Tensor> {
        let n = x.dim(0)?;
        let feats = Tensor::cat(&[&Tensor::ones((n, 1), DType::F32, x.device())?, v], 1)?;
        let d_fluid = fluid.offsets(x, x)?;
        let d_wall = wall.offsets(x, &walls.positions)?;
        let a = self.fluid0.forward(fluid, &feats, &d_fluid)?;
        let b = self.wall0.forward(wall, &walls.features, &d_wall)?;
        let c = self.dense0.forward(&feats)?;
        let mut h = Tensor::cat(&[&a, &b, &c], 1)?;
        for (conv, dense) in self.convs.iter().zip(&self.dense) {
            let inp = h.relu()?;
            let y = (conv.forward(fluid, &inp, &d_fluid)? + dense.forward(&inp)?)?;
            h = if y.dims() == h.dims() { (y + h)? } else { y };
        }
        Ok((h * (1.0 / 128.0))?)
    }

    /// One explicit step plus the learned correction: `v* = v + dt g`, `x* = x + dt (v* + v)/2`,
    /// `x' = x* + Δx(x*, v*)`, `v' = (x' - x)/dt`; differentiable in `x`, `v` and the weights.
    pub fn step(&self, ctx: &StepContext<'_>, x: &Tensor, v: &Tensor) -> Result<StepOutput> {
        let n = x.dim(0)?;
        let gv = Tensor::from_vec(vec![0.0f32, -(ctx.dt * ctx.g) as f32], (1, 2), x.device())?;
        let v_star = v.broadcast_add(&gv)?;
        let x_star = (x + ((&v_star + v)? * (0.5 * ctx.dt))?)?;
        let pts = to_points(&x_star)?;
        if let Some(p) = pts.iter().find(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return Err(Error::NonFinite { what: "liquid position", detail: format!("{p:?}") });
        }
        // A particle far outside the tank would make the search grid huge: a typed error.
        let [lo, hi] = ctx.walls.tank;
        let far = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        if let Some(p) = pts.iter().find(|p| (0..2).any(|a| p[a] < lo[a] - far || p[a] > hi[a] + far)) {
            return Err(Error::NonFinite { what: "liquid position (far outside the tank)", detail: format!("{p:?}") });
        }
        let domain = PairGraph::bounding_domain(self.radius, &[&pts, &ctx.walls.x])?;
        let fluid = Arc::new(PairGraph::build_self(&domain, self.radius, &pts)?);
        let wall = Arc::new(PairGraph::build_cross(&domain, self.radius, &pts, &ctx.walls.x)?);
        let dx = self.correction(&fluid, &wall, &x_star, &v_star, ctx.walls)?;
        let x_new = (x_star + dx)?;
        let v_new = ((&x_new - x)? * (1.0 / ctx.dt))?;
        debug_assert_eq!(fluid.n_receivers(), n);
        Ok(StepOutput { x: x_new, v: v_new, neighbors: fluid.neighbor_counts() })
    }
}

/// Training settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LiquidTrainConfig {
    /// The network's widths.
    pub shape: NetShape,
    /// Adam updates.
    pub steps: u64,
    /// Two-step samples per update (CConv: 16).
    pub batch: usize,
    /// Initial learning rate (CConv: 1e-3).
    pub lr: f64,
    /// Adam's epsilon (CConv: 1e-6).
    pub eps: f64,
    /// Mirror the scene `x -> W - x` with probability 1/2 (2D's rotation about gravity).
    pub mirror: bool,
    /// Seed of the weights and of the sample draws.
    pub seed: u64,
    /// Write a checkpoint every this many steps when a run directory is given (0: a tenth of the steps).
    pub checkpoint_every: u64,
    /// Stop after this many steps (an interrupted run; the schedule stays that of `steps`).
    pub stop_after: Option<u64>,
}

impl Default for LiquidTrainConfig {
    fn default() -> Self {
        LiquidTrainConfig {
            shape: NetShape::default(),
            steps: 3000,
            batch: 2,
            lr: 1e-3,
            eps: 1e-6,
            mirror: true,
            seed: 0,
            checkpoint_every: 0,
            stop_after: None,
        }
    }
}

impl LiquidTrainConfig {
    /// The acceptance run: the default widths, 12000 updates of batch 2 (about 12 min on two
    /// shared cores; CConv: 50k of batch 16), Adam eps 1e-6, initial learning rate 3e-3 with
    /// CConv's halvings. CConv's 1e-3 at this short budget (first acceptance run) gave a
    /// two-step loss of 2.63 and a rollout that lost particles at frame 91; 3e-3 gave 2.55 and
    /// two stable 200-frame rollouts.
    pub fn acceptance() -> Self {
        LiquidTrainConfig { steps: 12_000, batch: 2, lr: 3e-3, ..Default::default() }
    }

    /// The learning rate at `step`: `lr`, halved at 50, 60, 70, 80 and 90% of the steps.
    pub fn lr_at(&self, step: u64) -> f64 {
        let frac = step as f64 / self.steps.max(1) as f64;
        let halvings = [0.5, 0.6, 0.7, 0.8, 0.9].iter().filter(|&&f| frac >= f).count();
        self.lr * 0.5f64.powi(halvings as i32)
    }
}

/// A trained network.
#[derive(Clone)]
pub struct TrainedLiquid {
    /// The network.
    pub net: LiquidNet,
    /// Its variables.
    pub varmap: VarMap,
    /// `(step, loss)` of this call's updates.
    pub losses: Vec<(u64, f64)>,
    /// The step this call resumed from.
    pub start_step: u64,
    /// Seconds of training in this call.
    pub seconds: f64,
}

impl TrainedLiquid {
    /// Mean loss of the first `k` and the last `k` updates of this call.
    pub fn loss_ends(&self, k: usize) -> (f64, f64) {
        let n = self.losses.len();
        let k = k.clamp(1, n.max(1));
        let mean = |s: &[(u64, f64)]| s.iter().map(|l| l.1).sum::<f64>() / s.len().max(1) as f64;
        (mean(&self.losses[..k.min(n)]), mean(&self.losses[n.saturating_sub(k)..]))
    }
}

/// CConv's loss of one step: `mean_i exp(-N_i/40) (|x̂_i - x_i|² + 1e-12)^(1/4)`.
fn step_loss(pred: &Tensor, truth: &Tensor, neighbors: &[usize]) -> Result<Tensor> {
    let n = neighbors.len();
    let w: Vec<f32> = neighbors.iter().map(|&c| (-(c as f64) / 40.0).exp() as f32).collect();
    let w = Tensor::from_vec(w, n, pred.device())?;
    let d = ((pred - truth)?.sqr()?.sum(1)? + 1e-12)?.powf(0.25)?;
    Ok((d * w)?.mean_all()?)
}

/// The two-step loss of sample `(sequence, t, mirrored)`.
fn sample_loss(data: &LiquidDataset, net: &LiquidNet, seq: &Sequence, t: usize, mirror: bool) -> Result<Tensor> {
    let w = data.walls.tank[1][0] + data.walls.tank[0][0];
    let flip = |p: &[[f64; 2]], vel: bool| -> Vec<[f64; 2]> {
        if !mirror {
            return p.to_vec();
        }
        p.iter().map(|q| if vel { [-q[0], q[1]] } else { [w - q[0], q[1]] }).collect()
    };
    let ctx = StepContext { g: data.config.g, dt: data.config.frame_dt, walls: &data.walls };
    let x0 = tensor(&flip(&seq.frames[t].x, false))?;
    let v0 = tensor(&flip(&seq.frames[t].v, true))?;
    let s1 = net.step(&ctx, &x0, &v0)?;
    let l1 = step_loss(&s1.x, &tensor(&flip(&seq.frames[t + 1].x, false))?, &s1.neighbors)?;
    let s2 = net.step(&ctx, &s1.x, &s1.v)?;
    let l2 = step_loss(&s2.x, &tensor(&flip(&seq.frames[t + 2].x, false))?, &s2.neighbors)?;
    Ok(((l1 + l2)? * (0.5 * 128.0))?)
}

/// The two-step training loss (unmirrored) averaged over every start frame of `sequences`,
/// a deterministic measure of fit (the training loss of one update is a random sample of it).
pub fn dataset_loss(data: &LiquidDataset, net: &LiquidNet, sequences: &[Sequence]) -> Result<f64> {
    let (mut sum, mut count) = (0.0, 0usize);
    for seq in sequences {
        for t in 0..seq.frames.len().saturating_sub(2) {
            sum += sample_loss(data, net, seq, t, false)?.to_scalar::<f32>()? as f64;
            count += 1;
        }
    }
    Ok(sum / count.max(1) as f64)
}

/// Trains a [`LiquidNet`] on the training sequences. With `run_dir`, checkpoints (weights and
/// Adam's state) and `loss.csv` go there and a stopped run resumes exactly; the sample draws
/// of step `k` follow from `(seed, k)`.
pub fn train(data: &LiquidDataset, cfg: &LiquidTrainConfig, run_dir: Option<&Path>) -> Result<TrainedLiquid> {
    if cfg.batch == 0 || !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return Err(Error::Config { field: "batch", reason: format!("batch {} lr {}", cfg.batch, cfg.lr) });
    }
    let varmap = VarMap::new();
    let net = LiquidNet::new(&varmap, cfg.shape.clone(), data.config.radius(), cfg.seed)?;
    let loop_cfg = LoopConfig {
        steps: cfg.stop_after.map_or(cfg.steps, |s| s.min(cfg.steps)),
        checkpoint_every: if cfg.checkpoint_every > 0 { cfg.checkpoint_every } else { (cfg.steps / 10).max(1) },
        dir: run_dir.map(Path::to_path_buf),
        progress: run_dir.is_some(),
        ..Default::default()
    };
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, eps: cfg.eps, ..Default::default() });
    let start = std::time::Instant::now();
    let train_loop = TrainLoop::resume(&varmap, loop_cfg)?;
    let start_step = train_loop.start();
    let report = train_loop.run::<Error>(
        &adam,
        |s| cfg.lr_at(s),
        CheckpointMeta::at,
        |step| {
            let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed, step));
            let mut loss: Option<Tensor> = None;
            for _ in 0..cfg.batch {
                let seq = &data.train[rng.random_range(0..data.train.len())];
                let t = rng.random_range(0..seq.frames.len() - 2);
                let mirror = cfg.mirror && rng.random_bool(0.5);
                let l = sample_loss(data, &net, seq, t, mirror)?;
                loss = Some(match loss {
                    None => l,
                    Some(acc) => (acc + l)?,
                });
            }
            Ok((loss.expect("batch >= 1") / cfg.batch as f64)?)
        },
    )?;
    Ok(TrainedLiquid { net, varmap, losses: report.losses, start_step, seconds: start.elapsed().as_secs_f64() })
}

/// A learned rollout against its SPH reference.
#[derive(Clone, Debug)]
pub struct RolloutReport {
    /// The test column.
    pub column: Column,
    /// Frames compared (the initial one included), up to the first broken one.
    pub frames: usize,
    /// Frames asked for.
    pub frames_requested: usize,
    /// Per frame: mean over particles of `|x_learned - x_sph|` in m.
    pub mean_distance: Vec<f64>,
    /// Per frame: mean distance of the SPH reference from its initial frame in m, the
    /// [`RolloutReport::mean_distance`] of a model that keeps every particle where it started
    /// (a scale for the learned distances).
    pub frozen_distance: Vec<f64>,
    /// Per frame: mean kinetic energy per unit mass `|v|²/2` of the learned rollout.
    pub kinetic_learned: Vec<f64>,
    /// Per frame: the same of the SPH reference.
    pub kinetic_reference: Vec<f64>,
    /// Per frame: particles of the learned rollout outside the tank grown by
    /// [`ESCAPE_MARGIN_SPACINGS`] spacings.
    pub escaped: Vec<usize>,
    /// The first frame with a non-finite learned state or a failed step, if any.
    pub first_broken: Option<usize>,
    /// Learned positions of every frame.
    pub learned: Vec<Vec<[f64; 2]>>,
    /// Learned velocities of every frame.
    pub learned_v: Vec<Vec<[f64; 2]>>,
    /// Seconds of the learned rollout.
    pub seconds: f64,
}

/// How far outside the tank (in particle spacings) a particle must be to count as escaped: past
/// the first wall layer's centre and half a spacing more.
pub const ESCAPE_MARGIN_SPACINGS: f64 = 1.0;

impl RolloutReport {
    /// Every frame finite, every step done, no particle escaped.
    pub fn stable(&self) -> bool {
        self.first_broken.is_none() && self.frames == self.frames_requested && self.escaped.iter().all(|&e| e == 0)
    }

    /// Largest learned mean kinetic energy over the reference's largest.
    pub fn kinetic_ratio(&self) -> f64 {
        let m = |v: &[f64]| v.iter().fold(0.0f64, |a, &b| a.max(b));
        m(&self.kinetic_learned) / m(&self.kinetic_reference).max(1e-300)
    }

    /// Mean of [`RolloutReport::mean_distance`] over frames `range` (clamped to the frames done).
    pub fn mean_distance_over(&self, range: std::ops::Range<usize>) -> f64 {
        let end = range.end.min(self.mean_distance.len());
        let s = &self.mean_distance[range.start.min(end)..end];
        s.iter().sum::<f64>() / s.len().max(1) as f64
    }
}

fn kinetic(v: &[[f64; 2]]) -> f64 {
    v.iter().map(|q| 0.5 * (q[0] * q[0] + q[1] * q[1])).sum::<f64>() / v.len().max(1) as f64
}

/// Rolls `net` out from the first frame of test scene `test_index` for the reference's frames
/// (`eval_factor * frames`) and compares with the SPH reference frame by frame.
pub fn evaluate(data: &LiquidDataset, net: &LiquidNet, test_index: usize) -> Result<RolloutReport> {
    evaluate_for(data, net, test_index, usize::MAX)
}

/// [`evaluate`] for the first `frames` frames only (the initial one included).
pub fn evaluate_for(data: &LiquidDataset, net: &LiquidNet, test_index: usize, frames: usize) -> Result<RolloutReport> {
    let seq = data.test.get(test_index).ok_or_else(|| Error::Config {
        field: "test_index",
        reason: format!("{test_index}; there are {} test scenes", data.test.len()),
    })?;
    let cfg = &data.config;
    let ctx = StepContext { g: cfg.g, dt: cfg.frame_dt, walls: &data.walls };
    let [lo, hi] = data.walls.tank;
    let m = ESCAPE_MARGIN_SPACINGS * cfg.spacing;
    let start = std::time::Instant::now();
    let mut r = RolloutReport {
        column: seq.column,
        frames: 0,
        frames_requested: seq.frames.len().min(frames),
        mean_distance: Vec::new(),
        frozen_distance: Vec::new(),
        kinetic_learned: Vec::new(),
        kinetic_reference: Vec::new(),
        escaped: Vec::new(),
        first_broken: None,
        learned: Vec::new(),
        learned_v: Vec::new(),
        seconds: 0.0,
    };
    let (mut x, mut v) = (seq.frames[0].x.clone(), seq.frames[0].v.clone());
    for (f, reference) in seq.frames.iter().take(frames).enumerate() {
        if f > 0 {
            let step = net.step(&ctx, &tensor(&x)?, &tensor(&v)?);
            let out = match step {
                Ok(out) => out,
                Err(_) => {
                    r.first_broken = Some(f);
                    break;
                }
            };
            x = to_points(&out.x)?;
            v = to_points(&out.v)?;
            if x.iter().chain(&v).any(|p| !(p[0].is_finite() && p[1].is_finite())) {
                r.first_broken = Some(f);
                break;
            }
        }
        let dist = |p: &[[f64; 2]], q: &[[f64; 2]]| {
            p.iter().zip(q).map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()).sum::<f64>()
                / p.len().max(1) as f64
        };
        r.mean_distance.push(dist(&x, &reference.x));
        r.frozen_distance.push(dist(&seq.frames[0].x, &reference.x));
        r.kinetic_learned.push(kinetic(&v));
        r.kinetic_reference.push(kinetic(&reference.v));
        r.escaped.push(
            x.iter().filter(|p| p[0] < lo[0] - m || p[0] > hi[0] + m || p[1] < lo[1] - m || p[1] > hi[1] + m).count(),
        );
        r.learned.push(x.clone());
        r.learned_v.push(v.clone());
        r.frames = f + 1;
    }
    r.seconds = start.elapsed().as_secs_f64();
    Ok(r)
}

/// Side-by-side rasters learned | SPH of every frame, their height and width.
#[cfg(feature = "viz")]
fn side_by_side(data: &LiquidDataset, report: &RolloutReport) -> Result<(Vec<Vec<f64>>, usize, usize)> {
    use pbdl_particles::render::scatter;
    let seq = data
        .test
        .iter()
        .find(|s| s.column == report.column)
        .ok_or_else(|| Error::Config { field: "report", reason: "its test column is not in the data set".into() })?;
    let sp = data.config.spacing;
    let [t0, t1] = data.walls.tank;
    let pad = 4.0 * sp;
    let (lo, hi) = ([t0[0] - pad, t0[1] - pad], [t1[0] + pad, t1[1] + pad]);
    let ppu = 200.0 / (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let radius_px = (0.75 * sp * ppu).max(0.6);
    let speed = |v: &[[f64; 2]]| -> Vec<f64> { v.iter().map(|q| (q[0] * q[0] + q[1] * q[1]).sqrt()).collect() };
    let raster = |x: &[[f64; 2]], v: &[[f64; 2]]| {
        let mut pts = data.walls.x.clone();
        let mut vals = vec![0.0; pts.len()];
        pts.extend_from_slice(x);
        vals.extend(speed(v));
        scatter(&pts, &vals, lo, hi, ppu, radius_px)
    };
    let mut frames = Vec::with_capacity(report.frames);
    let (mut h, mut w) = (0, 0);
    for f in 0..report.frames {
        let a = raster(&report.learned[f], &report.learned_v[f]);
        let b = raster(&seq.frames[f].x, &seq.frames[f].v);
        let gap = 4;
        (h, w) = (a.h, a.w + gap + b.w);
        let mut data = vec![f64::NAN; h * w];
        for y in 0..h {
            data[y * w..y * w + a.w].copy_from_slice(&a.data[y * a.w..(y + 1) * a.w]);
            data[y * w + a.w + gap..(y + 1) * w].copy_from_slice(&b.data[y * b.w..(y + 1) * b.w]);
        }
        frames.push(data);
    }
    Ok((frames, h, w))
}

#[cfg(feature = "viz")]
fn speed_style(frames: &[Vec<f64>]) -> pbdl_core::viz::FieldStyle {
    let vmax = frames.iter().flatten().filter(|v| v.is_finite()).fold(0.0f64, |a, &b| a.max(b)).max(1e-6);
    pbdl_core::viz::FieldStyle {
        range: pbdl_core::viz::ColorRange::Fixed(0.0, vmax),
        nan_color: [255, 255, 255],
        ..Default::default()
    }
}

/// Writes the rollout as an animated GIF, learned (left) | SPH (right), particles coloured by
/// speed (walls at zero), all frames at one colour range.
#[cfg(feature = "viz")]
pub fn write_gif(path: &Path, data: &LiquidDataset, report: &RolloutReport) -> Result<()> {
    let (frames, h, w) = side_by_side(data, report)?;
    let style = pbdl_core::viz::GifStyle { field: speed_style(&frames), frame_delay_ms: 40, repeat: true };
    pbdl_core::viz::rollout_to_gif(path, &frames, h, w, &style)?;
    Ok(())
}

/// Writes frame `frame` of the rollout (learned | SPH, as [`write_gif`]) as a PNG.
#[cfg(feature = "viz")]
pub fn write_png(path: &Path, data: &LiquidDataset, report: &RolloutReport, frame: usize) -> Result<()> {
    let (frames, h, w) = side_by_side(data, report)?;
    let f = frames.get(frame).ok_or_else(|| Error::Config {
        field: "frame",
        reason: format!("{frame}; the rollout has {} frames", frames.len()),
    })?;
    pbdl_core::viz::field_to_png(path, f, h, w, &speed_style(&frames))?;
    Ok(())
}
