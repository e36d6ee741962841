//! Reproducible initialisation and parameter counting of a network's `VarMap`.

use crate::Result;
use candle_nn::VarMap;

/// Number of scalar parameters held by `varmap` (the sum of its variables' element counts).
pub fn count_parameters(varmap: &VarMap) -> usize {
    varmap.all_vars().iter().map(|v| v.elem_count()).sum()
}

/// Re-initialises every variable of `varmap` like PyTorch's default layer initialisation, but
/// from `seed` (candle's own random init cannot be seeded): a weight of rank >= 2 is uniform
/// in `±1/sqrt(fan_in)` with `fan_in` the product of its dims after the first; a `bias` is
/// uniform with the bound of its sibling `weight`, or 0 when that weight has rank 1 (a norm);
/// other rank-1 variables (norm scales) are 1. Recurrent weights and biases named as PyTorch's
/// LSTM (`weight_ih*`, `weight_hh*`, `bias_ih*`, `bias_hh*`, first dim `4 hidden`) are uniform
/// in `±1/sqrt(hidden)` as PyTorch initialises them; batch-norm running statistics
/// (`running_mean`, `running_var`) restart at 0 and 1. Variables are visited in name order, so
/// the same seed and network give the same numbers.
pub fn seeded_init(varmap: &VarMap, seed: u64) -> Result<()> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let fan_bound = |dims: &[usize]| 1.0 / (dims[1..].iter().product::<usize>().max(1) as f64).sqrt();
    for (i, name) in names.into_iter().enumerate() {
        let var = &data[name];
        let dims = var.dims();
        let sibling = name.strip_suffix("bias").and_then(|stem| data.get(&format!("{stem}weight")));
        let leaf = name.rsplit('.').next().unwrap_or(name);
        let recurrent = ["weight_ih", "weight_hh", "bias_ih", "bias_hh"].iter().any(|p| leaf.starts_with(p));
        if leaf == "running_mean" || leaf == "running_var" {
            var.set(&if leaf == "running_mean" { var.zeros_like()? } else { var.ones_like()? })?;
            continue;
        }
        let bound = match (dims.len(), sibling) {
            _ if recurrent => Some(1.0 / ((dims[0] / 4).max(1) as f64).sqrt()),
            (n, _) if n >= 2 => Some(fan_bound(dims)),
            (_, Some(w)) if w.rank() >= 2 => Some(fan_bound(w.dims())),
            _ => None,
        };
        let value = match bound {
            Some(b) => {
                pbdl_core::seed::rand_uniform(dims, -b, b, var.dtype(), var.device(), seed.wrapping_add(i as u64))?
            }
            None if name.ends_with("bias") => var.zeros_like()?,
            None => var.ones_like()?,
        };
        var.set(&value)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::{Init, VarBuilder};

    /// PyTorch's LSTM init: every recurrent weight and bias in ±1/sqrt(hidden), not the fan-in
    /// bound of a linear layer (1/sqrt(input) for weight_ih, 1/sqrt(hidden) for weight_hh) and
    /// not 1 for the biases; running statistics back to 0 and 1.
    #[test]
    fn recurrent_names_get_pytorch_lstm_bounds_and_running_stats_reset() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu);
        let (input, hidden) = (100, 4);
        crate::recurrent::Lstm::new(crate::recurrent::LstmConfig::new(input, hidden), vb.pp("lstm")).unwrap();
        vb.get_with_hints(3, "bn.running_mean", Init::Const(5.0)).unwrap();
        vb.get_with_hints(3, "bn.running_var", Init::Const(5.0)).unwrap();
        seeded_init(&varmap, 7).unwrap();
        let data = varmap.data().lock().unwrap();
        let bound = 1.0 / (hidden as f64).sqrt();
        for name in ["lstm.weight_ih_l0", "lstm.weight_hh_l0", "lstm.bias_ih_l0", "lstm.bias_hh_l0"] {
            let v = data[name].flatten_all().unwrap().to_vec1::<f64>().unwrap();
            let max = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(max <= bound && max > 0.8 * bound, "{name}: max |w| {max}, bound {bound}");
        }
        assert_eq!(data["bn.running_mean"].to_vec1::<f64>().unwrap(), [0.0; 3]);
        assert_eq!(data["bn.running_var"].to_vec1::<f64>().unwrap(), [1.0; 3]);
    }
}
