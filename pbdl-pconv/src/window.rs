//! Radial window functions `a(r)`, `r = |x_j - x_i| / R`, that fade a filter out at the support.
//!
//! ```
//! use pbdl_pconv::window::Window;
//!
//! assert_eq!(Window::Poly6.eval(0.0f64).0, 1.0);
//! assert_eq!(Window::Poly6.eval(1.0f64).0, 0.0);
//! ```

use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// A window over the scaled distance `r` in `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Window {
    /// `a = 1` (SFBC's Fourier networks need none).
    None,
    /// `a = max(1 - r², 0)³` (CConv's default).
    Poly6,
    /// `a = max(1 - r, 0)²` (the symmetric "peak" window of DMCF).
    Peak,
}

impl Window {
    /// The name used in configs and tables.
    pub fn name(self) -> &'static str {
        match self {
            Window::None => "none",
            Window::Poly6 => "poly6",
            Window::Peak => "peak",
        }
    }

    /// `(a(r), a'(r) / r)`: the second factor times the scaled offset `s` is `∂a/∂s` (finite at
    /// the origin for [`Window::Poly6`]; [`Window::Peak`] has a kink there and returns 0).
    #[inline]
    pub fn eval<T: Real>(self, r: T) -> (T, T) {
        match self {
            Window::None => (T::one(), T::zero()),
            Window::Poly6 => {
                let u = T::one() - r * r;
                if u <= T::zero() {
                    (T::zero(), T::zero())
                } else {
                    (u * u * u, T::c(-6.0) * u * u)
                }
            }
            Window::Peak => {
                let u = T::one() - r;
                if u <= T::zero() {
                    (T::zero(), T::zero())
                } else if r > T::zero() {
                    (u * u, T::c(-2.0) * u / r)
                } else {
                    (T::one(), T::zero())
                }
            }
        }
    }
}
