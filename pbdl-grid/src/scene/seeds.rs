//! Seeded runs of a scene: run `k` of a batch (`cargo xtask sim grid SCENE --seeds N`, one data
//! item per run) is the scene with every seeded input advanced by `k`.
//!
//! The seeded inputs of a grid scene are listed by [`Scene::seeded_inputs`]; today that is the
//! `seed` of `init = random_modes` (2D and 3D), the only random part of a grid scene (the
//! physics, forcing, sources and obstacles are deterministic). Run `k` draws with
//! `seed + k` (wrapping), the convention of the particle scenes, so that
//! - run `k` depends on the scene and `k` only, not on how many runs there are or which job of a
//!   sharded generation makes it;
//! - run 0 is the scene itself, and runs `0..n` of one scene use `n` different seeds.
//!
//! (A scene with `seed = 3` and one with `seed = 4` share runs shifted by one; give the scenes of
//! one data set seeds at least `n` apart.) A scene without seeded inputs gives the same run for
//! every `k`: callers that want different runs should check [`Scene::is_seeded`] first (`sim grid
//! --seeds` refuses such scenes).
//!
//! ```
//! use pbdl_grid::scene::{Init, Scene};
//! let base = Scene::builtin("burgers_2d")?;
//! assert_eq!(base.seeded_inputs(), vec![("init.seed", 3)]);
//! let run2 = base.clone().with_seed_offset(2);
//! assert!(matches!(run2.init, Init::RandomModes { seed: 5, .. }));
//! assert_eq!(base.clone().with_seed_offset(0), base);
//! assert!(!Scene::builtin("taylor_green")?.is_seeded());
//! # Ok::<(), pbdl_grid::scene::SceneError>(())
//! ```

use super::{Init, Scene};

impl Scene {
    /// The seeded (random) inputs of the scene as `(key, seed)`, e.g. `[("init.seed", 3)]` for
    /// `init = random_modes` with `seed = 3`; empty for a deterministic scene.
    pub fn seeded_inputs(&self) -> Vec<(&'static str, u64)> {
        let mut out = Vec::new();
        if let Init::RandomModes { seed, .. } = self.init {
            out.push(("init.seed", seed));
        }
        out
    }

    /// `true` when the scene has a seeded input ([`Scene::seeded_inputs`] is not empty), so that
    /// [`Scene::with_seed_offset`] gives different runs for different offsets.
    pub fn is_seeded(&self) -> bool {
        !self.seeded_inputs().is_empty()
    }

    /// Run `k` of a batch of seeded runs: every seeded input's seed becomes `seed + k`
    /// (wrapping); everything else is kept. Offset 0 is the scene itself; a scene without
    /// seeded inputs is returned unchanged (see the module docs).
    pub fn with_seed_offset(mut self, k: u64) -> Self {
        if let Init::RandomModes { seed, .. } = &mut self.init {
            *seed = seed.wrapping_add(k);
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::builtin_names;
    use candle_core::Tensor;

    fn initial_fields(scene: &Scene) -> Vec<(String, Tensor)> {
        scene.build().unwrap().fields().unwrap()
    }

    fn max_abs_diff(a: &[(String, Tensor)], b: &[(String, Tensor)]) -> f64 {
        assert_eq!(a.len(), b.len());
        let mut m: f64 = 0.0;
        for ((na, ta), (nb, tb)) in a.iter().zip(b) {
            assert_eq!(na, nb);
            let d = (ta - tb).unwrap().abs().unwrap().flatten_all().unwrap();
            let d = d.to_dtype(candle_core::DType::F64).unwrap().max(0).unwrap().to_scalar::<f64>().unwrap();
            m = m.max(d);
        }
        m
    }

    #[test]
    fn seed_offsets_give_distinct_reproducible_runs() {
        let base = Scene::builtin("burgers_2d").unwrap().with_resolution(16);
        assert!(base.is_seeded());
        let Init::RandomModes { seed, .. } = base.init else { panic!("burgers_2d starts from random modes") };
        let runs: Vec<Scene> = (0..3).map(|k| base.clone().with_seed_offset(k)).collect();
        assert_eq!(runs[0], base);
        for (k, r) in runs.iter().enumerate() {
            assert_eq!(r.seeded_inputs(), vec![("init.seed", seed + k as u64)]);
            // Only the seed changes.
            let mut back = r.clone();
            back.init = base.init;
            assert_eq!(back, base);
        }
        // The same offset builds the same initial state; different offsets differ clearly.
        let f: Vec<_> = runs.iter().map(initial_fields).collect();
        assert_eq!(max_abs_diff(&f[1], &initial_fields(&base.clone().with_seed_offset(1))), 0.0);
        assert!(max_abs_diff(&f[0], &f[1]) > 1e-2);
        assert!(max_abs_diff(&f[1], &f[2]) > 1e-2);
        // Offsets compose (run k of run j is run j + k) and wrap instead of overflowing.
        assert_eq!(base.clone().with_seed_offset(1).with_seed_offset(1), runs[2]);
        let wrapped = base.clone().with_seed_offset(u64::MAX);
        assert_eq!(wrapped.seeded_inputs(), vec![("init.seed", seed.wrapping_sub(1))]);
    }

    #[test]
    fn deterministic_scenes_have_no_seeded_inputs_and_ignore_offsets() {
        let mut seeded = Vec::new();
        for name in builtin_names() {
            let scene = Scene::builtin(name).unwrap();
            if scene.is_seeded() {
                seeded.push(name);
            } else {
                assert!(scene.seeded_inputs().is_empty());
                assert_eq!(scene.clone().with_seed_offset(7), scene, "{name}");
            }
        }
        // The built-in scenes that start from random modes (the list `sim grid --seeds` offers).
        assert_eq!(seeded, ["burgers_2d", "decaying_turbulence", "kolmogorov"]);
    }
}
