//! racecar ("Reviving Autoencoder Pretraining", Xie and Thuerey): a reverse-pass reconstruction loss
//! with transposed shared weights, for dense networks, and the SVD analysis of what it does to
//! the weights.
//!
//! For a network `d_{m+1} = act_m(d_m W_m + b_m)` (ReLU hidden layers, linear output, no batch
//! norm here), the reverse pass starts from the output, `d'_L = d_L`, and goes back through the
//! *same* weights transposed: `d'_m = act_{m-1}((d'_{m+1} - b_m) W_m^T)`, where `act_{m-1}` is
//! the activation that produced `d_m` (identity for the input, `m = 0`). The loss adds
//! `lambda sum_m 1/2 ||d'_m - d_m||^2` (mean over the batch) to the task loss.
//!
//! Minimising `||W W^T d - d||` over the data makes `W W^T` a projector onto the data's
//! principal subspace: the leading input-space singular vectors of `W_0` end up in the span of
//! the training inputs. [`span_alignment`] measures that (`|cos|` between each singular vector
//! and the span), and [`alignment_experiment`] compares a racecar-trained network with a plain
//! one on inputs that lie in a low-dimensional subspace.
//!
//! The submodules add batch norm ([`batch_norm`], [`bn_mlp`]: the paper's peak model), conv
//! nets ([`conv_net`]: the reverse pass of a conv is the transposed conv with the same
//! weights), the orthogonality baseline ([`ortho`]), procedural peak images ([`peak`]), the
//! alignment with a principal subspace ([`svd`]) and the plain / orthogonality / racecar
//! comparison on peak images ([`peak_experiment`]).

pub mod batch_norm;
pub mod bn_mlp;
pub mod conv_net;
pub mod digits;
pub mod mnist;
pub mod ortho;
pub mod peak;
pub mod peak_experiment;
pub mod svd;

use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarMap};
use faer::Mat;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// `steps` full-batch Adam updates (learning rate `lr`, other settings at their defaults) of
/// `vars` on the loss `loss_at(step)`, run on pbdl-core's [`TrainLoop`] (in memory, no
/// checkpoints, no progress bar). Returns the training seconds.
///
/// A non-finite loss stops the run with [`Error::Diverged`] before that update (the variables
/// keep the last good step); the loop's guard also stops on a non-finite gradient norm, as
/// [`Error::Core`].
pub(crate) fn full_batch_adam(
    vars: &[Var],
    lr: f64,
    steps: usize,
    loss_at: impl FnMut(u64) -> Result<Tensor>,
) -> Result<f64> {
    let varmap = VarMap::new();
    varmap
        .data()
        .lock()
        .map_err(|_| candle_core::Error::Msg("full_batch_adam: the variable map's lock is poisoned".into()))?
        .extend(vars.iter().enumerate().map(|(i, v)| (format!("v{i}"), v.clone())));
    let run = TrainLoop::resume(&varmap, LoopConfig { steps: steps as u64, progress: false, ..Default::default() })?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr, ..Default::default() });
    let report = run.run::<Error>(&adam, |_| lr, CheckpointMeta::at, loss_at).map_err(|e| match e {
        // The loss guard's error as the racecar trainers have always reported it.
        Error::Core(pbdl_core::Error::Diverged { step, quantity, value, .. }) if quantity == "loss" => {
            Error::Diverged { step, loss: value, last_good: step.saturating_sub(1) }
        }
        e => e,
    })?;
    Ok(report.seconds)
}

/// A dense ReLU network whose weights are shared with its reverse (reconstruction) pass.
#[derive(Clone, Debug)]
pub struct RacecarMlp {
    /// `W_m` as `[in, out]`.
    weights: Vec<Var>,
    /// `b_m` as `[1, out]`.
    biases: Vec<Var>,
}

impl RacecarMlp {
    /// Glorot-uniform weights from `seed`, zero biases; `sizes` from input to output.
    pub fn new(sizes: &[usize], seed: u64) -> Result<Self> {
        if sizes.len() < 2 || sizes.contains(&0) {
            return Err(crate::Error::shape(
                "racecar layer sizes",
                "at least two sizes, all > 0",
                format!("{sizes:?}"),
            ));
        }
        let mut rng = pbdl_core::seed::rng(seed);
        let (mut weights, mut biases) = (Vec::new(), Vec::new());
        for w in sizes.windows(2) {
            let lim = (6.0 / (w[0] + w[1]) as f64).sqrt();
            let v: Vec<f64> = (0..w[0] * w[1]).map(|_| rng.random_range(-lim..lim)).collect();
            weights.push(Var::from_tensor(&Tensor::from_vec(v, (w[0], w[1]), &Device::Cpu)?)?);
            biases.push(Var::zeros((1, w[1]), DType::F64, &Device::Cpu)?);
        }
        Ok(Self { weights, biases })
    }

    /// All trainable variables.
    pub fn vars(&self) -> Vec<Var> {
        self.weights.iter().chain(&self.biases).cloned().collect()
    }

    /// Layer `m`'s weights `[in, out]` as a tensor.
    pub fn weight(&self, m: usize) -> &Tensor {
        self.weights[m].as_tensor()
    }

    /// The forward pass: `[d_0 = x, d_1, ..., d_L]` (ReLU hidden layers, linear output).
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Vec<Tensor>> {
        let n = self.weights.len();
        let mut acts = vec![x.clone()];
        for m in 0..n {
            let z = acts[m].matmul(self.weights[m].as_tensor())?.broadcast_add(self.biases[m].as_tensor())?;
            acts.push(if m + 1 < n { z.relu()? } else { z });
        }
        Ok(acts)
    }

    /// `sum_m 1/2 ||d'_m - d_m||^2` (mean over the batch) of the reverse pass through the
    /// transposed weights, starting from the output `d'_L = d_L` (see the module docs).
    pub fn reconstruction_loss(&self, acts: &[Tensor]) -> candle_core::Result<Tensor> {
        let n = self.weights.len();
        let batch = acts[0].dim(0)? as f64;
        let mut rec = acts[n].clone();
        let mut total: Option<Tensor> = None;
        for m in (0..n).rev() {
            let back = rec.broadcast_sub(self.biases[m].as_tensor())?.matmul(&self.weights[m].as_tensor().t()?)?;
            rec = if m > 0 { back.relu()? } else { back };
            let term = ((&rec - &acts[m])?.sqr()?.sum_all()? * (0.5 / batch))?;
            total = Some(match total {
                Some(t) => (t + term)?,
                None => term,
            });
        }
        total.ok_or_else(|| candle_core::Error::Msg("no layers".into()))
    }
}

/// `|cos|` between each of the `k` leading input-space singular vectors of `w: [in, out]` (the
/// left singular vectors of the `[in, out]` matrix) and the span of the rows of `data: [n, in]`,
/// i.e. the norm of each unit vector's projection onto that span.
pub fn span_alignment(w: &Tensor, data: &Tensor, k: usize) -> Result<Vec<f64>> {
    let to_mat = |t: &Tensor| -> Result<Mat<f64>> {
        let v = t.to_dtype(DType::F64)?.to_vec2::<f64>()?;
        Ok(Mat::from_fn(v.len(), v[0].len(), |i, j| v[i][j]))
    };
    let (wm, dm) = (to_mat(w)?, to_mat(data)?);
    let map_err = |_| crate::Error::SvdNoConvergence { rows: wm.nrows(), cols: wm.ncols() };
    let ws = wm.thin_svd().map_err(map_err)?;
    // Orthonormal basis of the data span: left singular vectors of data^T above a tolerance.
    let dt = dm.transpose().to_owned();
    let ds = dt.thin_svd().map_err(|_| crate::Error::SvdNoConvergence { rows: dt.nrows(), cols: dt.ncols() })?;
    let s = ds.S().column_vector();
    let tol = 1e-10 * s[0];
    let rank = (0..s.nrows()).filter(|&i| s[i] > tol).count();
    let (u, q) = (ws.U(), ds.U());
    Ok((0..k.min(u.ncols()))
        .map(|i| {
            let proj2: f64 = (0..rank)
                .map(|r| {
                    let c: f64 = (0..u.nrows()).map(|d| u[(d, i)] * q[(d, r)]).sum();
                    c * c
                })
                .sum();
            proj2.sqrt()
        })
        .collect())
}

/// Settings of [`alignment_experiment`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AlignmentConfig {
    /// Input dimension. Default `64`.
    pub dim: usize,
    /// Dimension of the subspace the inputs lie in. Default `6`.
    pub rank: usize,
    /// Training samples. Default `100` (as the paper's peak model).
    pub samples: usize,
    /// Hidden width. Default `32`.
    pub hidden: usize,
    /// Outputs (random linear targets of the input). Default `4`.
    pub outputs: usize,
    /// Weight of the reconstruction loss. Default `0.1`.
    pub lambda: f64,
    /// Full-batch Adam steps. Default `4000`.
    pub steps: usize,
    /// Adam learning rate. Default `1e-2`.
    pub lr: f64,
    /// Seed of data and networks. Default `0`.
    pub seed: u64,
}

impl Default for AlignmentConfig {
    fn default() -> Self {
        Self { dim: 64, rank: 6, samples: 100, hidden: 32, outputs: 4, lambda: 0.1, steps: 4000, lr: 1e-2, seed: 0 }
    }
}

/// What [`alignment_experiment`] measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AlignmentResult {
    /// `|cos|` of the `rank` leading singular vectors of the first layer with the data span,
    /// racecar-trained network.
    pub racecar: Vec<f64>,
    /// The same for the plain network (task loss only, same start).
    pub plain: Vec<f64>,
    /// Final task loss (mean squared error) of the racecar network.
    pub task_loss_racecar: f64,
    /// Final task loss of the plain network.
    pub task_loss_plain: f64,
}

/// Trains `dim -> hidden -> outputs` twice from the same start on inputs in a random
/// `rank`-dimensional subspace (regression to random linear targets), with and without the
/// racecar loss, and measures the first layer's alignment with the data span.
pub fn alignment_experiment(cfg: &AlignmentConfig) -> Result<AlignmentResult> {
    let mut rng = pbdl_core::seed::rng(cfg.seed);
    let mut uni = |n: usize| -> Vec<f64> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
    let basis = Tensor::from_vec(uni(cfg.rank * cfg.dim), (cfg.rank, cfg.dim), &Device::Cpu)?;
    let coef = Tensor::from_vec(uni(cfg.samples * cfg.rank), (cfg.samples, cfg.rank), &Device::Cpu)?;
    let x = coef.matmul(&basis)?;
    let a = Tensor::from_vec(uni(cfg.dim * cfg.outputs), (cfg.dim, cfg.outputs), &Device::Cpu)?;
    let y = x.matmul(&a)?;
    let sizes = [cfg.dim, cfg.hidden, cfg.outputs];
    let mut out = Vec::new();
    for lambda in [cfg.lambda, 0.0] {
        let net = RacecarMlp::new(&sizes, cfg.seed + 1)?;
        let mut opt = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() }).build(net.vars())?;
        let mut task = f64::NAN;
        for _ in 0..cfg.steps {
            let acts = net.forward(&x)?;
            let mse = (acts.last().expect("output") - &y)?.sqr()?.mean_all()?;
            task = mse.to_scalar::<f64>()?;
            let loss = if lambda > 0.0 { (&mse + (net.reconstruction_loss(&acts)? * lambda)?)? } else { mse };
            opt.backward_step(&loss)?;
        }
        out.push((span_alignment(net.weight(0), &x, cfg.rank)?, task));
    }
    let (plain, racecar) = (out.pop().expect("two runs"), out.pop().expect("two runs"));
    Ok(AlignmentResult { racecar: racecar.0, plain: plain.0, task_loss_racecar: racecar.1, task_loss_plain: plain.1 })
}
