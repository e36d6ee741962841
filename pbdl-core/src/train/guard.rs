//! Stop a run cleanly when the loss or the gradient norm stops being finite.
//!
//! A NaN or infinite loss poisons the parameters on the next optimiser step, and every step
//! after it is wasted compute. [`NanGuard`] checks the scalars of each step *before* the
//! optimiser runs and turns the first bad one into [`Error::Diverged`] with the step, the
//! quantity and its value. The parameters are then still those of the last good step, and the
//! last checkpoint on disk (written with `pbdl_core::io::checkpoint`) is left as it is: resume
//! from it with a lower learning rate or tighter gradient clipping.
//!
//! ```
//! use pbdl_core::{train::NanGuard, Error};
//!
//! let mut guard = NanGuard::new();
//! guard.check(0, 1.5, Some(0.3))?;
//! match guard.check(1, f64::NAN, Some(0.3)) {
//!     Err(Error::Diverged { step, quantity, .. }) => assert_eq!((step, quantity.as_str()), (1, "loss")),
//!     other => panic!("{other:?}"),
//! }
//! assert_eq!(guard.last_good_step(), Some(0));
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Checks each step's loss and gradient norm for NaN and infinities; see the module docs.
#[derive(Clone, Debug, Default)]
pub struct NanGuard {
    last_good: Option<u64>,
    checkpoint: Option<String>,
}

impl NanGuard {
    /// A guard whose error hint points to the checkpoints of `pbdl_core::io::checkpoint`.
    pub fn new() -> Self {
        Self::default()
    }

    /// Names where the checkpoints are (a path or a description), to be quoted in the error.
    pub fn with_checkpoint(mut self, location: impl Into<String>) -> Self {
        self.checkpoint = Some(location.into());
        self
    }

    /// The last step whose checks all passed.
    pub fn last_good_step(&self) -> Option<u64> {
        self.last_good
    }

    /// Checks the loss and, if given, the gradient norm of `step`; records the step as good.
    pub fn check(&mut self, step: u64, loss: f64, grad_norm: Option<f64>) -> Result<()> {
        self.check_value(step, "loss", loss)?;
        if let Some(norm) = grad_norm {
            self.check_value(step, "gradient norm", norm)?;
        }
        self.last_good = Some(step);
        Ok(())
    }

    /// Checks one named scalar of `step` without marking the step good (use [`NanGuard::check`]
    /// for that).
    pub fn check_value(&self, step: u64, quantity: &str, value: f64) -> Result<()> {
        if value.is_finite() {
            return Ok(());
        }
        Err(Error::Diverged { step, quantity: quantity.to_string(), value, hint: self.hint() })
    }

    /// Checks that a scalar tensor (e.g. the loss before `backward`) is finite and returns its
    /// value as `f64`.
    pub fn check_tensor(&self, step: u64, quantity: &str, t: &Tensor) -> Result<f64> {
        let v = t.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()?;
        self.check_value(step, quantity, v)?;
        Ok(v)
    }

    fn hint(&self) -> String {
        let last = match self.last_good {
            Some(s) => format!("the last finite step was {s}"),
            None => "no step was finite yet".to_string(),
        };
        let at = match &self.checkpoint {
            Some(c) => format!(" ({c})"),
            None => String::new(),
        };
        format!(
            " (not overwritten){at}; {last}. The parameters were not updated with this step. \
             Resume from that checkpoint (pbdl_core::io::checkpoint) with a lower learning rate, \
             gradient clipping (train::ClipConfig) or a smaller time step"
        )
    }
}
