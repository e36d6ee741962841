//! Butcher tableaux as data.

use serde::{Deserialize, Serialize};

/// An explicit Runge-Kutta scheme: `a` (strictly lower triangular, row `i` has `i` entries),
/// weights `b`, and where its stability region meets the axes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ButcherTableau {
    /// Short name, e.g. `"rk4"`.
    pub name: String,
    /// Stage coefficients: `a[i][j]` for `j < i`.
    pub a: Vec<Vec<f64>>,
    /// Weights of the stages in the final update.
    pub b: Vec<f64>,
    /// Largest `|dt lambda|` on the imaginary axis inside the stability region (0: none).
    pub imag_limit: f64,
    /// Largest `|dt lambda|` on the negative real axis inside the stability region.
    pub real_limit: f64,
}

/// The named schemes, for configs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scheme {
    /// Classic fourth-order Runge-Kutta (4 stages, 4 projections per step).
    #[default]
    Rk4,
    /// Strong-stability-preserving third-order Runge-Kutta (3 stages).
    SspRk3,
    /// Forward Euler: unstable for central advection; only for pure diffusion.
    ForwardEuler,
}

impl Scheme {
    /// The scheme's tableau.
    pub fn tableau(self) -> ButcherTableau {
        match self {
            Scheme::Rk4 => ButcherTableau::rk4(),
            Scheme::SspRk3 => ButcherTableau::ssp_rk3(),
            Scheme::ForwardEuler => ButcherTableau::forward_euler(),
        }
    }

    /// The operator name a stepper lists for the scheme, e.g. `"time_stepping.rk4"`.
    ///
    /// ```
    /// assert_eq!(pbdl_grid::Scheme::SspRk3.operator_name(), "time_stepping.ssp_rk3");
    /// ```
    pub fn operator_name(self) -> &'static str {
        match self {
            Scheme::Rk4 => "time_stepping.rk4",
            Scheme::SspRk3 => "time_stepping.ssp_rk3",
            Scheme::ForwardEuler => "time_stepping.forward_euler",
        }
    }
}

impl ButcherTableau {
    /// Classic RK4. Its stability region reaches `2 sqrt 2` on the imaginary axis and `2.785` on
    /// the negative real axis.
    pub fn rk4() -> Self {
        Self {
            name: "rk4".into(),
            a: vec![vec![], vec![0.5], vec![0.0, 0.5], vec![0.0, 0.0, 1.0]],
            b: vec![1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0],
            imag_limit: 2.0 * std::f64::consts::SQRT_2,
            real_limit: 2.785_293_563,
        }
    }

    /// Shu-Osher SSP-RK3: `sqrt 3` on the imaginary axis, `2.5127` on the real axis.
    pub fn ssp_rk3() -> Self {
        Self {
            name: "ssp_rk3".into(),
            a: vec![vec![], vec![1.0], vec![0.25, 0.25]],
            b: vec![1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
            imag_limit: 3f64.sqrt(),
            real_limit: 2.512_745_326,
        }
    }

    /// Forward Euler: no part of the imaginary axis, 2 on the real axis.
    pub fn forward_euler() -> Self {
        Self { name: "forward_euler".into(), a: vec![vec![]], b: vec![1.0], imag_limit: 0.0, real_limit: 2.0 }
    }

    /// Number of stages.
    pub fn stages(&self) -> usize {
        self.b.len()
    }

    /// Checks the shape of the tableau and consistency (`sum b = 1`).
    pub fn validate(&self) -> crate::Result<()> {
        let bad = |reason: String| Err(crate::Error::Invalid { field: "tableau", reason });
        if self.b.is_empty() || self.a.len() != self.b.len() {
            return bad(format!("{}: a has {} rows, b has {} weights", self.name, self.a.len(), self.b.len()));
        }
        if let Some(i) = (0..self.a.len()).find(|&i| self.a[i].len() != i) {
            return bad(format!("{}: row {i} of a must have {i} entries (explicit scheme)", self.name));
        }
        let s: f64 = self.b.iter().sum();
        if (s - 1.0).abs() > 1e-12 {
            return bad(format!("{}: weights sum to {s}, not 1", self.name));
        }
        Ok(())
    }
}
