//! Training a learned metric from scratch: data from pbdl-grid's solvers, LSiM's and VolSiM's
//! losses and ground truths, calibration of the normalisation statistics, the training loop and
//! the papers' evaluation protocol (Spearman correlation per data set).
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | 11-frame sequences (advection-diffusion, Burgers, smoke, shapes) with one parameter changed linearly and noise injected into the simulation, after the authors' generation scripts; `.npz` cache |
//! | [`loss`] | the 55 pairs, linear and "fit2" ground truth, [`loss::metric_loss`] (`w MSE + 0.7 * 0.5 (1 - Pearson)`) |
//! | [`fit`] | [`fit::train`]: calibration epoch, then Adam on one sequence per step with LSiM's flips, quarter turns, random crops (per sequence, or per group of pairs: [`fit::grouped_distances`]) and dropout; [`fit::TrainReport`]; [`fit::train_resumable`]: the same in a run directory, crash-safe and resumable bit for bit |
//! | [`eval`] | the papers' protocol: reference distances min-max normalised to [0.1, 1] per sequence, Spearman per data set; markdown table |
//! | [`experiment`] | [`experiment::run_experiment`]: data of the chosen training kinds, training, the untrained control and the table in one call (the example and the ignored test run it) |
//! | [`model`] | [`MetricNet`]: a trainable LSiM base network with calibrated feature normalisation and clamped channel weights |
//!
//! See `docs/metric-training.md` for the measured results.

pub mod data;
pub mod eval;
pub mod experiment;
pub mod fit;
pub mod loss;
pub mod model;

pub use data::{Kind, Param, Sequence};
pub use eval::{evaluate, markdown_table, EvalRow, Scored};
pub use experiment::{run_experiment, ExperimentConfig, ExperimentReport};
pub use fit::{train, train_resumable, TrainConfig, TrainReport};
pub use loss::{GroundTruth, LossConfig};
pub use model::{MetricNet, MetricNetConfig};
