//! Rollout metrics: MSE, temporal stability, probe spectrum and shedding frequency, sample
//! spread. LSiM per field is computed in [`super::eval::evaluate`] (it needs the metric's weights).

use super::data::{cell_of, CylinderConfig, DIAMETER, INFLOW, PROBE};
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_grid::diagnostics::strouhal_spectral_peak;

/// Mean squared error of two equally shaped tensors.
pub fn mse(a: &Tensor, b: &Tensor) -> Result<f64> {
    if a.dims() != b.dims() {
        return Err(Error::shape("mse", a.dims(), b.dims()));
    }
    Ok((a - b)?.sqr()?.mean_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?)
}

/// Temporal stability of a rollout `[T, C, ny, nx]`: for each step `t >= 1` the mean over
/// cells and channels of `|s^t - s^(t-1)| / dt` (the L1 norm of the time derivative, per
/// element). Returns `T - 1` values.
pub fn temporal_stability(frames: &Tensor, dt: f64) -> Result<Vec<f64>> {
    let t = frames.dim(0)?;
    if frames.rank() != 4 || t < 2 {
        return Err(Error::shape("temporal_stability frames", "[T >= 2, C, ny, nx]", frames.dims()));
    }
    let d = (frames.narrow(0, 1, t - 1)? - frames.narrow(0, 0, t - 1)?)?.abs()?;
    let per = d.flatten_from(1)?.mean(1)?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    Ok(per.into_iter().map(|x| x / dt).collect())
}

/// Mean of a slice (NaN when empty).
pub fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

/// The `vy` probe signal of physical frames `[T, >=2, ny, nx]` at [`PROBE`].
pub fn probe_signal(frames: &Tensor, config: &CylinderConfig) -> Result<Vec<f64>> {
    let (_, c, ny, nx) = frames.dims4()?;
    let (dnx, dny) = config.data_size();
    if c < 2 || (ny, nx) != (dny, dnx) {
        return Err(Error::shape("probe_signal frames", format!("[T, >=2, {dny}, {dnx}]"), frames.dims()));
    }
    let (j, i) = cell_of(config, PROBE[0], PROBE[1]);
    Ok(frames
        .narrow(1, 1, 1)?
        .narrow(2, j, 1)?
        .narrow(3, i, 1)?
        .flatten_all()?
        .to_dtype(DType::F64)?
        .to_vec1::<f64>()?)
}

/// Strouhal number `f D / U` of physical frames from the probe's dominant frequency
/// ([`strouhal_spectral_peak`]: rollouts are noisy, so the spectral peak, not zero crossings).
pub fn strouhal(frames: &Tensor, config: &CylinderConfig) -> Result<f64> {
    let s = probe_signal(frames, config)?;
    Ok(strouhal_spectral_peak(&s, config.frame_dt(), DIAMETER, INFLOW))
}

/// Mean over cells and channels of the standard deviation across samples `[S, ...]`.
pub fn sample_spread(samples: &Tensor) -> Result<f64> {
    let s = samples.dim(0)?;
    if s < 2 {
        return Err(Error::shape("sample_spread samples", "[S >= 2, ...]", samples.dims()));
    }
    let x = samples.to_dtype(DType::F64)?;
    let m = x.mean_keepdim(0)?;
    let var = x.broadcast_sub(&m)?.sqr()?.sum_keepdim(0)?.affine(1.0 / (s - 1) as f64, 0.0)?;
    Ok(var.sqrt()?.mean_all()?.to_scalar::<f64>()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stability_of_a_linear_ramp() {
        // s^t = 0.5 t everywhere: |ds/dt| = 0.5 / dt exactly.
        let f = Tensor::arange(0f32, 5.0, &candle_core::Device::Cpu).unwrap().affine(0.5, 0.0).unwrap();
        let f = f.reshape((5, 1, 1, 1)).unwrap().broadcast_as((5, 2, 3, 4)).unwrap().contiguous().unwrap();
        let s = temporal_stability(&f, 0.1).unwrap();
        assert_eq!(s.len(), 4);
        assert!(s.iter().all(|x| (x - 5.0).abs() < 1e-5), "{s:?}");
    }
}
