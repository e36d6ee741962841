//! The HIG paper's quantum dipole: a particle in a 1D box driven by an electric field.
//!
//! `i dpsi/dt = (-d^2/dx^2 + u(t) x) psi` on `[0, L]` with `psi = 0` at both walls, `n`
//! interior points `x_j = j dx` (`dx = L / (n + 1)`, `j = 1..n`) and the second difference
//! `(psi_{j-1} - 2 psi_j + psi_{j+1}) / dx^2`. Each step of size `dt` is Crank-Nicolson with
//! the control `u_k` held over the step:
//!
//! ```text
//! A_k psi_{k+1} = B_k psi_k,   A_k = I + i dt/2 H_k,   B_k = I - i dt/2 H_k,   H_k = T + u_k X
//! ```
//!
//! a Cayley transform of the Hermitian `H_k`, hence unitary: the norm is kept to round-off.
//! `A_k` is tridiagonal, so a step is one complex Thomas solve.
//!
//! Context: the initial state, outcome: the final state, both as `2 n` reals (interleaved
//! `Re, Im` per interior point); control: one `u_k` per step. The paper's setup
//! ([`QuantumDipole::hig_paper`]): `L = 2`, `n = 14` (16 points with the walls), `dt = 0.05`,
//! 384 steps; start in the ground state, target `(c_1 phi_2 + c_2 phi_3) / ||c||` with
//! `c ~ N(0, 1)` ([`QuantumDipole::dataset`]), loss `1 - |<psi*|psi_T>|^2`
//! ([`crate::hig::Loss::Infidelity`]).
//!
//! Exact Jacobian by an adjoint sweep. Differentiating a step in `u_k` gives
//! `A_k dpsi_{k+1} = s_k := -i dt/2 X (psi_k + psi_{k+1})`, and later steps map `dpsi` by the
//! complex-linear `M_m = A_m^-1 B_m`. With `P = M_{N-1} ... M_{k+1}`,
//! `dpsi_N/du_k = P A_k^-1 s_k`. `A` and `B` are complex *symmetric*, so row `i` of `P A_k^-1`
//! is `q_i = A_k^-1 r_i` for row `r_i` of `P`, and the next row is `B_k q_i`: one Thomas solve,
//! one tridiagonal product and one dot product per row and step, `O(N n^2)` per sample.
//! The vector-Jacobian product is the same sweep with a single row.

use super::{Dataset, Physics};
use crate::error::{check_len, Error, Result};
use std::ops::{Add, Mul, Sub};

/// A complex number, just what the solver needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct C {
    re: f64,
    im: f64,
}

impl C {
    const fn new(re: f64, im: f64) -> Self {
        Self { re, im }
    }

    fn inv(self) -> Self {
        let d = self.re * self.re + self.im * self.im;
        Self::new(self.re / d, -self.im / d)
    }

    fn conj(self) -> Self {
        Self::new(self.re, -self.im)
    }
}

impl Add for C {
    type Output = C;
    fn add(self, o: C) -> C {
        C::new(self.re + o.re, self.im + o.im)
    }
}

impl Sub for C {
    type Output = C;
    fn sub(self, o: C) -> C {
        C::new(self.re - o.re, self.im - o.im)
    }
}

impl Mul for C {
    type Output = C;
    fn mul(self, o: C) -> C {
        C::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
}

/// The quantum dipole with Crank-Nicolson time stepping.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantumDipole {
    /// Interior grid points `n` (the walls are extra).
    pub points: usize,
    /// Box length `L`.
    pub length: f64,
    /// Time step.
    pub dt: f64,
    /// Number of steps (= control length).
    pub steps: usize,
}

/// The Crank-Nicolson matrices of one step and the LU factors of `A` (Thomas algorithm).
struct Step {
    /// `dt / 2`.
    h: f64,
    /// `1 / dx^2`.
    inv_dx2: f64,
    /// Positions `x_j` of the interior points.
    x: Vec<f64>,
    /// Off-diagonal of `A` (that of `B` is its negative).
    off: C,
    /// Diagonal of `B`.
    diag_b: Vec<C>,
    /// `c'_j` of the Thomas elimination.
    cp: Vec<C>,
    /// Inverse pivots `1 / (a_j - off c'_{j-1})`.
    piv: Vec<C>,
}

impl Step {
    fn new(d: &QuantumDipole) -> Self {
        let n = d.points;
        let dx = d.dx();
        let inv_dx2 = 1.0 / (dx * dx);
        let h = 0.5 * d.dt;
        Self {
            h,
            inv_dx2,
            x: (1..=n).map(|j| j as f64 * dx).collect(),
            off: C::new(0.0, -h * inv_dx2),
            diag_b: vec![C::default(); n],
            cp: vec![C::default(); n],
            piv: vec![C::default(); n],
        }
    }

    /// Sets up `A = I + i h H` and `B = I - i h H` for control `u` and factors `A`.
    fn factor(&mut self, u: f64) {
        let o = self.off;
        for j in 0..self.x.len() {
            let hj = self.h * (2.0 * self.inv_dx2 + u * self.x[j]);
            self.diag_b[j] = C::new(1.0, -hj);
            let a = C::new(1.0, hj);
            let p = if j == 0 { a } else { a - o * self.cp[j - 1] };
            self.piv[j] = p.inv();
            self.cp[j] = o * self.piv[j];
        }
    }

    /// `v <- A^-1 v`.
    fn solve_a(&self, v: &mut [C]) {
        let (o, n) = (self.off, v.len());
        v[0] = v[0] * self.piv[0];
        for j in 1..n {
            v[j] = (v[j] - o * v[j - 1]) * self.piv[j];
        }
        for j in (0..n - 1).rev() {
            v[j] = v[j] - self.cp[j] * v[j + 1];
        }
    }

    /// `out = B v` (`B` has off-diagonal `-off`).
    fn apply_b(&self, v: &[C], out: &mut [C]) {
        let (ob, n) = (C::new(-self.off.re, -self.off.im), v.len());
        for j in 0..n {
            let mut acc = self.diag_b[j] * v[j];
            if j > 0 {
                acc = acc + ob * v[j - 1];
            }
            if j + 1 < n {
                acc = acc + ob * v[j + 1];
            }
            out[j] = acc;
        }
    }

    /// `psi <- A^-1 B psi` (factor first), using `tmp` as scratch.
    fn advance(&self, psi: &mut [C], tmp: &mut [C]) {
        self.apply_b(psi, tmp);
        self.solve_a(tmp);
        psi.copy_from_slice(tmp);
    }

    /// `s = d(rhs)/du = -i h X (psi + psi_next)`.
    fn control_source(&self, psi: &[C], psi_next: &[C], s: &mut [C]) {
        for j in 0..s.len() {
            let v = psi[j] + psi_next[j];
            let f = self.h * self.x[j];
            // -i f v = f (v_im - i v_re)
            s[j] = C::new(f * v.im, -f * v.re);
        }
    }
}

impl QuantumDipole {
    /// The HIG paper's setup: `L = 2`, 14 interior points (`dx = 2/15`), `dt = 0.05`, 384 steps.
    pub fn hig_paper() -> Self {
        Self { points: 14, length: 2.0, dt: 0.05, steps: 384 }
    }

    /// Grid spacing `L / (n + 1)`.
    pub fn dx(&self) -> f64 {
        self.length / (self.points + 1) as f64
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<()> {
        if self.points < 2 {
            return Err(Error::InvalidConfig {
                name: "points",
                value: self.points as f64,
                hint: "use at least 2 interior points (the paper: 14)",
            });
        }
        for (name, value, hint) in [
            ("length", self.length, "use a finite box length > 0 (the paper: 2)"),
            ("dt", self.dt, "use a finite time step > 0 (the paper: 0.05)"),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(Error::InvalidConfig { name, value, hint });
            }
        }
        if self.steps == 0 {
            return Err(Error::InvalidConfig {
                name: "steps",
                value: 0.0,
                hint: "use at least 1 step (the paper: 384)",
            });
        }
        Ok(())
    }

    /// Eigenstate `m` (`1..=n`) of the discrete Hamiltonian without field,
    /// `sin(pi m j / (n + 1))` normalised to unit norm, interleaved `(Re, Im)` (`2 n` reals).
    pub fn eigenstate(&self, m: usize) -> Result<Vec<f64>> {
        self.check_mode(m)?;
        let k = std::f64::consts::PI * m as f64 / (self.points + 1) as f64;
        let norm = ((self.points + 1) as f64 / 2.0).sqrt();
        Ok((1..=self.points).flat_map(|j| [(k * j as f64).sin() / norm, 0.0]).collect())
    }

    /// Eigenvalue of [`QuantumDipole::eigenstate`] `m`: `(4 / dx^2) sin^2(pi m / (2 (n + 1)))`.
    pub fn eigenvalue(&self, m: usize) -> Result<f64> {
        self.check_mode(m)?;
        let s = (std::f64::consts::PI * m as f64 / (2 * (self.points + 1)) as f64).sin();
        Ok(4.0 / (self.dx() * self.dx()) * s * s)
    }

    fn check_mode(&self, m: usize) -> Result<()> {
        if m == 0 || m > self.points {
            return Err(Error::shape("eigenstate index (1 = ground state)", format!("1..={}", self.points), m));
        }
        Ok(())
    }

    /// The paper's data: `len` samples starting in the ground state (context) with targets
    /// `(c_1 phi_2 + c_2 phi_3) / ||c||`, `c_i ~ N(0, 1)`; the network input is the target.
    pub fn dataset(&self, len: usize, seed: u64) -> Result<Dataset> {
        use rand::Rng;
        self.validate()?;
        let (ground, phi2, phi3) = (self.eigenstate(1)?, self.eigenstate(2)?, self.eigenstate(3)?);
        let mut rng = pbdl_core::seed::rng(seed);
        // Box-Muller keeps `rand_distr` out of this crate's dependencies.
        let mut normal = || {
            let u1: f64 = 1.0 - rng.random_range(0.0..1.0);
            let u2: f64 = rng.random_range(0.0..1.0);
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        };
        let mut targets = Vec::with_capacity(len * 2 * self.points);
        for _ in 0..len {
            let (c1, c2) = (normal(), normal());
            let norm = (c1 * c1 + c2 * c2).sqrt();
            targets.extend(phi2.iter().zip(&phi3).map(|(a, b)| (c1 * a + c2 * b) / norm));
        }
        let contexts = ground.repeat(len);
        Dataset::new(targets.clone(), contexts, targets, len)
    }

    fn check_all(&self, x: &[f64], u: &[f64], y: &[f64]) -> Result<()> {
        self.validate()?;
        self.check_sample(x, u, y)?;
        crate::error::check_finite("initial state", x, 2)?;
        crate::error::check_finite("control", u, 1)
    }

    /// The states `psi_0..psi_N` of a rollout, `(N + 1) n` complex values.
    fn rollout(&self, x: &[f64], u: &[f64], st: &mut Step) -> Vec<C> {
        let n = self.points;
        let mut traj = Vec::with_capacity((u.len() + 1) * n);
        traj.extend(x.chunks_exact(2).map(|p| C::new(p[0], p[1])));
        let mut psi = traj.clone();
        let mut tmp = vec![C::default(); n];
        for &uk in u {
            st.factor(uk);
            st.advance(&mut psi, &mut tmp);
            traj.extend_from_slice(&psi);
        }
        traj
    }

    /// The adjoint sweep over a stored trajectory for the rows `rows` (`[r, n]`, each the
    /// row of `d psi_N / d psi_N = I` or a cotangent), calling `emit(k, i, w)` with
    /// `w = q_i . s_k = (row_i of dpsi_N/dpsi_{k+1}) A_k^-1 s_k` for every step `k` (last first).
    fn adjoint(&self, u: &[f64], traj: &[C], st: &mut Step, rows: &mut [C], mut emit: impl FnMut(usize, usize, C)) {
        let n = self.points;
        let mut s = vec![C::default(); n];
        let mut tmp = vec![C::default(); n];
        for k in (0..u.len()).rev() {
            st.factor(u[k]);
            st.control_source(&traj[k * n..(k + 1) * n], &traj[(k + 1) * n..(k + 2) * n], &mut s);
            for (i, r) in rows.chunks_exact_mut(n).enumerate() {
                st.solve_a(r);
                let w = r.iter().zip(&s).fold(C::default(), |acc, (a, b)| acc + *a * *b);
                emit(k, i, w);
                st.apply_b(r, &mut tmp);
                r.copy_from_slice(&tmp);
            }
        }
    }
}

impl Physics for QuantumDipole {
    fn context_dim(&self) -> usize {
        2 * self.points
    }

    fn control_dim(&self) -> usize {
        self.steps
    }

    fn output_dim(&self) -> usize {
        2 * self.points
    }

    fn forward(&self, x: &[f64], u: &[f64], y: &mut [f64]) -> Result<()> {
        self.check_all(x, u, y)?;
        let n = self.points;
        let mut st = Step::new(self);
        let mut psi: Vec<C> = x.chunks_exact(2).map(|p| C::new(p[0], p[1])).collect();
        let mut tmp = vec![C::default(); n];
        for &uk in u {
            st.factor(uk);
            st.advance(&mut psi, &mut tmp);
        }
        for (o, p) in y.chunks_exact_mut(2).zip(&psi) {
            o[0] = p.re;
            o[1] = p.im;
        }
        Ok(())
    }

    fn jacobian(&self, x: &[f64], u: &[f64], y: &mut [f64], jac: &mut [f64]) -> Result<()> {
        self.check_all(x, u, y)?;
        let (n, nu) = (self.points, self.steps);
        check_len("physics Jacobian length", 2 * n * nu, jac.len())?;
        let mut st = Step::new(self);
        let traj = self.rollout(x, u, &mut st);
        for (o, p) in y.chunks_exact_mut(2).zip(&traj[nu * n..]) {
            o[0] = p.re;
            o[1] = p.im;
        }
        // Rows of the identity: row i of dpsi_N/dpsi_N.
        let mut rows = vec![C::default(); n * n];
        for i in 0..n {
            rows[i * n + i] = C::new(1.0, 0.0);
        }
        // u is real, so d(Re psi_i)/du_k = Re w and d(Im psi_i)/du_k = Im w.
        self.adjoint(u, &traj, &mut st, &mut rows, |k, i, w| {
            jac[2 * i * nu + k] = w.re;
            jac[(2 * i + 1) * nu + k] = w.im;
        });
        Ok(())
    }

    fn vjp(&self, x: &[f64], u: &[f64], cot_y: &[f64], cot_u: &mut [f64]) -> Result<()> {
        let n = self.points;
        self.check_all(x, u, cot_y)?;
        check_len("physics control cotangent length", self.steps, cot_u.len())?;
        let mut st = Step::new(self);
        let traj = self.rollout(x, u, &mut st);
        // sum_i (c_re,i Re w_i + c_im,i Im w_i) = Re(sum_i conj(c_i) w_i): one row, conj(c)^T P.
        let mut row: Vec<C> = cot_y.chunks_exact(2).map(|c| C::new(c[0], c[1]).conj()).collect();
        debug_assert_eq!(row.len(), n);
        self.adjoint(u, &traj, &mut st, &mut row, |k, _, w| cot_u[k] = w.re);
        Ok(())
    }
}
