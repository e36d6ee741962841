//! Lid-driven cavity at Re = 100 (unit box, lid speed 1, nu = 0.01) run to steady state and
//! compared with Ghia, Ghia & Shin (1982), J. Comput. Phys. 48(3):387-411, Tables I and II
//! (centreline velocities; `tests/data/ghia1982_*.csv`, citation inside the files).
//!
//! Error: max over Ghia's points of |ours - Ghia|, ours linearly interpolated along the
//! centreline (walls and lid included as end points). Issue-3 target: <= 0.01 at 64^2
//! (PhiFlow 3.4 semi-Lagrangian: 0.049).

use candle_core::DType;
use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};

/// Reads `(coordinate, value at Re 100)` pairs from a Ghia table.
fn ghia(name: &str) -> Vec<(f64, f64)> {
    let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with('x') && !l.starts_with('y') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|s| s.trim().parse().unwrap()).collect();
            (v[0], v[1])
        })
        .collect()
}

fn interp(pts: &[(f64, f64)], x: f64) -> f64 {
    let k = pts.windows(2).position(|w| x >= w[0].0 && x <= w[1].0).unwrap();
    let (a, b) = (pts[k], pts[k + 1]);
    a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)
}

/// Runs the cavity until the velocity changes by less than `tol` per unit time (or `t_max`);
/// returns (max u error, max v error, steady time).
fn cavity(n: usize, t_max: f64, tol: f64) -> (f64, f64, f64) {
    let grid = Grid::square(n, 1.0).unwrap();
    let bc = Boundaries::lid_driven_cavity(1.0);
    let cfg = NavierStokesConfig { nu: 0.01, dt: 1.0, scheme: Scheme::Rk4 };
    let probe = NavierStokes::new(grid, bc, NavierStokesConfig { dt: 1e-6, ..cfg.clone() }).unwrap();
    let dt = 0.9 * probe.stable_time_step([1.0, 1.0]);
    let ns = NavierStokes::new(grid, bc, NavierStokesConfig { dt, ..cfg }).unwrap();
    let mut u = MacField::zeros(grid, bc, 1, DType::F64).unwrap();
    let mut t = 0.0;
    let check_every = (0.5 / dt).ceil() as usize;
    'outer: while t < t_max {
        let before = u.values().clone();
        for _ in 0..check_every {
            u = ns.step_unchecked(&u).unwrap();
            t += dt;
        }
        ns.check(&u).unwrap();
        let change = (u.values() - &before).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap()
            / (check_every as f64 * dt);
        if change < tol {
            break 'outer;
        }
    }
    let vals = u.values().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let (nn, h) = (n * n, 1.0 / n as f64);
    // u on x = 0.5 (face column n/2 - 1), cell centres in y, wall 0 and lid 1 at the ends.
    let mut uline = vec![(0.0, 0.0)];
    uline.extend((0..n).map(|j| ((j as f64 + 0.5) * h, vals[j * n + n / 2 - 1])));
    uline.push((1.0, 1.0));
    // v on y = 0.5 (face row n/2 - 1), cell centres in x, walls at the ends.
    let mut vline = vec![(0.0, 0.0)];
    vline.extend((0..n).map(|i| ((i as f64 + 0.5) * h, vals[nn + (n / 2 - 1) * n + i])));
    vline.push((1.0, 0.0));
    let eu = ghia("ghia1982_u_vertical_centerline.csv")
        .iter()
        .map(|&(y, g)| (interp(&uline, y) - g).abs())
        .fold(0.0, f64::max);
    if std::env::var("CAVITY_DEBUG").is_ok() {
        for (x, g) in ghia("ghia1982_v_horizontal_centerline.csv") {
            eprintln!("v x={x} ours={:.5} ghia={g}", interp(&vline, x));
        }
        for (y, g) in ghia("ghia1982_u_vertical_centerline.csv") {
            eprintln!("u y={y} ours={:.5} ghia={g}", interp(&uline, y));
        }
    }
    let ev = ghia("ghia1982_v_horizontal_centerline.csv")
        .iter()
        .map(|&(x, g)| (interp(&vline, x) - g).abs())
        .fold(0.0, f64::max);
    (eu, ev, t)
}

/// Measured here: u 0.0022, v 0.0083 (steady at t = 14).
#[test]
fn cavity_re100_32_matches_ghia() {
    let (eu, ev, t) = cavity(32, 40.0, 1e-4);
    eprintln!("cavity Re100 32^2: max |u - Ghia| {eu:.4}, max |v - Ghia| {ev:.4}, steady at t = {t:.1}");
    assert!(eu.max(ev) <= 0.01, "32^2: u error {eu:.4}, v error {ev:.4}");
}

/// The target at 64^2. Measured here: u 0.0038, v 0.0085 (steady at t = 18, a few
/// seconds). The remaining v difference is mostly Ghia's: from 32^2 to 64^2 our extrema move
/// *away* from the table (v at x = 0.8047: -0.2482 -> -0.2527, Ghia -0.2453), towards the larger
/// magnitudes that later fine-grid studies report, so a finer grid will not shrink this error.
#[test]
fn cavity_re100_64_matches_ghia_within_001() {
    let (eu, ev, t) = cavity(64, 60.0, 1e-5);
    eprintln!("cavity Re100 64^2: max |u - Ghia| {eu:.4}, max |v - Ghia| {ev:.4}, steady at t = {t:.1}");
    assert!(eu.max(ev) <= 0.01, "64^2: u error {eu:.4}, v error {ev:.4}");
}
