//! `cargo xtask`: pbdl's task runner.
//!
//! * `tour`: runs every available method on its embedded default scene and writes
//!   `target/pbdl/tour/` (`report.md`, PNG/GIF files, `summary.json`), printing a table of time
//!   and error. This is the main job.
//! * `bench [crate]`: time against error in the shared schema, `target/pbdl/bench/<crate>.json`
//!   plus a markdown table and a PNG plot.
//! * `stress [crate]`: long and extreme runs; reports the first step at which an invariant breaks.
//!   `stress fuzz [--target NAME] [--seconds S] [--seed N]`: mutation fuzzing of the file
//!   readers (`xtask::fuzz`); `--write-corpus` regenerates the seed corpus `fuzz/corpus/`.
//! * `sim grid|particles <scene | file.toml>`: runs a scene, writes its trajectory (`.npz`) and
//!   renders; `--seeds N [--shard i/n]` one run per seed, as data shards for a job array.
//! * `metric <lsim|volsim|mse|ssim|...> A B`: a distance between two `.npy`/`.npz`/`.png`
//!   fields as one JSON object (see `pbdl_metrics::files`).
//! * `weights convert IN.pth OUT.safetensors`: the official LSiM / VolSiM checkpoints (legacy
//!   PyTorch pickles) to the safetensors files `pbdl_metrics` loads.
//! * `weather score --forecast F --truth T`: WeatherBench's official scores (RMSE, MAE, ACC,
//!   per lead time) of NetCDF or `.npy` files as one JSON object.
//! * `data metric|acdm ... --shard i/n --out DIR` (also `sim grid|particles --seeds N --shard i/n`,
//!   `weather generate --shard i/n`): training data in shards for a job array;
//!   `data check DIR`: every item once, hashes as recorded (see `pbdl_core::shard`).
//! * `sol train --variant pre|non|sol-<m> --out DIR [--iterations N] [--seed S] [--config F]
//!   [--quick]`: Solver-in-the-Loop on the cylinder wake; generates the reference data (cached in
//!   `DIR/data/`) and trains resumably into `DIR` (the same command continues a stopped run).
//!   `sol eval --runs DIR... [--steps 128] --out F`: velocity MAE per step on the held-out Re for
//!   the source and each run; `F.md`, `F.json` (mean MAE over steps 1-32, 1-128, 65-128), `F.png`.
//! * `control train --out DIR [--config F] [--seed S] [--quick]`: PDE control of forced Burgers,
//!   supervised pre-training then end-to-end training, each phase resumable.
//!   `control eval --run DIR --out F`: held-out scenes, controller vs supervised-only vs direct
//!   optimiser at equal wall-clock vs no control; `F.md`, `F.json` (effort, target error, combined).
//! * `ci`: format check, clippy with `-D warnings`, the test suite.

mod bench;
mod ci;
mod data;
mod metric;
mod pconv;
mod report;
mod sim;
mod sol;
mod stress;
mod stress_summary;
mod tour;
mod weather;
mod weights;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use xtask::registry;

/// candle allocates every op output afresh; with glibc, blocks >= 128 KiB go through mmap and
/// each step pays page faults (grid steps at 128^2+). mimalloc reuses them: see
/// docs/candle-traps.md. Binaries and benches only; libraries never set a global allocator.
///
/// Wrapped in a counter of live bytes (two relaxed atomics per allocation) so that
/// `cargo xtask stress fuzz` can flag inputs that make a reader allocate far beyond their size.
#[global_allocator]
static GLOBAL: xtask::fuzz::CountingAlloc<mimalloc::MiMalloc> = xtask::fuzz::CountingAlloc(mimalloc::MiMalloc);

extern "C" {
    /// mimalloc's option setter (exported by the linked mimalloc; declared here because the
    /// `mimalloc` crate only declares it with its `extended` feature).
    fn mi_option_set(option: std::ffi::c_int, value: std::ffi::c_long);
}

/// `mi_option_purge_delay` (the same index in mimalloc v2 and v3).
const MI_OPTION_PURGE_DELAY: std::ffi::c_int = 15;

/// Keeps freed pages mapped instead of returning them to the OS 10 ms later: a training step
/// frees and re-allocates the same few MB-sized op outputs, and every returned page came back
/// as a page fault the kernel clears (38% of the WeatherBench ResNet step was `clear_page`;
/// with purging off the step took 3.5-3.6 s instead of 4.8-5.2 s). The price is that the
/// process keeps its peak memory.
fn keep_freed_pages() {
    // SAFETY: setting a documented mimalloc option to a documented value (-1: never purge).
    unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, -1) }
}

#[derive(Parser)]
#[command(name = "cargo xtask", about = "pbdl's task runner: tour, bench, stress, ci")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run every method on its embedded default scene; write target/pbdl/tour/.
    Tour {
        /// Only this crate (core, grid, ...); all when omitted.
        krate: Option<String>,
        /// Only the entry of this name.
        #[arg(long)]
        entry: Option<String>,
        /// Smaller sizes and fewer repetitions.
        #[arg(long)]
        quick: bool,
        /// Output directory (default: target/pbdl/tour).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Measure time against error; write target/pbdl/bench/<crate>.{json,md,png}.
    Bench {
        /// Only this crate (core, grid, ...); all when omitted.
        krate: Option<String>,
        /// Smaller sizes and fewer repetitions.
        #[arg(long)]
        quick: bool,
        /// Only the entry of this name (its report goes to <crate>_<entry>.{json,md,png}).
        #[arg(long)]
        entry: Option<String>,
    },
    /// Long and extreme runs; exits non-zero when an invariant breaks. `stress fuzz` fuzzes the
    /// file readers instead (see --target, --seconds, --seed, --write-corpus).
    Stress {
        /// Only this crate; all when omitted. `fuzz`: mutation fuzzing of the file readers.
        krate: Option<String>,
        /// Smaller sizes and fewer steps (fuzz: 5 s per target).
        #[arg(long)]
        quick: bool,
        /// Only the entry of this name (its report goes to <crate>_<entry>.json).
        #[arg(long)]
        entry: Option<String>,
        #[command(flatten)]
        fuzz: stress::FuzzArgs,
    },
    /// Run a simulation scene; write its trajectory (.npz, [T, C, Y, X] per field) and PNG/GIF
    /// renders to target/pbdl/sim/<scene>/.
    #[command(after_help = SIM_HELP)]
    Sim {
        /// The simulator crate: `grid` or `particles`.
        krate: String,
        /// A built-in scene name (grid: burgers_1d, burgers_2d, heat, poisson,
        /// advection_diffusion, taylor_green, lid_driven_cavity, kolmogorov, smoke_plume,
        /// cylinder; particles: shock_tube, dam_break, dam_break_iisph, dam_break_dfsph, periodic_1d_noise,
        /// periodic_2d_box) or a .toml file.
        scene: String,
        /// Cells along x (y scaled to keep the aspect ratio).
        #[arg(long)]
        res: Option<usize>,
        /// Number of steps (replaces the scene's steps / t_end; the time step is kept). For
        /// particles: the number of output frames (the frame interval is kept).
        #[arg(long)]
        steps: Option<usize>,
        /// Runs 0..N, one .npz each: particles with seeds seed+k (noise scenes differ per seed);
        /// grid scenes with their random inputs' seeds + k (`init = random_modes`: burgers_2d,
        /// decaying_turbulence, kolmogorov; other scenes are refused).
        #[arg(long)]
        seeds: Option<usize>,
        /// With --seeds: only this job's runs, `i/n` (0-based), written as data shards
        /// (`item-<k>.npz` + `manifest-i-of-n.json`; check with `cargo xtask data check`).
        #[arg(long)]
        shard: Option<pbdl_core::shard::Shard>,
        /// Particles: f32 or f64 (replaces the scene's `precision`, default f64).
        #[arg(long)]
        precision: Option<String>,
        /// Start from the fields in this .npz (see below for names and layout).
        #[arg(long)]
        init: Option<PathBuf>,
        /// Output directory (default: target/pbdl/sim/<scene>).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// A distance between two fields in files (.npy, single-array .npz, .png); prints one JSON
    /// object `{"distance": d}` (a list for batches of LSiM/VolSiM pairs).
    #[command(after_help = METRIC_HELP)]
    Metric {
        /// lsim, volsim, mse, mae, rmse, rel_l2, psnr, ssim, pearson, spearman or spectral.
        metric: String,
        /// First field (the reference for rel_l2 and psnr).
        a: PathBuf,
        /// Second field, of the same shape.
        b: PathBuf,
        /// Weight file of lsim/volsim (default: ../shared/weights/ or $PBDL_WEIGHTS_DIR).
        #[arg(long)]
        weights: Option<PathBuf>,
        /// LSiM at the input's own size instead of the nearest resize to 224.
        #[arg(long)]
        native: bool,
        /// Normalise a batch jointly (official code) instead of per pair.
        #[arg(long)]
        joint_batch: bool,
        /// VolSiM: cubic-spline resize of both volumes to 64^3 first (the official option).
        #[arg(long)]
        resize64: bool,
    },
    /// Weight files of the learned metrics.
    #[command(subcommand)]
    Weights(WeightsCommand),
    /// WeatherBench: official scores of forecast files; the stand-in climate, the ResNet forecaster.
    #[command(subcommand)]
    Weather(WeatherCommand),
    /// Training data in shards (`--shard i/n`, one job each, any scheduler) and their check.
    #[command(subcommand)]
    Data(data::DataCommand),
    /// Solver-in-the-Loop (Um et al. 2020) on the cylinder wake: train PRE / NON / SOL-m
    /// correctors (resumable), evaluate them on held-out Reynolds numbers.
    #[command(subcommand)]
    Sol(sol::SolCommand),
    /// Learned particle convolutions (CConv / SFBC / antisymmetric) on SFBC's test case I:
    /// train one network (resumable), or evaluate every basis (time-against-error table).
    #[command(subcommand)]
    Pconv(pconv::PconvCommand),
    /// Latent-space physics (Wiewel et al. 2019) on 2D smoke: train the pressure autoencoder and
    /// the LSTM (resumable), evaluate hybrid rollouts against the solver (time vs error).
    #[command(subcommand)]
    Latent(xtask::latent::LatentCommand),
    /// Temporally coherent super-resolution of smoke (tempoGAN / TecoGAN): train the baseline,
    /// per-frame GAN and temporal GAN (resumable), score them, upscale an .npz sequence.
    #[command(subcommand)]
    Temporal(xtask::temporal::TemporalCommand),
    /// PDE control of forced 1D Burgers (Holl et al. 2020): train the controller (resumable),
    /// evaluate it against the direct optimiser and no control.
    #[command(subcommand)]
    Control(sol::ControlCommand),
    /// fmt check, clippy -D warnings, tests.
    Ci,
    /// List the registered tour, bench and stress entries.
    List,
}

#[derive(Subcommand)]
enum WeatherCommand {
    /// Score a forecast against the truth as WeatherBench's score.py does (latitude-weighted,
    /// f64); prints one JSON object on the last line.
    #[command(after_help = WEATHER_SCORE_HELP)]
    Score {
        /// Forecast: NetCDF (classic or NetCDF-4) or .npy [time, lat, lon].
        #[arg(long)]
        forecast: PathBuf,
        /// Truth: NetCDF or .npy [time, lat, lon]; must hold no NaN.
        #[arg(long)]
        truth: PathBuf,
        /// Variable to score (default: the file's only data variable).
        #[arg(long)]
        var: Option<String>,
        /// rmse (one square root over time and space, score.py's default), rmse_mean_per_time
        /// (the paper's mean of per-forecast RMSEs), mae or acc.
        #[arg(long, default_value = "rmse")]
        metric: String,
        /// Latitudes (degrees, 1-D .npy) of .npy inputs.
        #[arg(long)]
        lat: Option<PathBuf>,
        /// Pressure level (hPa) of a variable with a level dimension (default: 500 for z, 850 for t).
        #[arg(long)]
        level: Option<f64>,
    },
    /// Run the stand-in climate (shallow water on the sphere): an unbiased "truth" and a biased
    /// "climate model"; writes NetCDF-4 files in WeatherBench's layout (with --shard i/n: data
    /// shards, one .npz per run).
    Generate {
        /// Output directory (default: target/pbdl/weather/data).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Years of the truth run (the last two are validation and test).
        #[arg(long, default_value_t = 4.0)]
        truth_years: f64,
        /// Years of the biased climate-model run (pretraining data).
        #[arg(long, default_value_t = 10.0)]
        climate_years: f64,
        /// Seed of the truth run (the climate run uses seed + 1000).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Only this job's runs, `i/n` (0-based), as data shards: item 0 is the truth run, item 1
        /// the climate run, each one `item-<k>.npz` (z, t, times, grid; the truth also the
        /// constants) plus `manifest-i-of-n.json`; `weather train`/`eval --data DIR` read the
        /// checked directory (`cargo xtask data check DIR`). Without it: the NetCDF files.
        #[arg(long)]
        shard: Option<pbdl_core::shard::Shard>,
    },
    /// Train the CPU-sized Rasp & Thuerey ResNet (continuous lead 6 h..5 d) on generated data.
    Train(weather::TrainArgs),
    /// Score baselines and trained runs on the truth's test year: RMSE and ACC per lead,
    /// report.md, scores.json and RMSE-vs-lead plots.
    Eval {
        /// Data directory of `weather generate`, plain or its shards (default:
        /// target/pbdl/weather/data).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Run directories of `weather train` to score.
        #[arg(long = "run")]
        runs: Vec<PathBuf>,
        /// Output directory (default: target/pbdl/weather/eval).
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

const WEATHER_SCORE_HELP: &str = "\
NetCDF variables are [time, lat, lon] or [time, level, lat, lon] at valid times, or
[lead_time, time, lat, lon] with time = initialisation time and lead_time in hours (NaN where
no truth exists): then each lead is scored at valid time = init + lead and the output is
{\"lead_time\": [...], \"rmse\": [...]}. Forecast and truth are joined on time (inner join);
.npy inputs are matched by position. WeatherBench 2 names (latitude, longitude,
prediction_timedelta) are accepted; latitudes must ascend.

Examples:
  cargo xtask weather score --forecast fc.nc --truth z500_2017.nc --var z
  cargo xtask weather score --forecast fc.npy --truth truth.npy --lat lat.npy --metric acc";

#[derive(Subcommand)]
enum WeightsCommand {
    /// Convert an official LSiM / VolSiM checkpoint (legacy, pre-1.6 PyTorch `.pth`) to the
    /// safetensors layout of `pbdl_metrics::weights` (tensors `model.<key>`, `norm.mean.<i>`,
    /// `norm.m2.<i>`; metadata `normCount`, `hyperparams`).
    #[command(after_help = WEIGHTS_HELP)]
    Convert {
        /// The `.pth` file (tum-pbs/LSIM `Models/LSiM.pth` or tum-pbs/VOLSIM `models/MS_3scales.pth`).
        input: PathBuf,
        /// The safetensors file to write (e.g. `LSiM.safetensors`, `VolSiM_MS_3scales.safetensors`).
        output: PathBuf,
    },
}

const WEIGHTS_HELP: &str = "\
Get the official files (MIT licence, TUM; keep the licence with them):
  https://github.com/tum-pbs/LSIM/raw/master/Models/LSiM.pth
  https://github.com/tum-pbs/VOLSIM/raw/main/models/MS_3scales.pth

Example:
  cargo xtask weights convert LSiM.pth weights/LSiM.safetensors
  cargo xtask weights convert MS_3scales.pth weights/VolSiM_MS_3scales.safetensors
then set PBDL_WEIGHTS_DIR=weights (or put them in ../shared/weights).";

const METRIC_HELP: &str = "\
Layouts: lsim [H, W], [H, W, C] or a batch [B, H, W, C] (C = 1 or 3; u8/f32/f64); volsim
[D, H, W], [D, H, W, C] or [B, D, H, W, C]; the classic metrics read the whole array as one field
of 1 to 3 dimensions (ssim: 2 or 3). PNG: 8-bit gray is [H, W] u8, colour [H, W, 3] u8.

Examples:
  cargo xtask metric lsim ref.npy a.npy
  cargo xtask metric lsim ref.png a.png --native
  cargo xtask metric volsim a.npy b.npy --weights VolSiM_MS_3scales.safetensors
  cargo xtask metric volsim a.npy b.npy --resize64
  cargo xtask metric ssim a.npz b.npz";

const SIM_HELP: &str = "\
Output: <out>/<scene>.npz with one array per field, [T, C, Y, X] (x fastest, y up), plus
`time` [T] and `step` [T]; PNG/GIF renders beside it. Velocity scenes write `velocity`
[T, 2, Y, X] on cell centres, `velocity_mac` [T, 2, Y, X] as stored (u at x-faces
((i+1) dx, (j+1/2) dy), v at y-faces ((i+1/2) dx, (j+1) dy)) and `vorticity` [T, 1, Y, X] at
the cell corners; smoke_plume also writes `density` [T, 1, Y, X]. Scalar scenes write `u`
(burgers_1d, Y = 1), `temperature` (heat), `phi` and `source` (poisson), `concentration`
(advection_diffusion).

--init FILE.npz: velocity scenes read `velocity` on cell centres, [2, Y, X] or [1, 2, Y, X] or a
trajectory [T, 2, Y, X] (its last frame), any Y, X (resampled bilinearly to the grid), then
averaged to the faces and made divergence-free; or `velocity_mac` with the grid's exact shape.
Scalar scenes read their scalar by the name above ([Y, X], [1, Y, X] or [T, 1, Y, X]; the
Poisson scene reads `source`). smoke_plume reads `density` ([Y, X], [1, Y, X] or
[T, 1, Y, X], resampled like the velocity), the velocity, or both; what is missing is kept.
A trajectory written by `sim` is a valid --init file.

--seeds N (grid): N runs of a scene with a random input (`init = random_modes`: burgers_2d,
decaying_turbulence, kolmogorov, or a .toml), run k with the scene's seed + k (run 0 is the
scene itself), written as <out>/<scene>_seed<k>.npz + renders. Scenes without a random input
refuse --seeds (their runs would all be equal), and so does --init. --shard i/n (grid and
particles) makes job i of n write only its runs, as item-<k>.npz + renders and
manifest-i-of-n.json; run k is the same whatever n is, so the n jobs equal one run, file for
file (`cargo xtask data check DIR` checks the directory).

Particles (`sim particles`): <out>/<scene>_seed<k>.npz with `positions` [T, N, D],
`velocities` [T, N, D], `density` [T, N], `mass` [T, N], for 1D compressible runs (shock
tubes, periodic_1d) `pressure`, `internal_energy` and `smoothing_length` [T, N], and, where
there are walls, ghosts or buffers, `fixed_positions` [F, D] (last frame), in the run's
precision (f64, or f32 with `precision = \"f32\"` in the scene or --precision f32), and `time`
[T] (always f64); <scene>_seed<k>.png (last frame) and .gif beside it. --init FILE.npz reads
`positions` [N, D] or [T, N, D] (last frame), optional `velocities`, `mass`, `density`,
`internal_energy` (or `pressure` with `density`), `smoothing_length` (the fluid; walls come
from the scene; a shock tube's buffers from `fixed_positions`, else laid out beyond the end
particles; f32 or f64). Every trajectory is a valid --init file; a restart in the
trajectory's precision starts from exactly its last frame (its time restarts at 0).

Examples:
  cargo xtask sim grid taylor_green --res 128
  cargo xtask sim grid lid_driven_cavity --res 64 --out /tmp/cavity
  cargo xtask sim grid my_scene.toml --init start.npz --steps 500
  cargo xtask sim grid burgers_2d --seeds 64 --shard 3/8 --out data/burgers   # job 3 of 8
  cargo xtask sim particles periodic_2d_box --seeds 4 --out /tmp/box
  cargo xtask sim particles dam_break_iisph --steps 50
  cargo xtask sim particles shock_tube --precision f32";

fn main() -> anyhow::Result<()> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    keep_freed_pages();
    let cli = Cli::parse();
    match cli.command {
        Command::Tour { krate, entry, quick, out } => tour::run(
            krate.as_deref(),
            entry.as_deref(),
            quick,
            out.unwrap_or_else(|| report::target_dir().join("tour")),
        ),
        Command::Bench { krate, quick, entry } => bench::run(krate.as_deref(), quick, entry.as_deref()),
        Command::Stress { krate, quick, entry, fuzz } if krate.as_deref() == Some("fuzz") => {
            anyhow::ensure!(entry.is_none(), "`stress fuzz` takes --target, not --entry");
            stress::fuzz(fuzz, quick)
        }
        Command::Stress { krate, quick, entry, fuzz } => {
            anyhow::ensure!(fuzz.is_empty(), "--target, --seconds, --seed and --write-corpus are for `stress fuzz`");
            stress::run(krate.as_deref(), quick, entry.as_deref())
        }
        Command::Sim { krate, scene, res, steps, seeds, shard, precision, init, out } => {
            sim::run(sim::SimArgs { krate, scene, res, steps, init, out, seeds, shard, precision })
        }
        Command::Metric { metric, a, b, weights, native, joint_batch, resize64 } => {
            metric::run(metric::MetricArgs { metric, a, b, weights, native, joint_batch, resize64 })
        }
        Command::Weights(WeightsCommand::Convert { input, output }) => weights::convert(&input, &output),
        Command::Data(cmd) => data::run(cmd),
        Command::Weather(WeatherCommand::Score { forecast, truth, var, metric, lat, level }) => {
            weather::score(weather::ScoreArgs { forecast, truth, var, metric, lat, level })
        }
        Command::Weather(WeatherCommand::Generate { out, truth_years, climate_years, seed, shard }) => {
            let out = out.unwrap_or_else(|| report::target_dir().join("weather/data"));
            weather::generate(weather::GenerateArgs { out, truth_years, climate_years, seed, shard })
        }
        Command::Weather(WeatherCommand::Train(args)) => weather::train_cmd(args),
        Command::Weather(WeatherCommand::Eval { data, runs, out }) => {
            let data = data.unwrap_or_else(|| report::target_dir().join("weather/data"));
            let out = out.unwrap_or_else(|| report::target_dir().join("weather/eval"));
            weather::eval(weather::EvalArgs { data, runs, out })
        }
        Command::Sol(cmd) => sol::run_sol(cmd),
        Command::Pconv(cmd) => pconv::run(cmd),
        Command::Latent(cmd) => xtask::latent::run(cmd),
        Command::Temporal(cmd) => xtask::temporal::run(cmd),
        Command::Control(cmd) => sol::run_control(cmd),
        Command::Ci => ci::run(),
        Command::List => {
            registry::print_list();
            Ok(())
        }
    }
}
