//! The SVD analysis: how well the leading singular vectors of a weight matrix lie in the
//! principal subspace of the data it is applied to.

use crate::error::{Error, Result};
use candle_core::{DType, Tensor};
use faer::Mat;

/// Which subspace of the data the singular vectors are compared with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Subspace {
    /// The whole span of the data rows (singular values above `1e-10` of the largest).
    Span,
    /// The fewest leading (uncentred) principal directions that hold this fraction of
    /// `sum_i s_i^2`, e.g. `0.99`.
    Energy(f64),
    /// The `r` leading principal directions.
    Rank(usize),
}

/// The `|cos|` of the `k` leading input-space singular vectors of `w: [in, out]` (left
/// singular vectors of the `[in, out]` matrix) with a subspace of the rows of `data: [n, in]`:
/// the norm of each unit vector's projection onto it. Also returns the subspace's dimension.
pub fn principal_alignment(w: &Tensor, data: &Tensor, k: usize, subspace: Subspace) -> Result<(Vec<f64>, usize)> {
    let (wm, dm) = (to_mat(w)?, to_mat(data)?);
    if dm.ncols() != wm.nrows() {
        return Err(Error::shape("data columns (= weight rows, the input size)", wm.nrows(), dm.ncols()));
    }
    let ws = wm.thin_svd().map_err(|_| Error::SvdNoConvergence { rows: wm.nrows(), cols: wm.ncols() })?;
    let dt = dm.transpose().to_owned();
    let ds = dt.thin_svd().map_err(|_| Error::SvdNoConvergence { rows: dt.nrows(), cols: dt.ncols() })?;
    let s = ds.S().column_vector();
    let n = s.nrows();
    let rank = match subspace {
        Subspace::Span => (0..n).filter(|&i| s[i] > 1e-10 * s[0]).count(),
        Subspace::Rank(r) => r.min(n),
        Subspace::Energy(f) => {
            if !(f > 0.0 && f <= 1.0) {
                return Err(Error::InvalidConfig {
                    name: "energy fraction",
                    value: f,
                    hint: "use a fraction in (0, 1]",
                });
            }
            let total: f64 = (0..n).map(|i| s[i] * s[i]).sum();
            let mut acc = 0.0;
            let mut r = 0;
            while r < n && acc < f * total {
                acc += s[r] * s[r];
                r += 1;
            }
            r
        }
    };
    let (u, q) = (ws.U(), ds.U());
    let cos = (0..k.min(u.ncols()))
        .map(|i| {
            let p2: f64 = (0..rank)
                .map(|r| {
                    let c: f64 = (0..u.nrows()).map(|d| u[(d, i)] * q[(d, r)]).sum();
                    c * c
                })
                .sum();
            p2.sqrt()
        })
        .collect();
    Ok((cos, rank))
}

fn to_mat(t: &Tensor) -> Result<Mat<f64>> {
    let v = t.to_dtype(DType::F64)?.to_vec2::<f64>()?;
    if v.is_empty() || v[0].is_empty() {
        return Err(Error::shape("matrix for the SVD analysis", "at least 1x1", format!("{:?}", t.dims())));
    }
    Ok(Mat::from_fn(v.len(), v[0].len(), |i, j| v[i][j]))
}
