//! A training progress bar that stays silent in CI and in redirected output.
//!
//! [`Progress::new`] draws an indicatif bar on stdout only when stdout is a terminal and the
//! `CI` environment variable is unset (or `""`, `0`, `false`); otherwise the bar is hidden and
//! every call is a cheap no-op, so logs and CI output stay clean. Without the `progress`
//! feature nothing is ever drawn: the type only counts steps, so callers need no `cfg`.
//!
//! ```
//! use pbdl_core::train::Progress;
//!
//! let progress = Progress::hidden(100); // `Progress::new(100)` in a real run
//! for step in 0..100 {
//!     let loss = 1.0 / (step + 1) as f64;
//!     progress.update(step, loss); // position step + 1, message "loss 1.0000e-2"
//! }
//! progress.finish();
//! assert_eq!(progress.position(), 100);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use std::ffi::OsStr;
use std::io::IsTerminal;

#[cfg(feature = "progress")]
const TEMPLATE: &str = "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} (eta {eta}) {msg}";

/// Whether a bar should be drawn here: stdout is a terminal and `CI` is not set.
pub fn should_draw() -> bool {
    draw_decision(std::io::stdout().is_terminal(), std::env::var_os("CI").as_deref())
}

/// The rule behind [`should_draw`]: draw on a terminal unless `ci` is set to something other
/// than `""`, `"0"` or `"false"` (CI services set `CI=true`).
pub fn draw_decision(stdout_is_terminal: bool, ci: Option<&OsStr>) -> bool {
    let in_ci = ci.is_some_and(|v| !matches!(v.to_str(), Some("" | "0" | "false")));
    stdout_is_terminal && !in_ci
}

/// A progress bar over the steps of a run, with the loss as its message.
#[derive(Clone, Debug)]
pub struct Progress {
    #[cfg(feature = "progress")]
    bar: indicatif::ProgressBar,
    #[cfg(not(feature = "progress"))]
    position: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl Progress {
    /// A bar over `total_steps` steps, drawn only where [`should_draw`] says so.
    pub fn new(total_steps: u64) -> Self {
        Self::with_visibility(total_steps, should_draw())
    }

    /// A bar that never draws (tests, batch jobs).
    pub fn hidden(total_steps: u64) -> Self {
        Self::with_visibility(total_steps, false)
    }

    /// A bar that draws on stdout when `visible` (and the `progress` feature is on), else a
    /// hidden one.
    pub fn with_visibility(total_steps: u64, visible: bool) -> Self {
        #[cfg(feature = "progress")]
        {
            use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
            let target = if visible { ProgressDrawTarget::stdout() } else { ProgressDrawTarget::hidden() };
            let bar = ProgressBar::with_draw_target(Some(total_steps), target);
            // The template is a constant; fall back to indicatif's default rather than fail a run.
            bar.set_style(ProgressStyle::with_template(TEMPLATE).unwrap_or_else(|_| ProgressStyle::default_bar()));
            Self { bar }
        }
        #[cfg(not(feature = "progress"))]
        {
            let _ = (total_steps, visible);
            Self { position: Default::default() }
        }
    }

    /// Whether the bar is hidden (always, without the `progress` feature).
    pub fn is_hidden(&self) -> bool {
        #[cfg(feature = "progress")]
        return self.bar.is_hidden();
        #[cfg(not(feature = "progress"))]
        true
    }

    /// Steps marked done so far.
    pub fn position(&self) -> u64 {
        #[cfg(feature = "progress")]
        return self.bar.position();
        #[cfg(not(feature = "progress"))]
        self.position.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Marks step `step` (counting from 0) as done and shows its loss.
    pub fn update(&self, step: u64, loss: f64) {
        #[cfg(feature = "progress")]
        {
            self.bar.set_position(step + 1);
            self.bar.set_message(format!("loss {loss:.4e}"));
        }
        #[cfg(not(feature = "progress"))]
        {
            let _ = loss;
            self.position.store(step + 1, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Sets the number of steps done without touching the message.
    pub fn set_position(&self, done: u64) {
        #[cfg(feature = "progress")]
        self.bar.set_position(done);
        #[cfg(not(feature = "progress"))]
        self.position.store(done, std::sync::atomic::Ordering::Relaxed);
    }

    /// Replaces the message (e.g. `"loss 1.2e-3 lr 1e-4"`).
    pub fn set_message(&self, message: impl Into<String>) {
        #[cfg(feature = "progress")]
        self.bar.set_message(message.into());
        #[cfg(not(feature = "progress"))]
        let _ = message;
    }

    /// Prints a line above the bar (nothing when hidden; use a [`super::ScalarLog`] for records).
    pub fn println(&self, line: impl AsRef<str>) {
        #[cfg(feature = "progress")]
        self.bar.println(line);
        #[cfg(not(feature = "progress"))]
        let _ = line;
    }

    /// Finishes the bar, leaving it on screen.
    pub fn finish(&self) {
        #[cfg(feature = "progress")]
        self.bar.finish();
    }

    /// The underlying indicatif bar, for anything not covered here.
    #[cfg(feature = "progress")]
    pub fn bar(&self) -> &indicatif::ProgressBar {
        &self.bar
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_in_ci_and_when_not_a_terminal() {
        assert!(draw_decision(true, None));
        assert!(!draw_decision(false, None));
        assert!(!draw_decision(true, Some(OsStr::new("true"))));
        assert!(!draw_decision(true, Some(OsStr::new("1"))));
        assert!(draw_decision(true, Some(OsStr::new("false"))));
        assert!(draw_decision(true, Some(OsStr::new(""))));
    }

    #[test]
    fn hidden_bar_tracks_position_and_message() {
        let p = Progress::hidden(10);
        assert!(p.is_hidden());
        p.update(4, 0.5);
        assert_eq!(p.position(), 5);
        #[cfg(feature = "progress")]
        assert_eq!(p.bar().message(), "loss 5.0000e-1");
        // Under `cargo test` stdout is captured, never a terminal: `new` must hide.
        if !std::io::stdout().is_terminal() {
            assert!(Progress::new(3).is_hidden());
        }
    }
}
