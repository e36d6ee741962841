//! A global shallow-water model on the sphere (spectral transform method) that makes stand-in
//! weather data, validated with the standard test set of Williamson et al. (1992).
//!
//! * [`gauss`]: Gaussian latitudes and weights ([`GaussianGrid`]), and linear interpolation to
//!   the WeatherBench latitudes ([`to_weatherbench`]).
//! * [`legendre`]: orthonormal associated Legendre functions at the Gaussian latitudes.
//! * [`transform`]: [`SpectralTransform`], the scalar and vector transforms with triangular
//!   truncation `T_M`.
//! * [`model`]: [`ShallowWater`], the vorticity-divergence equations with semi-implicit leapfrog
//!   time stepping, orography, Newtonian relaxation, drag, hyperdiffusion and a tracer.
//! * [`williamson`]: initial states of test cases 2 and 6 and the normalised error norms.
//!
//! Conventions: grid fields are `[lat][lon]` row-major, latitudes ascending (south to north),
//! longitudes `0, d, ..., 360 - d` with `d = 360 / n_lon` (the WeatherBench order). Spectral
//! coefficients `X_n^m` (`0 <= m <= n <= M`) of a real field `X = sum X_n^m P_n^m(mu) e^{i m lambda}`
//! (negative `m` by conjugate symmetry) with `int_{-1}^{1} (P_n^m)^2 dmu = 1`.
//!
//! ```
//! use pbdl_weather::shallow_water::{williamson, ModelParams, ShallowWater};
//! let mut model = ShallowWater::new(ModelParams::new(21, 32, 1800.0))?;
//! let init = williamson::test2_initial(model.grid(), &model.params().planet, 0.0);
//! model.set_state_from_winds(&init.u, &init.v, &init.phi)?;
//! let h0 = model.height();
//! for _ in 0..48 {
//!     model.step();
//! }
//! let err = williamson::error_norms(model.grid(), &model.height(), &h0)?;
//! assert!(err.l2 < 1e-8);
//! # Ok::<(), pbdl_weather::Error>(())
//! ```

pub mod gauss;
pub mod legendre;
pub mod model;
pub mod transform;
pub mod williamson;

mod fft;

pub use gauss::{to_weatherbench, GaussianGrid};
pub use model::{Hyperdiffusion, ModelParams, Planet, ShallowWater};
pub use transform::SpectralTransform;

use std::ops::{Add, AddAssign, Mul, Neg, Sub, SubAssign};

/// A complex number (spectral and Fourier coefficients); kept minimal to need no extra crate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Complex {
    /// Real part.
    pub re: f64,
    /// Imaginary part.
    pub im: f64,
}

impl Complex {
    /// Zero.
    pub const ZERO: Complex = Complex { re: 0.0, im: 0.0 };

    /// `re + i im`.
    pub const fn new(re: f64, im: f64) -> Self {
        Self { re, im }
    }

    /// The complex conjugate.
    pub fn conj(self) -> Self {
        Self::new(self.re, -self.im)
    }

    /// `i m z`: the longitude derivative of the wavenumber-`m` component.
    #[inline]
    pub fn times_im(self, m: f64) -> Self {
        Self::new(-m * self.im, m * self.re)
    }

    /// The modulus.
    pub fn abs(self) -> f64 {
        self.re.hypot(self.im)
    }

    /// The argument in `(-pi, pi]`.
    pub fn arg(self) -> f64 {
        self.im.atan2(self.re)
    }
}

impl Add for Complex {
    type Output = Complex;
    #[inline]
    fn add(self, o: Complex) -> Complex {
        Complex::new(self.re + o.re, self.im + o.im)
    }
}

impl Sub for Complex {
    type Output = Complex;
    #[inline]
    fn sub(self, o: Complex) -> Complex {
        Complex::new(self.re - o.re, self.im - o.im)
    }
}

impl Mul for Complex {
    type Output = Complex;
    #[inline]
    fn mul(self, o: Complex) -> Complex {
        Complex::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
}

impl Mul<f64> for Complex {
    type Output = Complex;
    #[inline]
    fn mul(self, s: f64) -> Complex {
        Complex::new(self.re * s, self.im * s)
    }
}

impl Neg for Complex {
    type Output = Complex;
    #[inline]
    fn neg(self) -> Complex {
        Complex::new(-self.re, -self.im)
    }
}

impl AddAssign for Complex {
    #[inline]
    fn add_assign(&mut self, o: Complex) {
        self.re += o.re;
        self.im += o.im;
    }
}

impl SubAssign for Complex {
    #[inline]
    fn sub_assign(&mut self, o: Complex) {
        self.re -= o.re;
        self.im -= o.im;
    }
}
