//! 2D smoke shape-transition control (Holl et al. 2020): gradients through the solver against
//! finite differences, mass conservation, typed errors, and (ignored) the acceptance run.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::nn::Activation;
use pbdl_sol::smoke_control::*;
use pbdl_sol::Error;
use std::time::Instant;

const FD_REL_TOL: f64 = 1e-4;

fn dev() -> Device {
    Device::Cpu
}

fn scalar(t: &Tensor) -> f64 {
    t.to_dtype(DType::F64).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap()
}

/// Central difference of `loss` along the single entry `at` of `var` (flat index).
fn central_difference(var: &Var, at: usize, eps: f64, loss: &dyn Fn() -> f64) -> f64 {
    let x0 = var.as_tensor().copy().unwrap();
    let n = x0.elem_count();
    let mut e = vec![0.0f64; n];
    e[at] = eps;
    let dir = Tensor::from_vec(e, x0.shape(), &dev()).unwrap();
    var.set(&(&x0 + &dir).unwrap()).unwrap();
    let lp = loss();
    var.set(&(&x0 - &dir).unwrap()).unwrap();
    let lm = loss();
    var.set(&x0).unwrap();
    (lp - lm) / (2.0 * eps)
}

fn entry(g: &Tensor, at: usize) -> f64 {
    g.flatten_all().unwrap().to_vec1::<f64>().unwrap()[at]
}

fn tiny() -> SmokeControlConfig {
    SmokeControlConfig { cells: 8, steps: 4, loss_levels: 2, ..Default::default() }
}

/// Random forces of magnitude `amp` (seeded), `[batch, 2, n, n]` each.
fn random_forces(p: &SmokeControlConfig, batch: usize, amp: f64, seed: u64) -> Vec<Tensor> {
    (0..p.steps)
        .map(|t| {
            pbdl_core::seed::rand_uniform(&[batch, 2, p.cells, p.cells], -amp, amp, DType::F64, &dev(), seed + t as u64)
                .unwrap()
        })
        .collect()
}

#[test]
fn gradient_wrt_force_entries_through_all_steps_matches_finite_differences() {
    let p = tiny();
    let physics = SmokePhysics::new(&p, DType::F64, &dev()).unwrap();
    println!("operators: {:?}", physics.operators());
    let s = scene::generate(&p, 3, 0..2, DType::F64, &dev()).unwrap();
    let vars: Vec<Var> = random_forces(&p, 2, 0.3, 11).iter().map(|f| Var::from_tensor(f).unwrap()).collect::<Vec<_>>();
    let s0 = physics.rest(&s.initial).unwrap();
    let loss_t = || {
        let f: Vec<Tensor> = vars.iter().map(|v| physics.mask_force(v.as_tensor()).unwrap()).collect();
        let states = physics.rollout(&s0, &f).unwrap();
        loss::objective(&f, &states[p.steps].density, &s.target, p.loss_levels, p.effort_weight)
            .unwrap()
            .sum_all()
            .unwrap()
    };
    let grads = loss_t().backward().unwrap();
    let n = p.cells;
    // (step, flat index): u and v faces near the blobs, in both scenes, early and late steps.
    let picks = [
        (0, 3 * n + 3),
        (0, n * n + 4 * n + 2),
        (1, 2 * n * n + 5 * n + 4),
        (2, 2 * n * n + n * n + 3 * n + 5),
        (3, 4 * n + 4),
    ];
    for (t, at) in picks {
        let ad = entry(grads.get(&vars[t]).unwrap(), at);
        let fd = central_difference(&vars[t], at, 1e-6, &|| scalar(&loss_t()));
        let rel = (ad - fd).abs() / ad.abs().max(1e-8);
        println!("F_{t}[{at}]: autodiff {ad:.10e} fd {fd:.10e} rel {rel:.2e}");
        assert!(ad.abs() > 1e-8, "F_{t}[{at}]: gradient vanishes ({ad:e}); pick an entry the loss depends on");
        assert!(rel < FD_REL_TOL, "F_{t}[{at}]: autodiff {ad:e} vs fd {fd:e} (rel {rel:e})");
    }
    // A wall face is masked out: no gradient.
    let wall = n - 1;
    assert_eq!(entry(grads.get(&vars[0]).unwrap(), wall), 0.0);
}

#[test]
fn gradient_wrt_network_weights_through_the_controlled_rollout_matches_finite_differences() {
    let p = tiny();
    let net = ConvNet2dConfig { width: 2, levels: 2, kernel: 3, activation: Activation::Gelu };
    let ctrl = SmokeController::new(&p, &net, DType::F64, &dev(), 5).unwrap();
    let s = scene::generate(&p, 3, 0..2, DType::F64, &dev()).unwrap();
    let loss_t = || {
        let r = ctrl.rollout(&s.initial, &s.target).unwrap();
        loss::objective(&r.forces, r.final_density().unwrap(), &s.target, p.loss_levels, p.effort_weight)
            .unwrap()
            .sum_all()
            .unwrap()
    };
    let grads = loss_t().backward().unwrap();
    for prefix in ["cfe.down0.0", "cfe.out", "op02.down1.1", "op04.up0.0"] {
        let vars = ctrl.vars_with_prefix(prefix);
        let w = &vars[vars.len() - 1]; // the weight (sorted after the bias)
        let g = grads.get(w).unwrap();
        // The entry with the largest gradient and one with a small one.
        let gv = g.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let big = (0..gv.len()).max_by(|&a, &b| gv[a].abs().total_cmp(&gv[b].abs())).unwrap();
        for at in [big, (big + 1) % gv.len()] {
            let ad = entry(g, at);
            let fd = central_difference(w, at, 1e-3, &|| scalar(&loss_t()));
            let rel = (ad - fd).abs() / ad.abs().max(1e-8);
            println!("{prefix}[{at}]: autodiff {ad:.10e} fd {fd:.10e} rel {rel:.2e}");
            assert!(ad.abs() > 1e-8, "{prefix}[{at}]: gradient vanishes ({ad:e})");
            assert!(rel < FD_REL_TOL, "{prefix}[{at}]: autodiff {ad:e} vs fd {fd:e} (rel {rel:e})");
        }
    }
}

#[test]
fn density_mass_is_conserved_over_a_controlled_rollout() {
    let p = SmokeControlConfig { cells: 16, steps: 8, ..Default::default() };
    let physics = SmokePhysics::new(&p, DType::F64, &dev()).unwrap();
    let s = scene::generate(&p, 4, 0..3, DType::F64, &dev()).unwrap();
    let m0 = scalar(&s.initial);
    let expected = 3.0 * scene::scene_mass(p.cells);
    assert!((m0 - expected).abs() < 1e-9 * expected, "scene mass {m0} vs {expected}");
    // Strong forces: CFL up to ~2 per step.
    let forces = random_forces(&p, 3, 0.8, 21);
    let states = physics.rollout(&physics.rest(&s.initial).unwrap(), &forces).unwrap();
    let mut worst: f64 = 0.0;
    for (t, st) in states.iter().enumerate() {
        let m = scalar(&st.density);
        let drift = (m - m0).abs() / m0;
        worst = worst.max(drift);
        let min = st.density.min_all().unwrap().to_scalar::<f64>().unwrap();
        assert!(min > -1e-9, "step {t}: negative density {min}");
        assert!(drift < 1e-12, "step {t}: mass {m} vs {m0} (rel drift {drift:e})");
    }
    println!("worst relative mass drift over {} steps: {worst:.2e}", p.steps);
    // The controller's rollout too.
    let net = ConvNet2dConfig { width: 2, levels: 2, ..Default::default() };
    let ctrl = SmokeController::new(&p, &net, DType::F64, &dev(), 1).unwrap();
    let r = ctrl.rollout(&s.initial, &s.target).unwrap();
    let m = scalar(r.final_density().unwrap());
    assert!((m - m0).abs() < 1e-12 * m0, "controlled rollout: mass {m} vs {m0}");
}

#[test]
fn scenes_are_seeded_and_split_by_seed() {
    let p = SmokeControlConfig { cells: 16, ..Default::default() };
    let a = scene::generate(&p, 1, 0..4, DType::F32, &dev()).unwrap();
    let b = scene::generate(&p, 1, 2..4, DType::F32, &dev()).unwrap();
    let c = scene::generate(&p, 2, 0..4, DType::F32, &dev()).unwrap();
    assert_eq!(a.shapes[2..], b.shapes[..]);
    assert_ne!(a.shapes, c.shapes);
    for (s, t) in &a.shapes {
        let d = ((s.centre[0] - t.centre[0]).powi(2) + (s.centre[1] - t.centre[1]).powi(2)).sqrt();
        assert!(d >= 2.0, "target only {d} cells away");
    }
    let mass = |t: &Tensor| t.sum(3).unwrap().sum(2).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    for m in mass(&a.initial).into_iter().chain(mass(&a.target)) {
        assert!((m as f64 - scene::scene_mass(16)).abs() < 1e-3, "mass {m}");
    }
}

#[test]
fn bad_configurations_and_inputs_are_typed_errors() {
    let d = SmokeControlConfig::default();
    let bad = |c: SmokeControlConfig, field: &str| match c.validate() {
        Err(Error::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
        other => panic!("{field}: expected InvalidConfig, got {other:?}"),
    };
    bad(SmokeControlConfig { cells: 4, ..d }, "cells");
    bad(SmokeControlConfig { cells: 30, ..d }, "cells");
    bad(SmokeControlConfig { steps: 0, ..d }, "steps");
    bad(SmokeControlConfig { steps: 12, ..d }, "steps");
    bad(SmokeControlConfig { dt: 0.0, ..d }, "dt");
    bad(SmokeControlConfig { effort_weight: -1.0, ..d }, "effort_weight");
    bad(SmokeControlConfig { loss_levels: 0, ..d }, "loss_levels");
    bad(SmokeControlConfig { loss_levels: 7, ..d }, "loss_levels");
    bad(
        SmokeControlConfig { velocity_advection: pbdl_grid::fluid::Advection::Conservative, ..d },
        "velocity_advection",
    );
    bad(SmokeControlConfig { density_advection: pbdl_grid::fluid::Advection::CentralRk4, ..d }, "density_advection");
    assert!(matches!(
        SmokePhysics::new(&SmokeControlConfig { cells: 4, ..d }, DType::F32, &dev()),
        Err(Error::InvalidConfig { field: "cells", .. })
    ));
    assert!(matches!(
        scene::generate(&SmokeControlConfig { steps: 0, ..d }, 0, 0..1, DType::F32, &dev()),
        Err(Error::InvalidConfig { field: "steps", .. })
    ));
    assert!(matches!(
        scene::generate(&d, 0, 0..0, DType::F32, &dev()),
        Err(Error::InvalidConfig { field: "range", .. })
    ));
    // A network too deep for the grid.
    let p = SmokeControlConfig { cells: 8, steps: 4, loss_levels: 2, ..d };
    let deep = ConvNet2dConfig { levels: 4, ..Default::default() };
    assert!(matches!(
        SmokeController::new(&p, &deep, DType::F32, &dev(), 0),
        Err(Error::InvalidConfig { field: "levels", .. })
    ));
    // Mismatched shapes.
    let net = ConvNet2dConfig { width: 2, levels: 2, ..Default::default() };
    let ctrl = SmokeController::new(&p, &net, DType::F32, &dev(), 0).unwrap();
    let s = scene::generate(&p, 0, 0..2, DType::F32, &dev()).unwrap();
    let wrong_grid = Tensor::zeros((2, 1, 16, 16), DType::F32, &dev()).unwrap();
    assert!(matches!(ctrl.rollout(&wrong_grid, &wrong_grid), Err(Error::Shape { .. })));
    assert!(matches!(ctrl.rollout(&s.initial, &s.target.narrow(0, 0, 1).unwrap()), Err(Error::Shape { .. })));
    let physics = ctrl.physics();
    let s0 = physics.rest(&s.initial).unwrap();
    let one_channel = Tensor::zeros((2, 1, 8, 8), DType::F32, &dev()).unwrap();
    assert!(matches!(physics.step(&s0, &one_channel), Err(Error::Shape { .. })));
    let other_batch = Tensor::zeros((3, 2, 8, 8), DType::F32, &dev()).unwrap();
    assert!(matches!(physics.step(&s0, &other_batch), Err(Error::Shape { .. })));
    assert!(matches!(ctrl.predict(3, &s.initial, &s.target), Err(Error::InvalidConfig { field: "n", .. })));
    assert!(matches!(
        optimize_forces(&p, &s.initial, &wrong_grid, &DirectOptimConfig::default()),
        Err(Error::Shape { .. })
    ));
    assert!(matches!(
        optimize_forces(&p, &s.initial, &s.target, &DirectOptimConfig { lr: 0.0, ..Default::default() }),
        Err(Error::InvalidConfig { field: "lr", .. })
    ));
    let cfg = SmokeTrainConfig { batch: 3, ..Default::default() };
    assert!(matches!(train_end_to_end(&ctrl, &s, &cfg), Err(Error::InvalidConfig { field: "batch", .. })));
}

#[test]
fn direct_optimisation_moves_the_density_towards_the_target() {
    let p = SmokeControlConfig { cells: 16, steps: 4, loss_levels: 3, ..Default::default() };
    let s = scene::generate(&p, 5, 0..2, DType::F32, &dev()).unwrap();
    let zero =
        optimize_forces(&p, &s.initial, &s.target, &DirectOptimConfig { max_iterations: 0, ..Default::default() })
            .unwrap();
    let opt = optimize_forces(
        &p,
        &s.initial,
        &s.target,
        &DirectOptimConfig { max_iterations: 40, lr: 0.05, ..Default::default() },
    )
    .unwrap();
    println!("no control {:?}\noptimised ({} its) {:?}", zero.score, opt.iterations, opt.score);
    assert!(opt.score.objective < 0.8 * zero.score.objective);
    assert!(opt.score.target_error < zero.score.target_error);
}

/// The acceptance run (release, on 2 cores):
/// `cargo test --release -p pbdl-sol --test smoke_control -- --ignored --nocapture`.
///
/// 32x32 closed box, 16 steps. 64 training scenes (set seed 1), 16 held-out scenes (seed 2).
/// Supervision: the direct optimiser's trajectories on the training scenes (40 Adam updates);
/// supervised pre-training (at most 170 s); the supervised-only controller is scored on the
/// held-out scenes; then end-to-end training through the solver from there (batch 4, at most
/// 400 s: the phases are bounded by wall-clock, so the update counts depend on the machine's
/// load; the run prints them). Bars (written before the first run):
/// mean final-density error `||rho_T - rho*||^2` on the held-out scenes of the end-to-end
/// controller < the supervised-only controller < no control. The direct optimiser given the
/// controller's inference wall-clock (and given 60 s) is reported, not asserted.
///
/// First run (786 s, 2 shared cores): final-density error end-to-end 27.6, supervised-only
/// 126.3, no control 130.6; the optimiser 40.5 at the controller's 3.9 s (7 updates) and 7.7
/// in 60 s (62 updates).
#[test]
#[ignore = "trains for ~13 minutes; run in release"]
fn acceptance_end_to_end_beats_supervised_beats_no_control() {
    let t_all = Instant::now();
    let problem = SmokeControlConfig::default();
    let dev = dev();
    let (n_train, n_test) = (64, 16);
    let train = scene::generate(&problem, 1, 0..n_train, DType::F32, &dev).unwrap();
    let test = scene::generate(&problem, 2, 0..n_test, DType::F32, &dev).unwrap();
    let ctrl = SmokeController::new(&problem, &ConvNet2dConfig::default(), DType::F32, &dev, 0).unwrap();
    println!("{ctrl:?}");
    println!("operators: {:?}", ctrl.physics().operators());

    let score = |r: &Rollout| {
        SmokeScore::of(&r.forces, r.final_density().unwrap(), &test.target, problem.loss_levels, problem.effort_weight)
            .unwrap()
    };
    // No control.
    let none = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { max_iterations: 0, ..Default::default() },
    )
    .unwrap()
    .score;
    println!("no control: {none:?}");

    // Supervision by the direct optimiser on the training scenes.
    let sup_opt = DirectOptimConfig { lr: 0.03, max_iterations: 40, time_budget_s: 240.0 };
    let data = Supervision::generate(&ctrl, &train, &sup_opt, 32).unwrap();
    println!(
        "supervision: optimiser on {n_train} training scenes in {:.1}s, mean final-density error {:.3}",
        data.seconds, data.target_error
    );
    let sup = pretrain_supervised(
        &ctrl,
        &data,
        &SmokeTrainConfig {
            iterations: 600,
            batch: 16,
            lr: 1e-3,
            seed: 1,
            time_budget_s: Some(170.0),
            ..Default::default()
        },
    )
    .unwrap();
    println!(
        "supervised: {} its in {:.1}s, loss {:.4} -> {:.4}",
        sup.losses.len(),
        sup.seconds,
        sup.head_mean(20),
        sup.tail_mean(20)
    );
    let supervised = score(&ctrl.rollout(&test.initial, &test.target).unwrap());
    println!("supervised-only controller: {supervised:?}");

    let e2e = train_end_to_end(
        &ctrl,
        &train,
        &SmokeTrainConfig {
            iterations: 400,
            batch: 4,
            lr: 1e-3,
            seed: 2,
            time_budget_s: Some(400.0),
            ..Default::default()
        },
    )
    .unwrap();
    println!(
        "end-to-end: {} its in {:.1}s, loss {:.3} -> {:.3}",
        e2e.losses.len(),
        e2e.seconds,
        e2e.head_mean(10),
        e2e.tail_mean(10)
    );
    let t = Instant::now();
    let r = ctrl.rollout(&test.initial, &test.target).unwrap();
    let _ = r.final_density().unwrap().to_dtype(DType::F64).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
    let inference_s = t.elapsed().as_secs_f64();
    let end_to_end = score(&r);
    println!("end-to-end controller: {end_to_end:?} (inference of {n_test} scenes: {inference_s:.3}s)");

    let same_clock = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { time_budget_s: inference_s, ..Default::default() },
    )
    .unwrap();
    println!(
        "direct optimiser, same wall-clock ({inference_s:.3}s, {} its): {:?}",
        same_clock.iterations, same_clock.score
    );
    let long = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { time_budget_s: 60.0, ..Default::default() },
    )
    .unwrap();
    println!("direct optimiser, 60 s ({} its): {:?}", long.iterations, long.score);
    println!(
        "final-density error: end-to-end {:.3} | supervised {:.3} | no control {:.3} | optimiser same clock {:.3} | optimiser 60 s {:.3}",
        end_to_end.target_error,
        supervised.target_error,
        none.target_error,
        same_clock.score.target_error,
        long.score.target_error
    );
    println!("total {:.1}s", t_all.elapsed().as_secs_f64());
    assert!(
        end_to_end.target_error < supervised.target_error,
        "end-to-end {} not below supervised {}",
        end_to_end.target_error,
        supervised.target_error
    );
    assert!(
        supervised.target_error < none.target_error,
        "supervised {} not below no control {}",
        supervised.target_error,
        none.target_error
    );
}
