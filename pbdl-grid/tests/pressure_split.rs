//! The pressure split of a fluid step (what latent-space physics replaces on some steps):
//! `step == project_keep_pressure(step_unprojected)` to round-off, the kept pressure fed back
//! through `correct_with_pressure` gives the same velocity, the result is divergence-free, and
//! steppers that project more than once per step refuse the split with a typed error.

use candle_core::{DType, Device, Tensor};
use pbdl_grid::fluid::Advection;
use pbdl_grid::{fd, Boundaries, CenteredField, Fluid, FluidConfig, Grid, Obstacle, ScalarBoundaries};

fn plume(grid: Grid, obstacles: Vec<Obstacle>, nu: f64) -> Fluid {
    let cfg = FluidConfig {
        dt: 0.5,
        nu,
        advection: Advection::MacCormack,
        density_advection: Advection::MacCormack,
        buoyancy: Some(0.1),
        inflow: Some(Obstacle::Cylinder { center: [0.5 * grid.lx, 0.15 * grid.ly], radius: 0.1 * grid.lx }),
        obstacles,
    };
    Fluid::new(grid, Boundaries::lid_driven_cavity(0.0), Some(ScalarBoundaries::neumann()), cfg).unwrap()
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
}

#[test]
fn split_step_equals_the_step_and_the_kept_pressure_reproduces_the_projection() {
    let g = Grid::new(24, 32, 24.0, 32.0).unwrap();
    let rate = Tensor::new(&[1.0f64], &Device::Cpu).unwrap();
    for (obstacles, nu) in [(vec![], 0.0), (vec![Obstacle::Box { lo: [4.0, 14.0], hi: [10.0, 18.0] }], 0.05)] {
        let f = plume(g, obstacles, nu);
        let mut s = f.rest(2, DType::F64).unwrap();
        for _ in 0..12 {
            s = f.step(&s, Some(&rate)).unwrap();
        }
        let reference = f.step(&s, Some(&rate)).unwrap();
        let before = f.step_unprojected(&s, Some(&rate)).unwrap();
        let (projected, pressure) = f.project_keep_pressure(&before.velocity).unwrap();
        let scale = max_abs_diff(reference.velocity.values(), &reference.velocity.values().zeros_like().unwrap());
        assert!(scale > 1e-3, "the plume must move ({scale})");
        let d = max_abs_diff(projected.values(), reference.velocity.values());
        assert!(d <= 1e-12 * scale.max(1.0), "split step differs from the step by {d}");
        let rho = max_abs_diff(before.density.as_ref().unwrap().values(), reference.density.as_ref().unwrap().values());
        assert!(rho <= 1e-14, "density differs by {rho}");
        assert_eq!(pressure.values().dims(), [2, 1, 32, 24]);
        // The kept pressure, given back, makes the same correction without a solve.
        let corrected = f.correct_with_pressure(&before.velocity, &pressure).unwrap();
        let d = max_abs_diff(corrected.values(), reference.velocity.values());
        assert!(d <= 1e-12 * scale.max(1.0), "correction with the kept pressure differs by {d}");
        // Divergence-free, while the unprojected velocity is not.
        let div = |u: &pbdl_grid::MacField| {
            fd::divergence(u)
                .unwrap()
                .values()
                .abs()
                .unwrap()
                .flatten_all()
                .unwrap()
                .max(0)
                .unwrap()
                .to_scalar::<f64>()
                .unwrap()
        };
        assert!(div(&corrected) <= 1e-9, "{}", div(&corrected));
        assert!(div(&before.velocity) > 1e-4, "{}", div(&before.velocity));
        // A wrong pressure shape is a typed error naming the field.
        let bad = CenteredField::new(
            Tensor::zeros((1, 1, 32, 24), DType::F64, &Device::Cpu).unwrap(),
            g,
            Boundaries::lid_driven_cavity(0.0).pressure(),
        )
        .unwrap();
        let e = f.correct_with_pressure(&before.velocity, &bad).unwrap_err();
        assert!(e.to_string().contains("pressure"), "{e}");
    }
}

#[test]
fn steppers_with_several_projections_per_step_refuse_the_split() {
    let g = Grid::square(16, 16.0).unwrap();
    let central = FluidConfig { advection: Advection::CentralRk4, dt: 0.1, ..plume(g, vec![], 0.0).config().clone() };
    let f = Fluid::new(g, Boundaries::lid_driven_cavity(0.0), Some(ScalarBoundaries::neumann()), central).unwrap();
    let s = f.rest(1, DType::F64).unwrap();
    let e = f.step_unprojected(&s, None).unwrap_err();
    assert!(e.to_string().contains("more than once"), "{e}");
    assert!(f.project_keep_pressure(&s.velocity).is_err());
}
