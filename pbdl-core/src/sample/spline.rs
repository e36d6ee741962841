//! Cubic B-spline resizing as `scipy.ndimage.zoom(x, zoom, order=3)` with its defaults
//! (`prefilter=True`, `mode="constant"`, `grid_mode=False`); VolSiM resizes its inputs to 64^3
//! this way.
//!
//! Along one axis of `n_in` samples resized to `n_out`:
//! 1. **Prefilter**: the samples `x` become B-spline coefficients `c` with `x[k] = (c[k-1] + 4 c[k]
//!    + c[k+1]) / 6`, the coefficients extended by whole-sample mirroring (`c[-k] = c[k]`,
//!    `c[n-1+k] = c[n-1-k]`). This is the recursive filter of Unser (1999): gain 6, a causal and
//!    an anticausal first-order pass with the pole `z = sqrt(3) - 2`, each started with the exact
//!    value of the mirrored, periodic (period `2 n_in - 2`) extension. scipy uses this mirror
//!    boundary for the prefilter of `mode="constant"` too (checked: `spline_filter1d` gives
//!    identical results for `"constant"` and `"mirror"`).
//! 2. **Evaluation** at `src = o * (n_in - 1) / (n_out - 1)` (`src = 0` when `n_out == 1`):
//!    `sum_j c[j] B3(src - j)` over the 4 coefficients `floor(src) - 1 ..= floor(src) + 2`
//!    (mirrored at the edges), with the cubic B-spline `B3`.
//!
//! Both steps are linear, so each axis is one `n_out x n_in` matrix ([`spline_zoom_matrix`]);
//! [`spline_zoom`] applies the matrices axis by axis with matmuls, which makes the resize
//! differentiable through candle's autograd. An axis whose size does not change is left as is
//! (the spline interpolates its samples exactly).
//!
//! Agreement with scipy 1.17 (`pbdl-metrics/tests/data/make_spline_reference.py`): about 1e-15
//! relative in `f64`. One deliberate difference, as for the nearest resize in [`super::Resize`]:
//! where `(n_out - 1) * zoom` rounds to slightly above `n_in - 1` (e.g. 8 -> 26, 22 -> 20; no
//! size to 64 is affected for inputs up to 512), scipy's `mode="constant"` writes `cval = 0`
//! into the last output sample; here it is the spline's value at `n_in - 1` (the last input).

use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// The pole of the cubic B-spline prefilter.
fn pole() -> f64 {
    3f64.sqrt() - 2.0
}

/// Turns samples into cubic B-spline coefficients in place (mirror boundary; see the module docs).
pub fn spline_prefilter(c: &mut [f64]) {
    let n = c.len();
    if n < 2 {
        return;
    }
    let z = pole();
    let gain = (1.0 - z) * (1.0 - 1.0 / z);
    c.iter_mut().for_each(|v| *v *= gain);
    // Causal pass, started with the exact sum over the mirrored periodic extension.
    let zn1 = z.powi((n - 1) as i32);
    let mut sum = c[0] + zn1 * c[n - 1];
    let mut zi = z;
    for i in 1..n - 1 {
        sum += zi * (c[i] + zn1 * c[n - 1 - i]);
        zi *= z;
    }
    c[0] = sum / (1.0 - zn1 * zn1);
    for i in 1..n {
        c[i] += z * c[i - 1];
    }
    // Anticausal pass.
    c[n - 1] = z / (z * z - 1.0) * (c[n - 1] + z * c[n - 2]);
    for i in (0..n - 1).rev() {
        c[i] = z * (c[i + 1] - c[i]);
    }
}

/// Index `j` folded into `0..n` by whole-sample mirroring (period `2n - 2`).
fn mirror(j: i64, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let p = 2 * (n as i64 - 1);
    let m = j.rem_euclid(p);
    (if m > n as i64 - 1 { p - m } else { m }) as usize
}

/// The cubic B-spline weights of the coefficients `floor(src) - 1 ..= floor(src) + 2` for the
/// fractional part `t` of `src`.
fn weights(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    let u = 1.0 - t;
    [u * u * u / 6.0, (4.0 - 6.0 * t2 + 3.0 * t3) / 6.0, (1.0 + 3.0 * t + 3.0 * t2 - 3.0 * t3) / 6.0, t3 / 6.0]
}

/// The linear map of one axis, `n_in` samples to `n_out`, row-major `[n_out, n_in]`: output `o`
/// is `sum_i m[o * n_in + i] * x[i]`.
///
/// Errors: a zero size.
pub fn spline_zoom_matrix(n_in: usize, n_out: usize) -> Result<Vec<f64>> {
    if n_in == 0 || n_out == 0 {
        return Err(Error::InvalidArgument {
            op: "spline_zoom_matrix",
            arg: "size",
            reason: format!("sizes must be >= 1, got {n_in} -> {n_out}"),
        });
    }
    // Prefilter matrix P (c = P x), column by column: the filter of each unit vector.
    let mut p = vec![0.0; n_in * n_in];
    let mut col = vec![0.0; n_in];
    for j in 0..n_in {
        col.iter_mut().enumerate().for_each(|(i, v)| *v = if i == j { 1.0 } else { 0.0 });
        spline_prefilter(&mut col);
        for i in 0..n_in {
            p[i * n_in + j] = col[i];
        }
    }
    let zoom = if n_out > 1 { (n_in - 1) as f64 / (n_out - 1) as f64 } else { 0.0 };
    let mut m = vec![0.0; n_out * n_in];
    for o in 0..n_out {
        // Clamped: see the module docs on scipy's last sample.
        let src = (o as f64 * zoom).min((n_in - 1) as f64);
        let base = src.floor();
        let w = weights(src - base);
        for (k, wk) in w.iter().enumerate() {
            let row = mirror(base as i64 - 1 + k as i64, n_in);
            for i in 0..n_in {
                m[o * n_in + i] += wk * p[row * n_in + i];
            }
        }
    }
    Ok(m)
}

/// Resizes the last `size.len()` axes of `x` to `size` with cubic B-spline interpolation, as
/// `scipy.ndimage.zoom(x, zoom, order=3)` with the zoom factors `size / shape` (1 for the leading
/// axes). Example: a volume `[batch, channel, z, y, x]` to 64^3 with `size = [64, 64, 64]`.
///
/// `f32` or `f64`; the matrices are built in `f64` and applied in `x`'s dtype. Differentiable
/// in `x` (the resize is a chain of matmuls).
///
/// Errors: [`Error::DType`] for other dtypes, [`Error::Shape`] if `x` has fewer axes than
/// `size`, [`Error::InvalidArgument`] for a zero size or an empty input axis.
pub fn spline_zoom(x: &Tensor, size: &[usize]) -> Result<Tensor> {
    const OP: &str = "spline_zoom";
    if !matches!(x.dtype(), DType::F32 | DType::F64) {
        return Err(Error::DType { op: OP, arg: "x", expected: "f32 or f64", got: x.dtype() });
    }
    let rank = x.rank();
    if rank < size.len() {
        return Err(Error::Shape {
            op: OP,
            arg: "x",
            expected: format!("at least {} axes (one per entry of `size`)", size.len()),
            got: x.dims().to_vec(),
        });
    }
    let first = rank - size.len();
    if let Some((a, n)) = x.dims()[first..].iter().zip(size).find(|(&a, &n)| a == 0 || n == 0) {
        return Err(Error::InvalidArgument {
            op: OP,
            arg: "size",
            reason: format!("cannot resize an axis of {a} samples to {n}; both must be >= 1"),
        });
    }
    let mut y = x.clone();
    for (k, &n_out) in size.iter().enumerate() {
        let axis = first + k;
        let n_in = y.dim(axis)?;
        if n_in == n_out {
            continue;
        }
        let m = Tensor::from_vec(spline_zoom_matrix(n_in, n_out)?, (n_out, n_in), x.device())?.to_dtype(x.dtype())?;
        // Move the axis last, contract it with m^T, move it back.
        let moved = y.transpose(axis, rank - 1)?.contiguous()?;
        let mut dims = moved.dims().to_vec();
        let rows: usize = dims[..rank - 1].iter().product();
        let out = moved.reshape((rows, n_in))?.matmul(&m.t()?)?;
        dims[rank - 1] = n_out;
        y = out.reshape(dims)?.transpose(axis, rank - 1)?.contiguous()?;
    }
    Ok(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// The prefilter inverts the mirrored interpolation condition x[k] = (c[k-1] + 4c[k] + c[k+1]) / 6.
    #[test]
    fn prefilter_inverts_the_interpolation_condition() {
        for n in [2usize, 3, 5, 17] {
            let x: Vec<f64> = (0..n).map(|i| ((i * 7 + 3) % 11) as f64 - 4.0).collect();
            let mut c = x.clone();
            spline_prefilter(&mut c);
            for k in 0..n {
                let at = |j: i64| c[mirror(j, n)];
                let back = (at(k as i64 - 1) + 4.0 * at(k as i64) + at(k as i64 + 1)) / 6.0;
                assert!((back - x[k]).abs() < 1e-13, "n {n}, k {k}: {back} vs {}", x[k]);
            }
        }
    }

    /// Where output samples fall on input samples the spline returns them exactly; constants stay.
    #[test]
    fn nodes_are_interpolated_and_constants_kept() {
        // 5 -> 9: output 2i sits on input i.
        let m = spline_zoom_matrix(5, 9).unwrap();
        for i in 0..5 {
            for j in 0..5 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((m[2 * i * 5 + j] - want).abs() < 1e-14);
            }
        }
        for (a, b) in [(9, 12), (12, 7), (1, 4), (2, 64), (64, 64)] {
            let m = spline_zoom_matrix(a, b).unwrap();
            for o in 0..b {
                let s: f64 = m[o * a..(o + 1) * a].iter().sum();
                assert!((s - 1.0).abs() < 1e-13, "{a} -> {b}, row {o}: {s}");
            }
        }
    }

    #[test]
    fn spline_zoom_is_differentiable_and_checks_its_input() {
        let dev = Device::Cpu;
        let x = crate::seed::rand_uniform((1, 2, 4, 5), -1.0, 1.0, DType::F64, &dev, 3).unwrap();
        let f = |v: &[Tensor]| {
            let w = Tensor::arange(0f64, 42.0, &dev)?.reshape((1, 2, 3, 7))?;
            (spline_zoom(&v[0], &[3, 7]).map_err(candle_core::Error::wrap)? * w)?.sum_all()
        };
        let r = crate::check_grad(f, &[x], &Default::default()).unwrap();
        assert!(r.max_rel_error < 1e-6, "{r:?}");
        let u = Tensor::zeros((2, 3), DType::U8, &dev).unwrap();
        assert!(matches!(spline_zoom(&u, &[4, 4]), Err(Error::DType { .. })));
        let e = Tensor::zeros((2, 0), DType::F32, &dev).unwrap();
        assert!(matches!(spline_zoom(&e, &[4, 4]), Err(Error::InvalidArgument { .. })));
        assert!(matches!(spline_zoom(&e, &[1, 4, 4]), Err(Error::Shape { .. })));
    }
}
