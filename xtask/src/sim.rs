//! `cargo xtask sim grid|particles <scene | file.toml>`: run a scene, write its trajectory and
//! renders; `--seeds N [--shard i/n]`: one run per seed, as data shards for a job array.

use crate::report;
use pbdl_grid::scene::{write_trajectory, Scene};
use pbdl_particles::scene::{InitState, Precision};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `cargo xtask sim` was asked to do.
pub struct SimArgs {
    /// The simulator crate: `grid` or `particles`.
    pub krate: String,
    /// A built-in scene name or a `.toml` path.
    pub scene: String,
    /// Cells along x (y scaled to keep the aspect).
    pub res: Option<usize>,
    /// Number of steps (replaces the scene's `steps` / `t_end`).
    pub steps: Option<usize>,
    /// Initial fields (`.npz`).
    pub init: Option<PathBuf>,
    /// Output directory.
    pub out: Option<PathBuf>,
    /// Number of seeds (runs `0..seeds`; grid scenes: run `k` is `Scene::with_seed_offset(k)`).
    pub seeds: Option<usize>,
    /// This job's seeds only, as data shards (with `seeds` only).
    pub shard: Option<pbdl_core::shard::Shard>,
    /// `f32` or `f64`, replacing the scene's `precision` (particles only).
    pub precision: Option<String>,
}

/// Runs the scene and writes `<out>/<scene>.npz` plus PNG/GIF renders; with `--seeds N` one run
/// per seed (see [`run_grid_seeds`]).
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    if args.krate == "particles" {
        return run_particles(args);
    }
    anyhow::ensure!(args.krate == "grid", "unknown simulator `{}`; available: grid, particles", args.krate);
    anyhow::ensure!(
        args.precision.is_none(),
        "--precision is for `sim particles`; grid scenes set `precision` in the TOML"
    );
    let mut scene = Scene::load(&args.scene)?;
    if let Some(n) = args.res {
        scene = scene.with_resolution(n);
    }
    if let Some(s) = args.steps {
        scene = scene.with_steps(s);
    }
    let out = args.out.clone().unwrap_or_else(|| report::target_dir().join("sim").join(&scene.name));
    if let Some(seeds) = args.seeds {
        return run_grid_seeds(scene, seeds, args.shard, args.init.as_deref(), &out);
    }
    anyhow::ensure!(args.shard.is_none(), "--shard splits the seeds of --seeds N among jobs; give --seeds");
    run_grid_once(&scene, args.init.as_deref(), &out)
}

/// `sim grid SCENE --seeds N [--shard i/n]`: run `k` is the scene with its seeded inputs
/// advanced by `k` ([`Scene::with_seed_offset`]), so it depends on the scene and `k` only.
/// Without `--shard` it writes `<out>/<scene>_seed<k>.npz` (+ renders) for `k` in `0..N`; with
/// `--shard i/n` only this job's runs, as `item-<k>.npz` (+ renders) and the manifest
/// `manifest-i-of-n.json` (see [`pbdl_core::shard`]). A scene without a seeded input is refused:
/// its runs would all be the same.
fn run_grid_seeds(
    scene: Scene,
    seeds: usize,
    shard: Option<pbdl_core::shard::Shard>,
    init: Option<&Path>,
    out: &Path,
) -> anyhow::Result<()> {
    anyhow::ensure!(seeds >= 1, "--seeds must be at least 1");
    if !scene.is_seeded() {
        let random: Vec<&str> = pbdl_grid::scene::builtin_names()
            .into_iter()
            .filter(|n| Scene::builtin(n).is_ok_and(|s| s.is_seeded()))
            .collect();
        anyhow::bail!(
            "scene `{}` has no random input (only `init = random_modes` is seeded), so its --seeds runs would \
             all be the same; drop --seeds, or use a scene that starts from random modes ({}, or a .toml \
             with [init] kind = \"random_modes\")",
            scene.name,
            random.join(", ")
        );
    }
    anyhow::ensure!(
        init.is_none(),
        "--init with --seeds: the runs would start from the same file instead of their seeds' random modes"
    );
    let run_seed = |k: usize, stem: &str, dir: &Path| {
        let mut run = scene.clone().with_seed_offset(k as u64);
        let inputs: Vec<String> = run.seeded_inputs().iter().map(|(key, v)| format!("{key} = {v}")).collect();
        println!("sim: {} run {k} of {seeds} ({})", scene.name, inputs.join(", "));
        // The name only names the output files.
        run.name = stem.to_string();
        run_grid_once(&run, None, dir)
    };
    let Some(shard) = shard else {
        for k in 0..seeds {
            run_seed(k, &format!("{}_seed{k}", scene.name), out)?;
        }
        return Ok(());
    };
    // The manifests record the whole scene (seed, resolution, steps included), so shards of
    // different scenes or settings cannot be mixed in one directory.
    let config = serde_json::json!({ "scene": serde_json::to_value(&scene)?, "seeds": seeds });
    let m = pbdl_core::shard::generate_shard(out, "pbdl-grid/sim", &config, seeds, shard, |k, path| {
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("item").to_string();
        let dir = path.parent().unwrap_or(out);
        run_seed(k, &stem, dir).map_err(|e| pbdl_core::Error::invalid("sim grid", "--shard", e.to_string()))
    })?;
    println!("sim: shard {} wrote seeds {:?} ({})", m.shard, shard.items(seeds), m.shard.manifest_name());
    Ok(())
}

/// One grid run of `scene` (from the fields of `init` if given): `<out>/<scene.name>.npz` and
/// renders.
fn run_grid_once(scene: &Scene, init: Option<&Path>, out: &Path) -> anyhow::Result<()> {
    let mut sim = scene.build()?;
    if let Some(path) = init {
        let arrays = pbdl_core::io::read_npz(path)?;
        let used = sim.set_fields(&arrays)?;
        println!("sim: initial {} from {}", used.join(", "), path.display());
    }
    let g = sim.scene().grid;
    let cells = if g.nz > 1 { format!("{}x{}x{}", g.nx, g.ny, g.nz) } else { format!("{}x{}", g.nx, g.ny) };
    println!(
        "sim: {} on {} ({}), dt = {:.4e}, {} steps to t = {:.4}",
        sim.scene().name,
        cells,
        sim.scene().about,
        sim.dt(),
        sim.steps(),
        sim.steps() as f64 * sim.dt()
    );
    println!("sim: operators {}", sim.operators().join(", "));
    let progress = pbdl_core::train::Progress::new(sim.steps() as u64);
    let started = Instant::now();
    let traj = sim.run(|k| progress.set_position(k as u64))?;
    progress.finish();
    let wall = started.elapsed().as_secs_f64();
    let files = write_trajectory(&sim, &traj, out)?;
    println!(
        "sim: {} steps in {:.2} s ({:.3} ms/step), {} frames",
        sim.step_index(),
        wall,
        1e3 * wall / sim.step_index().max(1) as f64,
        traj.times.len()
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

/// `sim particles`: one run per seed, `<out>/<scene>_seed<k>.npz` + PNG + GIF each, in the
/// scene's precision (or `--precision`).
fn run_particles(args: SimArgs) -> anyhow::Result<()> {
    use pbdl_particles::scene::Scene;
    anyhow::ensure!(args.res.is_none(), "--res is for `sim grid`; particle scenes set their spacing in the TOML");
    let mut scene = Scene::load(&args.scene)?;
    if let Some(s) = args.steps {
        scene = scene.with_frames(s);
    }
    if let Some(p) = &args.precision {
        scene = scene.with_precision(Precision::parse(p)?);
    }
    let init = match &args.init {
        Some(path) => Some(InitState::from_arrays(&pbdl_core::io::read_npz(path)?)?),
        None => None,
    };
    let seeds = args.seeds.unwrap_or(1).max(1);
    let out = args.out.unwrap_or_else(|| report::target_dir().join("sim").join(&scene.name));
    // One dispatch on the precision; the run itself is generic.
    let run_seed = |k: usize, stem: &str| match scene.precision {
        Precision::F64 => run_particle_seed::<f64>(&scene, k, init.as_ref(), &out, stem),
        Precision::F32 => run_particle_seed::<f32>(&scene, k, init.as_ref(), &out, stem),
    };
    let Some(shard) = args.shard else {
        for k in 0..seeds {
            run_seed(k, &format!("{}_seed{k}", scene.name))?;
        }
        return Ok(());
    };
    anyhow::ensure!(args.seeds.is_some(), "--shard splits the seeds of --seeds N among jobs; give --seeds");
    anyhow::ensure!(init.is_none(), "--shard with --init: every seed would start from the same file");
    // Item k is seed k of this scene: the manifests record the whole scene, so shards of
    // different scenes or settings cannot be mixed in one directory.
    let config = serde_json::json!({ "scene": serde_json::to_value(&scene)?, "seeds": seeds });
    let m = pbdl_core::shard::generate_shard(&out, "pbdl-particles/sim", &config, seeds, shard, |k, path| {
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("item").to_string();
        run_seed(k, &stem).map_err(|e| pbdl_core::Error::invalid("sim particles", "--shard", e.to_string()))
    })?;
    println!("sim: shard {} wrote seeds {:?} ({})", m.shard, shard.items(seeds), m.shard.manifest_name());
    Ok(())
}

/// One `sim particles` run (seed `k`) in precision `T`.
fn run_particle_seed<T: pbdl_core::Real>(
    scene: &pbdl_particles::scene::Scene,
    k: usize,
    init: Option<&InitState>,
    out: &Path,
    stem: &str,
) -> anyhow::Result<()> {
    use pbdl_particles::scene::{run_frames, write_trajectory};
    let mut sim = scene.build_as::<T>(k as u64, init)?;
    println!(
        "sim: {} ({}), seed {}, {} frames of {:.4e} to t = {:.4}, {}",
        scene.name,
        scene.about,
        scene.seed + k as u64,
        scene.frames,
        scene.frame_dt,
        scene.t_end(),
        scene.precision
    );
    println!("sim: operators {}", sim.operators().join(", "));
    let progress = pbdl_core::train::Progress::new(scene.frames as u64);
    let started = Instant::now();
    let frames = run_frames(scene, &mut sim, |f| progress.set_position(f as u64))?;
    progress.finish();
    let wall = started.elapsed().as_secs_f64();
    let files = write_trajectory(&sim, &frames, out, stem)?;
    println!(
        "sim: {} particles, {} steps in {:.2} s ({:.3} ms/step), {} frames",
        frames[0].mass.len(),
        sim.steps(),
        wall,
        1e3 * wall / sim.steps().max(1) as f64,
        frames.len()
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
