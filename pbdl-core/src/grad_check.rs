//! Finite-difference gradient checks, and a check that every trainable variable got a gradient.
//!
//! [`check_grad`] compares the gradient that candle's backward pass computes with central
//! differences, both in `f64`. To test all outputs at once, the scalar that is differentiated is
//! `sum(f(x) * r)` with a fixed, seeded random cotangent `r`, so every output element contributes.
//! The reported error of one input is `max_i |g_i - fd_i| / max(max_i |g_i|, max_i |fd_i|)`, a
//! relative error in the max norm that stays meaningful where single gradient entries are ~0.

use crate::{seed, Error, Result};
use candle_core::{backprop::GradStore, DType, Device, Tensor, Var};
use rand::seq::index::sample;

/// Options of [`check_grad`].
#[derive(Clone, Debug)]
pub struct GradCheckOptions {
    /// Step of the central difference (in `f64`). Default `1e-6`.
    pub eps: f64,
    /// At most this many elements of each input are probed (chosen at random, seeded);
    /// all of them when the input is smaller. Default 48.
    pub max_probes: usize,
    /// Seed of the cotangent and of the probe selection. Default 0.
    pub seed: u64,
}

impl Default for GradCheckOptions {
    fn default() -> Self {
        Self { eps: 1e-6, max_probes: 48, seed: 0 }
    }
}

/// Outcome of [`check_grad`].
#[derive(Clone, Debug)]
pub struct GradCheckReport {
    /// The largest relative error over all inputs.
    pub max_rel_error: f64,
    /// The relative error of each input.
    pub per_input: Vec<f64>,
    /// Total number of probed elements.
    pub probes: usize,
    /// Worst element: (input, flat index, analytic, finite difference).
    pub worst: (usize, usize, f64, f64),
}

impl GradCheckReport {
    /// Turns the report into an error if `max_rel_error > tolerance`.
    pub fn ensure(&self, tolerance: f64) -> Result<&Self> {
        if self.max_rel_error.is_nan() || self.max_rel_error > tolerance {
            let (input, index, analytic, numeric) = self.worst;
            return Err(Error::GradCheck {
                max_rel_error: self.max_rel_error,
                tolerance,
                input,
                index,
                analytic,
                numeric,
            });
        }
        Ok(self)
    }
}

/// Checks the gradient of `f` at `inputs` against central finite differences in `f64`.
///
/// `inputs` are converted to `f64` CPU tensors; `f` must accept them and may return a tensor of
/// any shape. An input whose gradient is missing is an [`Error::MissingGradient`].
pub fn check_grad<F>(f: F, inputs: &[Tensor], opts: &GradCheckOptions) -> Result<GradCheckReport>
where
    F: Fn(&[Tensor]) -> candle_core::Result<Tensor>,
{
    if inputs.is_empty() {
        return Err(Error::invalid("check_grad", "inputs", "give at least one input tensor"));
    }
    if !(opts.eps > 0.0 && opts.eps.is_finite()) {
        return Err(Error::invalid("check_grad", "eps", format!("must be a positive finite step, got {}", opts.eps)));
    }
    let cpu = Device::Cpu;
    let base: Vec<Tensor> =
        inputs.iter().map(|t| t.to_device(&cpu)?.to_dtype(DType::F64)).collect::<candle_core::Result<_>>()?;

    // Analytic gradient of sum(f(x) * r).
    let vars: Vec<Var> = base.iter().map(Var::from_tensor).collect::<candle_core::Result<_>>()?;
    let var_tensors: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
    let out = f(&var_tensors)?.to_dtype(DType::F64)?;
    let cotangent = seed::rand_uniform(out.shape(), -1.0, 1.0, DType::F64, &cpu, opts.seed)?;
    let loss = |t: &Tensor| -> candle_core::Result<f64> {
        t.to_dtype(DType::F64)?.mul(&cotangent)?.sum_all()?.to_scalar::<f64>()
    };
    let grads = out.to_dtype(DType::F64)?.mul(&cotangent)?.sum_all()?.backward()?;
    let missing: Vec<String> = vars
        .iter()
        .enumerate()
        .filter(|(_, v)| grads.get(v.as_tensor()).is_none())
        .map(|(i, _)| format!("input {i}"))
        .collect();
    if !missing.is_empty() {
        return Err(Error::MissingGradient { names: missing });
    }

    let mut per_input = Vec::with_capacity(base.len());
    let mut worst = (0, 0, 0.0, 0.0);
    let mut worst_err = -1.0;
    let mut probes = 0;
    for (i, x) in base.iter().enumerate() {
        let analytic = grads.get(vars[i].as_tensor()).expect("checked above").flatten_all()?.to_vec1::<f64>()?;
        let x_flat = x.flatten_all()?.to_vec1::<f64>()?;
        let n = x_flat.len();
        let picks: Vec<usize> = if n <= opts.max_probes {
            (0..n).collect()
        } else {
            let mut r = seed::rng(opts.seed.wrapping_add(1 + i as u64));
            let mut v = sample(&mut r, n, opts.max_probes).into_vec();
            v.sort_unstable();
            v
        };
        let mut max_diff = 0.0f64;
        let mut saw_nan = false;
        let mut scale = 0.0f64;
        let mut local_worst = (i, 0, 0.0, 0.0, -1.0);
        for &j in &picks {
            let eval = |delta: f64| -> candle_core::Result<f64> {
                let mut p = x_flat.clone();
                p[j] += delta;
                let mut args = base.clone();
                args[i] = Tensor::from_vec(p, x.shape(), &cpu)?;
                loss(&f(&args)?)
            };
            let numeric = (eval(opts.eps)? - eval(-opts.eps)?) / (2.0 * opts.eps);
            let a = analytic[j];
            let diff = (a - numeric).abs();
            scale = scale.max(a.abs()).max(numeric.abs());
            if diff > local_worst.4 || diff.is_nan() {
                local_worst = (i, j, a, numeric, diff);
            }
            max_diff = max_diff.max(diff);
            saw_nan |= diff.is_nan();
        }
        probes += picks.len();
        let err = if saw_nan {
            f64::INFINITY
        } else if scale > 0.0 {
            max_diff / scale
        } else {
            0.0
        };
        if err > worst_err {
            worst_err = err;
            worst = (local_worst.0, local_worst.1, local_worst.2, local_worst.3);
        }
        per_input.push(err);
    }
    let max_rel_error = per_input.iter().cloned().fold(0.0, f64::max);
    Ok(GradCheckReport { max_rel_error, per_input, probes, worst })
}

/// Checks that every variable in `named` received a gradient in `grads`; lists those that did not.
///
/// Use it after the first `backward()` of a training loop: an op without backward on a
/// parameter's path shows up here instead of as a parameter that silently never trains.
pub fn assert_all_have_grads<'a>(named: impl IntoIterator<Item = (&'a str, &'a Var)>, grads: &GradStore) -> Result<()> {
    let missing: Vec<String> =
        named.into_iter().filter(|(_, v)| grads.get(v.as_tensor()).is_none()).map(|(n, _)| n.to_string()).collect();
    if missing.is_empty() {
        Ok(())
    } else {
        Err(Error::MissingGradient { names: missing })
    }
}

/// [`assert_all_have_grads`] for every variable of a candle-nn `VarMap`.
pub fn assert_varmap_has_grads(varmap: &candle_nn::VarMap, grads: &GradStore) -> Result<()> {
    let data = varmap.data().lock().expect("VarMap lock poisoned");
    let mut named: Vec<(&str, &Var)> = data.iter().map(|(k, v)| (k.as_str(), v)).collect();
    named.sort_by_key(|(k, _)| *k);
    assert_all_have_grads(named, grads)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detects_a_wrong_gradient() {
        // detach() cuts the gradient of one factor: the analytic gradient is then half the true one.
        let x = Tensor::new(&[0.5f64, 1.5, -0.7], &Device::Cpu).unwrap();
        let good = check_grad(|xs| xs[0].sqr(), std::slice::from_ref(&x), &GradCheckOptions::default()).unwrap();
        assert!(good.max_rel_error < 1e-8, "{good:?}");
        let bad = check_grad(|xs| xs[0].mul(&xs[0].detach()), &[x], &GradCheckOptions::default()).unwrap();
        assert!(bad.max_rel_error > 0.4, "{bad:?}");
        assert!(matches!(bad.ensure(1e-6), Err(Error::GradCheck { .. })));
    }

    #[test]
    fn unused_input_is_a_missing_gradient() {
        let x = Tensor::new(&[1.0f64], &Device::Cpu).unwrap();
        let y = Tensor::new(&[2.0f64], &Device::Cpu).unwrap();
        let err = check_grad(|xs| xs[0].exp(), &[x, y], &GradCheckOptions::default()).unwrap_err();
        assert!(matches!(err, Error::MissingGradient { ref names } if names == &["input 1".to_string()]), "{err}");
    }

    #[test]
    fn varmap_helper_names_untrained_parameters() {
        let varmap = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu);
        let used = vb.get((2,), "used").unwrap();
        let _unused = vb.get((2,), "unused").unwrap();
        let grads = used.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        match assert_varmap_has_grads(&varmap, &grads) {
            Err(Error::MissingGradient { names }) => assert_eq!(names, vec!["unused".to_string()]),
            other => panic!("expected MissingGradient, got {other:?}"),
        }
    }
}
