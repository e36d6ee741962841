//! CConv-style 3D liquid data (Ummenhofer et al. 2020): fluid blocks and balls with random
//! sizes, positions and initial velocities dropped into a closed box, simulated with
//! [`Wcsph3d`](crate::wcsph3d::Wcsph3d), written one scene per `.npz` file.
//!
//! CConv's training data are DFSPH scenes of fluid bodies falling into boxes, frames 1/50 s
//! apart, with the box given as boundary particles and their normals. Here:
//!
//! * scale: particle spacing 0.05 m (CConv: `2 r_p` with `r_p = 0.025` m) and frame step
//!   0.02 s, as pbdl-pconv's 2D liquid data;
//! * every random number comes from [`Liquid3dConfig::seed`] through a counter-based
//!   generator (SplitMix64, one stream per scene), so scene `k` is reproduced bit for bit from
//!   the seed alone, independent of the other scenes and of the thread count;
//! * per scene `scene_KKKK.npz` holds `pos [T, N, 3]` and `vel [T, N, 3]` (f32, frame 0 the
//!   initial state), `box [M, 3]` (the solver's innermost wall layer, half a spacing outside
//!   the box surface) and `box_normals [M, 3]` (unit normals pointing into the box, towards the
//!   fluid, as CConv's boundary input), all in metres with `y` up; `scene_KKKK.json` beside it
//!   records the configuration, the seed, the scene's own seed and the drawn bodies.
//!
//! ```
//! use pbdl_particles::liquid3d::Liquid3dConfig;
//!
//! let dir = tempfile::tempdir().unwrap();
//! let cfg = Liquid3dConfig { scenes: 1, frames: 2, ..Liquid3dConfig::tiny() };
//! let files = cfg.generate(dir.path())?;
//! assert_eq!(files.len(), 1);
//! let pos = pbdl_core::io::read_npz_array(&files[0], "pos")?;
//! assert_eq!(pos.dims()[0], 2);
//! # Ok::<(), pbdl_particles::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::wcsph3d::{BlockDrop3d, FluidBody3d, Shape3d, Wcsph3dParams};
use candle_core::{Device, Tensor};
use pbdl_core::stepper::Evolve;
use serde::{Deserialize, Serialize};
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// What to generate: the number of scenes, their box and frames, and the ranges the bodies are
/// drawn from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Liquid3dConfig {
    /// The seed every scene is drawn from.
    pub seed: u64,
    /// Number of scenes.
    pub scenes: usize,
    /// Particle spacing in m (default 0.05, CConv's `2 r_p`).
    pub spacing: f64,
    /// Time between frames in s (default 0.02, CConv's 1/50).
    pub frame_dt: f64,
    /// Frames per scene, the initial state included (default 50: one second).
    pub frames: usize,
    /// Inner size of the box in m, `y` up (default 1 x 1 x 1).
    pub box_size: [f64; 3],
    /// Smallest and largest number of fluid bodies per scene (default 1 to 3).
    pub bodies: [usize; 2],
    /// Smallest and largest edge length (blocks, per axis) or diameter (balls) in m (default
    /// 0.2 to 0.4).
    pub body_size: [f64; 2],
    /// Probability that a body is a ball rather than a block (default 0.3).
    pub sphere_fraction: f64,
    /// Largest initial speed in m/s, drawn uniformly in `[0, max_speed]` with a uniform
    /// direction (default 1).
    pub max_speed: f64,
    /// Gravity in m/s² along `-y` (default 9.81).
    pub g: f64,
    /// Solver parameters (default [`Wcsph3dParams::default`]).
    pub params: Wcsph3dParams,
}

impl Default for Liquid3dConfig {
    fn default() -> Self {
        Liquid3dConfig {
            seed: 0,
            scenes: 4,
            spacing: 0.05,
            frame_dt: 0.02,
            frames: 50,
            box_size: [1.0, 1.0, 1.0],
            bodies: [1, 3],
            body_size: [0.2, 0.4],
            sphere_fraction: 0.3,
            max_speed: 1.0,
            g: 9.81,
            params: Wcsph3dParams::default(),
        }
    }
}

/// Where the bodies of one scene did not fit: a body whose bounding box overlaps an earlier one
/// is redrawn up to this many times, then left out.
const PLACEMENT_TRIES: usize = 100;

impl Liquid3dConfig {
    /// A tiny configuration for tests: spacing 0.1 m in a 0.6 m box, 1 or 2 bodies of 0.2 to
    /// 0.3 m, 2 scenes of 4 frames.
    pub fn tiny() -> Self {
        Liquid3dConfig {
            scenes: 2,
            spacing: 0.1,
            frames: 4,
            box_size: [0.6, 0.6, 0.6],
            bodies: [1, 2],
            body_size: [0.2, 0.3],
            ..Liquid3dConfig::default()
        }
    }

    /// Checks the numbers.
    ///
    /// Errors: [`Error::Invalid`] naming the field: non-positive spacing, frame step or box,
    /// fewer than 1 frame, an empty or inverted range, bodies smaller than two spacings or
    /// larger than the box, a probability outside `[0, 1]`, negative speed or gravity.
    pub fn validate(&self) -> Result<()> {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        if !pos(self.spacing) {
            return Err(Error::invalid("spacing", format!("{}; must be positive and finite", self.spacing)));
        }
        if !pos(self.frame_dt) {
            return Err(Error::invalid("frame_dt", format!("{}; must be positive and finite", self.frame_dt)));
        }
        if self.frames == 0 {
            return Err(Error::invalid("frames", "0; a scene needs at least its initial frame"));
        }
        if !self.box_size.iter().all(|&l| pos(l)) {
            return Err(Error::invalid("box_size", format!("{:?}; must be positive and finite", self.box_size)));
        }
        // The tank is laid out in whole spacings; a side that is not a whole number of them
        // would shrink the tank below the box the bodies are drawn in.
        if let Some(&l) = self
            .box_size
            .iter()
            .find(|&&l| ((l / self.spacing) - (l / self.spacing).round()).abs() > 1e-9 * (l / self.spacing))
        {
            return Err(Error::invalid(
                "box_size",
                format!("{l} is not a whole number of spacings ({}); use a multiple of the spacing", self.spacing),
            ));
        }
        if self.frames > 1_000_000 || self.scenes > 1_000_000 {
            return Err(Error::invalid(
                "frames",
                format!("{} frames x {} scenes; use at most 1e6 of each", self.frames, self.scenes),
            ));
        }
        if self.bodies[0] == 0 || self.bodies[0] > self.bodies[1] || self.bodies[1] > 64 {
            return Err(Error::invalid("bodies", format!("{:?}; use 1 <= min <= max <= 64", self.bodies)));
        }
        let [lo, hi] = self.body_size;
        let smallest_box = self.box_size.iter().copied().fold(f64::INFINITY, f64::min);
        if !(lo.is_finite() && hi.is_finite() && lo >= 2.0 * self.spacing && lo <= hi && hi <= smallest_box) {
            return Err(Error::invalid(
                "body_size",
                format!(
                    "{:?}; use 2 spacings ({}) <= min <= max <= the box's smallest side ({smallest_box})",
                    self.body_size,
                    2.0 * self.spacing
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.sphere_fraction) {
            return Err(Error::invalid("sphere_fraction", format!("{}; use 0 to 1", self.sphere_fraction)));
        }
        if !(self.max_speed >= 0.0 && self.max_speed.is_finite()) {
            return Err(Error::invalid("max_speed", format!("{}; must be non-negative", self.max_speed)));
        }
        if !(self.g >= 0.0 && self.g.is_finite()) {
            return Err(Error::invalid("g", format!("{}; must be non-negative", self.g)));
        }
        Ok(())
    }

    /// The seed of scene `index`: the configuration's seed and the index mixed by SplitMix64.
    pub fn scene_seed(&self, index: usize) -> u64 {
        let mut s = SplitMix64(self.seed ^ (index as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
        s.next_u64()
    }

    /// The scene `index` drawn from the seed: bodies with random shapes, sizes, positions
    /// (inside the box, bounding boxes not overlapping) and initial velocities.
    ///
    /// Errors: as [`Liquid3dConfig::validate`].
    pub fn scene(&self, index: usize) -> Result<BlockDrop3d> {
        self.validate()?;
        let mut rng = SplitMix64(self.scene_seed(index));
        let count = self.bodies[0] + (rng.uniform() * (self.bodies[1] - self.bodies[0] + 1) as f64) as usize;
        let count = count.min(self.bodies[1]);
        let mut bodies: Vec<FluidBody3d> = Vec::new();
        let mut boxes: Vec<([f64; 3], [f64; 3])> = Vec::new();
        for _ in 0..count {
            for _ in 0..PLACEMENT_TRIES {
                let sphere = rng.uniform() < self.sphere_fraction;
                let size: [f64; 3] = if sphere {
                    [rng.range(self.body_size); 3]
                } else {
                    std::array::from_fn(|_| rng.range(self.body_size))
                };
                let lo: [f64; 3] = std::array::from_fn(|d| rng.uniform() * (self.box_size[d] - size[d]));
                let hi: [f64; 3] = std::array::from_fn(|d| lo[d] + size[d]);
                let speed = rng.uniform() * self.max_speed;
                let dir = rng.unit_vector();
                if boxes.iter().any(|(l, h)| (0..3).all(|d| lo[d] < h[d] && hi[d] > l[d])) {
                    continue;
                }
                let shape = if sphere {
                    Shape3d::Sphere { center: std::array::from_fn(|d| lo[d] + 0.5 * size[d]), radius: 0.5 * size[0] }
                } else {
                    Shape3d::Block { lo, hi }
                };
                boxes.push((lo, hi));
                bodies.push(FluidBody3d { shape, velocity: dir.map(|c| c * speed) });
                break;
            }
        }
        Ok(BlockDrop3d {
            box_size: self.box_size,
            dx: self.spacing,
            bodies,
            g: self.g,
            rho0: 1000.0,
            c0_factor: 10.0,
            wall_layers: None,
        })
    }

    /// Simulates scene `index` and returns its frames.
    ///
    /// Errors: as [`Liquid3dConfig::scene`] and [`BlockDrop3d::build`], solver errors.
    pub fn simulate(&self, index: usize) -> Result<LiquidScene3d> {
        self.simulate_with(index, |_| {})
    }

    fn simulate_with(&self, index: usize, mut on_frame: impl FnMut(usize)) -> Result<LiquidScene3d> {
        let scene = self.scene(index)?;
        let mut sim = scene.build(self.params)?;
        let tank = scene.tank(&self.params)?;
        let (bpos, bnrm) = tank.boundary_with_normals();
        let n = sim.n_fluid();
        // Refuse a trajectory that cannot be held (or indexed) before allocating it.
        let len = self.frames.checked_mul(n * 3).filter(|&l| l <= (1usize << 32)).ok_or_else(|| {
            Error::invalid("frames", format!("{} frames of {n} particles: more than 2^32 values per array; use fewer frames or a coarser spacing", self.frames))
        })?;
        let mut pos = Vec::with_capacity(len);
        let mut vel = Vec::with_capacity(len);
        for f in 0..self.frames {
            if f > 0 {
                sim.run_until(f as f64 * self.frame_dt)?;
            }
            pos.extend(sim.x[..n].iter().flat_map(|p| p.map(|c| c as f32)));
            vel.extend(sim.v.iter().flat_map(|v| v.map(|c| c as f32)));
            on_frame(f);
        }
        Ok(LiquidScene3d {
            index,
            seed: self.scene_seed(index),
            scene,
            frames: self.frames,
            n_fluid: n,
            pos,
            vel,
            box_pos: bpos.iter().flat_map(|p| p.map(|c| c as f32)).collect(),
            box_normals: bnrm.iter().flat_map(|p| p.map(|c| c as f32)).collect(),
            steps: sim.steps(),
            leaked: sim.leaked(),
        })
    }

    /// Generates every scene into `dir` (created if missing): `scene_KKKK.npz` and
    /// `scene_KKKK.json` per scene, each written atomically; returns the `.npz` paths. Shows a
    /// progress bar over all frames on a terminal.
    ///
    /// Errors: bad configuration, solver errors, IO errors.
    pub fn generate(&self, dir: &Path) -> Result<Vec<PathBuf>> {
        self.validate()?;
        std::fs::create_dir_all(dir).map_err(|e| pbdl_core::Error::io(dir, e))?;
        let progress = pbdl_core::train::Progress::new((self.scenes * self.frames) as u64);
        let mut files = Vec::with_capacity(self.scenes);
        for k in 0..self.scenes {
            progress.set_message(format!("scene {}/{}", k + 1, self.scenes));
            let done = (k * self.frames) as u64;
            let scene = self.simulate_with(k, |f| progress.set_position(done + f as u64 + 1))?;
            let npz = dir.join(format!("scene_{k:04}.npz"));
            scene.write_npz(&npz)?;
            let json = self.sidecar_json(&scene)?;
            pbdl_core::io::write_atomic(dir.join(format!("scene_{k:04}.json")), |w| w.write_all(json.as_bytes()))?;
            progress.println(format!(
                "scene {k}: {} particles, {} frames, {} steps, {} leaked",
                scene.n_fluid, scene.frames, scene.steps, scene.leaked
            ));
            files.push(npz);
        }
        progress.finish();
        Ok(files)
    }

    /// The JSON sidecar of a scene: the configuration (readable back as a [`Liquid3dConfig`]),
    /// the seeds, the solver's constants and the drawn bodies.
    fn sidecar_json(&self, s: &LiquidScene3d) -> Result<String> {
        let v = serde_json::json!({
            "format": "pbdl liquid3d v1",
            "seed": self.seed,
            "scene_index": s.index,
            "scene_seed": s.seed,
            "config": self,
            "solver": "wcsph3d",
            "c0": s.scene.c0(),
            "rho0": s.scene.rho0,
            "n_fluid": s.n_fluid,
            "n_box": s.box_pos.len() / 3,
            "steps": s.steps,
            "arrays": {
                "pos": "[frames, n_fluid, 3] f32 m",
                "vel": "[frames, n_fluid, 3] f32 m/s",
                "box": "[n_box, 3] f32 m",
                "box_normals": "[n_box, 3] f32, unit, pointing into the box",
            },
            "bodies": s.scene.bodies,
        });
        serde_json::to_string_pretty(&v).map(|t| t + "\n").map_err(|e| Error::invalid("sidecar", e.to_string()))
    }
}

/// One simulated scene: the frames of every fluid particle and the box's boundary particles.
#[derive(Clone, Debug, PartialEq)]
pub struct LiquidScene3d {
    /// Scene index within its configuration.
    pub index: usize,
    /// The scene's own seed ([`Liquid3dConfig::scene_seed`]).
    pub seed: u64,
    /// The drawn scene.
    pub scene: BlockDrop3d,
    /// Frames (the initial state included).
    pub frames: usize,
    /// Fluid particles.
    pub n_fluid: usize,
    /// Positions, `[frames, n_fluid, 3]` row-major.
    pub pos: Vec<f32>,
    /// Velocities, `[frames, n_fluid, 3]` row-major.
    pub vel: Vec<f32>,
    /// Boundary particles, `[n_box, 3]` row-major.
    pub box_pos: Vec<f32>,
    /// Their unit normals pointing into the box, `[n_box, 3]`.
    pub box_normals: Vec<f32>,
    /// Solver steps taken.
    pub steps: u64,
    /// Fluid particles outside the box at the end.
    pub leaked: usize,
}

impl LiquidScene3d {
    /// Writes `pos`, `vel`, `box` and `box_normals` to a `.npz` file, atomically.
    ///
    /// Errors: IO errors.
    pub fn write_npz(&self, path: &Path) -> Result<()> {
        let dev = Device::Cpu;
        let nb = self.box_pos.len() / 3;
        let pos = Tensor::from_slice(&self.pos, (self.frames, self.n_fluid, 3), &dev)?;
        let vel = Tensor::from_slice(&self.vel, (self.frames, self.n_fluid, 3), &dev)?;
        let bx = Tensor::from_slice(&self.box_pos, (nb, 3), &dev)?;
        let bn = Tensor::from_slice(&self.box_normals, (nb, 3), &dev)?;
        pbdl_core::io::write_npz(path, &[("pos", &pos), ("vel", &vel), ("box", &bx), ("box_normals", &bn)])?;
        Ok(())
    }
}

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny counter-based generator whose output is fixed
/// by its definition, so data sets do not change with a random-number crate's version.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)` with 53 random bits.
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[r[0], r[1]]`.
    fn range(&mut self, r: [f64; 2]) -> f64 {
        r[0] + (r[1] - r[0]) * self.uniform()
    }

    /// Uniform on the unit sphere (rejection from the cube).
    fn unit_vector(&mut self) -> [f64; 3] {
        loop {
            let v: [f64; 3] = std::array::from_fn(|_| 2.0 * self.uniform() - 1.0);
            let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            if n2 > 1e-6 && n2 <= 1.0 {
                let n = n2.sqrt();
                return v.map(|c| c / n);
            }
        }
    }
}
