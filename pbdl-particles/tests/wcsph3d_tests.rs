//! 3D WCSPH: physics sanity at coarse resolution (fast, default), typed errors, and the README's
//! bar 3D1 (`#[ignore]`d, release): the 3D dam-break front within 0..+10% of Martin & Moyce for
//! T in [1, 2.5] at dx = a/20, and the run to T = 10 with 0 leaked particles.

use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::wcsph3d::{BlockDrop3d, DamBreak3d, FluidBody3d, Shape3d, Tank3d, Wcsph3dParams};
use pbdl_particles::{Error, Evolve};

/// A coarse column (dx = a/8, 512 fluid particles) for the fast tests. NOT the acceptance
/// resolution: the bar 3D1 is checked at dx = a/20 by the ignored test below.
fn coarse() -> DamBreak3d {
    DamBreak3d { dx: 0.125, ..DamBreak3d::default() }
}

#[test]
fn coarse_dam_break_sanity_not_the_acceptance_bar() {
    let scene = coarse();
    let mut sim = scene.build(Wcsph3dParams::default()).unwrap();
    let n = sim.n_fluid();
    assert_eq!(n, 8 * 16 * 4);
    // Mass: equal-mass particles on the lattice, exactly rho0 times the column's volume.
    let volume = scene.a * 2.0 * scene.a * scene.depth * scene.a;
    assert!((sim.fluid_mass() / (scene.rho0 * volume) - 1.0).abs() < 1e-12);
    let x0 = sim.front();
    let mut last = x0;
    let mut max_dens = 0.0f64;
    for k in 1..=20 {
        sim.run_until(scene.physical_time(0.1 * k as f64)).unwrap();
        assert!(sim.is_finite(), "not finite at T = {}", 0.1 * k as f64);
        assert_eq!(sim.leaked(), 0, "leak at T = {}", 0.1 * k as f64);
        // The front never runs backwards by more than a particle spacing.
        assert!(sim.front() > last - scene.dx * scene.a, "front receded at T = {}", 0.1 * k as f64);
        last = last.max(sim.front());
        max_dens = max_dens.max(sim.mean_density_error());
    }
    let z = sim.front() / scene.a;
    // Physical sanity only: the surge has moved well to the right but not past Ritter's
    // shallow-water bound Z = 1 + 2T.
    assert!(z > 1.8 && z < 1.0 + 2.0 * 2.0, "Z(T = 2) = {z}");
    assert!(max_dens < 0.02, "mean density error {max_dens}");
    // The side walls are symmetric: no net momentum across the depth.
    let m = sim.momentum();
    assert!(m[2].abs() < 1e-6 * (m[0].abs() + m[1].abs() + 1.0), "momentum {m:?}");
    assert_eq!(sim.n_fluid(), n);
}

#[test]
fn f32_dam_break_runs() {
    let scene = coarse();
    let mut sim = scene.build_as::<f32>(Wcsph3dParams::default()).unwrap();
    sim.run_until(scene.physical_time(0.3)).unwrap();
    assert!(sim.is_finite() && sim.leaked() == 0);
    let mut sim64 = scene.build(Wcsph3dParams::default()).unwrap();
    sim64.run_until(scene.physical_time(0.3)).unwrap();
    assert!((sim.front() - sim64.front()).abs() < 0.05 * scene.a, "{} vs {}", sim.front(), sim64.front());
}

#[test]
fn free_falling_block_keeps_momentum_balance() {
    // A block in the air: internal forces cancel pairwise, so the momentum changes by M g t
    // only, and the block falls as a rigid body (until it reaches the floor).
    let scene = BlockDrop3d {
        box_size: [1.0, 1.2, 0.8],
        dx: 0.1,
        bodies: vec![FluidBody3d {
            shape: Shape3d::Block { lo: [0.2, 0.6, 0.2], hi: [0.6, 1.0, 0.6] },
            velocity: [0.5, 0.0, 0.0],
        }],
        ..BlockDrop3d::default()
    };
    let mut sim = scene.build(Wcsph3dParams::default()).unwrap();
    assert_eq!(sim.n_fluid(), 64);
    let t = 0.1;
    sim.run_until(t).unwrap();
    let m = sim.momentum();
    let mass = sim.fluid_mass();
    assert!((m[0] / mass - 0.5).abs() < 1e-9, "{m:?}");
    assert!((m[1] / mass + scene.g * t).abs() < 1e-9, "{m:?}");
    assert!(m[2].abs() < 1e-9 * mass);
    assert!(sim.operators().contains(&"wall_pressure_extrapolation"));
}

#[test]
fn drops_into_a_box_stay_inside() {
    let scene = BlockDrop3d {
        box_size: [0.6, 0.8, 0.6],
        dx: 0.1,
        bodies: vec![
            FluidBody3d { shape: Shape3d::Block { lo: [0.0, 0.0, 0.0], hi: [0.6, 0.2, 0.6] }, velocity: [0.0; 3] },
            FluidBody3d {
                shape: Shape3d::Sphere { center: [0.3, 0.55, 0.3], radius: 0.2 },
                velocity: [0.3, -1.0, 0.2],
            },
        ],
        ..BlockDrop3d::default()
    };
    let mut sim = scene.build(Wcsph3dParams::default()).unwrap();
    for k in 1..=10 {
        sim.run_until(0.05 * k as f64).unwrap();
        assert!(sim.is_finite());
        assert_eq!(sim.leaked(), 0, "t = {}", 0.05 * k as f64);
    }
    assert!(sim.mean_density_error() < 0.05);
}

#[test]
fn tank_boundary_normals_are_unit_and_point_inside() {
    let tank = Tank3d::new([0.6, 0.4, 0.3], 0.1, 3).unwrap();
    let (pos, nrm) = tank.boundary_with_normals();
    let size = tank.size();
    // The innermost layer around a 6x4x3 box: (8*6*5) - (6*4*3) cells.
    assert_eq!(pos.len(), 8 * 6 * 5 - 6 * 4 * 3);
    for (p, n) in pos.iter().zip(&nrm) {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-12);
        for d in 0..3 {
            let outside_low = p[d] < 0.0;
            let outside_high = p[d] > size[d];
            assert_eq!(n[d] > 0.0, outside_low, "{p:?} {n:?}");
            assert_eq!(n[d] < 0.0, outside_high, "{p:?} {n:?}");
        }
        // One spacing along the normal lands inside (or on) the box.
        let q: Vec<f64> = (0..3).map(|d| p[d] + n[d] * 0.1).collect();
        assert!((0..3).all(|d| q[d] > -1e-9 && q[d] < size[d] + 1e-9), "{p:?} {n:?}");
    }
    assert_eq!(tank.wall_particles().len(), 12 * 10 * 9 - 6 * 4 * 3);
}

#[test]
fn bad_input_gives_typed_errors() {
    let p = Wcsph3dParams::default();
    let bad = |r: Result<_, Error>, field: &str| match r {
        Err(Error::Invalid { field: f, .. }) => assert_eq!(f, field),
        Err(e) => panic!("{field}: unexpected {e}"),
        Ok(_) => panic!("{field}: accepted"),
    };
    bad(DamBreak3d { dx: -1.0, ..coarse() }.build(p).map(|_| ()), "dx");
    bad(DamBreak3d { depth: f64::NAN, ..coarse() }.build(p).map(|_| ()), "depth");
    bad(DamBreak3d { tank_width: 0.5, ..coarse() }.build(p).map(|_| ()), "tank_width");
    bad(DamBreak3d { dx: 0.5, ..coarse() }.build(p).map(|_| ()), "dx");
    bad(coarse().build(Wcsph3dParams { h_over_dx: 0.1, ..p }).map(|_| ()), "h_over_dx");
    bad(coarse().build(Wcsph3dParams { cfl: 0.0, ..p }).map(|_| ()), "cfl");
    bad(coarse().build(Wcsph3dParams { alpha: -1.0, ..p }).map(|_| ()), "alpha");
    bad(BlockDrop3d { bodies: vec![], ..BlockDrop3d::default() }.build(p).map(|_| ()), "bodies");
    let outside = FluidBody3d { shape: Shape3d::Sphere { center: [0.9, 0.5, 0.5], radius: 0.3 }, velocity: [0.0; 3] };
    bad(BlockDrop3d { bodies: vec![outside], ..BlockDrop3d::default() }.build(p).map(|_| ()), "bodies");
    let nan_v = FluidBody3d { velocity: [f64::NAN, 0.0, 0.0], ..BlockDrop3d::default().bodies[0] };
    bad(BlockDrop3d { bodies: vec![nan_v], ..BlockDrop3d::default() }.build(p).map(|_| ()), "bodies");
    bad(BlockDrop3d { box_size: [1.0, 0.0, 1.0], ..BlockDrop3d::default() }.build(p).map(|_| ()), "box_size");
    bad(BlockDrop3d { dx: 1e-6, ..BlockDrop3d::default() }.build(p).map(|_| ()), "dx");
    // A step beyond the stable limit is refused and leaves the state alone.
    let mut sim = coarse().build(p).unwrap();
    let (limit, _) = sim.stable_dt();
    let before = sim.x.clone();
    assert!(matches!(sim.step(2.0 * limit), Err(Error::UnstableTimeStep { .. })));
    assert!(matches!(sim.step(f64::NAN), Err(Error::UnstableTimeStep { .. })));
    assert_eq!(sim.x, before);
    assert_eq!(sim.steps(), 0);
}

#[test]
fn operators_follow_the_parameters() {
    let sim = coarse().build(Wcsph3dParams { alpha: 0.0, delta: 0.0, ..Wcsph3dParams::default() }).unwrap();
    assert_eq!(
        sim.operators(),
        vec!["tait_eos", "pressure_gradient", "continuity", "gravity", "wall_pressure_extrapolation"]
    );
    let sim = coarse().build(Wcsph3dParams::default()).unwrap();
    assert_eq!(sim.operators().len(), 7);
}

/// Martin & Moyce (1952) points with T in [1, 2.5].
fn mm_points() -> Vec<(f64, f64)> {
    martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)).collect()
}

/// Bar 3D1 (README "Round 2 bars"): the 3D dam-break front at dx = a/20 with the parameter set
/// fixed in `wcsph3d`'s docs lies within 0..+10% of Martin & Moyce for T in [1, 2.5].
/// `cargo test --release -p pbdl-particles --test wcsph3d_tests -- --ignored --nocapture dam_break_3d_front`
#[test]
#[ignore = "bar 3D1, NOT met: +10.5% at T = 1.212, -2.6% at T = 2.283 (release, ~80 s)"]
fn dam_break_3d_front_within_band_of_martin_moyce() {
    let scene = DamBreak3d::default();
    let mut sim = scene.build(Wcsph3dParams::default()).unwrap();
    let t0 = std::time::Instant::now();
    println!(
        "3D dam break, dx = a/20, depth {}a: {} fluid + {} wall particles",
        scene.depth,
        sim.n_fluid(),
        sim.x.len() - sim.n_fluid()
    );
    println!("| T | Z measured | Z Martin & Moyce | deviation |");
    println!("|---|---|---|---|");
    let mut worst: Vec<String> = Vec::new();
    let mut devs: Vec<String> = Vec::new();
    for (tm, zm) in mm_points() {
        sim.run_until(scene.physical_time(tm)).unwrap();
        let z = sim.front() / scene.a;
        let dev = z / zm - 1.0;
        println!("| {tm:.3} | {z:.3} | {zm:.3} | {:+.1}% |", 100.0 * dev);
        devs.push(format!("{:+.1}%", 100.0 * dev));
        if !(0.0..=0.10).contains(&dev) {
            worst.push(format!("T = {tm}: {:+.1}%", 100.0 * dev));
        }
    }
    println!("{} steps in {:.1} s, {} leaked", sim.steps(), t0.elapsed().as_secs_f64(), sim.leaked());
    println!(
        "ACCEPTANCE: wcsph3d_dam_break_front measured=Z/Z_MM - 1 = {} at T = {:?} bar=each in 0..+10%",
        devs.join(", "),
        mm_points().iter().map(|p| p.0).collect::<Vec<_>>()
    );
    assert_eq!(sim.leaked(), 0);
    assert!(worst.is_empty(), "outside 0..+10%: {}", worst.join("; "));
}

/// Bar 3D1, second half: the 3D dam break at dx = a/20 to T = 10 stays finite with 0 leaked
/// particles, checked every 0.1 T.
/// `cargo test --release -p pbdl-particles --test wcsph3d_tests -- --ignored --nocapture dam_break_3d_to_t10`
#[test]
#[ignore = "bar 3D1 second half, met (release, ~3-5 min)"]
fn dam_break_3d_to_t10_leaks_no_particle() {
    let scene = DamBreak3d::default();
    let mut sim = scene.build(Wcsph3dParams::default()).unwrap();
    let t0 = std::time::Instant::now();
    let mut max_dens = 0.0f64;
    let (mut first_leak, mut max_leaked) = (None, 0usize);
    for k in 1..=100 {
        let big_t = 0.1 * k as f64;
        sim.run_until(scene.physical_time(big_t)).unwrap();
        assert!(sim.is_finite(), "not finite at T = {big_t}");
        if sim.leaked() > 0 {
            first_leak.get_or_insert(big_t);
        }
        max_leaked = max_leaked.max(sim.leaked());
        max_dens = max_dens.max(sim.mean_density_error());
    }
    println!(
        "ACCEPTANCE: wcsph3d_dam_break_t10 measured={max_leaked} leaked (first at T = {first_leak:?}), finite, max mean density error {max_dens:.4} bar=0 leaked to T = 10, finite"
    );
    assert_eq!(max_leaked, 0, "leaked particles, first at T = {first_leak:?}");
    println!(
        "T = 10: {} steps in {:.1} s, max mean density error {:.4}",
        sim.steps(),
        t0.elapsed().as_secs_f64(),
        max_dens
    );
}
