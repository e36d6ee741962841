//! Low-storage implicit-explicit Runge-Kutta schemes for `du/dt = N(u) + L u` with a diagonal
//! linear part `L` (viscosity, drag): the explicit terms take a 2N-storage Runge-Kutta step, the
//! linear terms Crank-Nicolson over each stage (Canuto et al. 2007, appendix D.3). One stage is
//!
//! ```text
//! h <- N(u) + beta_k h
//! mu = dt (alpha_{k+1} - alpha_k) / 2
//! u <- (u + gamma_k dt h + mu L u) / (1 - mu L)
//! ```
//!
//! so a stage needs one evaluation of `N` and two arrays (`u`, `h`). The explicit part is
//! 4th order (Carpenter & Kennedy 1994) or 3rd order (Williamson 1980), the implicit part 2nd
//! order, which is the trade-off spectral turbulence codes make: viscosity is stiff at high
//! wavenumbers but small where the error matters.

use serde::{Deserialize, Serialize};

/// A low-storage IMEX scheme: its stage coefficients.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImexScheme {
    /// Five stages, explicit part 4th order (Carpenter & Kennedy 1994, solution 3), with
    /// Crank-Nicolson per stage. The default (JAX-CFD's `crank_nicolson_rk4`).
    #[default]
    CnRk4,
    /// Three stages, explicit part 3rd order (Williamson 1980), with Crank-Nicolson per stage.
    CnRk3,
}

/// The coefficients of one scheme.
#[derive(Clone, Copy, Debug)]
pub struct ImexCoefficients {
    /// Stage times `alpha_0 = 0 < ... < alpha_s = 1`.
    pub alphas: &'static [f64],
    /// Weights of the previous `h` in each stage (`beta_0 = 0`).
    pub betas: &'static [f64],
    /// Step fractions of each stage.
    pub gammas: &'static [f64],
}

const CK_ALPHAS: [f64; 6] = [0.0, 0.1496590219993, 0.3704009573644, 0.6222557631345, 0.9582821306748, 1.0];
const CK_BETAS: [f64; 5] = [0.0, -0.4178904745, -1.192151694643, -1.697784692471, -1.514183444257];
const CK_GAMMAS: [f64; 5] = [0.1496590219993, 0.3792103129999, 0.8229550293869, 0.6994504559488, 0.1530572479681];
const W_ALPHAS: [f64; 4] = [0.0, 1.0 / 3.0, 3.0 / 4.0, 1.0];
const W_BETAS: [f64; 3] = [0.0, -5.0 / 9.0, -153.0 / 128.0];
const W_GAMMAS: [f64; 3] = [1.0 / 3.0, 15.0 / 16.0, 8.0 / 15.0];

impl ImexScheme {
    /// The stage coefficients.
    pub fn coefficients(self) -> ImexCoefficients {
        match self {
            ImexScheme::CnRk4 => ImexCoefficients { alphas: &CK_ALPHAS, betas: &CK_BETAS, gammas: &CK_GAMMAS },
            ImexScheme::CnRk3 => ImexCoefficients { alphas: &W_ALPHAS, betas: &W_BETAS, gammas: &W_GAMMAS },
        }
    }

    /// The operator name listed by a stepper.
    pub fn operator(self) -> &'static str {
        match self {
            ImexScheme::CnRk4 => "time_stepping.imex_cn_rk4",
            ImexScheme::CnRk3 => "time_stepping.imex_cn_rk3",
        }
    }

    /// Stages per step (evaluations of the explicit terms).
    pub fn stages(self) -> usize {
        self.coefficients().betas.len()
    }

    /// The amplification factor of one step of `du/dt = z u / dt` taken entirely by the
    /// explicit part (`z = lambda dt`, complex as `(re, im)`).
    pub fn explicit_amplification(self, z: (f64, f64)) -> (f64, f64) {
        let c = self.coefficients();
        let mul = |a: (f64, f64), b: (f64, f64)| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
        let (mut u, mut h) = ((1.0, 0.0), (0.0, 0.0));
        for k in 0..c.betas.len() {
            let n = mul(z, u);
            h = (n.0 + c.betas[k] * h.0, n.1 + c.betas[k] * h.1);
            u = (u.0 + c.gammas[k] * h.0, u.1 + c.gammas[k] * h.1);
        }
        u
    }

    /// The largest `y` such that every `|R(i y')| <= 1` for `0 <= y' <= y`: the stability limit
    /// of the explicit part on the imaginary axis (pure advection). Computed from the
    /// coefficients by a scan (steps of 1e-3), so it is the scheme's own number.
    pub fn imaginary_axis_limit(self) -> f64 {
        let mut y = 0.0;
        loop {
            let next = y + 1e-3;
            let (re, im) = self.explicit_amplification((0.0, next));
            if re * re + im * im > 1.0 + 1e-12 || next > 10.0 {
                return y;
            }
            y = next;
        }
    }
}
