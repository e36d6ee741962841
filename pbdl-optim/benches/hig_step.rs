//! Criterion: one HIG step on the nonlinear oscillators (b = 128, J is 512 x 2956), split into
//! the composed Jacobian, the solve alone (thin SVD vs eigendecomposition of `J J^T`) and the
//! whole step (Jacobian + solve + update) for both decompositions. Goal: <= 0.3 s on 2 threads.
//! The same network as a [`CandleModel`] (candle Vars + closure) shows the adapter's Jacobian
//! cost next to the hand-written one, with rows from the batch graph and from per-sample graphs.
//! Set `RAYON_NUM_THREADS`: without it candle 0.11 reads `/proc/cpuinfo` on every CPU matmul.
//!
//! `cargo bench -p pbdl-optim --bench hig_step`
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use criterion::{criterion_group, Criterion};
use faer::{MatRef, Par};
use pbdl_optim::hig::{
    composed_jacobian, from_mlp, CandleModel, Decomposition, HalfInverse, HigConfig, HigTrainer, JacobianMode,
    MlpForward,
};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Oscillators};

/// `net` rebuilt from candle Vars (same weights, ReLU hidden layers, linear output).
fn as_candle(net: &Mlp, mode: JacobianMode) -> CandleModel<MlpForward> {
    from_mlp(net).expect("model").with_mode(mode)
}

fn hig_step_oscillators(c: &mut Criterion) {
    let physics = Oscillators::nonlinear();
    let data = Dataset::return_to_start(128, 4, 1);
    let net = Mlp::new(&[4, 20, 20, 20, 96], Activation::Relu, 2).expect("net");
    let mut group = c.benchmark_group("hig_oscillators");
    group.sample_size(10);
    group.bench_function("composed_jacobian_f64_j512x2956", |b| {
        b.iter(|| composed_jacobian(&net, &physics, data.all()).expect("jacobian"))
    });
    for (name, mode) in [("batch_graph", JacobianMode::Batch), ("per_sample", JacobianMode::PerSample)] {
        let model = as_candle(&net, mode);
        group.bench_function(format!("composed_jacobian_candle_{name}_f64_j512x2956"), |b| {
            b.iter(|| composed_jacobian(&model, &physics, data.all()).expect("jacobian"))
        });
    }
    let (jac, y) = composed_jacobian(&net, &physics, data.all()).expect("jacobian");
    let (rows, cols) = (y.len(), net.n_params());
    let j = MatRef::from_row_major_slice(&jac, rows, cols);
    let g: Vec<f64> = y.iter().zip(data.all().targets).map(|(a, t)| 2.0 * (a - t) / 128.0).collect();
    for (name, dec) in [("svd", Decomposition::Svd), ("eigen_jjt", Decomposition::Eigen)] {
        let cfg = HigConfig::hig(1.0, 1e-6).with_decomposition(dec);
        let mut solver = HalfInverse::new(rows, cols, Par::rayon(0));
        let mut out = vec![0.0; cols];
        group.bench_function(format!("solve_{name}_f64_j512x2956"), |b| {
            b.iter(|| solver.solve(&cfg, j, &g, &mut out).expect("solve"))
        });
        let mut trainer = HigTrainer::new(cfg).expect("trainer");
        let mut stepped = net.clone();
        group.bench_function(format!("hig_step_{name}_f64_j512x2956"), |b| {
            b.iter(|| {
                // Restart from the same parameters so every iteration does the same work.
                stepped.set_params(net.params()).expect("params");
                trainer.step(&mut stepped, &physics, data.all()).expect("step")
            })
        });
    }
    group.finish();
}

criterion_group!(benches, hig_step_oscillators);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
