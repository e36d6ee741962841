//! `pbdl-metrics`' entries for `cargo xtask` (see [`crate::registry`]).
//!
//! * tour `lsim`: LSiM on the published plume example (`../shared/data/lsim-example`), the two
//!   distances against the published 0.3791 / 0.4433 and the time per call.
//! * bench `lsim`: LSiM time per pair (224 path from 128x128 and 256x256, native 128x128, batches
//!   of 16 on both paths) with the error against the published values where the example data is
//!   present; VolSiM (3-scale weights) per 64^3 pair, at native size and from 48^3 with the
//!   cubic-spline resize to 64^3. The official PyTorch code is measured on the same cases by
//!   `bench/peers/metrics_run.sh` (peer rows, merged with their date and versions).
//! * bench `classic`: MSE, SSIM, Pearson, Spearman and the energy spectrum on 16 fields of 128x128.
//! * stress `acceptance`: the README's metric-training claim from its `#[ignore]`d test
//!   ([`crate::acceptance`]).

use crate::acceptance::AcceptanceTest;
use crate::bench_schema::{format_seconds, median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::seed;
use pbdl_metrics::classic::{energy_spectrum, mse, pearson, spearman, ssim2d, SsimConfig};
use pbdl_metrics::lsim::{hwc_to_nchw, LsimOptions, LsimSize, PUBLISHED_EXAMPLE_DISTANCES as LSIM_PUBLISHED};
use pbdl_metrics::weights::{weights_dir, LSIM_FILE, VOLSIM_FILE};
use pbdl_metrics::{Lsim, Volsim};
use std::path::PathBuf;

/// The entries of `pbdl-metrics`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "metrics",
        tour: vec![Entry {
            name: "lsim",
            about: "LSiM on the published plume example: distances against the published values, time per call.",
            run: tour_lsim,
        }],
        bench: vec![
            Entry {
                name: "lsim",
                about: "LSiM time per pair (224 and native, batches of 16) and error vs published; VolSiM per 64^3 pair (native, resized from 48^3). Peers: bench/peers/metrics_run.sh.",
                run: bench_lsim,
            },
            Entry {
                name: "classic",
                about: "MSE, SSIM, Pearson, Spearman, energy spectrum on 16 fields of 128x128.",
                run: bench_classic,
            },
        ],
        stress: vec![
            Entry {
                name: "acceptance",
                about: "The README's metric-training claim: trains from scratch in its #[ignore]d test (about 8 min; not in quick).",
                run: stress_acceptance,
            },
        ],
    }
}

/// `../shared/data/lsim-example` if it exists.
fn example_dir() -> Option<PathBuf> {
    let d = PathBuf::from("../shared/data/lsim-example");
    d.is_dir().then_some(d)
}

fn load_lsim() -> TaskResult<Lsim> {
    let dir = weights_dir().ok_or("LSiM weights not found: set PBDL_WEIGHTS_DIR or put them in ../shared/weights")?;
    Ok(Lsim::load(dir.join(LSIM_FILE))?)
}

/// The three example images as `[1, 3, 256, 256]` u8 tensors: reference, A, B.
fn example_images(dir: &std::path::Path) -> TaskResult<[Tensor; 3]> {
    let read = |n: &str| -> TaskResult<Tensor> {
        Ok(hwc_to_nchw(&pbdl_core::io::read_npy(dir.join(format!("lsim_example_plume{n}.npy")))?)?)
    };
    Ok([read("Reference")?, read("A")?, read("B")?])
}

fn tour_lsim(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let lsim = load_lsim()?;
    let dir = example_dir().ok_or("../shared/data/lsim-example not found")?;
    let [r, a, b] = example_images(&dir)?;
    let reps = if ctx.quick { 3 } else { 7 };
    let mut rows = Vec::new();
    let mut md =
        String::from("| pair | LSiM (pbdl) | published | abs. error | time per call |\n|---|---:|---:|---:|---:|\n");
    for ((name, x), published) in [("plumeA", &a), ("plumeB", &b)].into_iter().zip(LSIM_PUBLISHED) {
        let d = lsim.distance(&r, x)?[0];
        let secs = median_seconds(1, reps, || lsim.distance(&r, x).ok());
        md.push_str(&format!(
            "| reference vs {name} | {d:.4} | {published:.4} | {:.1e} | {} |\n",
            (d - published).abs(),
            format_seconds(secs)
        ));
        rows.push(TourRow {
            item: format!("LSiM d(reference, {name}), 256x256 -> 224"),
            seconds: secs,
            error: Some((d - published).abs()),
            error_kind: "abs diff vs published".into(),
            note: format!("d = {d:.4}, published {published:.4}"),
        });
    }
    md.push_str(&format!(
        "\nOn {} threads; the published values are from tum-pbs/LSIM `distance_example.py`.",
        ctx.threads
    ));
    Ok(TourOutcome { rows, files: vec![], markdown: md })
}

fn row(case: &str, size: &str, seconds: f64, error: Option<f64>, threads: usize) -> BenchRow {
    BenchRow {
        case: case.into(),
        method: "pbdl".into(),
        size: size.into(),
        seconds,
        unit: "pair".into(),
        error,
        error_kind: if error.is_some() { "abs diff vs published LSiM example".into() } else { String::new() },
        peer: false,
        threads,
    }
}

fn bench_lsim(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let lsim = load_lsim()?;
    let reps = if ctx.quick { 3 } else { 7 };
    let dev = Device::Cpu;
    let mut rows = Vec::new();
    // Published example: 256x256 -> 224, with its error.
    if let Some(dir) = example_dir() {
        let [r, a, b] = example_images(&dir)?;
        let err = (lsim.distance(&r, &a)?[0] - LSIM_PUBLISHED[0])
            .abs()
            .max((lsim.distance(&r, &b)?[0] - LSIM_PUBLISHED[1]).abs());
        let secs = median_seconds(1, reps, || lsim.distance(&r, &a).ok());
        rows.push(row("lsim_example", "256x256->224", secs, Some(err), ctx.threads));
    }
    let pair = |n: usize, batch: usize, s: u64| -> TaskResult<(Tensor, Tensor)> {
        Ok((
            seed::rand_uniform((batch, 1, n, n), 0.0, 1.0, DType::F32, &dev, s)?,
            seed::rand_uniform((batch, 1, n, n), 0.0, 1.0, DType::F32, &dev, s + 1)?,
        ))
    };
    let (a, b) = pair(128, 1, 10)?;
    let secs = median_seconds(1, reps, || lsim.distance(&a, &b).ok());
    rows.push(row("lsim_224", "128x128->224", secs, None, ctx.threads));
    let native = LsimOptions { size: LsimSize::Native, ..Default::default() };
    let secs = median_seconds(1, reps, || lsim.distance_with(&a, &b, &native).ok());
    rows.push(row("lsim_native", "128x128", secs, None, ctx.threads));
    let (a, b) = pair(128, 16, 20)?;
    let secs = median_seconds(1, reps.min(3), || lsim.distance(&a, &b).ok()) / 16.0;
    rows.push(row("lsim_224_batch16", "16x128x128->224", secs, None, ctx.threads));
    let secs = median_seconds(1, reps.min(3), || lsim.distance_with(&a, &b, &native).ok()) / 16.0;
    rows.push(row("lsim_native_batch16", "16x128x128", secs, None, ctx.threads));
    // VolSiM (3-scale weights), one pair at 64^3, if its weights are there too.
    if let Some(v) = weights_dir().map(|d| d.join(VOLSIM_FILE)).filter(|p| p.exists()) {
        let v = Volsim::load(v)?;
        let a = seed::rand_uniform((1, 1, 64, 64, 64), 0.0, 1.0, DType::F32, &dev, 30)?;
        let b = seed::rand_uniform((1, 1, 64, 64, 64), 0.0, 1.0, DType::F32, &dev, 31)?;
        let secs = median_seconds(1, reps.min(3), || v.distance(&a, &b).ok());
        rows.push(row("volsim_3scales", "64x64x64", secs, None, ctx.threads));
        let r = v.with_resize(Some(pbdl_metrics::volsim::VOLSIM_RESIZE))?;
        let a = seed::rand_uniform((1, 1, 48, 48, 48), 0.0, 1.0, DType::F32, &dev, 32)?;
        let b = seed::rand_uniform((1, 1, 48, 48, 48), 0.0, 1.0, DType::F32, &dev, 33)?;
        let secs = median_seconds(1, reps.min(3), || r.distance(&a, &b).ok());
        rows.push(row("volsim_3scales_resize64", "48^3->64^3", secs, None, ctx.threads));
    }
    Ok(rows)
}

fn bench_classic(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let dev = Device::Cpu;
    let reps = if ctx.quick { 3 } else { 9 };
    let a = seed::randn((16, 1, 128, 128), 0.0, 1.0, DType::F32, &dev, 1)?;
    let b = (&a + seed::randn((16, 1, 128, 128), 0.0, 0.1, DType::F32, &dev, 2)?)?;
    let cfg = SsimConfig::default();
    let timed: Vec<(&str, f64)> = vec![
        ("mse", median_seconds(1, reps, || mse(&a, &b).ok())),
        ("ssim2d", median_seconds(1, reps, || ssim2d(&a, &b, &cfg).ok())),
        ("pearson", median_seconds(1, reps, || pearson(&a, &b).ok())),
        ("spearman", median_seconds(1, reps, || spearman(&a, &b).ok())),
        ("energy_spectrum", median_seconds(1, reps, || energy_spectrum(&a).ok())),
    ];
    Ok(timed
        .into_iter()
        .map(|(case, s)| BenchRow {
            case: case.into(),
            method: "pbdl".into(),
            size: "16x1x128x128".into(),
            seconds: s,
            unit: "batch".into(),
            error: None,
            error_kind: String::new(),
            peer: false,
            threads: ctx.threads,
        })
        .collect())
}

/// The `#[ignore]`d tests behind the README's metric-training claim (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[AcceptanceTest {
    package: "pbdl-metrics",
    file: "train_full",
    test: "trained_metric_on_unseen_kinds",
    claim: "trained metric beats L2 and SSIM (Spearman) on at least one unseen kind, test seed 1000",
    minutes: 8.0,
    env: &[("RAYON_NUM_THREADS", "1")],
}];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}
