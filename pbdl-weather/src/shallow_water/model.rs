//! The shallow-water equations on the rotating sphere in vorticity-divergence form, solved with
//! the spectral transform method and semi-implicit leapfrog time stepping.
//!
//! Prognostic: relative vorticity `zeta`, divergence `delta`, layer geopotential `Phi = g h` (`h`
//! the fluid thickness above the surface) and a tracer `q`. With absolute vorticity `eta = zeta + f`
//! (`f = 2 Omega mu`, or the tilted-axis Coriolis parameter of [`ModelParams::axis_tilt`]),
//! `E = (U^2 + V^2) / (2 (1 - mu^2))`, surface geopotential `Phi_s` and the operators of
//! [`super::transform`]:
//!
//! * `d zeta/dt  = -div(U eta, V eta) - r zeta`
//! * `d delta/dt = curl(U eta, V eta) - lap(E + Phi + Phi_s) - r delta`
//! * `d Phi/dt   = -div(U Phi, V Phi) - (Phi - Phi_eq) / tau`
//! * `d q/dt     = -(U dq/dlambda + V (1 - mu^2) dq/dmu) / (a (1 - mu^2)) - (q - q_eq) / tau_q`
//!
//! plus implicit hyperdiffusion `-nu_n X` on all four with `nu_n = (n(n+1) / (M(M+1)))^p / tau_h`
//! (`p = 2`: del^4, `p = 4`: del^8). Time stepping (Hack and Jakob 1992, NCAR/TN-343): leapfrog
//! with the gravity-wave terms `-lap Phi` and `-Phi_ref delta` averaged over `t - dt` and
//! `t + dt` (a 2x2 solve per spectral degree `n`), drag, relaxation and diffusion backward at
//! `t + dt`, a Robert-Asselin filter, and a semi-implicit forward half-size first step.

use super::gauss::GaussianGrid;
use super::transform::{SpectralTransform, TransformScratch};
use super::Complex;
use crate::error::{Error, Result};

/// The planet: radius, rotation rate and gravity (defaults: Earth as in Williamson et al. 1992).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Planet {
    /// Radius `a` (m).
    pub radius: f64,
    /// Rotation rate `Omega` (1/s).
    pub omega: f64,
    /// Gravity `g` (m/s^2).
    pub gravity: f64,
}

impl Default for Planet {
    fn default() -> Self {
        Self { radius: 6.37122e6, omega: 7.292e-5, gravity: 9.80616 }
    }
}

/// Implicit hyperdiffusion `-nu_n X` with `nu_n = (n(n+1) / (M(M+1)))^order / tau` (`order` 2 is
/// del^4, 4 is del^8): `tau` is the e-folding time (s) of the smallest resolved scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hyperdiffusion {
    /// Power of the Laplacian (2: del^4, 4: del^8).
    pub order: u32,
    /// E-folding time (s) at the truncation wavenumber.
    pub tau: f64,
}

/// Model parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelParams {
    /// Triangular truncation `M`.
    pub truncation: usize,
    /// Gaussian latitudes (longitudes are twice as many).
    pub n_lat: usize,
    /// Time step (s).
    pub dt: f64,
    /// The planet.
    pub planet: Planet,
    /// Robert-Asselin filter coefficient (0.05 by default; NCAR CCM2 used 0.06).
    pub robert: f64,
    /// Optional hyperdiffusion (none by default).
    pub hyperdiffusion: Option<Hyperdiffusion>,
    /// Linear drag rate on vorticity and divergence (1/s; 0 by default).
    pub drag: f64,
    /// Tilt (radians) of the rotation axis toward longitude 180 degrees at the north pole: the
    /// Coriolis parameter is `2 Omega (sin(phi) cos(alpha) - cos(lambda) cos(phi) sin(alpha))` as
    /// in Williamson et al.'s tests 1-3 with `alpha != 0`. 0 by default.
    pub axis_tilt: f64,
    /// Reference geopotential of the semi-implicit scheme (m^2/s^2); `None`: the global mean of
    /// the geopotential set by [`ShallowWater::set_state_from_winds`] (at least `g * 1000 m`).
    pub phi_ref: Option<f64>,
}

impl ModelParams {
    /// `T_truncation` on `n_lat` Gaussian latitudes with time step `dt` seconds; Earth, Robert
    /// filter 0.05, no diffusion, no drag.
    pub fn new(truncation: usize, n_lat: usize, dt: f64) -> Self {
        Self {
            truncation,
            n_lat,
            dt,
            planet: Planet::default(),
            robert: 0.05,
            hyperdiffusion: None,
            drag: 0.0,
            axis_tilt: 0.0,
            phi_ref: None,
        }
    }

    /// T21 on the 32 x 64 grid (the 5.625 degree WeatherBench size).
    pub fn t21(dt: f64) -> Self {
        Self::new(21, 32, dt)
    }

    /// T42 on the 64 x 128 grid.
    pub fn t42(dt: f64) -> Self {
        Self::new(42, 64, dt)
    }

    fn check(&self) -> Result<()> {
        let bad = |what: &str, v: f64| Err(Error::InvalidArgument(format!("{what} = {v} is out of range")));
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt", self.dt);
        }
        let p = &self.planet;
        if !(p.radius.is_finite() && p.radius > 0.0) {
            return bad("planet.radius", p.radius);
        }
        if !(p.gravity.is_finite() && p.gravity > 0.0) {
            return bad("planet.gravity", p.gravity);
        }
        if !p.omega.is_finite() {
            return bad("planet.omega", p.omega);
        }
        if !(0.0..0.5).contains(&self.robert) {
            return bad("robert (use 0 <= robert < 0.5)", self.robert);
        }
        if !(self.drag.is_finite() && self.drag >= 0.0) {
            return bad("drag", self.drag);
        }
        if let Some(h) = self.hyperdiffusion {
            if !(h.tau.is_finite() && h.tau > 0.0) {
                return bad("hyperdiffusion.tau", h.tau);
            }
            if h.order == 0 || h.order > 8 {
                return bad("hyperdiffusion.order (1..=8)", h.order as f64);
            }
        }
        if !self.axis_tilt.is_finite() {
            return bad("axis_tilt", self.axis_tilt);
        }
        if let Some(r) = self.phi_ref {
            if !(r.is_finite() && r > 0.0) {
                return bad("phi_ref", r);
            }
        }
        Ok(())
    }
}

/// Spectral prognostic fields at one time level.
#[derive(Clone, Debug)]
struct Level {
    zeta: Vec<Complex>,
    delta: Vec<Complex>,
    phi: Vec<Complex>,
    q: Vec<Complex>,
}

impl Level {
    fn zeros(n: usize) -> Self {
        let z = vec![Complex::ZERO; n];
        Self { zeta: z.clone(), delta: z.clone(), phi: z.clone(), q: z }
    }
}

/// Preallocated work arrays so that [`ShallowWater::step`] allocates nothing.
#[derive(Clone, Debug)]
struct Work {
    psi: Vec<Complex>,
    chi: Vec<Complex>,
    /// Fourier coefficients `[lat][m]`, one per grid field below.
    four: Vec<Vec<Complex>>,
    /// Grid fields: U, V, zeta, Phi, q, q_lambda, q_mu, then products reuse them.
    grid: Vec<Vec<f64>>,
    t_zeta: Vec<Complex>,
    t_delta: Vec<Complex>,
    t_phi: Vec<Complex>,
    t_q: Vec<Complex>,
    e_spec: Vec<Complex>,
    scratch: TransformScratch,
}

/// The shallow-water model (see the module doc for the equations).
#[derive(Clone, Debug)]
pub struct ShallowWater {
    tr: SpectralTransform,
    params: ModelParams,
    prev: Level,
    curr: Level,
    next: Level,
    /// `n(n+1)/a^2` times `Phi_s` (the orography forcing of the divergence), spectral.
    lap_phis: Vec<Complex>,
    phis: Vec<Complex>,
    phi_eq: Vec<Complex>,
    relax_rate: f64,
    q_eq: Vec<Complex>,
    q_relax_rate: f64,
    phi_ref: f64,
    /// Hyperdiffusion rate per spectral index (1/s).
    nu: Vec<f64>,
    /// `n(n+1)/a^2` per spectral index.
    lap: Vec<f64>,
    /// Coriolis parameter on the grid.
    coriolis: Vec<f64>,
    work: Work,
    first: bool,
    steps: u64,
}

const NF: usize = 7;

impl ShallowWater {
    /// A model at rest with zero geopotential; set a state with [`Self::set_state_from_winds`].
    pub fn new(params: ModelParams) -> Result<Self> {
        params.check()?;
        let tr = SpectralTransform::new(params.truncation, params.n_lat, params.planet.radius)?;
        let ns = tr.n_spec();
        let mt = params.truncation as f64;
        let a2 = params.planet.radius * params.planet.radius;
        let lap: Vec<f64> = tr.n_n1().iter().map(|l| l / a2).collect();
        let nu = tr
            .n_n1()
            .iter()
            .map(|l| match params.hyperdiffusion {
                Some(h) => (l / (mt * (mt + 1.0))).powi(h.order as i32) / h.tau,
                None => 0.0,
            })
            .collect();
        let nf = tr.grid().n_lat() * (params.truncation + 1);
        let ng = tr.grid().len();
        let work = Work {
            psi: tr.zeros(),
            chi: tr.zeros(),
            four: vec![vec![Complex::ZERO; nf]; NF],
            grid: vec![vec![0.0; ng]; NF],
            t_zeta: tr.zeros(),
            t_delta: tr.zeros(),
            t_phi: tr.zeros(),
            t_q: tr.zeros(),
            e_spec: tr.zeros(),
            scratch: tr.scratch(),
        };
        let phi_ref = params.phi_ref.unwrap_or(params.planet.gravity * 1000.0);
        let g = tr.grid();
        let (sa, ca) = params.axis_tilt.sin_cos();
        let lon = g.lon_rad();
        let coriolis = (0..g.len())
            .map(|p| {
                let mu = g.mu[p / lon.len()];
                let l = lon[p % lon.len()];
                2.0 * params.planet.omega * (mu * ca - l.cos() * (1.0 - mu * mu).sqrt() * sa)
            })
            .collect();
        Ok(Self {
            prev: Level::zeros(ns),
            curr: Level::zeros(ns),
            next: Level::zeros(ns),
            lap_phis: tr.zeros(),
            phis: tr.zeros(),
            phi_eq: tr.zeros(),
            relax_rate: 0.0,
            q_eq: tr.zeros(),
            q_relax_rate: 0.0,
            phi_ref,
            nu,
            lap,
            coriolis,
            work,
            first: true,
            steps: 0,
            tr,
            params,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ModelParams {
        &self.params
    }

    /// The Gaussian grid of all grid fields.
    pub fn grid(&self) -> &GaussianGrid {
        self.tr.grid()
    }

    /// The spectral transforms.
    pub fn transform(&self) -> &SpectralTransform {
        &self.tr
    }

    /// Steps taken since the last state was set.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Model time (s) since the last state was set.
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.params.dt
    }

    /// The reference geopotential of the semi-implicit scheme (m^2/s^2).
    pub fn phi_ref(&self) -> f64 {
        self.phi_ref
    }

    /// Sets the state from grid winds `u`, `v` (m/s) and layer geopotential `phi = g h`
    /// (m^2/s^2), each `[lat][lon]` on [`Self::grid`]. Vorticity and divergence are the curl and
    /// divergence of `(u, v) cos(phi)` projected onto `T_M`. Restarts the leapfrog and the clock.
    pub fn set_state_from_winds(&mut self, u: &[f64], v: &[f64], phi: &[f64]) -> Result<()> {
        let g = self.tr.grid();
        for (f, w) in [(u, "u"), (v, "v"), (phi, "phi")] {
            g.check_len(f, w)?;
            if f.iter().any(|x| !x.is_finite()) {
                return Err(Error::InvalidArgument(format!("{w} holds non-finite values")));
            }
        }
        let nl = g.n_lon();
        let cos = |p: usize| (1.0 - g.mu[p / nl] * g.mu[p / nl]).sqrt();
        let uc: Vec<f64> = u.iter().enumerate().map(|(p, x)| x * cos(p)).collect();
        let vc: Vec<f64> = v.iter().enumerate().map(|(p, x)| x * cos(p)).collect();
        let (delta, zeta) = self.tr.div_curl(&uc, &vc)?;
        let phi_s = self.tr.analysis(phi)?;
        if self.params.phi_ref.is_none() {
            let mean = g.global_mean(phi)?;
            self.phi_ref = mean.max(self.params.planet.gravity * 1000.0);
        }
        self.curr.zeta = zeta;
        self.curr.delta = delta;
        self.curr.phi = phi_s;
        self.prev = self.curr.clone();
        self.first = true;
        self.steps = 0;
        Ok(())
    }

    /// Sets the tracer (grid field) at the current time; restarts the leapfrog for it.
    pub fn set_tracer(&mut self, q: &[f64]) -> Result<()> {
        self.curr.q = self.tr.analysis(q)?;
        self.prev.q = self.curr.q.clone();
        Ok(())
    }

    /// Sets the surface geopotential `Phi_s = g h_s` (m^2/s^2, grid field).
    pub fn set_orography(&mut self, phis: &[f64]) -> Result<()> {
        self.phis = self.tr.analysis(phis)?;
        for ((l, p), lp) in self.lap_phis.iter_mut().zip(&self.phis).zip(&self.lap) {
            *l = *p * *lp;
        }
        Ok(())
    }

    /// Relaxes the layer geopotential toward `phi_eq` (grid, m^2/s^2) with time scale `tau` (s).
    pub fn set_relaxation(&mut self, phi_eq: &[f64], tau: f64) -> Result<()> {
        if !(tau.is_finite() && tau > 0.0) {
            return Err(Error::InvalidArgument(format!("relaxation time {tau} s must be positive")));
        }
        self.phi_eq = self.tr.analysis(phi_eq)?;
        self.relax_rate = 1.0 / tau;
        Ok(())
    }

    /// Relaxes the tracer toward `q_eq` (grid) with time scale `tau` (s).
    pub fn set_tracer_relaxation(&mut self, q_eq: &[f64], tau: f64) -> Result<()> {
        if !(tau.is_finite() && tau > 0.0) {
            return Err(Error::InvalidArgument(format!("tracer relaxation time {tau} s must be positive")));
        }
        self.q_eq = self.tr.analysis(q_eq)?;
        self.q_relax_rate = 1.0 / tau;
        Ok(())
    }

    fn synth(&self, spec: &[Complex]) -> Vec<f64> {
        // The model's arrays always have the transform's length, so this cannot fail.
        self.tr.synthesis(spec).unwrap_or_default()
    }

    /// Layer geopotential `Phi = g h` (m^2/s^2) on the grid.
    pub fn geopotential(&self) -> Vec<f64> {
        self.synth(&self.curr.phi)
    }

    /// Layer thickness `h = Phi / g` (m) on the grid (add the orography for the free surface).
    pub fn height(&self) -> Vec<f64> {
        let g = self.params.planet.gravity;
        self.synth(&self.curr.phi).into_iter().map(|p| p / g).collect()
    }

    /// Relative vorticity (1/s) on the grid.
    pub fn vorticity(&self) -> Vec<f64> {
        self.synth(&self.curr.zeta)
    }

    /// Divergence (1/s) on the grid.
    pub fn divergence(&self) -> Vec<f64> {
        self.synth(&self.curr.delta)
    }

    /// The tracer on the grid.
    pub fn tracer(&self) -> Vec<f64> {
        self.synth(&self.curr.q)
    }

    /// Winds `(u, v)` (m/s) on the grid.
    pub fn winds(&self) -> (Vec<f64>, Vec<f64>) {
        let (mut u, mut v) =
            self.tr.winds_from_vort_div(&self.curr.zeta, &self.curr.delta).unwrap_or_else(|_| (Vec::new(), Vec::new()));
        let g = self.tr.grid();
        let nl = g.n_lon();
        for (p, (u, v)) in u.iter_mut().zip(v.iter_mut()).enumerate() {
            // U = u cos(phi): Gaussian latitudes never reach the poles.
            let c = (1.0 - g.mu[p / nl] * g.mu[p / nl]).sqrt();
            *u /= c;
            *v /= c;
        }
        (u, v)
    }

    /// Zonal wind (m/s) on the grid.
    pub fn u(&self) -> Vec<f64> {
        self.winds().0
    }

    /// Meridional wind (m/s) on the grid.
    pub fn v(&self) -> Vec<f64> {
        self.winds().1
    }

    /// Spectral coefficients of vorticity, divergence, geopotential and tracer at the current time.
    pub fn spectral_state(&self) -> (&[Complex], &[Complex], &[Complex], &[Complex]) {
        (&self.curr.zeta, &self.curr.delta, &self.curr.phi, &self.curr.q)
    }

    /// Advances `n` steps.
    pub fn run(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// Advances one time step (allocation-free).
    pub fn step(&mut self) {
        self.tendencies();
        self.implicit_update();
        self.steps += 1;
    }

    /// Explicit tendencies at the current level into `work.t_*`.
    fn tendencies(&mut self) {
        let tr = &self.tr;
        let w = &mut self.work;
        let c = &self.curr;
        let a = self.params.planet.radius;
        let a2 = a * a;
        for k in 0..tr.n_spec() {
            let l = tr.n_n1()[k];
            let f = if l == 0.0 { 0.0 } else { -a2 / l };
            w.psi[k] = c.zeta[k] * f;
            w.chi[k] = c.delta[k] * f;
        }
        let [fu, fv, fz, fp, fq, fx, fy] = &mut w.four[..] else { unreachable!() };
        tr.legendre_wind_synthesis(&w.psi, &w.chi, fu, fv);
        tr.legendre_synthesis(&c.zeta, fz);
        tr.legendre_synthesis(&c.phi, fp);
        tr.legendre_synthesis(&c.q, fq);
        tr.legendre_gradient_synthesis(&c.q, fx, fy);
        let buf = &mut w.scratch.buf;
        for i in 0..NF {
            tr.fourier_synthesis(&w.four[i], &mut w.grid[i], buf);
        }
        // Grid products; the seven grid arrays become U eta, V eta, U Phi, V Phi, E, N_q.
        let g = tr.grid();
        let nl = g.n_lon();
        {
            let [gu, gv, gz, gp, _, gx, gy] = &mut w.grid[..] else { unreachable!() };
            for j in 0..g.n_lat() {
                let mu = g.mu[j];
                let c2 = 1.0 - mu * mu;
                for p in j * nl..(j + 1) * nl {
                    let (u, v) = (gu[p], gv[p]);
                    let eta = gz[p] + self.coriolis[p];
                    let ph = gp[p];
                    let nq = -(u * gx[p] + v * gy[p]) / (a * c2);
                    gu[p] = u * eta;
                    gv[p] = v * eta;
                    gz[p] = u * ph;
                    gp[p] = v * ph;
                    gx[p] = (u * u + v * v) / (2.0 * c2);
                    gy[p] = nq;
                }
            }
        }
        for i in [0, 1, 2, 3, 5, 6] {
            tr.fourier_analysis(&w.grid[i], &mut w.four[i], buf);
        }
        let [fue, fve, fup, fvp, _, fe, fnq] = &w.four[..] else { unreachable!() };
        tr.legendre_div_curl(fue, fve, Some(&mut w.t_zeta), Some(&mut w.t_delta));
        tr.legendre_div_curl(fup, fvp, Some(&mut w.t_phi), None);
        tr.legendre_analysis(fe, &mut w.e_spec);
        tr.legendre_analysis(fnq, &mut w.t_q);
        for k in 0..tr.n_spec() {
            w.t_zeta[k] = -w.t_zeta[k];
            w.t_phi[k] = -w.t_phi[k];
            // -lap(E + Phi_s); -lap Phi is treated semi-implicitly.
            w.t_delta[k] += w.e_spec[k] * self.lap[k] + self.lap_phis[k];
        }
    }

    /// Semi-implicit leapfrog update, Robert-Asselin filter and level rotation.
    fn implicit_update(&mut self) {
        let dt = self.params.dt;
        // First step: forward (semi-implicit) over dt from the current level.
        let (tt, old) = if self.first { (dt, &self.curr) } else { (2.0 * dt, &self.prev) };
        let h = 0.5 * tt;
        let (c, n, w) = (&self.curr, &mut self.next, &self.work);
        let pr = self.phi_ref;
        let (r, rel, rq) = (self.params.drag, self.relax_rate, self.q_relax_rate);
        for k in 0..self.tr.n_spec() {
            let (l, nu) = (self.lap[k], self.nu[k]);
            let dv = 1.0 + tt * (r + nu);
            n.zeta[k] = (old.zeta[k] + w.t_zeta[k] * tt) * (1.0 / dv);
            let dp = 1.0 + tt * (rel + nu);
            let aa = old.delta[k] + w.t_delta[k] * tt + old.phi[k] * (h * l);
            let bb = old.phi[k] + (w.t_phi[k] + c.delta[k] * pr + self.phi_eq[k] * rel) * tt - old.delta[k] * (h * pr);
            let phi_new = (bb * dv - aa * (h * pr)) * (1.0 / (dv * dp + h * h * pr * l));
            n.phi[k] = phi_new;
            n.delta[k] = (aa + phi_new * (h * l)) * (1.0 / dv);
            let dq = 1.0 + tt * (rq + nu);
            n.q[k] = (old.q[k] + (w.t_q[k] + self.q_eq[k] * rq) * tt) * (1.0 / dq);
        }
        if self.first {
            self.first = false;
            // The unfiltered initial level becomes "t - dt" of the first leapfrog step.
            std::mem::swap(&mut self.prev, &mut self.curr);
        } else {
            let eps = self.params.robert;
            let (p, c, n) = (&mut self.prev, &self.curr, &self.next);
            for (pf, (cf, nf)) in [
                (&mut p.zeta, (&c.zeta, &n.zeta)),
                (&mut p.delta, (&c.delta, &n.delta)),
                (&mut p.phi, (&c.phi, &n.phi)),
                (&mut p.q, (&c.q, &n.q)),
            ] {
                for k in 0..pf.len() {
                    // Filtered current level becomes the new "previous".
                    pf[k] = cf[k] + (pf[k] - cf[k] * 2.0 + nf[k]) * eps;
                }
            }
        }
        // curr <- next; next keeps stale values that the next step overwrites.
        std::mem::swap(&mut self.curr, &mut self.next);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_parameters_and_inputs_are_errors_not_panics() {
        let ok = ModelParams::t21(1800.0);
        for bad in [
            ModelParams { dt: 0.0, ..ok.clone() },
            ModelParams { dt: f64::NAN, ..ok.clone() },
            ModelParams { robert: 0.7, ..ok.clone() },
            ModelParams { drag: -1.0, ..ok.clone() },
            ModelParams { hyperdiffusion: Some(Hyperdiffusion { order: 2, tau: 0.0 }), ..ok.clone() },
            ModelParams { truncation: 40, ..ok.clone() },
        ] {
            assert!(matches!(ShallowWater::new(bad), Err(Error::InvalidArgument(_))));
        }
        let mut m = ShallowWater::new(ok).unwrap();
        let n = m.grid().len();
        assert!(m.set_state_from_winds(&vec![0.0; n - 1], &vec![0.0; n], &vec![1e5; n]).is_err());
        assert!(m.set_state_from_winds(&vec![f64::NAN; n], &vec![0.0; n], &vec![1e5; n]).is_err());
        assert!(m.set_relaxation(&vec![1e5; n], -1.0).is_err());
        assert!(m.set_tracer(&[0.0; 3]).is_err());
    }

    #[test]
    fn state_at_rest_stays_at_rest_and_tracer_is_conserved() {
        let mut m = ShallowWater::new(ModelParams::t21(3600.0)).unwrap();
        let n = m.grid().len();
        let zero = vec![0.0; n];
        // A flat layer at rest with a tracer blob: nothing moves, the tracer stays put.
        m.set_state_from_winds(&zero, &zero, &vec![9.8e4; n]).unwrap();
        let q: Vec<f64> = (0..n).map(|p| (p % 7) as f64).collect();
        m.set_tracer(&q).unwrap();
        let q0 = m.tracer();
        m.run(24);
        let dq = m.tracer().iter().zip(&q0).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let umax = m.u().iter().fold(0.0_f64, |a, u| a.max(u.abs()));
        assert!(dq < 1e-10 && umax < 1e-10, "dq {dq} umax {umax}");
        assert_eq!(m.steps(), 24);
        assert_eq!(m.time(), 24.0 * 3600.0);
    }
}
