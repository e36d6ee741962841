//! The continuous convolution op (`pbdl_pconv::continuous_conv`): forward, and forward +
//! backward (loss `Σ out ⊙ R` with a fixed random `R`, gradients of features, weights and
//! positions), at 10k and 100k particles uniform in the periodic unit box, 2D (radius for ~30
//! neighbours) and 3D (~40 neighbours), `C_in = C_out = 32`, f32, with CConv's filter
//! (`FilterSpec::cconv(dim, 4, r)`: linear basis, ball-to-cube, poly6) and SFBC's Fourier filter
//! (`FilterSpec::sfbc(dim, Basis::Fourier, 4, r)`); `K = 16` in 2D, 64 in 3D. The offsets
//! (`PairGraph::offsets`) are part of every timed iteration; the graph build (cell-list
//! search) is its own row.
//!
//! Quick by design: 10 samples, short measurement; the 100k cases (seconds per iteration, which
//! criterion's 10 samples would make minutes each) are timed by hand, 3 runs, median. `PBDL_PCONV_BENCH_SKIP_100K_3D=1` leaves the
//! largest case out; `PBDL_PCONV_BENCH_FILTER=cconv|sfbc` runs one filter only;
//! `PBDL_PCONV_BENCH_N=10000` one size only (cases are set up before criterion's name filter).

//!
//! Measured 2026-11-27 (release, PBDL_THREADS=2 on a shared 2-core AMD EPYC under load 6-9;
//! medians of alternating runs, seconds, forward / forward+backward): 10k 3D CConv 0.13 / 0.50,
//! SFBC 0.15 / 0.79; 100k 3D CConv 2.6 / 8.9, SFBC 3.2 / 12.6; 10k 2D CConv 0.10 / 0.33, SFBC
//! 0.13 / 0.40; 100k 2D CConv 1.1 / 2.8, SFBC 1.3 / 3.2. Open3D 0.20 ContinuousConv (TF, 2
//! threads, no position gradient; bench/peers/pconv_open3d.sh) in the same session: 10k 3D
//! 0.28 / 0.88, 100k 3D 3.5 / 11.6.

#![allow(missing_docs)] // criterion_group! generates undocumented items

use candle_core::{Device, Tensor, Var};
use criterion::{criterion_group, BenchmarkId, Criterion, SamplingMode};
use pbdl_particles::Domain;
use pbdl_pconv::{continuous_conv, Basis, FilterSpec, PairGraph};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Same allocator as `cargo xtask` and the other benches (see docs/candle-traps.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

const C: usize = 32;

/// Radius for `neighbours` expected neighbours of `n` uniform points in the unit box.
fn radius(dim: usize, n: usize, neighbours: f64) -> f64 {
    match dim {
        2 => (neighbours / (PI * n as f64)).sqrt(),
        _ => (3.0 * neighbours / (4.0 * PI * n as f64)).cbrt(),
    }
}

fn points<const D: usize>(n: usize, seed: u64) -> Vec<[f64; D]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n).map(|_| std::array::from_fn(|_| rng.random::<f64>())).collect()
}

fn randn(rng: &mut StdRng, n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|_| (rng.random::<f32>() * 2.0 - 1.0) * scale).collect()
}

struct Case {
    graph: Arc<PairGraph>,
    pos: Var,
    features: Var,
    weights: Var,
    r: Tensor,
}

fn build_graph<const D: usize>(x: &[[f64; D]], r: f64) -> PairGraph {
    PairGraph::build_self(&Domain::periodic([0.0; D], [1.0; D]), r, x).unwrap()
}

fn case<const D: usize>(x: &[[f64; D]], r: f64, k: usize) -> Case {
    let dev = Device::Cpu;
    let n = x.len();
    let graph = Arc::new(build_graph(x, r));
    let mut rng = StdRng::seed_from_u64(7);
    let flat: Vec<f32> = x.iter().flat_map(|p| p.iter().map(|&v| v as f32)).collect();
    let pos = Var::from_tensor(&Tensor::from_vec(flat, (n, D), &dev).unwrap()).unwrap();
    let features = Var::from_tensor(&Tensor::from_vec(randn(&mut rng, n * C, 1.0), (n, C), &dev).unwrap()).unwrap();
    let wscale = 1.0 / ((k * C) as f32).sqrt();
    let weights =
        Var::from_tensor(&Tensor::from_vec(randn(&mut rng, k * C * C, wscale), (k, C, C), &dev).unwrap()).unwrap();
    let r = Tensor::from_vec(randn(&mut rng, n * C, 1.0), (n, C), &dev).unwrap();
    Case { graph, pos, features, weights, r }
}

fn forward(c: &Case, spec: &FilterSpec) -> Tensor {
    let d = c.graph.offsets(c.pos.as_tensor(), c.pos.as_tensor()).unwrap();
    continuous_conv(c.features.as_tensor(), c.weights.as_tensor(), &d, &c.graph, spec).unwrap()
}

fn forward_backward(c: &Case, spec: &FilterSpec) -> f32 {
    let out = forward(c, spec);
    let loss = (out * &c.r).unwrap().sum_all().unwrap();
    let grads = loss.backward().unwrap();
    let gw = grads.get(c.weights.as_tensor()).unwrap();
    let gx = grads.get(c.pos.as_tensor()).unwrap();
    let gf = grads.get(c.features.as_tensor()).unwrap();
    assert_eq!(gf.dims(), c.features.dims());
    gw.flatten_all().unwrap().get(0).unwrap().to_scalar::<f32>().unwrap()
        + gx.flatten_all().unwrap().get(0).unwrap().to_scalar::<f32>().unwrap()
}

fn run_dim<const D: usize>(c: &mut Criterion, n: usize, neighbours: f64, filters: &[&str]) {
    let r = radius(D, n, neighbours);
    let x = points::<D>(n, 42 + n as u64 + D as u64);
    let label = format!("{}k_{}d", n / 1000, D);
    let big = n >= 100_000;
    if big {
        manual(&format!("pconv_{label}/graph_build"), || build_graph(&x, r).num_pairs());
        for &name in filters {
            let spec = spec_of::<D>(name, r);
            let cs = case(&x, r, spec.filter_size());
            describe(&label, name, r, &cs, n);
            manual(&format!("pconv_{label}/forward/{name}"), || forward(&cs, &spec));
            manual(&format!("pconv_{label}/forward_backward/{name}"), || forward_backward(&cs, &spec));
        }
        return;
    }
    let mut g = c.benchmark_group(format!("pconv_{label}"));
    g.sample_size(10).sampling_mode(SamplingMode::Flat);
    g.warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
    g.bench_function("graph_build", |b| b.iter(|| build_graph(&x, r).num_pairs()));
    for &name in filters {
        let spec = spec_of::<D>(name, r);
        let cs = case(&x, r, spec.filter_size());
        describe(&label, name, r, &cs, n);
        g.bench_function(BenchmarkId::new("forward", name), |b| b.iter(|| forward(&cs, &spec)));
        g.bench_function(BenchmarkId::new("forward_backward", name), |b| b.iter(|| forward_backward(&cs, &spec)));
    }
    g.finish();
}

fn spec_of<const D: usize>(name: &str, r: f64) -> FilterSpec {
    match name {
        "cconv" => FilterSpec::cconv(D, 4, r),
        _ => FilterSpec::sfbc(D, Basis::Fourier, 4, r),
    }
}

fn describe(label: &str, name: &str, r: f64, cs: &Case, n: usize) {
    eprintln!(
        "{label} {name}: radius {r:.5}, {} pairs, {:.1} neighbours/particle",
        cs.graph.num_pairs(),
        cs.graph.num_pairs() as f64 / n as f64
    );
}

/// Three timed runs (no warm-up beyond the first), printed as `time: [min median max]`.
fn manual<R>(name: &str, mut f: impl FnMut() -> R) {
    let mut t: Vec<f64> = (0..3)
        .map(|_| {
            let t0 = Instant::now();
            std::hint::black_box(f());
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    println!("{name}\n                        time:   [{:.4} s {:.4} s {:.4} s] (3 runs)", t[0], t[1], t[2]);
}

fn pconv(c: &mut Criterion) {
    let filters: Vec<&str> = match std::env::var("PBDL_PCONV_BENCH_FILTER").as_deref() {
        Ok("cconv") => vec!["cconv"],
        Ok("sfbc") => vec!["sfbc"],
        _ => vec!["cconv", "sfbc"],
    };
    let skip_big = std::env::var("PBDL_PCONV_BENCH_SKIP_100K_3D").is_ok_and(|v| v == "1");
    let sizes: Vec<usize> = match std::env::var("PBDL_PCONV_BENCH_N") {
        Ok(v) => v.split(',').map(|s| s.trim().parse().expect("PBDL_PCONV_BENCH_N: particle counts")).collect(),
        Err(_) => vec![10_000, 100_000],
    };
    for n in sizes {
        run_dim::<2>(c, n, 30.0, &filters);
        if !(skip_big && n == 100_000) {
            run_dim::<3>(c, n, 40.0, &filters);
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = pconv
}
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
