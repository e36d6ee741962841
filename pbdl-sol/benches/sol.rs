//! Solver-in-the-Loop on the default cylinder wake (source 64 x 32, reference 4x finer), f32,
//! the corrector of the `#[ignore]`d acceptance test (`pbdl-sol/tests/sil.rs`: width 16, 2
//! residual blocks, 5x5, zero output conv; batch 2, Adam lr 1e-3).
//!
//! * `sol8_train`: one SOL-8 training step (8 corrected source steps forward, the loss,
//!   backward through solver and network, Adam update), and its parts, so that the share spent
//!   in the solver and in the network can be read off:
//!   - `solver_fwd_x8`: the 8 source steps alone (no network, no graph),
//!   - `net_fwd_x8`: the 8 network forwards alone (on the states of a source rollout),
//!   - `solver_fwd_bwd_x8`: the loss of 8 uncorrected source steps from a `Var` start, and
//!     its backward (the solver's share of the step: advection, viscosity and pressure
//!     adjoints),
//!   - `net_fwd_bwd_x8`: the loss of 8 network corrections on detached source states, and its
//!     backward with respect to the weights (the network's share),
//!   - `adam_update`: the optimiser update alone, from precomputed gradients.
//! * `rollout_step`: one step of a rollout (batch 1, no gradient wanted): the source at 1x,
//!   the corrected source at 1x (source step + network), the source at 2x (128 x 64, dt 1),
//!   and one step of the reference solver (256 x 128, dt 0.5; a frame is 2 such steps).
//!
//! `cargo bench -p pbdl-sol --bench sol -- --warm-up-time 1 --measurement-time 5`
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::{DType, Tensor, Var};
use candle_nn::Optimizer as _;
use criterion::{criterion_group, Criterion};
use pbdl_core::train::{train_step, AdamConfig, ClipConfig, NanGuard, OptimizerConfig};
use pbdl_grid::FluidState;
use pbdl_sol::sil::{
    downsample_mac, rollout, unrolled_loss, Corrector, CorrectorConfig, Normalisation, SourceSolver, WakeConfig,
};

/// Same allocator as `cargo xtask` (see docs/candle-traps.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// A held-out Reynolds number of the paper's split.
const RE: f64 = 585.9375;
/// Unrolled steps.
const M: usize = 8;
/// Start states per update (the acceptance test's batch).
const BATCH: usize = 2;

/// The acceptance test's corrector (pbdl-sol/tests/sil.rs, `acceptance_held_out_re`).
fn acceptance_corrector() -> CorrectorConfig {
    CorrectorConfig { width: 16, blocks: 2, kernel: 5, negative_slope: 0.3, zero_output: true }
}

/// A developed-ish coarse state: `warm` source steps from the kicked initial state.
fn coarse_state(wake: &WakeConfig, src: &SourceSolver, warm: usize) -> Tensor {
    let s0 = wake.initial_state(&src.fluid, src.grid, DType::F32).unwrap().velocity.into_values();
    rollout(src, &s0, warm, None).unwrap().pop().unwrap()
}

/// Sum over `states` of the scaled half MSE against `targets` (the loss of `unrolled_loss`).
fn half_mse_sum(states: &[Tensor], targets: &[Tensor], inv_sigma: &Tensor) -> Tensor {
    let mut total = Tensor::zeros((), DType::F32, &candle_core::Device::Cpu).unwrap();
    for (s, t) in states.iter().zip(targets) {
        let e = (s - t).unwrap().broadcast_mul(inv_sigma).unwrap().sqr().unwrap().mean_all().unwrap();
        total = (total + e.affine(0.5, 0.0).unwrap()).unwrap();
    }
    total.affine(1.0 / states.len() as f64, 0.0).unwrap()
}

fn sol8_train(c: &mut Criterion) {
    let wake = WakeConfig::default();
    let src = wake.source(RE).unwrap();
    let norm = Normalisation { sigma: [0.45, 0.25], re_mean: 1024.0, re_std: 1000.0 };
    let net = Corrector::new(acceptance_corrector(), norm, DType::F32, 0).unwrap();
    // Nonzero output weights: with the zero output conv the backward would be exact but the
    // corrected trajectory equal to the source one; give the net a small live output instead.
    {
        let data = net.varmap().data().lock().unwrap();
        for (name, var) in data.iter().filter(|(n, _)| n.starts_with("output.")) {
            let r = pbdl_core::seed::randn(var.dims(), 0.0, 1e-3, DType::F32, &candle_core::Device::Cpu, 7).unwrap();
            var.set(&r).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }
    // Batch of two start states 4 steps apart; targets: the source trajectory (timing only).
    let a = coarse_state(&wake, &src, 40);
    let b = rollout(&src, &a, 4, None).unwrap().pop().unwrap();
    let start = Tensor::cat(&[&a, &b], 0).unwrap();
    let traj = rollout(&src, &start, M, None).unwrap();
    let targets: Vec<Tensor> = traj.iter().map(|t| (t * 1.01).unwrap()).collect();
    let inv = Tensor::new(&[1.0 / norm.sigma[0] as f32, 1.0 / norm.sigma[1] as f32], &candle_core::Device::Cpu)
        .unwrap()
        .reshape((1, 2, 1, 1))
        .unwrap();
    let vars = net.varmap().all_vars();
    let opt_cfg = OptimizerConfig::Adam(AdamConfig { lr: 1e-3, ..AdamConfig::default() });
    let mut opt = opt_cfg.build(vars.clone()).unwrap();
    let mut guard = NanGuard::new();
    // Inputs of the network during the step: the source step of each state (detached).
    let net_inputs: Vec<Tensor> = std::iter::once(start.clone()).chain(traj[..M - 1].iter().cloned()).collect();
    let net_inputs: Vec<Tensor> = net_inputs.iter().map(|s| src.step(s).unwrap().detach()).collect();

    let mut g = c.benchmark_group(format!("sol8_train_b{BATCH}_64x32_f32"));
    g.sample_size(10);
    let mut it = 0u64;
    g.bench_function("full_step", |bch| {
        bch.iter(|| {
            let loss = unrolled_loss(&net, &src, &start, &targets).unwrap();
            it += 1;
            train_step(it, &loss, &mut opt, &vars, &ClipConfig::None, &mut guard).unwrap()
        })
    });
    g.bench_function("solver_fwd_x8", |bch| {
        bch.iter(|| {
            let mut s = start.clone();
            for _ in 0..M {
                s = src.step(&s).unwrap();
            }
            s
        })
    });
    g.bench_function("net_fwd_x8", |bch| {
        bch.iter(|| net_inputs.iter().map(|x| net.correction(x, RE).unwrap()).collect::<Vec<_>>())
    });
    g.bench_function("solver_fwd_bwd_x8", |bch| {
        bch.iter(|| {
            let s0 = Var::from_tensor(&start).unwrap();
            let mut s = s0.as_tensor().clone();
            let mut states = Vec::with_capacity(M);
            for _ in 0..M {
                s = src.step(&s).unwrap();
                states.push(s.clone());
            }
            let grads = half_mse_sum(&states, &targets, &inv).backward().unwrap();
            grads.get(s0.as_tensor()).unwrap().clone()
        })
    });
    g.bench_function("net_fwd_bwd_x8", |bch| {
        bch.iter(|| {
            let states: Vec<Tensor> = net_inputs.iter().map(|x| net.apply(x, RE).unwrap()).collect();
            half_mse_sum(&states, &targets, &inv).backward().unwrap()
        })
    });
    let loss = unrolled_loss(&net, &src, &start, &targets).unwrap();
    let grads = loss.backward().unwrap();
    g.bench_function("adam_update", |bch| bch.iter(|| opt.step(&grads).unwrap()));
    g.finish();
}

fn rollout_step(c: &mut Criterion) {
    let wake = WakeConfig::default();
    let src = wake.source(RE).unwrap();
    let norm = Normalisation { sigma: [0.45, 0.25], re_mean: 1024.0, re_std: 1000.0 };
    let net = Corrector::new(acceptance_corrector(), norm, DType::F32, 0).unwrap();
    let s1 = coarse_state(&wake, &src, 40);
    // The 2x source: the same channel at 128 x 64, one step of dt 1 per frame.
    let wake2 = WakeConfig { coarse: [128, 64], factor: 2, ..WakeConfig::default() };
    let src2 = wake2.source(RE).unwrap();
    let s2 = coarse_state(&wake2, &src2, 40);
    // The reference solver: 256 x 128, dt 0.5 (two steps per frame).
    let fine = wake.reference_grid().unwrap();
    let reference = wake.reference_stepper(RE).unwrap();
    let mut r = wake.initial_state(&reference, fine, DType::F32).unwrap();
    for _ in 0..20 {
        r = reference.step(&r, None).unwrap();
    }
    assert_eq!(downsample_mac(r.velocity.values(), 4).unwrap().dims(), s1.dims());

    let mut g = c.benchmark_group("sil_rollout_step_f32");
    g.sample_size(20);
    g.bench_function("source_1x_64x32", |bch| bch.iter(|| src.step(&s1).unwrap()));
    g.bench_function("corrected_1x_64x32", |bch| bch.iter(|| net.apply(&src.step(&s1).unwrap(), RE).unwrap().detach()));
    g.bench_function("source_2x_128x64", |bch| bch.iter(|| src2.step(&s2).unwrap()));
    g.bench_function("reference_4x_256x128_substep", |bch| {
        bch.iter(|| -> FluidState { reference.step(&r, None).unwrap() })
    });
    g.finish();
}

criterion_group!(benches, sol8_train, rollout_step);
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
