//! Support for tests that need files from outside the repository (published weights, reference
//! data in `../shared/`): a skip that is visible, and that fails where the data must be there.
//!
//! A test that cannot run without such a file calls [`skip_or_fail`] and returns. Outside CI it
//! prints `SKIPPED: <reason>` straight to the terminal (past the test harness's output capture,
//! so the skip shows in a passing run). In CI (`CI` set to anything but `false`/`0`) with the
//! shared folder present, or whenever `PBDL_REQUIRE_DATA=1`, it panics instead: a test that
//! silently stops testing in CI is a defect, not a pass.
//!
//! ```
//! use pbdl_core::testing::{shared_dir, skip_or_fail};
//!
//! let weights = shared_dir().join("weights/LSiM.safetensors");
//! if !weights.exists() {
//!     skip_or_fail(&format!("LSiM weights not found at {}", weights.display()));
//!     return;
//! }
//! ```

use std::io::Write as _;
use std::path::PathBuf;

/// Environment variable that turns every [`skip_or_fail`] into a failure (`1`) or never (`0`).
pub const REQUIRE_DATA_ENV: &str = "PBDL_REQUIRE_DATA";

/// The shared data folder beside the checkout (`<workspace>/../shared`), as the tests read it.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("..").join("shared")
}

/// Whether a skipped data test must fail: `PBDL_REQUIRE_DATA=1`, or CI with `../shared` present.
pub fn data_required() -> bool {
    let set = |name: &str| std::env::var(name).is_ok_and(|v| !v.is_empty() && v != "0" && v != "false");
    match std::env::var(REQUIRE_DATA_ENV).as_deref() {
        Ok("0") | Ok("false") => false,
        Ok(_) => set(REQUIRE_DATA_ENV),
        Err(_) => set("CI") && shared_dir().is_dir(),
    }
}

/// Reports that a test cannot run because of `reason` (a missing file, named with its path and
/// what to set or download). Panics when [`data_required`]; otherwise prints `SKIPPED: reason`
/// to standard error, bypassing the test harness's capture so that the skip is seen.
pub fn skip_or_fail(reason: &str) {
    if data_required() {
        panic!(
            "required test data missing: {reason} (CI with {} present, or {REQUIRE_DATA_ENV}=1)",
            shared_dir().display()
        );
    }
    // Written to the stderr handle, not with eprintln!: libtest captures only the print macros.
    let _ = writeln!(std::io::stderr(), "SKIPPED: {reason}");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_dir_is_beside_the_workspace() {
        assert!(shared_dir().ends_with("shared"));
        assert!(shared_dir().parent().unwrap().parent().unwrap().join("pbdl-core").is_dir());
    }
}
