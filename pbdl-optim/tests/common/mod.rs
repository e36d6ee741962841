//! Helpers shared by the stabilized-BPTT experiment tests (cart-pole, guidance, quantum control).

// Each test file uses only some of the helpers.
#![allow(dead_code)]

use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor, Var};
use pbdl_optim::bptt::{BpttRun, GradientMode};

/// Checks the gradients `grads` of `vars` at the given `(var index, flat entry)` pairs against
/// central differences (`h = 1e-6`) of `rollout_loss`, which must read the vars' current
/// values. Each relative error `|g - fd| / (1e-3 + |fd|)` must be at most `1e-6`; returns the
/// worst. The vars are left at their original values.
pub fn check_against_central_differences(
    vars: &[Var],
    grads: &GradStore,
    entries: &[(usize, usize)],
    rollout_loss: impl Fn() -> f64,
) -> f64 {
    let mut worst = 0.0f64;
    for &(vi, entry) in entries {
        let var = &vars[vi];
        let base = var.as_tensor().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let shape = var.as_tensor().shape().clone();
        let h = 1e-6;
        let eval = |d: f64| {
            let mut v = base.clone();
            v[entry] += d;
            var.set(&Tensor::from_vec(v, shape.clone(), &Device::Cpu).unwrap()).unwrap();
            rollout_loss()
        };
        let fd = (eval(h) - eval(-h)) / (2.0 * h);
        eval(0.0);
        let g = grads.get(var.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap()[entry];
        let rel = (g - fd).abs() / (1e-3 + fd.abs());
        worst = worst.max(rel);
        assert!(rel <= 1e-6, "var {vi}[{entry}]: {g} vs fd {fd}");
    }
    worst
}

/// Checks a tiny training run of 3 steps evaluated after each: every test loss passes
/// `loss_ok`, and only mode C reports a sign agreement.
pub fn check_tiny_run(run: &BpttRun, mode: GradientMode, loss_ok: impl Fn(f64) -> bool) {
    assert_eq!(run.steps, vec![0, 1, 2, 3]);
    assert!(run.test_loss.iter().all(|l| loss_ok(*l)), "{:?}", run.test_loss);
    assert_eq!(run.agreement.is_some(), mode == GradientMode::C);
}

/// Prints a training run of `steps` Adam steps: the first and final test loss with `digits`
/// decimals, the training time and milliseconds per step with `ms_digits` decimals, and the
/// sign agreement.
pub fn print_run(mode: GradientMode, run: &BpttRun, steps: usize, digits: usize, ms_digits: usize) {
    println!(
        "{mode:?}: test loss {:.digits$} -> {:.digits$} in {:.1} s ({:.ms_digits$} ms/step), agreement {:?}",
        run.test_loss[0],
        run.final_loss(),
        run.seconds,
        1e3 * run.seconds / steps as f64,
        run.agreement
    );
}
