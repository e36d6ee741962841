//! The parts LSiM and VolSiM share: per-layer feature normalisation with stored statistics, the
//! learned weighted feature distance, and the scope of the input normalisation.

use crate::Result;
use candle_core::Tensor;
use pbdl_core::sample::{resize2d, resize3d, Resize};

/// Added to the standard deviation before dividing, as in the official code.
const EPSILON: f64 = 1e-10;

/// Over which inputs the min/max of the input normalisation is taken (LSiM: per channel to
/// [0, 255]; VolSiM: over all channels to [-1, 1]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum NormScope {
    /// Each pair on its own (both inputs of the pair jointly). Batched = one call per pair. Default.
    #[default]
    PerPair,
    /// Jointly over both inputs of every pair in the call, as the official code does.
    JointBatch,
}

/// Mean and standard deviation maps `[1, 1, spatial...]` at the feature size `size`: the stored
/// maps, or (other sizes) the mean and M2 maps resized (bi/trilinear, aligned corners) and then
/// `std = sqrt(M2 / (count - 1))`, in the official order.
pub(crate) fn stats(mean: &Tensor, m2: &Tensor, count: f64, size: &[usize]) -> Result<(Tensor, Tensor)> {
    let (mut mean, mut m2) = (mean.clone(), m2.clone());
    if mean.dims()[2..] != *size {
        let mode = Resize::Bilinear { align_corners: true };
        if size.len() == 2 {
            mean = resize2d(&mean, (size[0], size[1]), mode)?;
            m2 = resize2d(&m2, (size[0], size[1]), mode)?;
        } else {
            mean = resize3d(&mean, (size[0], size[1], size[2]), mode)?;
            m2 = resize3d(&m2, (size[0], size[1], size[2]), mode)?;
        }
    }
    let std = (m2 / (count - 1.0))?.sqrt()?;
    Ok((mean, std))
}

/// `mean_(space) sum_c w_c (n(b) - n(a))^2` of one feature layer, with
/// `n = (phi - mu) / (std + 1e-10) / (sqrt(C) - 1)`; `[n]`.
pub(crate) fn layer_distance(a: &Tensor, b: &Tensor, mean: &Tensor, std: &Tensor, lin: &Tensor) -> Result<Tensor> {
    let c = a.dim(1)?;
    let den = (std + EPSILON)?;
    let scale = 1.0 / ((c as f64).sqrt() - 1.0);
    let norm = |f: &Tensor| -> candle_core::Result<Tensor> { f.broadcast_sub(mean)?.broadcast_div(&den)? * scale };
    let diff = (norm(b)? - norm(a)?)?.sqr()?;
    let weighted = diff.broadcast_mul(lin)?.sum(1)?;
    Ok(weighted.flatten_from(1)?.mean(1)?)
}
