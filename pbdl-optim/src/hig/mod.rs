//! Half-inverse gradients (Schnell, Holl & Thuerey, ICLR 2022) and the Gauss-Newton baseline.
//!
//! For a batch of `b` samples with network outputs `u_s = f(i_s; theta)` and physics outcomes
//! `y_s = P(x_s; u_s)`, stack the per-sample output Jacobians into
//! `J = d y / d theta` (`b * dim(y)` rows, `|theta|` columns), computed exactly as
//! `J_s = J_phys,s J_net,s` ([`composed_jacobian`]). With the loss gradient
//! `g = d(L / b)/dy` (least squares: `2 (y - y*) / b`; other per-sample losses: [`Loss`]) and
//! the thin SVD `J = U S V^T`:
//!
//! ```text
//! dtheta = V diag(s_i^-kappa if s_i > tau * s_max else 0) U^T g,   theta <- theta - eta dtheta
//! ```
//!
//! `kappa = 1/2` is HIG, `kappa = 1` Gauss-Newton (the truncated pseudo-inverse). The
//! truncation is relative to the largest singular value and strict. `c = U^T g` is scaled and
//! mapped back by `V`; the (half-)inverse matrix is never formed.
//!
//! On a linear model `y = A theta`, one step maps each residual mode `u_i^T r` (kept by the
//! truncation) to `(1 - 2 eta s_i^(1 - kappa) / b) u_i^T r`: for HIG `1 - 2 eta sqrt(s_i) / b`.
//!
//! | file | gives you |
//! |---|---|
//! | [`model`] | [`JacobianModel`]: what HIG needs from a network (flat parameters, forward, exact per-row VJPs); implemented by [`crate::mlp::Mlp`] |
//! | [`candle_model`] | [`CandleModel`]: any candle model (`Var`s + forward closure) as a [`JacobianModel`], one backward pass per Jacobian row |
//! | [`loss`] | [`Loss`]: the per-sample loss and its gradient (least squares, state infidelity) |
//! | [`solve`] | [`HigConfig`], [`HalfInverse`]: the SVD solve with buffers kept between steps |
//! | [`train`] | [`HigTrainer`], [`AdamTrainer`], [`evaluate`], [`run_curve`] (loss vs wall-clock), `*_with_loss` variants, generic over [`JacobianModel`] |
//!
//! Your own candle model, trained by HIG through a [`crate::physics::Physics`]: give its `Var`s
//! and a forward closure `[b, in_dim] -> [b, out_dim]` (here a dense layer, a tanh, and a
//! second dense layer written by hand; any differentiable candle code works, e.g.
//! `pbdl_core::conv` layers).
//!
//! ```
//! use candle_core::{DType, Device, Tensor, Var};
//! use pbdl_optim::hig::{evaluate, CandleModel, HigConfig, HigTrainer, JacobianMode};
//! use pbdl_optim::physics::{Dataset, Oscillators};
//!
//! // The pbdl-book linear chain: 4 initial values in, 24 controls out, back to the start.
//! let physics = Oscillators::linear_chain();
//! let data = Dataset::return_to_start(128, 4, 0);
//! let dev = Device::Cpu;
//! let w1 = Var::from_tensor(&pbdl_core::seed::randn((32, 4), 0.0, 0.5, DType::F64, &dev, 1)?)?;
//! let b1 = Var::zeros(32, DType::F64, &dev)?;
//! let w2 = Var::from_tensor(&pbdl_core::seed::randn((24, 32), 0.0, 0.2, DType::F64, &dev, 2)?)?;
//! let b2 = Var::zeros(24, DType::F64, &dev)?;
//! let (v1, c1, v2, c2) = (w1.clone(), b1.clone(), w2.clone(), b2.clone());
//! let forward = move |x: &Tensor| {
//!     let h = x.matmul(&v1.t()?)?.broadcast_add(&c1)?.tanh()?;
//!     h.matmul(&v2.t()?)?.broadcast_add(&c2)
//! };
//! // Samples do not interact in this model, so per-sample graphs give exact rows, cheaper.
//! let mut net = CandleModel::new(vec![w1, b1, w2, b2], 4, 24, forward)?.with_mode(JacobianMode::PerSample);
//! let before = evaluate(&net, &physics, &data)?;
//! let mut hig = HigTrainer::new(HigConfig::hig(1.0, 1e-10))?;
//! for step in 0..4 {
//!     hig.step(&mut net, &physics, data.batch(32 * step, 32))?;
//! }
//! let after = evaluate(&net, &physics, &data)?;
//! assert!(after < before, "{before} -> {after}"); // 0.568 -> 0.143 when this was written
//! # Ok::<(), pbdl_optim::Error>(())
//! ```

pub mod candle_model;
pub mod loss;
pub mod model;
pub mod solve;
pub mod train;

pub use candle_model::{from_mlp, CandleCache, CandleModel, JacobianMode, MlpForward};
pub use loss::Loss;
pub use model::JacobianModel;
pub use solve::{Decomposition, HalfInverse, HigConfig, SolveInfo};
pub use train::{
    composed_jacobian, evaluate, evaluate_with_loss, run_curve, run_curve_with_loss, AdamTrainer, Budget, Curve,
    HigTrainer, Method, StepInfo,
};
