//! # Solver-in-the-Loop (Um et al., NeurIPS 2020)
//!
//! A coarse *source* solver `P_s` (pbdl-grid's [`pbdl_grid::Fluid`]: MacCormack advection,
//! implicit viscosity, masked pressure projection around a cylinder) is corrected after every
//! step by a network,
//!
//! `s~_{t+1} = P_s(s~_t) + C(P_s(s~_t), Re | theta)`,
//!
//! trained to follow a *reference* `r` simulated at `factor` times the resolution and
//! face-averaged to the source grid (`T r`), with the loss
//!
//! `L = (1/m) sum_{i=1..m} 1/2 || (s~_{t+i} - T r_{t+i}) / sigma ||^2`
//!
//! backpropagated through `m` unrolled source steps (the pressure solve by its adjoint solve).
//! Variants ([`Variant`]): PRE (one step from the downsampled reference, `P_s(T r_t)`), NON
//! (one step from the uncorrected source trajectory, `P_s(s^src_t)`), SOL-m.
//!
//! | file | gives you |
//! |---|---|
//! | [`scene`] | [`SilScene`] (what the rest is generic over), [`WakeConfig`]: the cylinder wake, source and reference solvers ([`SourceSolver`]) |
//! | [`plume`] | [`PlumeConfig`]: the buoyancy-driven flow (a plume rising in a closed box; state `u, v, density`; the buoyancy factor varies) |
//! | [`data`] | [`downsample_mac`] (MAC face average), [`downsample_cells`] (cell average), [`DataConfig`] (training / held-out parameters), [`generate`] reference sets, [`source_trajectory`] |
//! | [`net`] | [`Corrector`] (the paper's ResNet, [`CorrectorConfig`], [`Normalisation`], [`scalar_sigma`]) |
//! | [`train`](mod@train) | [`TrainConfig`], [`Variant`], [`train()`], [`train_resumable`] (a crash-safe, exactly resumable run directory), [`load_trained`], [`unrolled_loss`], [`training_inputs`] |
//! | [`eval`] | [`rollout`], [`evaluate`] (MAE per step vs the reference; the density's too) |
//!
//! The scenes: the wake (the default type of [`ReferenceSet`]; parameter `Re`) and the plume
//! ([`PlumeConfig`]; parameter the buoyancy factor, stored where the wake keeps `Re`:
//! [`ReferenceSim::re`], [`DataConfig::train_re`]). For the plume the corrector sees and corrects
//! the density too (a zero-mean correction: no mass is created), and the loss covers all three
//! channels, each divided by its standard deviation over the training frames.
//!
//! ```no_run
//! use pbdl_sol::sil::*;
//! let wake = WakeConfig::default();
//! let data = generate(&wake, &DataConfig::default(), candle_core::DType::F32)?;
//! let sol = train(&data, &TrainConfig::new(Variant::Sol { m: 4 }, 1000, 0))?;
//! let corrected = evaluate(&wake, &data.test, 100, Some(&sol.corrector))?;
//! let source = evaluate(&wake, &data.test, 100, None)?;
//! println!("MAE source {:.4}, SOL-4 {:.4}", source.mean_over(0, 100), corrected.mean_over(0, 100));
//! # Ok::<(), pbdl_sol::Error>(())
//! ```

pub mod data;
pub mod eval;
pub mod net;
pub mod plume;
pub mod scene;
pub mod train;

pub use data::{
    downsample_cells, downsample_factor, downsample_mac, downsample_state, generate, reference_run, source_trajectory,
    DataConfig, ReferenceSet, ReferenceSim,
};
pub use eval::{evaluate, mae_per_step, rollout, scalar_mae_per_step, Evaluation};
pub use net::{scalar_sigma, Corrector, CorrectorConfig, Normalisation};
pub use plume::PlumeConfig;
pub use scene::{SilScene, SourceSolver, WakeConfig};
pub use train::{load_trained, train, train_resumable, training_inputs, unrolled_loss, TrainConfig, Trained, Variant};
