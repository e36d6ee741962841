//! Helpers shared by the integration tests (`mod common;` in each test file that uses them):
//! seeded networks and inputs, the finite-difference check of a whole network, and a short
//! Adam training loop.

#![allow(dead_code)]

use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use pbdl_core::train::{AdamConfig, OptimizerConfig};
use pbdl_core::{check_grad, seed, GradCheckOptions, GradCheckReport};
use pbdl_nets::seeded_init;
use std::collections::HashMap;
use std::time::Instant;

/// The device of the tests.
pub const CPU: Device = Device::Cpu;

/// A standard normal tensor of `shape` drawn from seed `s`.
pub fn randn(shape: &[usize], dtype: DType, s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, dtype, &CPU, s).unwrap()
}

/// A network built by `new` on the variables of a fresh [`VarMap`] (`dtype`, CPU), initialised
/// with [`seeded_init`] from `seed`.
pub fn build_seeded<N>(dtype: DType, seed: u64, new: impl FnOnce(VarBuilder) -> pbdl_nets::Result<N>) -> (VarMap, N) {
    let varmap = VarMap::new();
    let net = new(VarBuilder::from_varmap(&varmap, dtype, &CPU)).unwrap();
    seeded_init(&varmap, seed).unwrap();
    (varmap, net)
}

/// Central finite differences through a whole f64 network with respect to its input `x` and
/// the variables `probed` of `varmap` (at most 16 probes each); `forward` builds the network
/// from the given variables and applies it to the input. Prints and returns the report.
///
/// The step is 1e-4: at the default 1e-6 round-off dominates (measured through the tiny ACDM
/// U-Net: max rel error 8.7e-7, 7.8e-8, 8.4e-9 at eps 1e-6, 1e-5, 1e-4; it falls like 1/eps,
/// so the gradient itself is right).
pub fn check_network_grad(
    name: &str,
    varmap: &VarMap,
    probed: &[&str],
    x: Tensor,
    forward: impl Fn(VarBuilder, &Tensor) -> pbdl_nets::Result<Tensor>,
) -> GradCheckReport {
    let all: HashMap<String, Tensor> =
        varmap.data().lock().unwrap().iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
    let mut inputs = vec![x];
    inputs.extend(probed.iter().map(|n| all[*n].clone()));
    let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        let mut map = all.clone();
        for (name, value) in probed.iter().zip(&xs[1..]) {
            map.insert(name.to_string(), value.clone());
        }
        forward(VarBuilder::from_tensors(map, DType::F64, &CPU), &xs[0])
            .map_err(|e| candle_core::Error::Msg(e.to_string()))
    };
    let start = Instant::now();
    let opts = GradCheckOptions { max_probes: 16, eps: 1e-4, ..Default::default() };
    let report = check_grad(f, &inputs, &opts).unwrap();
    println!(
        "{name} FD check ({} probes, {:.1} s): max rel error {:.2e}; per input (x, {}): {:?}",
        report.probes,
        start.elapsed().as_secs_f64(),
        report.max_rel_error,
        probed.join(", "),
        report.per_input.iter().map(|e| format!("{e:.1e}")).collect::<Vec<_>>()
    );
    report
}

/// `steps` Adam steps at learning rate `lr` on all variables of `varmap`, minimising the scalar
/// that `loss` returns; returns the loss of every step (before its update).
pub fn train(
    varmap: &VarMap,
    lr: f64,
    steps: usize,
    mut loss: impl FnMut(usize) -> pbdl_nets::Result<Tensor>,
) -> Vec<f64> {
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr, ..Default::default() }).build(varmap.all_vars()).unwrap();
    (0..steps)
        .map(|step| {
            let l = loss(step).unwrap();
            let grads = l.backward().unwrap();
            opt.step(&grads).unwrap();
            l.to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
        })
        .collect()
}

/// Mean of the first and of the last `n` entries.
pub fn first_last_mean(losses: &[f64], n: usize) -> (f64, f64) {
    let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len() as f64;
    (mean(&losses[..n]), mean(&losses[losses.len() - n..]))
}
