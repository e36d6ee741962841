//! Support for tests that need files from outside the repository (published weights, reference
//! data in `../shared/`): a skip that is visible, and that fails where the data must be there.
//!
//! A test that cannot run without such a file calls [`skip_or_fail`] and returns. Outside CI it
//! prints `SKIPPED: <reason>` straight to the terminal (past the test harness's output capture,
//! so the skip shows in a passing run). In CI (`CI` set to anything but `false`/`0`) with the
//! shared folder present, or whenever `PBDL_REQUIRE_DATA=1`, it panics instead: a test that
//! silently stops testing in CI is a defect, not a pass.
//!
//!
//! It also holds the small linear-algebra checks the property tests of every crate share:
//! [`adjoint_gap`] for `<A x, y> = <x, A^T y>`, with `A^T y` from the op's own backward
//! ([`vjp`], [`adjoint_gap_by_backward`]). Like assertions, they panic on a candle error.
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

use candle_core::{Tensor, Var};
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

/// `<a, b>` in f64 (panics on a candle error, like an assertion).
pub fn dot(a: &Tensor, b: &Tensor) -> f64 {
    let (a, b) = (a.to_dtype(candle_core::DType::F64).expect("dot"), b.to_dtype(candle_core::DType::F64).expect("dot"));
    (a * b).and_then(|p| p.sum_all()).and_then(|s| s.to_scalar::<f64>()).expect("dot: shapes must match")
}

/// `|a|` (Euclidean, f64).
pub fn norm(a: &Tensor) -> f64 {
    dot(a, a).sqrt()
}

/// `J^T y` of `f` at `x` by candle's autograd, i.e. by the ops' hand-written backward passes.
pub fn vjp(f: impl Fn(&Tensor) -> Tensor, x: &Tensor, y: &Tensor) -> Tensor {
    let v = Var::from_tensor(x).expect("vjp: x");
    let out = f(v.as_tensor());
    let grads = (out * y).and_then(|p| p.sum_all()).and_then(|s| s.backward()).expect("vjp: backward");
    grads.get(v.as_tensor()).expect("vjp: the input gets no gradient").clone()
}

/// Relative violation of the adjoint identity `<ax, y> = <x, aty>`, scaled by
/// `|ax| |y| + |x| |aty|` (the size of the two inner products).
pub fn adjoint_gap(ax: &Tensor, y: &Tensor, x: &Tensor, aty: &Tensor) -> f64 {
    let (l, r) = (dot(ax, y), dot(x, aty));
    (l - r).abs() / (norm(ax) * norm(y) + norm(x) * norm(aty)).max(f64::MIN_POSITIVE)
}

/// [`adjoint_gap`] of an affine `f` (a linear one included): `A x = f(x) - f(0)` and
/// `A^T y` from `f`'s backward ([`vjp`]).
pub fn adjoint_gap_by_backward(f: impl Fn(&Tensor) -> Tensor, x: &Tensor, y: &Tensor) -> f64 {
    let ax = (f(x) - f(&x.zeros_like().expect("zeros"))).expect("adjoint_gap_by_backward: f(x) - f(0)");
    let aty = vjp(&f, x, y);
    adjoint_gap(&ax, y, x, &aty)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoint_gap_sees_a_wrong_transpose() {
        let dev = candle_core::Device::Cpu;
        let a = Tensor::new(&[[1.0f64, 2.0], [3.0, 4.0], [5.0, 6.0]], &dev).unwrap();
        let x = Tensor::new(&[[0.5f64], [-1.0]], &dev).unwrap();
        let y = Tensor::new(&[[1.0f64], [2.0], [-1.0]], &dev).unwrap();
        let f = |x: &Tensor| a.matmul(x).unwrap();
        assert!(adjoint_gap_by_backward(f, &x, &y) < 1e-15);
        // A^T y taken as A y's wrong-shaped cousin (the first two rows of A times y) must fail.
        let wrong = a.narrow(0, 0, 2).unwrap().matmul(&Tensor::new(&[[1.0f64], [2.0]], &dev).unwrap()).unwrap();
        assert!(adjoint_gap(&f(&x), &y, &x, &wrong) > 1e-3);
    }

    #[test]
    fn shared_dir_is_beside_the_workspace() {
        assert!(shared_dir().ends_with("shared"));
        assert!(shared_dir().parent().unwrap().parent().unwrap().join("pbdl-core").is_dir());
    }
}
