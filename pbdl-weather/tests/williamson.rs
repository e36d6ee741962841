//! Williamson et al. (1992) test cases 2 and 6 for the spectral shallow-water model, a timing,
//! and a forced-dissipative stability run. Norms are printed (`--nocapture`) for the README.
//!
//! Bars were fixed before the first measurement: test 2 is steady and band-limited, so a
//! spectral model must keep it to round-off (bars 1e-8 relative); test 6's phase speed must be
//! within 10% of Haurwitz's non-divergent value, T21 and T42 within 3% of each other, and the
//! height within l2 = 0.05 of the rigidly moved initial pattern at day 14.

use pbdl_weather::shallow_water::legendre::SpectralLayout;
use pbdl_weather::shallow_water::williamson::{self, ErrorNorms};
use pbdl_weather::shallow_water::{Complex, Hyperdiffusion, ModelParams, ShallowWater, SpectralTransform};
use std::f64::consts::PI;
use std::time::Instant;

const DAY: f64 = 86400.0;

fn test2(m: usize, n_lat: usize, dt: f64, alpha: f64, days: f64) -> ErrorNorms {
    let mut params = ModelParams::new(m, n_lat, dt);
    params.axis_tilt = alpha;
    let mut model = ShallowWater::new(params).unwrap();
    let init = williamson::test2_initial(model.grid(), &model.params().planet, alpha);
    model.set_state_from_winds(&init.u, &init.v, &init.phi).unwrap();
    let g = model.params().planet.gravity;
    let h0: Vec<f64> = init.phi.iter().map(|p| p / g).collect();
    model.run((days * DAY / dt).round() as usize);
    let e = williamson::error_norms(model.grid(), &model.height(), &h0).unwrap();
    eprintln!(
        "test 2  T{m:<3} alpha {alpha:.4} dt {dt:>5} s  day {days}:  l1 {:.3e}  l2 {:.3e}  linf {:.3e}",
        e.l1, e.l2, e.linf
    );
    e
}

fn check_test2(e: ErrorNorms) {
    println!(
        "ACCEPTANCE: williamson2 measured=l1 {:.1e}, l2 {:.1e}, linf {:.1e} bar=l1, l2 < 1e-8, linf < 1e-7",
        e.l1, e.l2, e.linf
    );
    assert!(e.l1 < 1e-8 && e.l2 < 1e-8 && e.linf < 1e-7, "{e:?}");
}

#[test]
fn test2_steady_zonal_flow_t21_t42() {
    for alpha in [0.0, PI / 4.0] {
        check_test2(test2(21, 32, 1800.0, alpha, 5.0));
        check_test2(test2(42, 64, 900.0, alpha, 5.0));
    }
}

#[test]
#[ignore = "T63 and T85, slower"]
fn test2_steady_zonal_flow_t63_t85() {
    for alpha in [0.0, PI / 4.0] {
        check_test2(test2(63, 96, 600.0, alpha, 5.0));
        check_test2(test2(85, 128, 450.0, alpha, 5.0));
    }
}

/// Phase speed (rad/s), its relative error vs Haurwitz, and the norms vs the rigidly rotated
/// initial height at the end.
/// `extra_depth` (m) is added to `h_0` everywhere (the balance is unchanged): a deep layer
/// approaches the non-divergent limit in which Haurwitz's speed is exact.
fn test6(m: usize, n_lat: usize, dt: f64, days: f64, extra_depth: f64) -> (f64, f64, ErrorNorms) {
    let mut model = ShallowWater::new(ModelParams::new(m, n_lat, dt)).unwrap();
    let planet = model.params().planet;
    let init = williamson::test6_initial(model.grid(), &planet);
    let phi: Vec<f64> = init.phi.iter().map(|p| p + planet.gravity * extra_depth).collect();
    model.set_state_from_winds(&init.u, &init.v, &phi).unwrap();
    let grid = model.grid().clone();
    let (j, nl) = (grid.nearest_lat(45.0), grid.n_lon());
    let phase = |h: &[f64]| williamson::zonal_phase(&h[j * nl..(j + 1) * nl], 4);
    let mut last = phase(&model.height());
    let mut unwrapped = 0.0;
    let steps = (days * DAY / dt).round() as usize;
    // Sample every 3 hours: the phase moves far less than pi between samples.
    let every = ((3.0 * 3600.0 / dt).round() as usize).max(1);
    for s in 1..=steps {
        model.step();
        if s % every == 0 || s == steps {
            let p = phase(&model.height());
            let mut d = p - last;
            d -= 2.0 * PI * (d / (2.0 * PI)).round();
            unwrapped += d;
            last = p;
        }
    }
    let t = model.time();
    // A pattern cos(4 (lambda - nu t)) has phase -4 nu t.
    let nu = -unwrapped / 4.0 / t;
    let nu_h = williamson::rossby_haurwitz_phase_speed(&planet);
    let rel = (nu - nu_h) / nu_h;
    let reference: Vec<f64> =
        williamson::test6_height(&grid, &planet, nu_h * t).iter().map(|h| h + extra_depth).collect();
    let e = williamson::error_norms(&grid, &model.height(), &reference).unwrap();
    let umax = model.u().iter().fold(0.0_f64, |a, u| a.max(u.abs()));
    eprintln!(
        "test 6  T{m:<3} dt {dt:>5} s  h0 + {extra_depth} m  day {days}:  phase speed {:.4} deg/day (Haurwitz {:.4}, rel. err {:+.3e}) \
         vs rigid Haurwitz pattern: l1 {:.3e}  l2 {:.3e}  linf {:.3e}  (lat {:.2}, max|u| {umax:.1} m/s)",
        nu.to_degrees() * DAY,
        nu_h.to_degrees() * DAY,
        rel,
        e.l1,
        e.l2,
        e.linf,
        grid.lat_deg[j]
    );
    (nu, rel, e)
}

#[test]
fn test6_rossby_haurwitz_wave_day7() {
    let (nu21, rel21, e21) = test6(21, 32, 1200.0, 7.0, 0.0);
    let (nu42, rel42, e42) = test6(42, 64, 600.0, 7.0, 0.0);
    assert!(rel21.abs() < 0.10 && rel42.abs() < 0.10);
    assert!(((nu42 - nu21) / nu42).abs() < 0.03);
    assert!(e21.l2 < 0.05 && e42.l2 < 0.05);
}

/// In a layer 100 times deeper the divergence is negligible and the wave must move at
/// Haurwitz's speed: this separates model error from the shallow-water physics.
#[test]
fn test6_non_divergent_limit_moves_at_haurwitz_speed() {
    let (_, rel, _) = test6(21, 32, 1200.0, 7.0, 99.0 * williamson::TEST6_H0);
    assert!(rel.abs() < 0.01, "relative phase speed error {rel}");
}

#[test]
#[ignore = "14 days at T21, T42 and T63"]
fn test6_rossby_haurwitz_wave_day14() {
    let (nu21, rel21, e21) = test6(21, 32, 1200.0, 14.0, 0.0);
    let (nu42, rel42, e42) = test6(42, 64, 600.0, 14.0, 0.0);
    let (nu63, rel63, e63) = test6(63, 96, 400.0, 14.0, 0.0);
    println!(
        "ACCEPTANCE: williamson6_day14 measured=phase error {:.1}% / {:.1}% / {:.1}%, l2 {:.2e} / {:.2e} / {:.2e} \
         (T21 / T42 / T63), speed T42-T21 {:.2}%, T63-T42 {:.2}% bar=|phase error| < 10%, l2 < 0.05, resolutions within 3%",
        100.0 * rel21,
        100.0 * rel42,
        100.0 * rel63,
        e21.l2,
        e42.l2,
        e63.l2,
        100.0 * (nu42 - nu21) / nu42,
        100.0 * (nu63 - nu42) / nu63
    );
    for (rel, e) in [(rel21, e21), (rel42, e42), (rel63, e63)] {
        assert!(rel.abs() < 0.10);
        assert!(e.l2 < 0.05);
    }
    assert!(((nu42 - nu21) / nu42).abs() < 0.03);
    assert!(((nu63 - nu42) / nu63).abs() < 0.03);
}

/// Spectral interpolation is exact: the test-6 height is band-limited well below T21, so its
/// T42 analysis truncated to T21 and evaluated on the T21 grid is the analytic field there.
#[test]
fn truncated_synthesis_of_band_limited_field_is_exact() {
    let planet = ModelParams::t21(1200.0).planet;
    let (fine, coarse) = (
        SpectralTransform::new(42, 64, planet.radius).unwrap(),
        SpectralTransform::new(21, 32, planet.radius).unwrap(),
    );
    let spec = fine.analysis(&williamson::test6_height(fine.grid(), &planet, 0.3)).unwrap();
    let h = williamson::synthesis_truncated(&spec, 42, &coarse).unwrap();
    let e = williamson::error_norms(coarse.grid(), &h, &williamson::test6_height(coarse.grid(), &planet, 0.3)).unwrap();
    assert!(e.linf < 1e-12, "{e:?}");
    assert!(williamson::truncate_spectral(&spec, 42, 63).is_err());
    assert!(williamson::truncate_spectral(&spec[1..], 42, 21).is_err());
}

/// Test 6 run (same scheme as [`test6`]: semi-implicit leapfrog, Robert filter 0.05, no
/// diffusion) from the analytic initial state; the spectral geopotential at each of `days`, the
/// transform, and the wall time (s).
fn test6_snapshots(m: usize, n_lat: usize, dt: f64, days: &[f64]) -> (SpectralTransform, Vec<Vec<Complex>>, f64) {
    let t0 = Instant::now();
    let mut model = ShallowWater::new(ModelParams::new(m, n_lat, dt)).unwrap();
    let init = williamson::test6_initial(model.grid(), &model.params().planet);
    model.set_state_from_winds(&init.u, &init.v, &init.phi).unwrap();
    let mut out = Vec::new();
    for &d in days {
        let steps = d * DAY / dt;
        assert!((steps - steps.round()).abs() < 1e-9, "T{m}: dt {dt} s does not divide day {d}");
        model.run(steps.round() as usize - model.steps() as usize);
        let phi = model.spectral_state().2.to_vec();
        assert!(phi.iter().all(|c| c.re.is_finite() && c.im.is_finite()), "T{m} dt {dt}: blew up by day {d}");
        out.push(phi);
    }
    (model.transform().clone(), out, t0.elapsed().as_secs_f64())
}

/// Self-convergence of test 6 (Williamson et al. 1992 measure it against a T213 run; the rigid
/// Haurwitz pattern of [`test6`] is not the shallow-water solution, so norms against it stall).
///
/// Runs T21 (32 x 64, dt 1200 s), T42 (64 x 128, 600 s), T63 (96 x 192, 400 s) and a T170
/// reference (256 x 512, 150 s): dt ~ 1/M, the scheme of [`test6`], no diffusion. Each run's
/// height is compared, on its own grid, with the reference truncated to its `T_M` and evaluated
/// there ([`williamson::synthesis_truncated`], exact). Diagnostics (no bar): T42 and T63 with
/// half the time step (is the error spatial or temporal?), the part of the reference that `T_M`
/// cannot represent (the l2 of the dropped coefficients, computed on the reference grid), and the
/// rigid Haurwitz pattern against the reference.
///
/// Bar, fixed before the first measurement: at day 7 and at day 14 each of l1, l2 and l_inf
/// decreases strictly T21 > T42 > T63. The observed orders are reported, not asserted.
#[test]
#[ignore = "T170 reference to day 14: about 10 minutes in release"]
fn test6_convergence_against_t170_reference() {
    const DAYS: [f64; 2] = [7.0, 14.0];
    const REF: (usize, usize, f64) = (170, 256, 150.0);
    let main = [(21, 32, 1200.0), (42, 64, 600.0), (63, 96, 400.0)];
    let half_dt = [(42, 64, 300.0), (63, 96, 200.0)];
    let t_all = Instant::now();
    // Two threads: the reference alone, the coarse runs one after another.
    let ((rtr, rphi, rsec), coarse) = std::thread::scope(|s| {
        let r = s.spawn(|| test6_snapshots(REF.0, REF.1, REF.2, &DAYS));
        let c: Vec<_> =
            main.iter().chain(&half_dt).map(|&(m, nl, dt)| (m, dt, test6_snapshots(m, nl, dt, &DAYS))).collect();
        (r.join().unwrap(), c)
    });
    let planet = ModelParams::t21(1200.0).planet;
    let g = planet.gravity;
    let to_h = |phi: Vec<f64>| -> Vec<f64> { phi.into_iter().map(|p| p / g).collect() };
    let rlay = SpectralLayout::new(REF.0);
    let nu_h = williamson::rossby_haurwitz_phase_speed(&planet);
    let mut table = String::from(
        "| day | run | dt (s) | l1 | l2 | l_inf | order l1 | order l2 | order l_inf |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    let fmt = |e: &ErrorNorms| format!("{:.3e} | {:.3e} | {:.3e}", e.l1, e.l2, e.linf);
    let mut bar_ok = true;
    let mut l2s = Vec::new();
    for (di, &day) in DAYS.iter().enumerate() {
        let href_full = to_h(rtr.synthesis(&rphi[di]).unwrap());
        let mut prev: Option<(usize, ErrorNorms)> = None;
        for (k, (m, dt, (tr, phi, _))) in coarse.iter().enumerate() {
            let h = to_h(tr.synthesis(&phi[di]).unwrap());
            let href = to_h(williamson::synthesis_truncated(&rphi[di], REF.0, tr).unwrap());
            let e = williamson::error_norms(tr.grid(), &h, &href).unwrap();
            let is_main = k < main.len();
            let orders = match (is_main, prev) {
                (true, Some((mp, ep))) => {
                    let r = (*m as f64 / mp as f64).ln();
                    bar_ok &= e.l1 < ep.l1 && e.l2 < ep.l2 && e.linf < ep.linf;
                    let o = |a: f64, b: f64| format!("{:.2}", (a / b).ln() / r);
                    format!("{} | {} | {}", o(ep.l1, e.l1), o(ep.l2, e.l2), o(ep.linf, e.linf))
                }
                _ => " | | ".into(),
            };
            let label = if is_main { format!("T{m}") } else { format!("T{m}, half dt") };
            table += &format!("| {day} | {label} | {dt} | {} | {orders} |\n", fmt(&e));
            if is_main {
                l2s.push(format!("day {day} T{m} {:.2e}", e.l2));
                prev = Some((*m, e));
            }
        }
        // What T_M cannot represent: the reference minus its own T_M truncation (reference grid).
        for &(m, _, _) in &main {
            let lay = SpectralLayout::new(m);
            let mut padded = vec![Complex::ZERO; rlay.len()];
            for (mm, n) in lay.modes() {
                padded[rlay.index(mm, n)] = rphi[di][rlay.index(mm, n)];
            }
            let e = williamson::error_norms(rtr.grid(), &to_h(rtr.synthesis(&padded).unwrap()), &href_full).unwrap();
            table += &format!("| {day} | reference minus its T{m} part | | {} | | | |\n", fmt(&e));
        }
        let rigid = williamson::test6_height(rtr.grid(), &planet, nu_h * day * DAY);
        let e = williamson::error_norms(rtr.grid(), &rigid, &href_full).unwrap();
        table += &format!("| {day} | rigid Haurwitz pattern (T{} grid) | | {} | | | |\n", REF.0, fmt(&e));
    }
    eprintln!(
        "\ntest 6 self-convergence, reference T{} ({} x {}, dt {} s), no diffusion; orders p = ln(e_prev / e) / ln(M / M_prev)\n\n{table}",
        REF.0,
        REF.1,
        2 * REF.1,
        REF.2
    );
    for (m, dt, (_, _, sec)) in &coarse {
        eprintln!("T{m} dt {dt} s: {sec:.1} s wall");
    }
    eprintln!("T{} dt {} s (reference): {rsec:.1} s wall; total {:.1} s", REF.0, REF.2, t_all.elapsed().as_secs_f64());
    println!(
        "ACCEPTANCE: williamson6_t170 measured=l2 {} bar=l1, l2, linf fall T21 > T42 > T63 at days 7 and 14",
        l2s.join(", ")
    );
    assert!(bar_ok, "errors do not decrease strictly T21 > T42 > T63 at day 7 and day 14 (see the table)");
}

#[test]
fn step_time_t21() {
    let dt = 1800.0;
    let mut model = ShallowWater::new(ModelParams::t21(dt)).unwrap();
    let init = williamson::test6_initial(model.grid(), &model.params().planet);
    model.set_state_from_winds(&init.u, &init.v, &init.phi).unwrap();
    model.set_tracer(&init.phi).unwrap();
    model.run(10);
    let n = 200;
    let t0 = Instant::now();
    model.run(n);
    let per = t0.elapsed().as_secs_f64() / n as f64;
    let profile = if cfg!(debug_assertions) { "dev profile (opt-level 1)" } else { "release" };
    eprintln!("T21 (32 x 64) step with tracer: {:.3} ms per step, {profile}, one thread", per * 1e3);
    assert!(model.height().iter().all(|h| h.is_finite()));
}

/// A forced-dissipative run as stand-in weather: relaxation toward a two-jet zonal equilibrium,
/// drag, del^4 hyperdiffusion, a 2 km Gaussian mountain and a relaxed tracer (a T850 stand-in).
fn forced_run(days: f64) {
    forced_run_cfg(days, ForcedCfg::default());
}

/// Equilibrium depth poleward of the jets `h0` (m), jump `2 dh` (m) across jets at +-40 degrees
/// of half-width `width` (degrees); relaxation, drag and hyperdiffusion times in days.
#[derive(Clone, Copy, Debug)]
struct ForcedCfg {
    h0: f64,
    dh: f64,
    width: f64,
    tau_r: f64,
    tau_drag: f64,
    tau_h: f64,
}

impl Default for ForcedCfg {
    /// Strong, fast relaxation toward sharp jets with weak drag: the jets are barotropically
    /// unstable and the flow stays unsteady (slower forcing, e.g. 10 days with 20-day drag,
    /// settles into a steady forced stationary wave at T21).
    fn default() -> Self {
        Self { h0: 8000.0, dh: 1000.0, width: 6.0, tau_r: 1.0, tau_drag: 100.0, tau_h: 2.0 }
    }
}

fn forced_run_cfg(days: f64, c: ForcedCfg) {
    let dt = 1200.0;
    let mut params = ModelParams::t21(dt);
    params.hyperdiffusion = Some(Hyperdiffusion { order: 2, tau: c.tau_h * DAY });
    params.drag = 1.0 / (c.tau_drag * DAY);
    let mut model = ShallowWater::new(params).unwrap();
    let grid = model.grid().clone();
    let g = model.params().planet.gravity;
    let lon = grid.lon_rad();
    let nl = grid.n_lon();
    let (phi0, width) = (40f64.to_radians(), c.width.to_radians());
    let mut hs = vec![0.0; grid.len()];
    let mut phi_eq = vec![0.0; grid.len()];
    let mut q_eq = vec![0.0; grid.len()];
    let (lat_c, lon_c) = (30f64.to_radians(), 90f64.to_radians());
    for p in 0..grid.len() {
        let (mu, l) = (grid.mu[p / nl], lon[p % nl]);
        let lat = mu.asin();
        // Great-circle distance to the mountain centre.
        let r = (lat_c.sin() * mu + lat_c.cos() * lat.cos() * (l - lon_c).cos()).clamp(-1.0, 1.0).acos();
        hs[p] = 2000.0 * (-(r / 0.35).powi(2)).exp();
        let h_eq = c.h0 + c.dh * (((lat + phi0) / width).tanh() - ((lat - phi0) / width).tanh());
        phi_eq[p] = g * (h_eq - hs[p]);
        q_eq[p] = 300.0 - 45.0 * mu * mu;
    }
    // Start at rest on the equilibrium with a small wave-3 bump to break the symmetry.
    let u0 = vec![0.0; grid.len()];
    let phi_init: Vec<f64> = (0..grid.len()).map(|p| phi_eq[p] + 50.0 * g * (3.0 * lon[p % nl]).cos()).collect();
    model.set_state_from_winds(&u0, &u0, &phi_init).unwrap();
    model.set_orography(&hs.iter().map(|h| g * h).collect::<Vec<_>>()).unwrap();
    model.set_relaxation(&phi_eq, c.tau_r * DAY).unwrap();
    model.set_tracer(&q_eq).unwrap();
    model.set_tracer_relaxation(&q_eq, 5.0 * DAY).unwrap();
    let steps_per_day = (DAY / dt).round() as usize;
    let mut umax_all: f64 = 0.0;
    let mut h_prev = model.height();
    for d in 1..=days as usize {
        model.run(steps_per_day);
        let hh = model.height();
        let change = (hh.iter().zip(&h_prev).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / hh.len() as f64).sqrt();
        h_prev = hh;
        let u = model.u();
        let v = model.v();
        let umax = u.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        let vmax = v.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        umax_all = umax_all.max(umax);
        let h = model.height();
        let q = model.tracer();
        assert!(h.iter().chain(&q).chain(&u).all(|x| x.is_finite()), "day {d}: non-finite");
        assert!(umax < 200.0, "day {d}: max |u| = {umax}");
        assert!(h.iter().all(|&x| x > 0.0), "day {d}: negative layer thickness");
        if d % 30 == 0 || d == days as usize {
            let (hmin, hmax) = h.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            let (qmin, qmax) = q.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            eprintln!(
                "forced T21 day {d:>3}: max|u| {umax:6.1} max|v| {vmax:5.1} m/s  h {hmin:7.1}..{hmax:7.1} m  q {qmin:6.1}..{qmax:6.1}  day-to-day rms dh {change:.2} m"
            );
        }
        if d == days as usize {
            // Stand-in weather must be weather: jets and waves that change from day to day.
            assert!(umax > 10.0 && vmax > 1.0, "umax {umax} vmax {vmax}");
            assert!(change > 1.0, "day-to-day rms height change {change} m: the flow is steady");
        }
    }
    eprintln!("forced T21 {days} days: max |u| over the run {umax_all:.1} m/s");
}

#[test]
fn forced_dissipative_t21_30_days() {
    forced_run(30.0);
}

#[test]
#[ignore = "one simulated year"]
fn forced_dissipative_t21_one_year() {
    forced_run(365.0);
}
