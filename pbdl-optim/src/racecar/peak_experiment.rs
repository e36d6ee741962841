//! The racecar SVD experiment on peak images: plain vs orthogonality vs racecar training of the
//! BN + ReLU dense net (`784 -> 128 -> 2`, the paper's peak model) and of a small conv net, and
//! how well the first layer's leading singular vectors lie in the data's principal subspace.
//!
//! Setup as the official peak run: 100 training images (50 per class, [`peak_images`]), pixel
//! values 0..255, full-batch Adam (lr `1e-4`), softmax cross entropy on the (BN + ReLU) output;
//! racecar weight `1e-6` on losses summed over the batch, i.e. `lambda = 1e-4` on our
//! batch-averaged loss; orthogonality `0.1 sigma_max(W^T W - I)^2` on both weight matrices.
//! (The official code applies a second softmax before the cross entropy; we do not.)
//!
//! Subspaces: the dense net's `W_1: [784, 128]` is compared with the span of the 100 images
//! (rank 100, the subspace a rank-128 projector `W W^T` can reproduce exactly); the conv net's
//! unfolded filters `[k k, C]` with the `C` leading principal directions of all image patches
//! the conv sees (the best rank-`C` projector of the patches).

use super::batch_norm::ReverseStats;
use super::bn_mlp::{BnMlp, Pass};
use super::conv_net::{patches, BnConvNet, ConvSpec};
use super::ortho::PowerIteration;
use super::peak::peak_images;
use super::svd::{principal_alignment, Subspace};
use crate::error::Result;
use candle_core::{DType, Tensor, Var, D};
use serde::{Deserialize, Serialize};

/// The extra loss term of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Regularizer {
    /// Task loss only.
    Plain,
    /// `factor * sigma_max(W^T W - I)^2` on every weight matrix.
    Orthogonality,
    /// The racecar reverse-pass reconstruction loss.
    Racecar,
}

impl Regularizer {
    /// Short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            Regularizer::Plain => "plain",
            Regularizer::Orthogonality => "orthogonality",
            Regularizer::Racecar => "racecar",
        }
    }
}

/// Which net a run trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PeakNet {
    /// The dense `side^2 -> hidden -> 2` BN + ReLU net.
    Mlp,
    /// The conv net of [`PeakConfig::conv`].
    Conv,
}

/// Settings of [`peak_alignment_experiment`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PeakConfig {
    /// Training images per class. Default `50` (the paper's 100 images).
    pub per_class: usize,
    /// Image side. Default `28`.
    pub side: usize,
    /// Hidden width of the dense net. Default `128`.
    pub hidden: usize,
    /// The conv net: default 8 filters 4x4, stride 4 (non-overlapping patches), dense to 2.
    pub conv: ConvSpec,
    /// Racecar weight on the batch-averaged reconstruction loss. Default `1e-4`.
    pub lambda: f64,
    /// Orthogonality weight. Default `0.1`.
    pub ortho: f64,
    /// Adam learning rate. Default `1e-4`.
    pub lr: f64,
    /// Full-batch steps. Default `5000` (as the paper).
    pub steps: usize,
    /// Number of leading singular vectors compared. Default `4`.
    pub lead: usize,
    /// Batch statistics of the reverse pass. Default [`ReverseStats::Own`].
    pub reverse_stats: ReverseStats,
    /// Seed of data and networks. Default `0`.
    pub seed: u64,
}

impl Default for PeakConfig {
    fn default() -> Self {
        Self {
            per_class: 50,
            side: 28,
            hidden: 128,
            conv: ConvSpec { side: 28, channels: 8, kernel: 4, stride: 4, padding: 0, outputs: 2 },
            lambda: 1e-4,
            ortho: 0.1,
            lr: 1e-4,
            steps: 5000,
            lead: 4,
            reverse_stats: ReverseStats::Own,
            seed: 0,
        }
    }
}

/// What one training run measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PeakRun {
    /// The net trained.
    pub net: PeakNet,
    /// The extra loss term.
    pub regularizer: Regularizer,
    /// `|cos|` of the `lead` leading singular vectors of the first layer with the subspace.
    pub cos: Vec<f64>,
    /// Dimension of the data subspace compared with.
    pub subspace_dim: usize,
    /// Dimension of the space the singular vectors live in (`784` or `k k`).
    pub ambient_dim: usize,
    /// Final training cross entropy.
    pub task_loss: f64,
    /// Final training accuracy.
    pub accuracy: f64,
    /// Final reconstruction loss (batch-averaged, without lambda), for every regularizer.
    pub reconstruction: f64,
    /// Training wall-clock seconds.
    pub seconds: f64,
}

impl PeakRun {
    /// The smallest `|cos|` over the leading singular vectors.
    pub fn min_cos(&self) -> f64 {
        self.cos.iter().copied().fold(f64::INFINITY, f64::min)
    }
}

/// Mean softmax cross entropy of `logits: [n, classes]` against `onehot`, and the accuracy.
fn cross_entropy(logits: &Tensor, onehot: &Tensor) -> Result<(Tensor, f64)> {
    let logp = pbdl_core::nn::log_softmax(logits, D::Minus1)?;
    let n = logits.dim(0)? as f64;
    let ce = ((logp * onehot)?.sum_all()? * (-1.0 / n))?;
    let pred = logits.argmax(D::Minus1)?;
    let truth = onehot.argmax(D::Minus1)?;
    let acc = pred.eq(&truth)?.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()? / n;
    Ok((ce, acc))
}

/// Trains one net with one regularizer on `x` and measures the alignment. The full-batch Adam
/// steps run on pbdl-core's [`pbdl_core::train::TrainLoop`] (in memory, no progress bar).
///
/// # Errors
/// [`crate::Error::Diverged`] when the loss becomes non-finite (the loop's guard also stops on
/// a non-finite gradient norm, as [`crate::Error::Core`]).
pub fn train_peak_net(
    cfg: &PeakConfig,
    net_kind: PeakNet,
    reg: Regularizer,
    x: &Tensor,
    onehot: &Tensor,
) -> Result<PeakRun> {
    let dtype = x.dtype();
    let mlp;
    let conv;
    // One interface over both nets: forward, reconstruction loss, weight matrices.
    #[allow(clippy::type_complexity)]
    let (forward, recon, mats, vars): (
        Box<dyn Fn(&Tensor) -> Result<Pass>>,
        Box<dyn Fn(&Pass) -> Result<Tensor>>,
        Box<dyn Fn() -> Result<Vec<Tensor>>>,
        Vec<Var>,
    ) = match net_kind {
        PeakNet::Mlp => {
            mlp = BnMlp::new(&[cfg.side * cfg.side, cfg.hidden, 2], dtype, cfg.seed + 1)?;
            (
                Box::new(|x| mlp.forward(x)),
                Box::new(|p| mlp.reconstruction_loss(p, cfg.reverse_stats)),
                Box::new(|| Ok(vec![mlp.weight(0).clone(), mlp.weight(1).clone()])),
                mlp.vars()?,
            )
        }
        PeakNet::Conv => {
            conv = BnConvNet::new(cfg.conv, dtype, cfg.seed + 1)?;
            (
                Box::new(|x| conv.forward(x)),
                Box::new(|p| conv.reconstruction_loss(p, cfg.reverse_stats)),
                Box::new(|| Ok(vec![conv.unfolded_filters()?, conv.dense_weight().clone()])),
                conv.vars()?,
            )
        }
    };
    let mut power: Vec<PowerIteration> = mats()?
        .iter()
        .enumerate()
        .map(|(i, w)| PowerIteration::new(w.dim(1)?, cfg.seed + 10 + i as u64))
        .collect::<candle_core::Result<_>>()?;
    let seconds = super::full_batch_adam(&vars, cfg.lr, cfg.steps, |_| {
        let pass = forward(x)?;
        let (task, _) = cross_entropy(pass.acts.last().expect("output"), onehot)?;
        Ok(match reg {
            Regularizer::Plain => task,
            Regularizer::Racecar => (task + (recon(&pass)? * cfg.lambda)?)?,
            Regularizer::Orthogonality => {
                let mut l = task;
                for (w, p) in mats()?.iter().zip(&mut power) {
                    l = (l + p.penalty(w, cfg.ortho)?)?;
                }
                l
            }
        })
    })?;
    let pass = forward(x)?;
    let (task, accuracy) = cross_entropy(pass.acts.last().expect("output"), onehot)?;
    let reconstruction = recon(&pass)?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
    let w0 = mats()?.remove(0);
    let (data, subspace) = match net_kind {
        PeakNet::Mlp => (x.clone(), Subspace::Span),
        PeakNet::Conv => (patches(&cfg.conv, x)?, Subspace::Rank(cfg.conv.channels)),
    };
    let (cos, subspace_dim) = principal_alignment(&w0, &data, cfg.lead, subspace)?;
    Ok(PeakRun {
        net: net_kind,
        regularizer: reg,
        cos,
        subspace_dim,
        ambient_dim: w0.dim(0)?,
        task_loss: task.to_dtype(DType::F64)?.to_scalar::<f64>()?,
        accuracy,
        reconstruction,
        seconds,
    })
}

/// Generates the peak images from `cfg.seed` and trains every `nets` x `regs` combination from
/// the same start (per net), in `f32`.
pub fn peak_alignment_experiment(cfg: &PeakConfig, nets: &[PeakNet], regs: &[Regularizer]) -> Result<Vec<PeakRun>> {
    let (x, labels) = peak_images(cfg.per_class, cfg.side, DType::F32, cfg.seed)?;
    let onehot = one_hot(&labels, 2)?.to_dtype(DType::F32)?;
    let mut runs = Vec::new();
    for &net in nets {
        for &reg in regs {
            runs.push(train_peak_net(cfg, net, reg, &x, &onehot)?);
        }
    }
    Ok(runs)
}

/// `[n, classes]` one-hot rows of `u32` labels.
fn one_hot(labels: &Tensor, classes: usize) -> Result<Tensor> {
    let l = labels.to_vec1::<u32>()?;
    let mut v = vec![0f64; l.len() * classes];
    for (i, &c) in l.iter().enumerate() {
        v[i * classes + c as usize] = 1.0;
    }
    Ok(Tensor::from_vec(v, (l.len(), classes), labels.device())?)
}
