//! racecar's "MNIST" model: one linear layer `784 -> 10` trained on two digit images, with and
//! without the reverse-pass reconstruction loss, and the SVD analysis of its weights.
//!
//! The images are our procedural digits ([`super::digits`]), a stand-in for the two MNIST PNGs
//! the official code reads (MNIST is not downloaded or shipped here). Settings as the official
//! `SVD-example/mnist_training.py` run by `RUN_ME.py` (tum-pbs/racecar): digits `0` and `1`,
//! both images in every step (batch 2), Adam with learning rate `1e-4`, 1000 steps, Glorot
//! uniform weights and zero biases, pixel values `0..255` (the PNGs are read without
//! rescaling: our renderer's `[0, 1]` values are multiplied by [`MnistConfig::pixel_scale`]),
//! and racecar weight `1e-5` on `tf.nn.l2_loss`, i.e. on `1/2 ||x' - x||^2` *summed* over the
//! batch. The reverse pass is `x' = (logits - b) W^T` with the forward weights `W: [784, 10]`.
//! The task loss is the mean softmax cross entropy of the logits (the official code applies a
//! second softmax before `softmax_cross_entropy_with_logits`; we do not, as in
//! [`super::peak_experiment`]). Computation in `f64`; gradients by candle's autodiff.
//!
//! Minimising `||W W^T x - x||` over the two images makes `W W^T` the identity on their span:
//! two input-space singular vectors of `W` (the paper's right singular vectors of the
//! `[10, 784]` layer matrix) lie in that span with singular value 1 and, reshaped to `28 x 28`,
//! look like the training digits. [`mnist_alignment_experiment`] measures this with
//! [`super::svd::principal_alignment`] for the racecar model and a plain one (same start).
//!
//! Measured (tests/racecar_mnist_tests.rs): with the official Glorot init the *other* eight
//! singular values stay near their initial `sqrt(784 * 2 / 794) = 1.4`, above 1, so the span
//! directions are the two *trailing* singular vectors, not the leading ones; with the initial
//! weights scaled by `0.5` ([`MnistConfig::init_scale`], not an official setting) they are the
//! leading ones. (The official `kernel_SVD.py` images rows 0..9 of the full `784 x 784` `U`,
//! which it names `vh`, rather than its columns.)

use super::digits::{digit_images, DigitJitter, SIDE};
use super::svd::{principal_alignment, Subspace};
use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor, Var, D};
use faer::Mat;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Settings of [`mnist_alignment_experiment`]; defaults are the official run's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MnistConfig {
    /// The two training digits (also their labels). Default `[0, 1]`.
    pub digits: [u8; 2],
    /// Number of classes (outputs). Default `10`.
    pub classes: usize,
    /// Racecar weight on `1/2 ||x' - x||^2` summed over the batch. Default `1e-5`.
    pub lambda: f64,
    /// Adam learning rate. Default `1e-4`.
    pub lr: f64,
    /// Full-batch Adam steps. Default `1000`.
    pub steps: usize,
    /// Factor from the renderer's `[0, 1]` to the training pixel values. Default `255`.
    pub pixel_scale: f64,
    /// Number of leading singular vectors reported in [`MnistRun::cos`]. Default `2`.
    pub lead: usize,
    /// Factor on the Glorot-uniform initial weights. Default `1` (the official init). Not an
    /// official setting: below about `0.7` the initial singular values (about
    /// `1.4 init_scale`) fall below 1, the value racecar gives the data directions.
    pub init_scale: f64,
    /// Style ranges of the two images. Default [`DigitJitter::default`].
    pub jitter: DigitJitter,
    /// Seed of the images (`seed`) and the weights (`seed + 1`). Default `0`.
    pub seed: u64,
}

impl Default for MnistConfig {
    fn default() -> Self {
        Self {
            digits: [0, 1],
            classes: 10,
            lambda: 1e-5,
            lr: 1e-4,
            steps: 1000,
            pixel_scale: 255.0,
            lead: 2,
            init_scale: 1.0,
            jitter: DigitJitter::default(),
            seed: 0,
        }
    }
}

/// One linear layer `logits = x W + b` whose reverse pass is `x' = (logits - b) W^T`.
#[derive(Clone, Debug)]
pub struct LinearRacecar {
    /// `W: [inputs, classes]`.
    w: Var,
    /// `b: [1, classes]`.
    b: Var,
}

impl LinearRacecar {
    /// Glorot-uniform `W` from `seed` (limit `scale sqrt(6 / (inputs + classes))`; `scale = 1`
    /// is Glorot's), zero `b`, `f64`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a zero size; [`Error::InvalidConfig`] for a `scale` that is
    /// not finite and `> 0`.
    pub fn new(inputs: usize, classes: usize, scale: f64, seed: u64) -> Result<Self> {
        if inputs == 0 || classes == 0 {
            return Err(Error::shape("linear layer (inputs, classes)", "both > 0", format!("({inputs}, {classes})")));
        }
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "init scale",
                value: scale,
                hint: "use a finite factor > 0 (1: Glorot)",
            });
        }
        let mut rng = pbdl_core::seed::rng(seed);
        let lim = scale * (6.0 / (inputs + classes) as f64).sqrt();
        let v: Vec<f64> = (0..inputs * classes).map(|_| rng.random_range(-lim..lim)).collect();
        let w = Var::from_tensor(&Tensor::from_vec(v, (inputs, classes), &Device::Cpu)?)?;
        let b = Var::zeros((1, classes), DType::F64, &Device::Cpu)?;
        Ok(Self { w, b })
    }

    /// `W: [inputs, classes]`.
    pub fn weight(&self) -> &Tensor {
        self.w.as_tensor()
    }

    /// `b: [1, classes]`.
    pub fn bias(&self) -> &Tensor {
        self.b.as_tensor()
    }

    /// The trainable variables `[W, b]`.
    pub fn vars(&self) -> Vec<Var> {
        vec![self.w.clone(), self.b.clone()]
    }

    /// [`linear_racecar_loss`] with this layer's weights.
    pub fn loss(&self, x: &Tensor, onehot: &Tensor, lambda: f64) -> Result<LinearLoss> {
        linear_racecar_loss(x, onehot, self.weight(), self.bias(), lambda)
    }
}

/// The parts of [`linear_racecar_loss`].
#[derive(Clone, Debug)]
pub struct LinearLoss {
    /// `task + lambda * reconstruction` (just `task` for `lambda == 0`).
    pub total: Tensor,
    /// Mean softmax cross entropy of the logits.
    pub task: Tensor,
    /// `1/2 sum_n ||x'_n - x_n||^2` with `x' = (logits - b) W^T`, summed over the batch.
    pub reconstruction: Tensor,
    /// `logits: [n, classes]`.
    pub logits: Tensor,
}

/// The racecar loss of one linear layer: for `x: [n, inputs]`, `onehot: [n, classes]`,
/// `w: [inputs, classes]`, `b: [1, classes]`, `logits = x w + b`, the task loss is the mean
/// softmax cross entropy and the reconstruction `1/2 sum ||(logits - b) w^T - x||^2` (summed over
/// the batch, as the official `tf.nn.l2_loss`). Differentiable in `x`, `w` and `b`.
///
/// # Errors
/// [`Error::ShapeMismatch`] for sizes that do not fit; [`Error::InvalidConfig`] for a negative
/// or non-finite `lambda`.
pub fn linear_racecar_loss(x: &Tensor, onehot: &Tensor, w: &Tensor, b: &Tensor, lambda: f64) -> Result<LinearLoss> {
    let (n, inputs) = x.dims2()?;
    let (wi, classes) = w.dims2()?;
    if wi != inputs || onehot.dims() != [n, classes] || b.dims() != [1, classes] {
        return Err(Error::shape(
            "linear racecar loss (x, onehot, w, b)",
            "[n, in], [n, classes], [in, classes], [1, classes]",
            format!("{:?}, {:?}, {:?}, {:?}", x.dims(), onehot.dims(), w.dims(), b.dims()),
        ));
    }
    if !(lambda >= 0.0 && lambda.is_finite()) {
        return Err(Error::InvalidConfig { name: "racecar lambda", value: lambda, hint: "use a finite weight >= 0" });
    }
    let logits = x.matmul(w)?.broadcast_add(b)?;
    let logp = pbdl_core::nn::log_softmax(&logits, D::Minus1)?;
    let task = ((logp * onehot)?.sum_all()? * (-1.0 / n as f64))?;
    let back = logits.broadcast_sub(b)?.matmul(&w.t()?)?;
    let reconstruction = ((back - x)?.sqr()?.sum_all()? * 0.5)?;
    // `t * 0.0` would cut the gradient path (candle trap): leave the term out instead.
    let total = if lambda > 0.0 { (&task + (&reconstruction * lambda)?)? } else { task.clone() };
    Ok(LinearLoss { total, task, reconstruction, logits })
}

/// What one training run measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MnistRun {
    /// The racecar weight used (`0`: plain model).
    pub lambda: f64,
    /// `|cos|` of the `lead` leading input-space singular vectors of `W` with the span of the
    /// training images.
    pub cos: Vec<f64>,
    /// `|cos|` of every input-space singular vector (`classes` of them), largest singular
    /// value first.
    pub cos_all: Vec<f64>,
    /// Dimension of that span (2 for two different images).
    pub span_dim: usize,
    /// The singular values of `W`, largest first.
    pub singular_values: Vec<f64>,
    /// Final cross entropy.
    pub task_loss: f64,
    /// Final training accuracy.
    pub accuracy: f64,
    /// Final reconstruction loss (without lambda), measured for both runs.
    pub reconstruction: f64,
    /// Training wall-clock seconds.
    pub seconds: f64,
}

impl MnistRun {
    /// The smallest `|cos|` over the leading singular vectors.
    pub fn min_cos(&self) -> f64 {
        self.cos.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The largest `|cos|` over the leading singular vectors.
    pub fn max_cos(&self) -> f64 {
        self.cos.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    }

    /// The `k` singular vectors most aligned with the span: `(index in singular-value order,
    /// |cos|)`, most aligned first.
    pub fn best_aligned(&self, k: usize) -> Vec<(usize, f64)> {
        let mut v: Vec<(usize, f64)> = self.cos_all.iter().copied().enumerate().collect();
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        v.truncate(k);
        v
    }
}

/// Trains a fresh [`LinearRacecar`] (weights from `cfg.seed + 1`) on `x: [n, 784]` (already
/// scaled) and `onehot` with weight `lambda` for `cfg.steps` full-batch Adam steps, and measures
/// the alignment of its leading singular vectors with the span of `x`.
///
/// The steps run on pbdl-core's [`pbdl_core::train::TrainLoop`] (in memory, no checkpoints, no
/// progress bar).
///
/// # Errors
/// [`Error::Diverged`] when the loss becomes non-finite (the guard of the loop also stops on a
/// non-finite gradient norm, as [`Error::Core`]); shape errors as [`linear_racecar_loss`].
pub fn train_linear(cfg: &MnistConfig, lambda: f64, x: &Tensor, onehot: &Tensor) -> Result<(LinearRacecar, MnistRun)> {
    let model = LinearRacecar::new(x.dim(1)?, cfg.classes, cfg.init_scale, cfg.seed + 1)?;
    let seconds =
        super::full_batch_adam(&model.vars(), cfg.lr, cfg.steps, |_| Ok(model.loss(x, onehot, lambda)?.total))?;
    let loss = model.loss(x, onehot, lambda)?;
    let pred = loss.logits.argmax(D::Minus1)?;
    let truth = onehot.argmax(D::Minus1)?;
    let accuracy = pred.eq(&truth)?.to_dtype(DType::F64)?.mean_all()?.to_scalar::<f64>()?;
    let (cos_all, span_dim) = principal_alignment(model.weight(), x, cfg.classes, Subspace::Span)?;
    let (_, singular_values) = singular_vectors(model.weight(), 0)?;
    let run = MnistRun {
        lambda,
        cos: cos_all.iter().copied().take(cfg.lead).collect(),
        cos_all,
        span_dim,
        singular_values,
        task_loss: loss.task.to_scalar::<f64>()?,
        accuracy,
        reconstruction: loss.reconstruction.to_scalar::<f64>()?,
        seconds,
    };
    Ok((model, run))
}

/// The `k` leading input-space singular vectors of `w: [inputs, outputs]` (left singular
/// vectors of the `[inputs, outputs]` matrix, each of unit norm, its sign chosen so that its
/// largest-magnitude entry is positive), and all singular values, largest first.
///
/// # Errors
/// [`Error::SvdNoConvergence`] if faer's SVD fails; [`Error::ShapeMismatch`] for an empty `w`.
pub fn singular_vectors(w: &Tensor, k: usize) -> Result<(Vec<Vec<f64>>, Vec<f64>)> {
    let v = w.to_dtype(DType::F64)?.to_vec2::<f64>()?;
    if v.is_empty() || v[0].is_empty() {
        return Err(Error::shape("weight matrix for the SVD", "at least 1x1", format!("{:?}", w.dims())));
    }
    let m = Mat::from_fn(v.len(), v[0].len(), |i, j| v[i][j]);
    let svd = m.thin_svd().map_err(|_| Error::SvdNoConvergence { rows: m.nrows(), cols: m.ncols() })?;
    let (u, s) = (svd.U(), svd.S().column_vector());
    let values = (0..s.nrows()).map(|i| s[i]).collect();
    let vectors = (0..k.min(u.ncols()))
        .map(|j| {
            let col: Vec<f64> = (0..u.nrows()).map(|i| u[(i, j)]).collect();
            let peak = col.iter().copied().fold(0.0, |a: f64, c| if c.abs() > a.abs() { c } else { a });
            let sign = if peak < 0.0 { -1.0 } else { 1.0 };
            col.into_iter().map(|c| sign * c).collect()
        })
        .collect();
    Ok((vectors, values))
}

/// What [`mnist_alignment_experiment`] produced.
#[derive(Clone, Debug)]
pub struct MnistExperiment {
    /// The training images `[2, 784]`, scaled by `pixel_scale`.
    pub images: Tensor,
    /// The racecar run (`lambda = cfg.lambda`).
    pub racecar: MnistRun,
    /// The plain run (`lambda = 0`, same start).
    pub plain: MnistRun,
    /// All input-space singular vectors of the racecar model's `W`, largest singular value
    /// first, 784 values each (row-major 28x28).
    pub racecar_vectors: Vec<Vec<f64>>,
    /// The same for the plain model.
    pub plain_vectors: Vec<Vec<f64>>,
}

/// Draws the two digits of `cfg` (seed `cfg.seed`), trains the racecar and the plain model from
/// the same start, and measures both.
///
/// # Errors
/// [`Error::InvalidConfig`] for equal digits (the span would be one image), a digit not below
/// `classes`, a bad `pixel_scale` or `lambda`; errors of the training.
pub fn mnist_alignment_experiment(cfg: &MnistConfig) -> Result<MnistExperiment> {
    let [d0, d1] = cfg.digits;
    if d0 == d1 {
        return Err(Error::InvalidConfig { name: "second digit", value: d1 as f64, hint: "use two different digits" });
    }
    if d0.max(d1) as usize >= cfg.classes {
        return Err(Error::InvalidConfig {
            name: "digit",
            value: d0.max(d1) as f64,
            hint: "use digits below the number of classes",
        });
    }
    if !(cfg.pixel_scale > 0.0 && cfg.pixel_scale.is_finite()) {
        return Err(Error::InvalidConfig {
            name: "pixel scale",
            value: cfg.pixel_scale,
            hint: "use a finite factor > 0 (255 as the official PNGs)",
        });
    }
    let images = (digit_images(&cfg.digits, &cfg.jitter, cfg.seed)? * cfg.pixel_scale)?;
    let mut onehot = vec![0.0; 2 * cfg.classes];
    onehot[d0 as usize] = 1.0;
    onehot[cfg.classes + d1 as usize] = 1.0;
    let onehot = Tensor::from_vec(onehot, (2, cfg.classes), &Device::Cpu)?;
    let (rc_model, racecar) = train_linear(cfg, cfg.lambda, &images, &onehot)?;
    let (plain_model, plain) = train_linear(cfg, 0.0, &images, &onehot)?;
    let (racecar_vectors, _) = singular_vectors(rc_model.weight(), cfg.classes)?;
    let (plain_vectors, _) = singular_vectors(plain_model.weight(), cfg.classes)?;
    debug_assert!(racecar_vectors.iter().all(|v| v.len() == SIDE * SIDE));
    Ok(MnistExperiment { images, racecar, plain, racecar_vectors, plain_vectors })
}
