//! `cargo xtask sol train|eval` (Solver-in-the-Loop, Um et al. 2020, on the cylinder wake, or
//! with `--scene plume` on the buoyancy-driven plume) and
//! `cargo xtask control train|eval` (PDE control of forced 1D Burgers, Holl et al. 2020).
//!
//! Training runs are run directories of pbdl-sol's resumable trainers
//! (`pbdl_sol::sil::train_resumable`, `pbdl_sol::control::{pretrain_supervised_resumable,
//! train_end_to_end_resumable}`): atomic checkpoints of the weights and Adam's state, `loss.csv`;
//! the same command on the same `--out` continues a stopped or killed run and ends with the
//! uninterrupted run's numbers, bit for bit; other settings are refused, naming the setting.
//! Settings come from the defaults (the README's acceptance recipes), `--quick` (tiny, for
//! tests), and an optional `--config` file (TOML or JSON) whose fields replace them.

use anyhow::{ensure, Context as _};
use candle_core::{DType, Device, Tensor};
use pbdl_core::io::{latest_checkpoint, load_checkpoint, load_varmap, save_checkpoint, CheckpointMeta};
use pbdl_core::train::ClipConfig;
use pbdl_core::viz::{line_plot, PlotStyle, Series};
use pbdl_sol::control::{
    optimize_forces, pretrain_supervised_resumable, scene, train_end_to_end_resumable, BurgersControlConfig,
    ControlScore, Controller, ConvNetConfig, DirectOptimConfig, ForcedBurgers, RunDir,
};
use pbdl_sol::sil::{
    self, CorrectorConfig, DataConfig, PlumeConfig, ReferenceSet, ReferenceSim, SilScene, Variant, WakeConfig,
};
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;
use xtask::run_files::{write_json, write_text};

/// `cargo xtask sol ...`.
#[derive(clap::Subcommand)]
pub enum SolCommand {
    /// Train a corrector (PRE, NON or SOL-m) on the cylinder wake (or, with `--scene plume`,
    /// the buoyancy-driven plume) into a run directory; the
    /// reference data is generated once and cached in it (`DIR/data/`). An existing run
    /// directory resumes.
    Train(SolTrainArgs),
    /// Velocity MAE per step on the held-out Reynolds numbers (buoyancy factors for a plume run;
    /// its density MAE too) for the source solver and each trained run: a markdown table and
    /// JSON (mean MAE over three step ranges) and a PNG plot.
    Eval(SolEvalArgs),
}

/// Arguments of `sol train`.
#[derive(clap::Args)]
pub struct SolTrainArgs {
    /// pre, non or sol-<m> (e.g. sol-8).
    #[arg(long, default_value = "sol-8")]
    pub variant: String,
    /// Optimiser updates (a resumed run continues up to this count).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Seed of the initial weights and the batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Run directory: checkpoints, loss.csv, summary.json, the cached data in data/.
    #[arg(long)]
    pub out: PathBuf,
    /// Settings file (.toml or .json) with any of: wake, data, corrector, lr, batch, clip,
    /// iterations, checkpoint_every (pbdl_sol::sil's field names).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Tiny sizes (a 16 x 8 wake, 2 training Re, a width-4 corrector): seconds, for tests.
    #[arg(long)]
    pub quick: bool,
    /// The scene: `wake` (the cylinder wake, varying Re) or `plume` (a buoyant plume in a closed
    /// box, varying the buoyancy factor; state u, v, density).
    #[arg(long, default_value = "wake")]
    pub scene: String,
}

/// Arguments of `sol eval`.
#[derive(clap::Args)]
pub struct SolEvalArgs {
    /// Run directories of `sol train` (trained on the same data).
    #[arg(long, num_args = 1.., required = true)]
    pub runs: Vec<PathBuf>,
    /// Rollout steps from the first held-out frame.
    #[arg(long, default_value_t = 128)]
    pub steps: usize,
    /// Output path: writes <out>.md, <out>.json and <out>.png (an extension given is replaced).
    #[arg(long)]
    pub out: PathBuf,
}

/// `cargo xtask control ...`.
#[derive(clap::Subcommand)]
pub enum ControlCommand {
    /// Supervised pre-training, then end-to-end training through the solver, each phase a
    /// resumable run directory (`DIR/supervised`, `DIR/end_to_end`); settings in
    /// `DIR/config.json`. An existing run directory resumes.
    Train(ControlTrainArgs),
    /// Held-out scenes: the controller against no control, the supervised-only controller and
    /// the direct optimiser given the controller's wall-clock; effort, target error, combined.
    Eval {
        /// Run directory of `control train`.
        #[arg(long)]
        run: PathBuf,
        /// Output path: writes <out>.md and <out>.json (an extension given is replaced).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Arguments of `control train`.
#[derive(clap::Args)]
pub struct ControlTrainArgs {
    /// Run directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Settings file (.toml or .json) with any of the fields of `config.json`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seed of the networks' initial weights.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Tiny sizes (32 cells, 4 steps, 8 scenes, a few updates): seconds, for tests.
    #[arg(long)]
    pub quick: bool,
}

/// Runs `sol train|eval`.
pub fn run_sol(cmd: SolCommand) -> anyhow::Result<()> {
    match cmd {
        SolCommand::Train(args) => sol_train(args),
        SolCommand::Eval(args) => sol_eval(args),
    }
}

/// Runs `control train|eval`.
pub fn run_control(cmd: ControlCommand) -> anyhow::Result<()> {
    match cmd {
        ControlCommand::Train(args) => control_train(args),
        ControlCommand::Eval { run, out } => control_eval(&run, &out),
    }
}

// ---------------------------------------------------------------------------------------------
// Shared helpers

/// Reads a settings file: TOML by its `.toml` extension, JSON otherwise.
fn read_config<T: DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading --config {}", path.display()))?;
    if path.extension().is_some_and(|e| e == "toml") {
        toml::from_str(&text).with_context(|| format!("--config {}: not a valid TOML settings file", path.display()))
    } else {
        serde_json::from_str(&text)
            .with_context(|| format!("--config {}: not a valid JSON settings file", path.display()))
    }
}

/// `out` with `ext` in place of its extension, if it has one of ours.
fn with_ext(out: &Path, ext: &str) -> PathBuf {
    let known = out.extension().is_some_and(|e| ["md", "json", "png"].iter().any(|k| e == *k));
    if known {
        out.with_extension(ext)
    } else {
        let mut s = out.as_os_str().to_owned();
        s.push(format!(".{ext}"));
        PathBuf::from(s)
    }
}

/// `v` as it reads back from its JSON file (a float may read back one unit in the last place
/// off what was printed; settings are compared in this form).
fn roundtrip<T: Serialize + DeserializeOwned>(v: &T) -> anyhow::Result<T> {
    Ok(serde_json::from_str(&serde_json::to_string(v)?)?)
}

fn require_dir(dir: &Path, what: &str) -> anyhow::Result<()> {
    ensure!(dir.is_dir(), "{what} {} does not exist (or is not a directory)", dir.display());
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// sol train

/// What `--config` may set for `sol train` (each field replaces the default or `--quick` value).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct SolFile {
    wake: Option<WakeConfig>,
    plume: Option<PlumeConfig>,
    data: Option<DataConfig>,
    corrector: Option<CorrectorConfig>,
    lr: Option<f64>,
    batch: Option<usize>,
    clip: Option<ClipConfig>,
    iterations: Option<usize>,
    checkpoint_every: Option<u64>,
}

/// The scene and data of a `sol train` run: the plume when `plume` is set (then `wake` is
/// unused), the wake otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct SolData {
    wake: WakeConfig,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    plume: Option<PlumeConfig>,
    data: DataConfig,
}

fn parse_scene(s: &str) -> anyhow::Result<bool> {
    match s.to_ascii_lowercase().as_str() {
        "wake" => Ok(false),
        "plume" => Ok(true),
        _ => anyhow::bail!("unknown --scene `{s}`: use wake or plume"),
    }
}

fn parse_variant(s: &str) -> anyhow::Result<Variant> {
    let l = s.to_ascii_lowercase();
    let bad = || anyhow::anyhow!("unknown --variant `{s}`: use pre, non or sol-<m> with m >= 1 (e.g. sol-8)");
    Ok(match l.as_str() {
        "pre" => Variant::Pre,
        "non" => Variant::Non,
        _ => {
            let m: usize = l.strip_prefix("sol-").and_then(|m| m.parse().ok()).ok_or_else(bad)?;
            ensure!(m >= 1, bad());
            Variant::Sol { m }
        }
    })
}

/// Defaults: the README's acceptance recipe (paper scene and Re split, 200 training frames
/// after 100 warm-up, 129 held-out frames; a width-16, 2-block corrector whose output starts
/// at zero, Adam 1e-3, batch 2, 2000 updates). Quick: a 16 x 8 wake at 2x reference.
/// With `--scene plume`: the plume of [`PlumeConfig::default`] and [`PlumeConfig::data`] (quick:
/// an 8 x 12 plume at 2x reference, buoyancy 0.03 and 0.1, held out 0.05), same training.
fn sol_settings(args: &SolTrainArgs, variant: Variant) -> anyhow::Result<(SolData, sil::TrainConfig)> {
    let plume_scene = parse_scene(&args.scene)?;
    let (wake, mut data, corrector, iterations) = if args.quick {
        (
            WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() },
            DataConfig {
                train_re: vec![200.0, 800.0],
                test_re: vec![400.0],
                warmup: 10,
                train_frames: 12,
                test_frames: 17,
            },
            CorrectorConfig { width: 4, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: true },
            20,
        )
    } else {
        (
            WakeConfig::default(),
            DataConfig { warmup: 100, train_frames: 200, test_frames: 129, ..Default::default() },
            CorrectorConfig { width: 16, blocks: 2, kernel: 5, negative_slope: 0.3, zero_output: true },
            2000,
        )
    };
    let file: SolFile = args.config.as_deref().map(read_config).transpose()?.unwrap_or_default();
    let plume = match (plume_scene, args.quick) {
        (false, _) => None,
        (true, true) => {
            data = DataConfig { train_re: vec![0.03, 0.1], test_re: vec![0.05], ..data };
            Some(PlumeConfig {
                coarse: [8, 12],
                factor: 2,
                extent: [16.0, 24.0],
                inflow_lo: [6.0, 2.0],
                inflow_hi: [10.0, 4.0],
                obstacle: Some(pbdl_grid::Obstacle::Box { lo: [4.0, 12.0], hi: [8.0, 14.0] }),
                reference_substeps: 1,
                ..Default::default()
            })
        }
        (true, false) => {
            data = PlumeConfig::data();
            Some(PlumeConfig::default())
        }
    };
    ensure!(plume_scene || file.plume.is_none(), "--config sets `plume`: add --scene plume");
    let plume = plume.map(|p| file.plume.clone().unwrap_or(p));
    let d = roundtrip(&SolData { wake: file.wake.unwrap_or(wake), plume, data: file.data.unwrap_or(data) })?;
    let base = sil::TrainConfig::new(variant, args.iterations.or(file.iterations).unwrap_or(iterations), args.seed);
    let cfg = sil::TrainConfig {
        corrector: file.corrector.unwrap_or(corrector),
        lr: file.lr.unwrap_or(1e-3),
        batch: file.batch.unwrap_or(2),
        clip: file.clip.unwrap_or_default(),
        checkpoint_every: file.checkpoint_every.unwrap_or(if args.quick { 5 } else { 100 }),
        ..base
    };
    Ok((d, cfg))
}

/// The cached reference data of a run directory: `DIR/data/reference` (one checkpoint file,
/// committed atomically; its sidecar records the scene and data settings).
fn data_path(run: &Path) -> PathBuf {
    run.join("data").join("reference")
}

fn save_data<S>(run: &Path, settings: &SolData, data: &ReferenceSet<S>) -> anyhow::Result<()> {
    let mut tensors: Vec<(String, Tensor)> = Vec::new();
    for (k, r) in data.train.iter().enumerate() {
        tensors.push((format!("train/{k}/frames"), r.frames.clone()));
        if let Some(s) = &r.source {
            tensors.push((format!("train/{k}/source"), s.clone()));
        }
    }
    for (k, r) in data.test.iter().enumerate() {
        tensors.push((format!("test/{k}/frames"), r.frames.clone()));
    }
    std::fs::create_dir_all(run.join("data"))?;
    let meta = CheckpointMeta { step: 0, seed: None, config: serde_json::to_value(settings)? };
    save_checkpoint(data_path(run), tensors, &meta)?;
    Ok(())
}

/// The cached data of `run` if there is any: its settings and the data set.
fn load_data(run: &Path) -> anyhow::Result<Option<(SolData, ReferenceSet)>> {
    let path = data_path(run);
    if !path.with_extension("json").exists() {
        return Ok(None);
    }
    let (mut tensors, info) = load_checkpoint(&path, &Device::Cpu)?;
    let settings: SolData = serde_json::from_value(info.config)
        .with_context(|| format!("{}: not the data cache of `sol train`", path.display()))?;
    let mut take =
        |name: String| tensors.remove(&name).ok_or_else(|| anyhow::anyhow!("{}: `{name}` is missing", path.display()));
    let mut train = Vec::new();
    for (k, &re) in settings.data.train_re.iter().enumerate() {
        let frames = take(format!("train/{k}/frames"))?;
        let source = take(format!("train/{k}/source")).ok();
        train.push(ReferenceSim { re, frames, source });
    }
    let mut test = Vec::new();
    for (k, &re) in settings.data.test_re.iter().enumerate() {
        test.push(ReferenceSim { re, frames: take(format!("test/{k}/frames"))?, source: None });
    }
    let set = ReferenceSet { wake: settings.wake.clone(), train, test };
    Ok(Some((settings, set)))
}

/// The simulations of `set` with the scene `scene`.
fn with_scene<S: Clone>(set: ReferenceSet, scene: &S) -> ReferenceSet<S> {
    ReferenceSet { wake: scene.clone(), train: set.train, test: set.test }
}

/// Generates (or reads the cached) data of `scene` and trains into `args.out`.
fn train_scene<S: SilScene>(
    args: &SolTrainArgs,
    settings: &SolData,
    cfg: &sil::TrainConfig,
    scene: &S,
) -> anyhow::Result<sil::Trained> {
    let t0 = Instant::now();
    let data = match load_data(&args.out)? {
        Some((cached, data)) => {
            ensure!(
                &cached == settings,
                "{} holds reference data of other settings ({}), not of this call's ({}); use the run's settings or another --out",
                args.out.display(),
                serde_json::to_string(&cached)?,
                serde_json::to_string(settings)?
            );
            println!("reference data: cached in {}", data_path(&args.out).display());
            with_scene(data, scene)
        }
        None => {
            let data = sil::generate(scene, &settings.data, DType::F32)?;
            save_data(&args.out, settings, &data)?;
            println!(
                "reference data: {} training and {} held-out simulations in {:.1} s",
                data.train.len(),
                data.test.len(),
                t0.elapsed().as_secs_f64()
            );
            data
        }
    };
    if let Some(ck) = latest_checkpoint(&args.out)? {
        println!("resuming {} from {}", args.out.display(), ck.display());
    }
    Ok(sil::train_resumable(&data, cfg, &args.out)?)
}

fn sol_train(args: SolTrainArgs) -> anyhow::Result<()> {
    let variant = parse_variant(&args.variant)?;
    let (settings, cfg) = sol_settings(&args, variant)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating --out {}", args.out.display()))?;
    let trained = match settings.plume.clone() {
        Some(plume) => train_scene(&args, &settings, &cfg, &plume)?,
        None => train_scene(&args, &settings, &cfg, &settings.wake)?,
    };
    let n = trained.losses.len();
    let tail = trained.losses[n - n.min(100)..].iter().sum::<f64>() / n.clamp(1, 100) as f64;
    let summary = serde_json::json!({
        "variant": variant.name(),
        "seed": cfg.seed,
        "iterations": cfg.iterations,
        "resumed_from": trained.resumed_from,
        "optimizer_restored": trained.optimizer_restored,
        "train": cfg,
        "scene": settings,
        "parameters": trained.corrector.parameters(),
        "final_loss_mean_last_100": tail,
        "seconds_this_call": trained.seconds,
    });
    write_json(args.out.join("summary.json"), &summary)?;
    println!(
        "{} (seed {}): {n} updates ({} in this call, {:.1} s), mean loss of the last 100 {tail:.4e}; wrote {}",
        variant.name(),
        cfg.seed,
        n as u64 - trained.resumed_from,
        trained.seconds,
        args.out.display()
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// sol eval

/// One row of the `sol eval` table.
#[derive(Serialize)]
struct MaeRow {
    name: String,
    run: Option<PathBuf>,
    /// Mean MAE over each of the table's step ranges.
    mean_mae: Vec<f64>,
    /// Mean MAE of the held-out simulations after each step.
    mae_per_step: Vec<f64>,
    /// `(Re, MAE over all steps)` per held-out simulation (the buoyancy factor for a plume).
    per_re: Vec<(f64, f64)>,
    /// Plume runs: the density's mean MAE over each step range (absent for the wake).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    density_mean_mae: Vec<f64>,
}

fn sol_eval(args: SolEvalArgs) -> anyhow::Result<()> {
    ensure!(args.steps >= 1, "--steps must be at least 1");
    for run in &args.runs {
        require_dir(run, "--runs directory")?;
    }
    let first = &args.runs[0];
    let (settings, data) = load_data(first)?.ok_or_else(|| {
        anyhow::anyhow!("{} holds no reference data: is it a `sol train` run directory?", first.display())
    })?;
    ensure!(!data.test.is_empty(), "{}: the data has no held-out Reynolds numbers to evaluate on", first.display());
    let frames = data.test.iter().map(ReferenceSim::len).min().unwrap_or(0);
    ensure!(
        args.steps < frames,
        "--steps {} needs {} held-out frames, the data of {} has {frames}: use --steps {} at most",
        args.steps,
        args.steps + 1,
        first.display(),
        frames - 1
    );
    let n = args.steps;
    // Columns: steps 1-32, 1-N and N/2+1-N (N = --steps; 1-32, 1-128, 65-128 by default).
    let ranges = [(0, 32.min(n)), (0, n), (n / 2, n)];
    let labels: Vec<String> = ranges.iter().map(|(a, b)| format!("steps {}-{}", a + 1, b)).collect();
    let mut rows = Vec::new();
    let row = |name: String, run: Option<PathBuf>, ev: sil::Evaluation| MaeRow {
        name,
        run,
        mean_mae: ranges.iter().map(|&(a, b)| ev.mean_over(a, b)).collect(),
        density_mean_mae: if ev.scalar_mae_per_step.is_empty() {
            Vec::new()
        } else {
            ranges.iter().map(|&(a, b)| ev.scalar_mean_over(a, b)).collect()
        },
        mae_per_step: ev.mae_per_step,
        per_re: ev.per_sim,
    };
    let evaluate = |c: Option<&sil::Corrector>| -> anyhow::Result<sil::Evaluation> {
        Ok(match &settings.plume {
            Some(p) => sil::evaluate(p, &data.test, n, c)?,
            None => sil::evaluate(&settings.wake, &data.test, n, c)?,
        })
    };
    let t0 = Instant::now();
    rows.push(row("source".into(), None, evaluate(None)?));
    for run in &args.runs {
        if run != first {
            let other = load_data(run)?.map(|(s, _)| s);
            ensure!(
                other.as_ref() == Some(&settings),
                "{} was trained on other data than {} (compare their data/reference.json); evaluate runs of one data set together",
                run.display(),
                first.display()
            );
        }
        let (corrector, step) = sil::load_trained(run).with_context(|| format!("reading the run {}", run.display()))?;
        let info = pbdl_core::io::read_checkpoint_info(latest_checkpoint(run)?.unwrap_or_default())?;
        let variant: Variant = serde_json::from_value(info.config["train"]["variant"].clone())?;
        let name = format!("{} (seed {}, {step} updates)", variant.name(), info.seed.unwrap_or(0));
        let ev = evaluate(Some(&corrector))?;
        rows.push(row(name, Some(run.clone()), ev));
    }
    for r in &rows {
        ensure!(r.mean_mae.iter().all(|x| x.is_finite()), "{}: non-finite MAE {:?}", r.name, r.mean_mae);
    }
    let res: Vec<f64> = data.test.iter().map(|r| r.re).collect();
    let (param, coarse, factor) = match &settings.plume {
        Some(p) => ("buoyancy", p.coarse, p.factor),
        None => ("Re", settings.wake.coarse, settings.wake.factor),
    };
    let mut columns = labels.clone();
    if settings.plume.is_some() {
        columns.extend(labels.iter().map(|l| format!("density {l}")));
    }
    let mut md = format!(
        "# Solver-in-the-Loop: velocity MAE on held-out {param} {res:?}, {n} steps from frame 0\n\n\
         Source {coarse:?} cells, reference {factor}x finer; mean over the held-out simulations of the MAE per step, averaged over each step range.\n\n\
         | | {} |\n|---|{}\n",
        columns.join(" | "),
        "---:|".repeat(columns.len())
    );
    for r in &rows {
        let cells: Vec<String> = r.mean_mae.iter().chain(&r.density_mean_mae).map(|x| format!("{x:.4}")).collect();
        md.push_str(&format!("| {} | {} |\n", r.name, cells.join(" | ")));
    }
    let png = with_ext(&args.out, "png");
    let series: Vec<Series> = rows
        .iter()
        .map(|r| Series::new(r.name.clone(), (1..=n).map(|s| s as f64).collect(), r.mae_per_step.clone()))
        .collect();
    let style = PlotStyle {
        title: format!("velocity MAE vs step, held-out {param} {res:?}"),
        x_label: "step".into(),
        y_label: "MAE".into(),
        ..Default::default()
    };
    if let Some(parent) = png.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    line_plot(&png, &series, &style)?;
    md.push_str(&format!("\n![MAE vs step]({})\n", png.file_name().map(|f| f.to_string_lossy()).unwrap_or_default()));
    let json = serde_json::json!({
        "steps": n, "held_out_re": res, "columns": labels, "rows": rows, "scene": settings,
        "seconds": t0.elapsed().as_secs_f64(),
    });
    write_json(with_ext(&args.out, "json"), &json)?;
    write_text(with_ext(&args.out, "md"), &md)?;
    println!("{md}");
    println!("wrote {} (.md, .json, .png)", with_ext(&args.out, "md").with_extension("").display());
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// control train | eval

/// The settings of a `control train` run, as stored in `DIR/config.json` (and as `--config`
/// may give them: any subset of the fields).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct ControlSettings {
    problem: BurgersControlConfig,
    net: ConvNetConfig,
    /// Seed of the networks' initial weights.
    net_seed: u64,
    /// Training scenes `0..train_scenes` of `train_seed`.
    train_scenes: usize,
    train_seed: u64,
    /// Held-out scenes `0..test_scenes` of `test_seed` (`control eval`).
    test_scenes: usize,
    test_seed: u64,
    supervised: pbdl_sol::control::TrainConfig,
    end_to_end: pbdl_sol::control::TrainConfig,
    checkpoint_every: u64,
}

impl Default for ControlSettings {
    /// The acceptance recipe of pbdl-sol/tests/control.rs without its time budgets (a resumed
    /// run is exact only without one): 1000 training scenes (seed 1), 32 held-out (seed 2),
    /// 3000 supervised updates (batch 16, lr 1e-3), 1000 end-to-end (batch 8, lr 1e-4, clip 10).
    fn default() -> Self {
        use pbdl_sol::control::TrainConfig;
        Self {
            problem: BurgersControlConfig::default(),
            net: ConvNetConfig::default(),
            net_seed: 0,
            train_scenes: 1000,
            train_seed: 1,
            test_scenes: 32,
            test_seed: 2,
            supervised: TrainConfig { iterations: 3000, batch: 16, lr: 1e-3, seed: 10, ..Default::default() },
            end_to_end: TrainConfig {
                iterations: 1000,
                batch: 8,
                lr: 1e-4,
                clip_norm: 10.0,
                seed: 11,
                ..Default::default()
            },
            checkpoint_every: 50,
        }
    }
}

impl ControlSettings {
    fn quick() -> Self {
        use pbdl_sol::control::TrainConfig;
        Self {
            problem: BurgersControlConfig { cells: 32, steps: 4, ..Default::default() },
            net: ConvNetConfig { width: 4, levels: 2, kernel: 3, ..Default::default() },
            train_scenes: 8,
            test_scenes: 4,
            supervised: TrainConfig { iterations: 6, batch: 4, lr: 3e-3, seed: 10, ..Default::default() },
            end_to_end: TrainConfig {
                iterations: 4,
                batch: 4,
                lr: 1e-3,
                clip_norm: 10.0,
                seed: 11,
                ..Default::default()
            },
            checkpoint_every: 2,
            ..Self::default()
        }
    }

    fn controller(&self) -> anyhow::Result<Controller> {
        Ok(Controller::new(&self.problem, &self.net, DType::F32, &Device::Cpu, self.net_seed)?)
    }
}

fn control_train(args: ControlTrainArgs) -> anyhow::Result<()> {
    let base = if args.quick { ControlSettings::quick() } else { ControlSettings::default() };
    let mut settings: ControlSettings = match &args.config {
        // The file's fields over the defaults (a partial file keeps the rest).
        Some(path) => {
            let mut v = serde_json::to_value(&base)?;
            let file: serde_json::Value = read_config(path)?;
            merge(&mut v, file);
            serde_json::from_value(v).with_context(|| format!("--config {}", path.display()))?
        }
        None => base,
    };
    settings.net_seed = args.seed;
    let settings = roundtrip(&settings)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating --out {}", args.out.display()))?;
    let config_path = args.out.join("config.json");
    if config_path.exists() {
        let stored: ControlSettings = serde_json::from_str(&std::fs::read_to_string(&config_path)?)
            .with_context(|| format!("{}: not the settings of `control train`", config_path.display()))?;
        ensure!(
            stored == settings,
            "{} holds a run of other settings ({}), not this call's ({}); resume with the run's settings or use another --out",
            args.out.display(),
            serde_json::to_string(&stored)?,
            serde_json::to_string(&settings)?
        );
        println!("resuming {}", args.out.display());
    } else {
        write_json(&config_path, &settings)?;
    }
    let dev = Device::Cpu;
    let t0 = Instant::now();
    let scenes = scene::generate(&settings.problem, settings.train_seed, 0..settings.train_scenes, DType::F32, &dev)?;
    let ctrl = settings.controller()?;
    let sup_dir = RunDir::new(args.out.join("supervised")).every(settings.checkpoint_every);
    let sup = pretrain_supervised_resumable(&ctrl, &scenes, &settings.supervised, &sup_dir)?;
    println!(
        "supervised: {} updates ({} in this call, {:.1} s), loss {:.4} -> {:.4} (mean of the last 50)",
        sup.losses.len(),
        sup.losses.len() as u64 - sup.resumed_from,
        sup.seconds,
        sup.losses.first().copied().unwrap_or(f64::NAN),
        sup.tail_mean(50)
    );
    let e2e_dir = RunDir::new(args.out.join("end_to_end")).every(settings.checkpoint_every);
    let e2e = train_end_to_end_resumable(&ctrl, &scenes, &settings.end_to_end, &e2e_dir)?;
    println!(
        "end to end: {} updates ({} in this call, {:.1} s), loss {:.4} -> {:.4} (mean of the last 20)",
        e2e.losses.len(),
        e2e.losses.len() as u64 - e2e.resumed_from,
        e2e.seconds,
        e2e.losses.first().copied().unwrap_or(f64::NAN),
        e2e.tail_mean(20)
    );
    let summary = serde_json::json!({
        "settings": settings,
        "parameters": pbdl_nets::count_parameters(ctrl.varmap()),
        "supervised": { "updates": sup.losses.len(), "final_loss_mean_last_50": sup.tail_mean(50) },
        "end_to_end": { "updates": e2e.losses.len(), "final_loss_mean_last_20": e2e.tail_mean(20) },
        "seconds_this_call": t0.elapsed().as_secs_f64(),
    });
    write_json(args.out.join("summary.json"), &summary)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// `patch`'s fields into `base`, recursively (objects merge, everything else replaces).
fn merge(base: &mut serde_json::Value, patch: serde_json::Value) {
    match (base, patch) {
        (serde_json::Value::Object(b), serde_json::Value::Object(p)) => {
            for (k, v) in p {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, p) => *b = p,
    }
}

/// One row of the `control eval` table.
#[derive(Serialize)]
struct ControlRow {
    name: String,
    effort: f64,
    target_error: f64,
    combined: f64,
    seconds: f64,
    note: String,
}

/// The controller of the newest checkpoint of a phase directory.
fn load_phase(settings: &ControlSettings, dir: &Path) -> anyhow::Result<Controller> {
    let ck = latest_checkpoint(dir)?.ok_or_else(|| {
        anyhow::anyhow!("{} holds no checkpoint: run `cargo xtask control train` first", dir.display())
    })?;
    let ctrl = settings.controller()?;
    load_varmap(&ck, ctrl.varmap()).with_context(|| format!("loading {}", ck.display()))?;
    Ok(ctrl)
}

fn control_eval(run: &Path, out: &Path) -> anyhow::Result<()> {
    require_dir(run, "--run directory")?;
    let config_path = run.join("config.json");
    ensure!(config_path.exists(), "{} has no config.json: is it a `control train` run directory?", run.display());
    let settings: ControlSettings = serde_json::from_str(&std::fs::read_to_string(&config_path)?)
        .with_context(|| format!("reading {}", config_path.display()))?;
    let p = settings.problem;
    let test = scene::generate(&p, settings.test_seed, 0..settings.test_scenes, DType::F32, &Device::Cpu)?;
    let ctrl = load_phase(&settings, &run.join("end_to_end"))?;
    let sup = load_phase(&settings, &run.join("supervised"))?;
    let score = |forces: &[Tensor], last: &Tensor| {
        ControlScore::of(forces, p.dt, last, &test.target, p.target_weight).map_err(anyhow::Error::from)
    };
    // The controller's inference wall-clock: one warm-up, then the median of three.
    ctrl.rollout(&test.initial, &test.target)?;
    let mut times = Vec::new();
    let mut ours = ControlScore::default();
    for _ in 0..3 {
        let t = Instant::now();
        let r = ctrl.rollout(&test.initial, &test.target)?;
        times.push(t.elapsed().as_secs_f64());
        ours = score(&r.forces, &r.states[p.steps])?;
    }
    times.sort_by(f64::total_cmp);
    let infer = times[1];
    let t = Instant::now();
    let rs = sup.rollout(&test.initial, &test.target)?;
    let sup_seconds = t.elapsed().as_secs_f64();
    let sup_score = score(&rs.forces, &rs.states[p.steps])?;
    let opt = optimize_forces(
        &p,
        &test.initial,
        &test.target,
        &DirectOptimConfig { lr: 0.1, max_iterations: 100_000, time_budget_s: infer },
    )?;
    let zero: Vec<Tensor> = (0..p.steps).map(|_| test.initial.zeros_like()).collect::<candle_core::Result<_>>()?;
    let natural = ForcedBurgers::new(&p)?.rollout(&test.initial, &zero)?;
    let none = score(&zero, &natural[p.steps])?;
    let row = |name: &str, s: &ControlScore, seconds: f64, note: String| ControlRow {
        name: name.into(),
        effort: s.effort,
        target_error: s.target_error,
        combined: s.combined,
        seconds,
        note,
    };
    let rows = vec![
        row("controller (end to end)", &ours, infer, "median of 3 timed rollouts".into()),
        row("controller (supervised only)", &sup_score, sup_seconds, String::new()),
        row("optimiser, same wall-clock", &opt.score, opt.seconds, format!("{} Adam steps (lr 0.1)", opt.iterations)),
        row("no control", &none, 0.0, String::new()),
    ];
    for r in &rows {
        ensure!(r.combined.is_finite(), "{}: non-finite score", r.name);
    }
    let mut md = format!(
        "# PDE control of forced Burgers: {} held-out scenes (seed {}), {} cells, {} steps\n\n\
         Run {}. Effort + target error (weight {}); the optimiser gets the controller's inference time.\n\n\
         | | effort | target error | effort + target error | seconds | |\n|---|---:|---:|---:|---:|---|\n",
        settings.test_scenes,
        settings.test_seed,
        p.cells,
        p.steps,
        run.display(),
        p.target_weight
    );
    for r in &rows {
        md.push_str(&format!(
            "| {} | {:.4} | {:.4} | {:.4} | {:.3} | {} |\n",
            r.name, r.effort, r.target_error, r.combined, r.seconds, r.note
        ));
    }
    let json = serde_json::json!({ "run": run, "settings": settings, "rows": rows });
    write_json(with_ext(out, "json"), &json)?;
    write_text(with_ext(out, "md"), &md)?;
    println!("{md}");
    println!("wrote {} (.md, .json)", with_ext(out, "md").with_extension("").display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_parse_and_bad_ones_are_named() {
        assert_eq!(parse_variant("sol-8").unwrap(), Variant::Sol { m: 8 });
        assert_eq!(parse_variant("PRE").unwrap(), Variant::Pre);
        assert_eq!(parse_variant("non").unwrap(), Variant::Non);
        for bad in ["sol-0", "sol", "sol-x", "foo"] {
            let e = parse_variant(bad).unwrap_err().to_string();
            assert!(e.contains(bad) && e.contains("sol-<m>"), "{e}");
        }
        assert_eq!(with_ext(Path::new("a/b.json"), "md"), PathBuf::from("a/b.md"));
        assert_eq!(with_ext(Path::new("a/b"), "png"), PathBuf::from("a/b.png"));
        assert_eq!(with_ext(Path::new("a/b.v2"), "png"), PathBuf::from("a/b.v2.png"));
    }
}
