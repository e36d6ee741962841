//! The heat problem's score network: a small periodic (circular-padding) residual conv net.
//!
//! Input: the state and a constant time channel `t / t1`; a 3x3 lifting conv to `channels`,
//! `blocks` residual blocks (conv, SiLU, conv, plus skip, SiLU), and a 3x3 projection to one
//! channel. All convs are `pbdl_core::conv` with circular padding, matching the periodic domain.

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{conv2d, Conv2dParams};

/// Weights and bias of one conv.
#[derive(Clone, Debug)]
struct ConvVars {
    w: Var,
    b: Var,
}

/// A periodic residual conv net `s(x, t)` for `[batch, 1, n, n]` states.
#[derive(Clone, Debug)]
pub struct HeatScoreNet {
    lift: ConvVars,
    blocks: Vec<(ConvVars, ConvVars)>,
    proj: ConvVars,
    params: Conv2dParams,
    t1: f64,
}

fn conv_vars(cin: usize, cout: usize, scale: f64, dtype: DType, seed: u64) -> Result<ConvVars> {
    let std = scale / ((cin * 9) as f64).sqrt();
    let w = pbdl_core::seed::randn((cout, cin, 3, 3), 0.0, std, dtype, &Device::Cpu, seed)?;
    let b = Tensor::zeros(cout, dtype, &Device::Cpu)?;
    Ok(ConvVars { w: Var::from_tensor(&w)?, b: Var::from_tensor(&b)? })
}

impl HeatScoreNet {
    /// A net with `channels` feature channels and `blocks` residual blocks, seeded; `t1` scales
    /// the time input to `[0, 1]`.
    pub fn new(channels: usize, blocks: usize, t1: f64, dtype: DType, seed: u64) -> Result<Self> {
        if channels == 0 || !(t1 > 0.0 && t1.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "channels/t1",
                value: format!("{channels}/{t1}"),
                hint: "use at least one channel (16-32) and a positive end time (0.2)",
            });
        }
        let lift = conv_vars(2, channels, 1.0, dtype, seed)?;
        let blocks = (0..blocks)
            .map(|i| {
                // The second conv of each block starts small so every block starts near identity.
                Ok((
                    conv_vars(channels, channels, 1.0, dtype, seed + 2 * i as u64 + 1)?,
                    conv_vars(channels, channels, 0.1, dtype, seed + 2 * i as u64 + 2)?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let proj = conv_vars(channels, 1, 0.1, dtype, seed + 1000)?;
        Ok(HeatScoreNet { lift, blocks, proj, params: Conv2dParams::default().padding(1).circular(), t1 })
    }

    /// All trainable variables.
    pub fn vars(&self) -> Vec<Var> {
        let mut v = vec![self.lift.w.clone(), self.lift.b.clone()];
        for (a, b) in &self.blocks {
            v.extend([a.w.clone(), a.b.clone(), b.w.clone(), b.b.clone()]);
        }
        v.extend([self.proj.w.clone(), self.proj.b.clone()]);
        v
    }

    /// Number of scalar parameters.
    pub fn num_params(&self) -> usize {
        self.vars().iter().map(|v| v.elem_count()).sum()
    }

    fn conv(&self, x: &Tensor, c: &ConvVars) -> Result<Tensor> {
        Ok(conv2d(x, c.w.as_tensor(), Some(c.b.as_tensor()), &self.params)?)
    }

    /// The score `s(x, t)` for states `x` (`[batch, 1, n, n]`), sample `i` at time `t[i]`.
    pub fn forward(&self, x: &Tensor, t: &[f64]) -> Result<Tensor> {
        if x.rank() != 4 || x.dim(1)? != 1 || x.dim(0)? != t.len() {
            return Err(Error::shape(
                "heat score net input [batch, 1, n, n] with one time per sample",
                format!("[{}, 1, n, n]", t.len()),
                x.dims(),
            ));
        }
        let tc = Tensor::from_vec(t.iter().map(|v| v / self.t1).collect::<Vec<f64>>(), (t.len(), 1, 1, 1), x.device())?
            .to_dtype(x.dtype())?
            .broadcast_as(x.shape())?
            .contiguous()?;
        let mut h = self.conv(&Tensor::cat(&[x, &tc], 1)?, &self.lift)?.silu()?;
        for (a, b) in &self.blocks {
            let r = self.conv(&self.conv(&h, a)?.silu()?, b)?;
            h = (h + r)?.silu()?;
        }
        self.conv(&h, &self.proj)
    }
}
