//! Property tests (proptest) of the particle operators, on random particle sets and parameters:
//!
//! * neighbour search: the cell list finds exactly the brute-force pairs (1D/2D/3D, periodic or
//!   bounded per axis, any radius the list accepts), and the relation is symmetric;
//! * the minimum-image displacement is antisymmetric and at most half a period, and wrapping is
//!   idempotent and lands in the box;
//! * SPH kernels: `∫ W dV = 1` (a particle's splatted mass integrates to its mass), `W >= 0`,
//!   compact support, `dW/dr` matches the derivative of `W`, and `∇W` is antisymmetric;
//! * compressible 1D SPH in a periodic box: momentum is conserved to round-off for random
//!   (unequal) masses, positions, velocities and energies, and mass never changes.
//!
//! The proptest seed is fixed (deterministic CI) unless `PROPTEST_RNG_SEED` is set;
//! `PROPTEST_CASES` overrides the case counts.

use pbdl_particles::neighbors::{brute_force, CellList, Domain, NeighborList};
use pbdl_particles::{Kernel, KernelKind, Sph1d, Sph1dParams};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// `cases` random cases (or `PROPTEST_CASES`), a fixed seed (or `PROPTEST_RNG_SEED`), and no
/// regression files written into the source tree (a failure prints its minimal input).
fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_none() {
        c.cases = cases;
    }
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_0025);
    }
    c.failure_persistence = None;
    c
}

/// `n` points uniform in the box (periodic axes) or spilling 20% beyond it (bounded axes).
fn points<const D: usize>(n: usize, dom: &Domain<f64, D>, seed: u64) -> Vec<[f64; D]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            std::array::from_fn(|d| {
                let l = dom.hi[d] - dom.lo[d];
                let spill = if dom.periodic[d] { 0.0 } else { 0.2 };
                dom.lo[d] - spill * l + rng.random::<f64>() * l * (1.0 + 2.0 * spill)
            })
        })
        .collect()
}

/// Cell list vs brute force, and symmetry; `Err` names the first difference.
fn neighbours_case<const D: usize>(dom: Domain<f64, D>, radius: f64, n: usize, seed: u64) -> Result<(), String> {
    let mut cells = CellList::new(dom, radius).map_err(|e| e.to_string())?;
    let pos = points(n, &dom, seed);
    let mut nl = NeighborList::default();
    cells.neighbors(&pos, &mut nl).map_err(|e| e.to_string())?;
    nl.sort_rows();
    let reference = brute_force(&dom, radius, &pos);
    if nl != reference {
        let i = (0..n).find(|&i| nl.neighbors(i) != reference.neighbors(i)).unwrap_or(0);
        return Err(format!("particle {i}: cell list {:?}, brute force {:?}", nl.neighbors(i), reference.neighbors(i)));
    }
    for i in 0..nl.len() {
        for &j in nl.neighbors(i) {
            if !nl.neighbors(j as usize).contains(&(i as u32)) {
                return Err(format!("{j} is a neighbour of {i} but not the reverse"));
            }
        }
    }
    Ok(())
}

fn domain<const D: usize>(lo: [f64; D], ext: [f64; D], periodic: [bool; D]) -> Domain<f64, D> {
    Domain { lo, hi: std::array::from_fn(|d| lo[d] + ext[d]), periodic }
}

/// `∫ W dV` over the support by composite Simpson in `r` (radial shells in 2D/3D). The
/// integrand is a piecewise polynomial whose pieces meet at `q = 1, 2` with at least a
/// continuous first derivative, so with 6000 intervals the error is below ~1e-9.
fn kernel_integral(k: &Kernel<f64>) -> f64 {
    let m = 6000;
    let r_max = k.support();
    let h = r_max / m as f64;
    let shell = |r: f64| match k.dim() {
        1 => 2.0,
        2 => 2.0 * std::f64::consts::PI * r,
        _ => 4.0 * std::f64::consts::PI * r * r,
    };
    let f = |i: usize| {
        let r = i as f64 * h;
        shell(r) * k.w(r)
    };
    let mut s = f(0) + f(m);
    for i in 1..m {
        s += if i % 2 == 1 { 4.0 } else { 2.0 } * f(i);
    }
    s * h / 3.0
}

proptest! {
    #![proptest_config(config(48))]

    /// The cell list equals brute force and is symmetric, 1D/2D/3D, random periodicity per axis.
    #[test]
    fn cell_list_matches_brute_force(
        lo in prop::array::uniform3(-2.0f64..2.0), ext in prop::array::uniform3(0.5f64..3.0),
        per in prop::array::uniform3(any::<bool>()), radius in 0.05f64..1.5, n in 1usize..120,
        dims in 1usize..4, s in any::<u64>(),
    ) {
        // The cell list refuses a periodic axis shorter than 2 radius (ambiguous minimum image).
        let radius = (0..dims).filter(|&d| per[d]).fold(radius, |r, d| r.min(0.49 * ext[d]));
        let r = match dims {
            1 => neighbours_case(domain([lo[0]], [ext[0]], [per[0]]), radius, n, s),
            2 => neighbours_case(domain([lo[0], lo[1]], [ext[0], ext[1]], [per[0], per[1]]), radius, n, s),
            _ => neighbours_case(domain(lo, ext, per), radius, n, s),
        };
        prop_assert!(r.is_ok(), "{dims}D radius {radius}, {n} particles: {}", r.unwrap_err());
    }

    /// Minimum image: `d(a, b) = -d(b, a)` exactly, `|d| <= L/2` on periodic axes; `wrap` lands in
    /// `[lo, hi)` and is idempotent.
    #[test]
    fn displacement_and_wrap(
        lo in prop::array::uniform3(-2.0f64..2.0), ext in prop::array::uniform3(0.5f64..3.0),
        per in prop::array::uniform3(any::<bool>()), a in prop::array::uniform3(-10.0f64..10.0),
        b in prop::array::uniform3(0.0f64..1.0),
    ) {
        let dom = domain(lo, ext, per);
        let wa = dom.wrap(a);
        prop_assert_eq!(dom.wrap(wa), wa, "wrap is not idempotent");
        let pb: [f64; 3] = std::array::from_fn(|d| lo[d] + b[d] * ext[d]);
        let (dab, dba) = (dom.displacement(&wa, &pb), dom.displacement(&pb, &wa));
        for d in 0..3 {
            if per[d] {
                let (w, lo, hi) = (wa[d], dom.lo[d], dom.hi[d]);
                prop_assert!(w >= lo && w < hi, "wrap {w} outside [{lo}, {hi})");
                // Half a period, plus one rounding of the subtraction.
                let (len, half) = (dab[d].abs(), 0.5 * ext[d]);
                prop_assert!(len <= half * (1.0 + 1e-15), "|d| = {len} > L/2 = {half}");
            } else {
                prop_assert_eq!(wa[d], a[d], "a bounded axis was wrapped");
            }
            prop_assert_eq!(dab[d], -dba[d], "displacement not antisymmetric on axis {}", d);
        }
    }

    /// Every kernel, dimension and smoothing length: unit integral (1e-7: Simpson error ~1e-9,
    /// with margin for h spanning 4 decades), `W >= 0`, `W = 0` beyond the support, `dW/dr` equal
    /// to a central difference of `W` (1e-5 relative to the kernel scale `W(0)/h`: the step is
    /// 1e-6 h, well inside one polynomial piece away from the knots), `∇W(-d) = -∇W(d)`.
    #[test]
    fn kernels_are_normalised_positive_and_consistent(
        kind in 0usize..6, dim in 1usize..4, h in 1e-2f64..1e2, q in 0.0f64..3.5,
        dir in prop::array::uniform3(-1.0f64..1.0),
    ) {
        let kind = KernelKind::ALL[kind];
        let k = Kernel::new(kind, dim, h).unwrap();
        let i = kernel_integral(&k);
        prop_assert!((i - 1.0).abs() < 1e-7, "{kind:?} {dim}D h {h}: integral {i}");
        let r = q * h;
        prop_assert!(k.w(r) >= 0.0, "{kind:?}: W({r}) = {}", k.w(r));
        if r >= k.support() {
            prop_assert_eq!(k.w(r), 0.0);
            prop_assert_eq!(k.dw_dr(r), 0.0);
        }
        // Away from the knots (q = 1, 2, 3) and from 0, where the spiky kernel has a kink.
        let near_knot = [0.0, 1.0, 2.0, 3.0].iter().any(|&c| (q - c).abs() < 1e-3);
        if !near_knot {
            let e = 1e-6 * h;
            let fd = (k.w(r + e) - k.w(r - e)) / (2.0 * e);
            let scale = k.w(0.0) / h;
            prop_assert!((fd - k.dw_dr(r)).abs() < 1e-5 * scale, "{kind:?} {dim}D q {q}: dW/dr {} vs {fd}", k.dw_dr(r));
        }
        let d: [f64; 3] = dir.map(|x| x * h);
        let (g, gm) = (k.grad(d), k.grad(d.map(|x| -x)));
        for a in 0..3 {
            prop_assert_eq!(g[a], -gm[a], "grad not antisymmetric");
        }
    }
}

proptest! {
    #![proptest_config(config(24))]

    /// Periodic 1D SPH with random unequal masses, jittered positions, random velocities and
    /// energies, 20 adaptive steps: total momentum changes by at most 1e-12 of `sum m |v|`
    /// (pairwise forces are exactly antisymmetric; what remains is the round-off of summing
    /// ~n^2 pair terms), and total mass is bit-for-bit unchanged.
    #[test]
    fn periodic_sph1d_conserves_momentum_and_mass(
        n in 16usize..64, l in 0.5f64..4.0, jitter in 0.0f64..0.3, s in any::<u64>(),
    ) {
        let mut rng = StdRng::seed_from_u64(s);
        let dx = l / n as f64;
        let x: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5 + jitter * (rng.random::<f64>() - 0.5)) * dx).collect();
        let v: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
        let u: Vec<f64> = (0..n).map(|_| 1.0 + rng.random::<f64>()).collect();
        let m: Vec<f64> = (0..n).map(|_| dx * (0.5 + rng.random::<f64>())).collect();
        let mut sim = Sph1d::new(Sph1dParams::default(), x, v, u, m, None, n, Domain::periodic([0.0], [l])).unwrap();
        let (p0, mass0, scale) = (sim.momentum(), sim.total_mass(), sim.momentum_scale());
        for _ in 0..20 {
            let dt = sim.stable_dt();
            sim.step(dt).unwrap();
        }
        let drift = (sim.momentum() - p0).abs() / scale;
        prop_assert!(drift <= 1e-12, "momentum drift {drift:e} after {} steps", sim.steps());
        prop_assert_eq!(sim.total_mass(), mass0);
    }
}
