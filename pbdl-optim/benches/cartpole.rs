//! One stabilized-BPTT gradient of the cart-pole experiment (b = 8, 100 steps, controller width
//! 100, the paper's size): the candle rollout (`bptt::gradients`) against the hand-written
//! adjoint (`cartpole::adjoint::AdjointBptt`), modes F and C, 2 and 4 poles, no clipping.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use candle_core::{DType, Device, Tensor};
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{gradients, GradientMode};
use pbdl_optim::cartpole::adjoint::{AdjointBptt, AdjointController};
use pbdl_optim::cartpole::{CartPole, Controller};

fn cartpole_gradient(c: &mut Criterion) {
    let mut group = c.benchmark_group("cartpole_gradient");
    group.sample_size(10);
    for poles in [2, 4] {
        let p = CartPole::new(poles);
        let net = Controller::with_zero_last_layer(p.state_dim(), 100, 1, 42).expect("controller");
        // Train-like weights: a non-zero last layer, so every gradient path carries signal.
        let last = pbdl_core::seed::rand_uniform((100, 1), -0.2, 0.2, DType::F64, &Device::Cpu, 1).expect("weights");
        net.vars()[4].set(&last).expect("set");
        let adjoint_net = AdjointController::from_dense(&net).expect("adjoint controller");
        let s0 = p.initial_states(8, 42).expect("states");
        let s0v = s0.flatten_all().and_then(|t| t.to_vec1::<f64>()).expect("states as f64");
        let mut bptt = AdjointBptt::new(&p, 100, 8);
        let fwd = |s: &Tensor| net.forward(s);
        let phys = |s: &Tensor, u: &Tensor| p.step(s, u);
        let loss = |t: &[Tensor]| p.loss(t.last().expect("non-empty rollout"));
        for mode in [GradientMode::F, GradientMode::C] {
            let id = format!("nc{poles}_{mode:?}");
            group.bench_function(BenchmarkId::new("candle", &id), |b| {
                b.iter(|| {
                    gradients(mode, net.vars(), &s0, p.steps, &fwd, &phys, &loss, &ClipConfig::None).expect("grad")
                })
            });
            group.bench_function(BenchmarkId::new("adjoint", &id), |b| {
                b.iter(|| bptt.gradients(&adjoint_net, &s0v, mode, &ClipConfig::None).expect("grad").loss)
            });
        }
    }
    group.finish();
}

criterion_group!(benches, cartpole_gradient);

fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
