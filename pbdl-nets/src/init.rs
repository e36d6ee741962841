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
/// other rank-1 variables (norm scales) are 1. Variables are visited in name order, so the
/// same seed and network give the same numbers.
pub fn seeded_init(varmap: &VarMap, seed: u64) -> Result<()> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let fan_bound = |dims: &[usize]| 1.0 / (dims[1..].iter().product::<usize>().max(1) as f64).sqrt();
    for (i, name) in names.into_iter().enumerate() {
        let var = &data[name];
        let dims = var.dims();
        let sibling = name.strip_suffix("bias").and_then(|stem| data.get(&format!("{stem}weight")));
        let bound = match (dims.len(), sibling) {
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
