//! Lid-driven cavity at Re = 100 and 1000 (unit box, lid speed 1, nu = 1/Re) run to steady
//! state and compared with Ghia, Ghia & Shin (1982), J. Comput. Phys. 48(3):387-411, Tables I and II
//! (centreline velocities; `tests/data/ghia1982_*.csv`, citation inside the files).
//!
//! Run the slow ones with `cargo test -p pbdl-grid --test cavity -- --ignored --nocapture`;
//! `cavity_user` runs any Re in Ghia's tables (100, 400, 1000) at any resolution, e.g.
//! `CAVITY_RE=400 CAVITY_N=96 cargo test -p pbdl-grid --test cavity cavity_user -- --ignored
//! --nocapture` (also `CAVITY_T_MAX`, `CAVITY_TOL`; `CAVITY_PROGRESS=1` prints the residual,
//! `CAVITY_DEBUG=1` the centreline values).
//!
//! Error: max over Ghia's points of |ours - Ghia|, ours linearly interpolated along the
//! centreline (walls and lid included as end points). Issue-3 targets: Re 100 <= 0.01 at 64^2,
//! Re 1000 <= 0.03 at 128^2. PhiFlow's error on the same case is measured by
//! `bench/peers/run.sh` (row `lid_driven_cavity_re100` of `cargo xtask bench grid`).

use candle_core::DType;
use pbdl_grid::validation::{cavity_centrelines, interpolate, GhiaTable};
use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};

/// Result of one cavity run.
struct CavityRun {
    /// Max |u - Ghia| on the vertical centreline.
    eu: f64,
    /// Max |v - Ghia| on the horizontal centreline.
    ev: f64,
    /// Simulated time at the stop.
    t: f64,
    /// Time steps taken.
    steps: usize,
    /// Last measured max |du/dt| (the steady-state residual).
    residual: f64,
}

/// Runs the cavity at Reynolds number `re` (lid speed 1, unit box, nu = 1/re) until the
/// velocity changes by less than `tol` per unit time (or `t_max`), and compares with Ghia.
fn cavity(re: f64, n: usize, t_max: f64, tol: f64) -> CavityRun {
    let verbose = std::env::var("CAVITY_PROGRESS").is_ok();
    let grid = Grid::square(n, 1.0).unwrap();
    let bc = Boundaries::lid_driven_cavity(1.0);
    let cfg = NavierStokesConfig { nu: 1.0 / re, dt: 1.0, scheme: Scheme::Rk4 };
    let probe = NavierStokes::new(grid, bc, NavierStokesConfig { dt: 1e-6, ..cfg.clone() }).unwrap();
    let dt = 0.9 * probe.stable_time_step([1.0, 1.0]);
    let ns = NavierStokes::new(grid, bc, NavierStokesConfig { dt, ..cfg }).unwrap();
    let mut u = MacField::zeros(grid, bc, 1, DType::F64).unwrap();
    let (mut t, mut steps, mut residual) = (0.0, 0, f64::INFINITY);
    let check_every = (0.5 / dt).ceil() as usize;
    while t < t_max {
        let before = u.values().clone();
        for _ in 0..check_every {
            u = ns.step_unchecked(&u).unwrap();
            t += dt;
        }
        steps += check_every;
        ns.check(&u).unwrap();
        residual = (u.values() - &before).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap()
            / (check_every as f64 * dt);
        if verbose {
            eprintln!("t = {t:.2}: max |du/dt| = {residual:.3e}");
        }
        if residual < tol {
            break;
        }
    }
    let ghia = GhiaTable::for_reynolds(re).unwrap();
    let lines = cavity_centrelines(&u).unwrap();
    if std::env::var("CAVITY_DEBUG").is_ok() {
        for &(x, g) in &ghia.v_horizontal {
            eprintln!("v x={x} ours={:.5} ghia={g}", interpolate(&lines.v, x));
        }
        for &(y, g) in &ghia.u_vertical {
            eprintln!("u y={y} ours={:.5} ghia={g}", interpolate(&lines.u, y));
        }
    }
    let (eu, ev) = lines.max_errors(&ghia);
    CavityRun { eu, ev, t, steps, residual }
}

/// Measured here: u 0.0022, v 0.0083 (steady at t = 14).
#[test]
fn cavity_re100_32_matches_ghia() {
    let CavityRun { eu, ev, t, .. } = cavity(100.0, 32, 40.0, 1e-4);
    eprintln!("cavity Re100 32^2: max |u - Ghia| {eu:.4}, max |v - Ghia| {ev:.4}, steady at t = {t:.1}");
    assert!(eu.max(ev) <= 0.01, "32^2: u error {eu:.4}, v error {ev:.4}");
}

/// The target at 64^2. Measured here: u 0.0038, v 0.0085 (steady at t = 18, a few
/// seconds). The remaining v difference is mostly Ghia's: from 32^2 to 64^2 our extrema move
/// *away* from the table (v at x = 0.8047: -0.2482 -> -0.2527, Ghia -0.2453), towards the larger
/// magnitudes that later fine-grid studies report, so a finer grid will not shrink this error.
#[test]
fn cavity_re100_64_matches_ghia_within_001() {
    let CavityRun { eu, ev, t, .. } = cavity(100.0, 64, 60.0, 1e-5);
    eprintln!("cavity Re100 64^2: max |u - Ghia| {eu:.4}, max |v - Ghia| {ev:.4}, steady at t = {t:.1}");
    assert!(eu.max(ev) <= 0.01, "64^2: u error {eu:.4}, v error {ev:.4}");
}

/// The Re = 1000 target at 128^2 (nu = 0.001), same stepper as above (RK4, flux-form
/// advection, dt = 0.9 x the stable step = 6.5e-3). Stops when max |du/dt| < 1e-4 (checked every
/// 0.5 time units) or at t = 300. Measured here: u 0.0032, v 0.0118, steady at t = 47.4 (7238
/// steps, 81 s on a loaded 2-core machine in the test profile). Stopping at 1e-5 instead (t = 78.6,
/// 12012 steps) moves centreline values by < 0.001: u 0.0030, v 0.0124. At 64^2: u 0.0185,
/// v 0.0206. The largest v error is in the right-wall jet (x = 0.9688: ours -0.2236, Ghia
/// -0.2139); there and at the v minimum (x = 0.9063: 64^2 -0.4949, 128^2 -0.5181, Ghia -0.5155)
/// refinement moves us past the table, so as at Re 100 a finer grid will not shrink this error.
#[test]
#[ignore = "Re 1000 at 128^2 to steady state: ~1.5 min in the test profile"]
fn cavity_re1000_128_matches_ghia_within_003() {
    let r = steady_cavity(1000.0, 128, 300.0, 1e-4);
    println!("ACCEPTANCE: cavity_re1000_128 measured=u {:.4}, v {:.4} bar=max(u, v) <= 0.03", r.eu, r.ev);
    assert!(r.eu.max(r.ev) <= 0.03, "128^2: u error {:.4}, v error {:.4}", r.eu, r.ev);
}

/// [`cavity`], timed and printed; fails if the run did not reach `tol`.
fn steady_cavity(re: f64, n: usize, t_max: f64, tol: f64) -> CavityRun {
    let start = std::time::Instant::now();
    let r = cavity(re, n, t_max, tol);
    eprintln!(
        "cavity Re{re} {n}^2: max |u - Ghia| {:.4}, max |v - Ghia| {:.4}, t = {:.1}, {} steps, residual max |du/dt| \
         {:.2e}, {:.0} s",
        r.eu,
        r.ev,
        r.t,
        r.steps,
        r.residual,
        start.elapsed().as_secs_f64()
    );
    assert!(r.residual < tol, "not steady by t = {:.0}: max |du/dt| {:.2e}", r.t, r.residual);
    r
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().map_or(default, |v| v.parse().unwrap_or_else(|_| panic!("{name}={v} is not a number")))
}

/// A user's cavity run, configured by `CAVITY_RE` (100, 400 or 1000; default 1000), `CAVITY_N`
/// (default 128), `CAVITY_T_MAX` (default 300) and `CAVITY_TOL` (steady when max |du/dt| is
/// below it; default 1e-4). Prints the errors against Ghia and fails if the run is not steady.
#[test]
#[ignore = "user entry: configured by CAVITY_* environment variables; minutes"]
fn cavity_user() {
    let (re, n) = (env_or("CAVITY_RE", 1000.0), env_or("CAVITY_N", 128));
    steady_cavity(re, n, env_or("CAVITY_T_MAX", 300.0), env_or("CAVITY_TOL", 1e-4));
}
