//! PDE control with a hierarchy of observation predictors (Holl, Koltun & Thuerey, "Learning
//! to Control PDEs with Differentiable Physics", ICLR 2020), for forced 1D Burgers.
//!
//! Problem: from `u_0`, reach the target `u*` after `T` steps of `u_{t+1} = P(u_t) + dt F_t`
//! (`P`: pbdl-grid's differentiable viscous Burgers) with little effort; the loss of a scene is
//! `sum_t ||u_{t+1} - P(u_t)||^2 + lambda ||u_T - u*||^2` (effort is `dt^2 sum_t ||F_t||^2`).
//!
//! | file | gives you |
//! |---|---|
//! | [`config`] | [`BurgersControlConfig`]: 128 cells, `nu = 0.003`, `dt = 0.03`, 32 steps, `lambda` |
//! | [`physics`] | [`ForcedBurgers`]: the forced step and rollouts (RK4 sub-steps of `ScalarLaw::step`) |
//! | [`scene`] | [`scene::generate`]: seeded "Gaussian clash" scenes with Gaussian forcing and their trajectories |
//! | [`loss`] | [`loss::effort`], [`loss::target_error`], [`loss::combined`], [`ControlScore`] |
//! | [`network`] | [`ConvNet1d`]: the periodic 1D U-Net of every predictor and the CFE |
//! | [`controller`] | [`Controller`]: `OP_2 .. OP_T` and the CFE, executed with prediction refinement |
//! | [`train`] | [`pretrain_supervised`], [`train_end_to_end`] (through the solver), [`TrainConfig`]; their crash-safe, exactly resumable run-directory forms [`pretrain_supervised_resumable`], [`train_end_to_end_resumable`] |
//! | [`resume`] | [`RunDir`] (directory and checkpoint cadence) and the resume check shared with [`crate::sil::train_resumable`] |
//! | [`optimize`] | [`optimize_forces`]: the iterative baseline (Adam on the 32 force fields) with a wall-clock budget |
//!
//! ```
//! use candle_core::{DType, Device};
//! use pbdl_sol::control::*;
//!
//! let problem = BurgersControlConfig { steps: 4, ..Default::default() };
//! let dev = Device::Cpu;
//! let scenes = scene::generate(&problem, 7, 0..4, DType::F32, &dev)?;
//! let net = ConvNetConfig { width: 4, levels: 2, kernel: 3, ..Default::default() };
//! let ctrl = Controller::new(&problem, &net, DType::F32, &dev, 0)?;
//! let cfg = TrainConfig { iterations: 2, batch: 2, ..Default::default() };
//! pretrain_supervised(&ctrl, &scenes, &cfg)?;
//! train_end_to_end(&ctrl, &scenes, &cfg)?;
//! let r = ctrl.rollout(&scenes.initial, &scenes.target)?;
//! let score = ControlScore::of(&r.forces, problem.dt, &r.states[4], &scenes.target, problem.target_weight)?;
//! assert!(score.combined.is_finite());
//! # Ok::<(), pbdl_sol::Error>(())
//! ```

pub mod config;
pub mod controller;
pub mod loss;
pub mod network;
pub mod optimize;
pub mod physics;
pub mod resume;
pub mod scene;
pub mod train;

pub use config::BurgersControlConfig;
pub use controller::{Controller, Rollout};
pub use loss::ControlScore;
pub use network::{ConvNet1d, ConvNetConfig};
pub use optimize::{optimize_forces, DirectOptimConfig, DirectOptimResult};
pub use physics::ForcedBurgers;
pub use resume::RunDir;
pub use scene::ControlScenes;
pub use train::{
    pretrain_supervised, pretrain_supervised_resumable, train_end_to_end, train_end_to_end_resumable, TrainConfig,
    TrainReport,
};
