//! The units of work that the U-Net benchmarks time: one training step (forward, smooth-L1
//! noise loss, backward, Adam update) and one sampling step (forward only) of an
//! [`AcdmUnet`] on fixed seeded data. `benches/unet.rs`, the `cargo xtask bench` entries and
//! the PyTorch peer script (`bench/peers/acdm_unet_torch.py`) run the same work.

use super::{seeded_init, AcdmUnet, AcdmUnetConfig};
use crate::Result;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use pbdl_core::train::{AdamConfig, Optim, OptimizerConfig};

/// Sizes of a U-Net workload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnetWorkload {
    /// Network width (`AcdmUnetConfig::dim`).
    pub dim: usize,
    /// Channels in and out (ACDM Inc: 12 = 3 frames x 4 fields).
    pub channels: usize,
    /// Batch size.
    pub batch: usize,
    /// Height.
    pub height: usize,
    /// Width.
    pub width: usize,
}

impl UnetWorkload {
    /// A short label, e.g. `dim32_b16_c12_64x32`.
    pub fn label(&self) -> String {
        format!("dim{}_b{}_c{}_{}x{}", self.dim, self.batch, self.channels, self.height, self.width)
    }
}

/// A network, its Adam optimiser (lr 1e-4, as ACDM) and fixed seeded inputs.
pub struct UnetFixture {
    /// The network.
    pub net: AcdmUnet,
    /// Its variables.
    pub varmap: VarMap,
    vars: Vec<Var>,
    opt: Optim,
    x: Tensor,
    t: Tensor,
    target: Tensor,
}

impl UnetFixture {
    /// Builds an ACDM U-Net (with step embedding) of the workload's size in `f32` with seeded
    /// weights, a noisy input, steps and target noise.
    pub fn new(w: &UnetWorkload, seed: u64) -> Result<Self> {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let net =
            AcdmUnet::new(AcdmUnetConfig::acdm(w.dim, w.channels), VarBuilder::from_varmap(&varmap, DType::F32, &dev))?;
        seeded_init(&varmap, seed)?;
        let vars = varmap.all_vars();
        let opt = OptimizerConfig::Adam(AdamConfig { lr: 1e-4, ..Default::default() }).build(vars.clone())?;
        let shape = (w.batch, w.channels, w.height, w.width);
        let x = pbdl_core::seed::randn(shape, 0.0, 1.0, DType::F32, &dev, seed + 1)?;
        let target = pbdl_core::seed::randn(shape, 0.0, 1.0, DType::F32, &dev, seed + 2)?;
        let t: Vec<f32> = (0..w.batch).map(|i| (i % 20) as f32).collect();
        let t = Tensor::from_vec(t, w.batch, &dev)?;
        Ok(Self { net, varmap, vars, opt, x, t, target })
    }

    /// One training step; returns the loss before the update.
    pub fn train_step(&mut self) -> Result<f32> {
        let pred = self.net.forward(&self.x, Some(&self.t))?;
        let loss = smooth_l1(&pred, &self.target)?;
        let grads = loss.backward()?;
        self.opt.step(&grads)?;
        Ok(loss.to_scalar::<f32>()?)
    }

    /// One sampling step: the noise prediction alone.
    pub fn sample_step(&self) -> Result<Tensor> {
        Ok(self.net.forward(&self.x, Some(&self.t))?)
    }

    /// Number of trainable scalars.
    pub fn parameters(&self) -> usize {
        self.vars.iter().map(|v| v.elem_count()).sum()
    }
}

/// Mean smooth-L1 (Huber, beta 1) loss, PyTorch's `F.smooth_l1_loss`: `0.5 d^2` for
/// `|d| < 1`, else `|d| - 0.5`, written as `q (|d| - q / 2)` with `q = min(|d|, 1)`.
pub fn smooth_l1(pred: &Tensor, target: &Tensor) -> Result<Tensor> {
    let a = (pred - target)?.abs()?;
    let q = a.clamp(0.0, 1.0)?;
    Ok((&q * (a - (&q * 0.5)?)?)?.mean_all()?)
}
