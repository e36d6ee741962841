//! Smoke plume: the built stepper lists only its operators; buoyancy's gradient matches finite
//! differences; the gradient of a loss after 20 plume steps with respect to the initial density
//! and the inflow rate matches finite differences to 1e-4 (f64); the plume rises, stays bounded
//! and divergence-free.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::fluid::Advection;
use pbdl_grid::forcing::buoyancy;
use pbdl_grid::{
    fd, Bc, Boundaries, CenteredField, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle, ScalarBc,
    ScalarBoundaries,
};

fn plume(grid: Grid, advection: Advection, obstacles: Vec<Obstacle>) -> Fluid {
    let cfg = FluidConfig {
        dt: 0.5,
        nu: 0.0,
        advection,
        density_advection: advection,
        buoyancy: Some(0.1),
        inflow: Some(Obstacle::Cylinder { center: [0.5 * grid.lx, 0.15 * grid.ly], radius: 0.1 * grid.lx }),
        obstacles,
    };
    Fluid::new(grid, Boundaries::lid_driven_cavity(0.0), Some(ScalarBoundaries::neumann()), cfg).unwrap()
}

#[test]
fn built_steppers_hold_only_the_operators_they_need() {
    let g = Grid::square(16, 16.0).unwrap();
    let p = plume(g, Advection::MacCormack, vec![]);
    assert_eq!(
        p.operators(),
        [
            "advect.mac_cormack(density)",
            "source.inflow",
            "advect.mac_cormack(velocity)",
            "buoyancy",
            "pressure.sparse_cholesky"
        ]
    );
    assert!(!p.operators().iter().any(|o| o.starts_with("diffuse") || *o == "obstacles"));
    assert_eq!(p.stable_time_step([10.0, 10.0]), f64::INFINITY);
    // Central flux form + RK4: explicit viscosity inside the RK stages, a finite stable step,
    // and a step beyond it is refused with a typed error.
    let central = FluidConfig { dt: 5.0, nu: 0.01, advection: Advection::CentralRk4, ..p.config().clone() };
    let c = Fluid::new(g, Boundaries::lid_driven_cavity(0.0), Some(ScalarBoundaries::neumann()), central).unwrap();
    assert_eq!(
        c.operators(),
        [
            "advect.mac_cormack(density)",
            "source.inflow",
            "advect.flux_form(velocity)",
            "buoyancy",
            "diffuse.explicit",
            "pressure.sparse_cholesky",
            "time_stepping.rk4"
        ]
    );
    assert!(c.stable_time_step([1.0, 1.0]).is_finite());
    let mut s = c.rest(1, DType::F64).unwrap();
    s.velocity = MacField::from_fn(g, Boundaries::lid_driven_cavity(0.0), DType::F64, |_, _| [1.0, 1.0]).unwrap();
    let e = c.step(&s, Some(&Tensor::new(&[1.0f64], &Device::Cpu).unwrap())).unwrap_err();
    assert!(matches!(e, pbdl_grid::Error::Unstable { .. }), "{e}");
    // No density: no density advection, no buoyancy, no inflow; obstacles and viscosity on.
    let cfg = FluidConfig {
        dt: 0.1,
        nu: 0.01,
        advection: Advection::SemiLagrangian,
        density_advection: Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles: vec![Obstacle::Box { lo: [6.0, 6.0], hi: [9.0, 9.0] }],
    };
    let f = Fluid::new(g, Boundaries::periodic(), None, cfg.clone()).unwrap();
    assert_eq!(
        f.operators(),
        ["advect.semi_lagrangian(velocity)", "diffuse.implicit", "obstacles", "pressure.masked_cholesky"]
    );
    // Buoyancy without density is refused with the field named.
    let e = Fluid::new(g, Boundaries::periodic(), None, FluidConfig { buoyancy: Some(1.0), ..cfg }).unwrap_err();
    assert!(e.to_string().contains("density"), "{e}");
}

#[test]
fn buoyancy_gradient_matches_finite_differences() {
    let g = Grid::new(7, 6, 1.4, 1.0).unwrap();
    let sbcs = [
        ScalarBoundaries::neumann(),
        ScalarBoundaries::periodic(),
        ScalarBoundaries {
            x_lo: ScalarBc::Neumann,
            x_hi: ScalarBc::Neumann,
            y_lo: ScalarBc::Dirichlet { value: 0.3 },
            y_hi: ScalarBc::Dirichlet { value: 1.0 },
        },
    ];
    let vbcs = [
        Boundaries::lid_driven_cavity(0.0),
        Boundaries::periodic(),
        Boundaries::new(Bc::FreeSlip, Bc::FreeSlip, Bc::Inflow { velocity: [0.0, 1.0] }, Bc::Outflow).unwrap(),
    ];
    for (k, (sbc, vbc)) in sbcs.into_iter().zip(vbcs).enumerate() {
        let x = seed::randn((2, 1, 6, 7), 0.0, 1.0, DType::F64, &Device::Cpu, 500 + k as u64).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(buoyancy(&CenteredField::new(xs[0].clone(), g, sbc)?, &vbc, 0.7)?.into_values())
        };
        let r = check_grad(f, &[x], &GradCheckOptions { max_probes: 84, ..Default::default() }).unwrap();
        eprintln!("buoyancy {:?}: {:.2e}", sbc.y_lo, r.max_rel_error);
        r.ensure(1e-6).unwrap();
    }
}

/// Loss after 20 steps of a 12x12 plume (f64): weighted density plus kinetic energy. Measured
/// relative errors are printed (analytic vs central differences, eps 1e-6).
#[test]
fn gradient_through_20_plume_steps_matches_finite_differences() {
    let g = Grid::square(12, 12.0).unwrap();
    for (advection, obstacles) in [
        (Advection::MacCormack, vec![]),
        (Advection::SemiLagrangian, vec![Obstacle::Box { lo: [4.0, 7.0], hi: [7.0, 8.0] }]),
    ] {
        let fluid = plume(g, advection, obstacles);
        let rho0 = seed::rand_uniform((1, 1, 12, 12), 0.0, 0.5, DType::F64, &Device::Cpu, 11).unwrap();
        let rate = Tensor::new(&[0.8f64], &Device::Cpu).unwrap();
        let w = seed::rand_uniform((1, 1, 12, 12), -1.0, 1.0, DType::F64, &Device::Cpu, 12).unwrap();
        let loss = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            let mut s = FluidState {
                velocity: MacField::zeros(g, Boundaries::lid_driven_cavity(0.0), 1, DType::F64)?,
                density: Some(CenteredField::new(xs[0].clone(), g, ScalarBoundaries::neumann())?),
            };
            for _ in 0..20 {
                s = fluid.step(&s, Some(&xs[1]))?;
            }
            let rho = s.density.expect("density").into_values();
            let ke = s.velocity.values().sqr()?.sum_all()?;
            (rho.mul(&w)?.sum_all()? + ke)?.reshape(1)
        };
        let r = check_grad(loss, &[rho0, rate], &GradCheckOptions { max_probes: 24, ..Default::default() }).unwrap();
        eprintln!(
            "20 plume steps {advection:?}: rel error initial density {:.2e}, inflow rate {:.2e} (worst {:?})",
            r.per_input[0], r.per_input[1], r.worst
        );
        r.ensure(1e-4).unwrap_or_else(|e| panic!("{advection:?}: {e}"));
    }
}

/// 60 steps of a 32x48 plume (f32): the density's centre of mass rises, the density stays
/// within [0, injected maximum] up to round-off (limited MacCormack), and the velocity stays
/// divergence-free.
#[test]
fn plume_rises_and_stays_bounded() {
    let g = Grid::new(32, 48, 32.0, 48.0).unwrap();
    let fluid = plume(g, Advection::MacCormack, vec![]);
    let mut s = fluid.rest(1, DType::F32).unwrap();
    let rate = Tensor::new(&[1.0f32], &Device::Cpu).unwrap();
    let centre_y = |s: &FluidState| {
        let rho = s
            .density
            .as_ref()
            .unwrap()
            .values()
            .to_dtype(DType::F64)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f64>()
            .unwrap();
        let (mut m, mut my) = (0.0, 0.0);
        for (k, r) in rho.iter().enumerate() {
            m += r;
            my += r * ((k / 32) as f64 + 0.5);
        }
        my / m
    };
    let mut y = Vec::new();
    for step in 0..60 {
        s = fluid.step(&s, Some(&rate)).unwrap();
        if step % 20 == 19 {
            y.push(centre_y(&s));
        }
    }
    let rho = s.density.as_ref().unwrap().values();
    let (mn, mx) =
        (rho.min_all().unwrap().to_scalar::<f32>().unwrap(), rho.max_all().unwrap().to_scalar::<f32>().unwrap());
    let div = fd::divergence(&s.velocity)
        .unwrap()
        .into_values()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    let umax = s.velocity.max_abs().unwrap();
    eprintln!("plume: centre of mass y {y:.2?}, density [{mn:.3e}, {mx:.3}], max|u| {umax:.3}, max|div u| dx/|u| {:.2e}, CFL {:.2}", div as f64 / umax, fluid.cfl(&s).unwrap());
    assert!(y[0] < y[1] && y[1] < y[2], "plume does not rise: {y:?}");
    assert!(mn > -1e-5, "negative density {mn}");
    assert!(umax > 0.1 && umax.is_finite(), "no buoyant flow: {umax}");
    assert!((div as f64) / umax < 1e-4, "divergence {div}");
}

/// Gradient through three steps of an obstacle flow with a velocity source (central flux form
/// + RK4 and MacCormack), with respect to the initial velocity and the source strength.
#[test]
fn obstacle_flow_gradient_matches_finite_differences() {
    use pbdl_grid::forcing::VelocitySource;
    let g = Grid::new(10, 8, 1.25, 1.0).unwrap();
    let bc = Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::NoSlip, Bc::FreeSlip).unwrap();
    for advection in [Advection::CentralRk4, Advection::MacCormack] {
        let cfg = FluidConfig {
            dt: 0.02,
            nu: 0.01,
            advection,
            density_advection: Advection::MacCormack,
            buoyancy: None,
            inflow: None,
            obstacles: vec![Obstacle::Cylinder { center: [0.5, 0.45], radius: 0.16 }],
        };
        let src = VelocitySource::new(g, &bc, Obstacle::Box { lo: [0.0, 0.0], hi: [0.2, 1.0] }, |_, y| {
            [4.0 * y * (1.0 - y), 0.0]
        })
        .unwrap();
        let fluid = Fluid::new(g, bc, None, cfg).unwrap().with_velocity_source(src);
        let u0 = seed::randn((1, 2, 8, 10), 0.0, 0.5, DType::F64, &Device::Cpu, 21).unwrap();
        let strength = Tensor::new(&[1.3f64], &Device::Cpu).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            let mut s = FluidState { velocity: MacField::new(xs[0].clone(), g, bc)?, density: None };
            for _ in 0..3 {
                // The strength enters through the source applied to the state before the step.
                let src = VelocitySource::new(g, &bc, Obstacle::Box { lo: [0.0, 0.0], hi: [0.2, 1.0] }, |_, y| {
                    [4.0 * y * (1.0 - y), 0.0]
                })?;
                s.velocity = src.apply(&s.velocity, Some(&xs[1]))?;
                s = fluid.step(&s, None)?;
            }
            Ok(s.velocity.into_values())
        };
        let r = check_grad(f, &[u0, strength], &GradCheckOptions { max_probes: 48, ..Default::default() }).unwrap();
        eprintln!("obstacle flow {advection:?}: rel errors {:?}", r.per_input);
        r.ensure(1e-6).unwrap_or_else(|e| panic!("{advection:?}: {e}"));
    }
}
