//! The racecar reverse pass for a small conv net: `conv (C filters) -> BN -> ReLU -> dense ->
//! BN -> ReLU`, on one-channel images.
//!
//! The reverse pass of a convolution is the transposed convolution with the same (shared)
//! weights, the adjoint of the forward one. From `d'_2 = d_2`: `d'_1 = ReLU(BN_1(reshape((d'_2 -
//! b_2) W_2^T)))`, `d'_0 = conv_transpose(d'_1 - b_1, W_1)`, loss `1/2 ||d'_0 - x||^2 + 1/2
//! ||d'_1 - d_1||^2` averaged over the batch. With kernel = stride (non-overlapping patches),
//! `conv_transpose(conv(x))` is `W W^T` applied to each patch, so the SVD link of the dense
//! layer carries over to the unfolded filters and the image patches ([`BnConvNet::unfolded_filters`],
//! [`patches`]).

use super::batch_norm::{BatchNorm, ReverseStats};
use super::bn_mlp::{glorot, reconstruction_sum, Pass};
use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{conv2d, conv_transpose2d, Conv2dParams};
use serde::{Deserialize, Serialize};

/// Shape of a [`BnConvNet`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConvSpec {
    /// Side of the square one-channel input images.
    pub side: usize,
    /// Number of filters of the conv layer.
    pub channels: usize,
    /// Kernel size.
    pub kernel: usize,
    /// Stride.
    pub stride: usize,
    /// Zero padding on each side.
    pub padding: usize,
    /// Outputs of the dense layer.
    pub outputs: usize,
}

impl ConvSpec {
    /// Side of the conv layer's output.
    pub fn out_side(&self) -> Result<usize> {
        let padded = self.side + 2 * self.padding;
        if self.stride == 0 || self.kernel == 0 || self.kernel > padded || self.channels == 0 || self.outputs == 0 {
            return Err(Error::shape(
                "racecar conv net",
                "stride, kernel, channels, outputs >= 1 and kernel <= side + 2 padding",
                format!("{self:?}"),
            ));
        }
        Ok((padded - self.kernel) / self.stride + 1)
    }

    /// The conv parameters.
    pub fn params(&self) -> Conv2dParams {
        Conv2dParams::default().stride(self.stride).padding(self.padding)
    }

    /// The output padding that makes the transposed conv return `side x side`.
    fn output_padding(&self) -> Result<usize> {
        let h = self.out_side()?;
        let base = (h - 1) * self.stride + self.kernel;
        let op = (self.side + 2 * self.padding).saturating_sub(base);
        if op >= self.stride.max(1) && op > 0 {
            return Err(Error::shape("racecar conv net output padding", "< stride", op));
        }
        Ok(op)
    }
}

/// A conv + dense net with BN and ReLU whose weights are shared with its reverse pass.
#[derive(Clone, Debug)]
pub struct BnConvNet {
    spec: ConvSpec,
    w1: Tensor,
    b1: Tensor,
    bn1: BatchNorm,
    w2: Tensor,
    b2: Tensor,
    bn2: BatchNorm,
}

impl BnConvNet {
    /// Glorot-uniform weights from `seed`, zero biases, `gamma = 1`, `beta = 0`.
    pub fn new(spec: ConvSpec, dtype: DType, seed: u64) -> Result<Self> {
        let h = spec.out_side()?;
        spec.output_padding()?;
        let mut rng = pbdl_core::seed::rng(seed);
        let k2 = spec.kernel * spec.kernel;
        let (c, feat) = (spec.channels, spec.channels * h * h);
        let w1 = glorot(&[c, 1, spec.kernel, spec.kernel], k2, c * k2, dtype, &mut rng)?;
        let w2 = glorot(&[feat, spec.outputs], feat, spec.outputs, dtype, &mut rng)?;
        let zeros = |n| -> candle_core::Result<Tensor> { Ok(Var::zeros(n, dtype, &Device::Cpu)?.as_tensor().clone()) };
        Ok(Self {
            spec,
            w1,
            b1: zeros(c)?,
            bn1: BatchNorm::new(c, dtype)?,
            w2,
            b2: zeros(spec.outputs)?,
            bn2: BatchNorm::new(spec.outputs, dtype)?,
        })
    }

    /// A net from given parameters: `w1: [C, 1, k, k]`, `b1: [C]`, `w2: [C h h, outputs]`,
    /// `b2: [outputs]` (e.g. for gradient checks).
    pub fn from_tensors(
        spec: ConvSpec,
        conv: (Tensor, Tensor, BatchNorm),
        dense: (Tensor, Tensor, BatchNorm),
    ) -> Result<Self> {
        let h = spec.out_side()?;
        spec.output_padding()?;
        let want1 = [spec.channels, 1, spec.kernel, spec.kernel];
        if conv.0.dims() != want1 {
            return Err(Error::shape("racecar conv weight", format!("{want1:?}"), format!("{:?}", conv.0.dims())));
        }
        let want2 = [spec.channels * h * h, spec.outputs];
        if dense.0.dims() != want2 {
            return Err(Error::shape("racecar dense weight", format!("{want2:?}"), format!("{:?}", dense.0.dims())));
        }
        Ok(Self { spec, w1: conv.0, b1: conv.1, bn1: conv.2, w2: dense.0, b2: dense.1, bn2: dense.2 })
    }

    /// All trainable variables.
    pub fn vars(&self) -> Result<Vec<Var>> {
        let mut v: Vec<Var> = [&self.w1, &self.b1, &self.w2, &self.b2]
            .into_iter()
            .map(Var::from_tensor)
            .collect::<candle_core::Result<_>>()?;
        v.extend(self.bn1.vars()?);
        v.extend(self.bn2.vars()?);
        Ok(v)
    }

    /// The conv filters `[C, 1, k, k]`.
    pub fn filters(&self) -> &Tensor {
        &self.w1
    }

    /// The dense weights `[C h h, outputs]`.
    pub fn dense_weight(&self) -> &Tensor {
        &self.w2
    }

    /// The filters as a dense `[k k, C]` matrix (`[in, out]`: one column per filter, rows in
    /// patch order `(ky, kx)`), the matrix the conv applies to every patch.
    pub fn unfolded_filters(&self) -> Result<Tensor> {
        let k2 = self.spec.kernel * self.spec.kernel;
        Ok(self.w1.reshape((self.spec.channels, k2))?.t()?.contiguous()?)
    }

    /// The forward pass of `x: [batch, side * side]`: acts `[x as [batch, 1, side, side], d_1
    /// [batch, C, h, h], d_2 [batch, outputs]]`.
    pub fn forward(&self, x: &Tensor) -> Result<Pass> {
        let s = self.spec;
        let b = x.dim(0)?;
        let x4 = x.reshape((b, 1, s.side, s.side))?;
        let z1 = conv2d(&x4, &self.w1, Some(&self.b1), &s.params())?;
        let (y1, s1) = self.bn1.forward(&z1)?;
        let d1 = y1.relu()?;
        let z2 = d1.flatten_from(1)?.matmul(&self.w2)?.broadcast_add(&self.b2)?;
        let (y2, s2) = self.bn2.forward(&z2)?;
        Ok(Pass { acts: vec![x4, d1, y2.relu()?], stats: vec![s1, s2] })
    }

    /// The reverse pass `[d'_0, d'_1]` (see the module docs).
    pub fn reverse(&self, pass: &Pass, mode: ReverseStats) -> Result<Vec<Tensor>> {
        let d1 = &pass.acts[1];
        let back1 = pass.acts[2].broadcast_sub(&self.b2)?.matmul(&self.w2.t()?)?.reshape(d1.dims())?;
        let r1 = self.bn1.reverse(&back1, &pass.stats[0], mode)?.relu()?;
        let r0 = conv_reverse(&r1, &self.w1, &self.b1, &self.spec)?;
        Ok(vec![r0, r1])
    }

    /// `1/2 ||d'_0 - x||^2 + 1/2 ||d'_1 - d_1||^2`, averaged over the batch.
    pub fn reconstruction_loss(&self, pass: &Pass, mode: ReverseStats) -> Result<Tensor> {
        let rec = self.reverse(pass, mode)?;
        reconstruction_sum(&rec, &pass.acts[..2])
    }
}

/// The reverse pass of a conv layer: `conv_transpose(y - b, w)` with the conv's own weights
/// `w: [C, 1, k, k]` (pbdl_core's differentiable transposed conv), back to `side x side`.
pub fn conv_reverse(y: &Tensor, w: &Tensor, b: &Tensor, spec: &ConvSpec) -> Result<Tensor> {
    let c = b.dim(0)?;
    let op = spec.output_padding()?;
    let y = y.broadcast_sub(&b.reshape((1, c, 1, 1))?)?;
    Ok(conv_transpose2d(&y, w, None, &spec.params(), [op, op])?)
}

/// Every patch the conv sees in `x: [batch, side * side]` (zero padded), as rows
/// `[batch * h * h, k k]` in the order of [`BnConvNet::unfolded_filters`].
pub fn patches(spec: &ConvSpec, x: &Tensor) -> Result<Tensor> {
    let s = *spec;
    let h = s.out_side()?;
    let b = x.dim(0)?;
    let v = x.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let mut rows = Vec::with_capacity(b * h * h * s.kernel * s.kernel);
    for n in 0..b {
        for oy in 0..h {
            for ox in 0..h {
                for ky in 0..s.kernel {
                    for kx in 0..s.kernel {
                        let (y, xx) = (
                            (oy * s.stride + ky) as isize - s.padding as isize,
                            (ox * s.stride + kx) as isize - s.padding as isize,
                        );
                        let inside = y >= 0 && xx >= 0 && (y as usize) < s.side && (xx as usize) < s.side;
                        rows.push(if inside {
                            v[n * s.side * s.side + y as usize * s.side + xx as usize]
                        } else {
                            0.0
                        });
                    }
                }
            }
        }
    }
    Ok(Tensor::from_vec(rows, (b * h * h, s.kernel * s.kernel), &Device::Cpu)?)
}
