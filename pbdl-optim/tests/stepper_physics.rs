//! [`StepperPhysics`]: a differentiable `pbdl_core::stepper::Stepper` as a HIG physics. Exact
//! Jacobians of linear steppers, the VJP against `J^T c`, typed errors, and a short HIG run.

use candle_core::{Device, Tensor};
use pbdl_core::stepper::{Differentiability, Stepper};
use pbdl_optim::hig::{evaluate, HigConfig, HigTrainer};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Physics, StepperPhysics};
use pbdl_optim::Error;
use rand::Rng;

/// `x -> A x` on a state of shape `[n]`, `A` row-major `n x n`.
struct Linear {
    a: Vec<f64>,
    n: usize,
}

impl Linear {
    fn matrix(&self) -> candle_core::Result<Tensor> {
        Tensor::from_slice(&self.a, (self.n, self.n), &Device::Cpu)
    }
}

impl Stepper for Linear {
    type State = Tensor;
    type Error = candle_core::Error;
    fn dt(&self) -> f64 {
        1.0
    }
    fn operators(&self) -> Vec<&'static str> {
        vec!["linear.matmul"]
    }
    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }
    fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.matrix()?.matmul(&x.unsqueeze(1)?)?.squeeze(1)
    }
}

/// Explicit diffusion on a periodic 1-D grid: `x + nu (x[i-1] - 2 x[i] + x[i+1])`.
struct Diffusion {
    nu: f64,
}

impl Stepper for Diffusion {
    type State = Tensor;
    type Error = candle_core::Error;
    fn dt(&self) -> f64 {
        1.0
    }
    fn operators(&self) -> Vec<&'static str> {
        vec!["diffuse.explicit_periodic"]
    }
    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }
    fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let n = x.dim(0)?;
        let left = Tensor::cat(&[x.narrow(0, n - 1, 1)?, x.narrow(0, 0, n - 1)?], 0)?;
        let right = Tensor::cat(&[x.narrow(0, 1, n - 1)?, x.narrow(0, 0, 1)?], 0)?;
        let lap = ((left + right)? - x.affine(2.0, 0.0)?)?;
        x + lap.affine(self.nu, 0.0)?
    }
}

/// Plain `f64` decay: not differentiable.
#[derive(Debug)]
struct PlainDecay;

impl Stepper for PlainDecay {
    type State = Tensor;
    type Error = candle_core::Error;
    fn dt(&self) -> f64 {
        1.0
    }
    fn operators(&self) -> Vec<&'static str> {
        vec!["decay.plain"]
    }
    fn differentiability(&self) -> Differentiability {
        Differentiability::None
    }
    fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        x.affine(0.5, 0.0)
    }
}

/// `a * b` for row-major `n x n` matrices.
fn matmul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            for j in 0..n {
                c[i * n + j] += a[i * n + k] * b[k * n + j];
            }
        }
    }
    c
}

fn random(len: usize, seed: u64) -> Vec<f64> {
    let mut rng = pbdl_core::seed::rng(seed);
    (0..len).map(|_| rng.random_range(-1.0..1.0)).collect()
}

fn linear(n: usize, seed: u64) -> Linear {
    // Scaled so that A^n stays of order one.
    let a = random(n * n, seed).iter().map(|v| v / n as f64).collect();
    Linear { a, n }
}

#[test]
fn jacobian_of_a_linear_stepper_is_a_to_the_n() {
    let n = 4;
    for steps in [0usize, 1, 3, 5] {
        let stepper = linear(n, 7);
        let mut an: Vec<f64> = (0..n * n).map(|i| if i % (n + 1) == 0 { 1.0 } else { 0.0 }).collect();
        for _ in 0..steps {
            an = matmul(&stepper.a, &an, n);
        }
        let physics = StepperPhysics::new(stepper, &[n], steps).unwrap();
        assert_eq!((physics.context_dim(), physics.control_dim(), physics.output_dim()), (0, n, n));
        let u = random(n, 11);
        let (mut y, mut jac) = (vec![0.0; n], vec![0.0; n * n]);
        physics.jacobian(&[], &u, &mut y, &mut jac).unwrap();
        let mut y_fwd = vec![0.0; n];
        physics.forward(&[], &u, &mut y_fwd).unwrap();
        assert_eq!(y, y_fwd, "jacobian() and forward() must give the same outcome");
        let worst = jac.iter().zip(&an).map(|(j, e)| (j - e).abs()).fold(0.0f64, f64::max);
        assert!(worst < 1e-12, "steps {steps}: max |J - A^n| = {worst:e}");
        // y = A^n u.
        for i in 0..n {
            let expect: f64 = (0..n).map(|j| an[i * n + j] * u[j]).sum();
            assert!((y[i] - expect).abs() < 1e-12, "steps {steps}: y[{i}] = {} vs {expect}", y[i]);
        }
    }
}

#[test]
fn jacobian_of_a_two_axis_state_matches_finite_differences() {
    // Diffusion on a [2, 3] state flattened by the adapter: the stepper sees axis 0 (length 2).
    let physics = StepperPhysics::new(Diffusion { nu: 0.2 }, &[2, 3], 3).unwrap();
    let len = 6;
    let u = random(len, 3);
    let (mut y, mut jac) = (vec![0.0; len], vec![0.0; len * len]);
    physics.jacobian(&[], &u, &mut y, &mut jac).unwrap();
    let h = 1e-6;
    let (mut up, mut dn, mut uu) = (vec![0.0; len], vec![0.0; len], u.clone());
    for k in 0..len {
        uu[k] = u[k] + h;
        physics.forward(&[], &uu, &mut up).unwrap();
        uu[k] = u[k] - h;
        physics.forward(&[], &uu, &mut dn).unwrap();
        uu[k] = u[k];
        for i in 0..len {
            let fd = (up[i] - dn[i]) / (2.0 * h);
            assert!((jac[i * len + k] - fd).abs() < 1e-8, "J[{i},{k}] = {} vs {fd}", jac[i * len + k]);
        }
    }
}

#[test]
fn vjp_is_j_transpose_c() {
    let n = 5;
    for (physics, seed) in [
        (Box::new(StepperPhysics::new(linear(n, 5), &[n], 4).unwrap()) as Box<dyn Physics>, 1u64),
        (Box::new(StepperPhysics::new(Diffusion { nu: 0.25 }, &[n], 6).unwrap()), 2),
    ] {
        let u = random(n, seed);
        let c = random(n, seed + 100);
        let (mut y, mut jac) = (vec![0.0; n], vec![0.0; n * n]);
        physics.jacobian(&[], &u, &mut y, &mut jac).unwrap();
        let mut cot_u = vec![f64::NAN; n];
        physics.vjp(&[], &u, &c, &mut cot_u).unwrap();
        for j in 0..n {
            let expect: f64 = (0..n).map(|i| jac[i * n + j] * c[i]).sum();
            assert!((cot_u[j] - expect).abs() < 1e-12, "cot_u[{j}] = {} vs J^T c = {expect}", cot_u[j]);
        }
    }
}

#[test]
fn sizes_and_non_differentiable_steppers_are_typed_errors() {
    match StepperPhysics::new(PlainDecay, &[3], 2) {
        Err(Error::Core(pbdl_core::Error::InvalidArgument { arg, .. })) => assert_eq!(arg, "stepper"),
        other => panic!("expected InvalidArgument, got {other:?}"),
    }
    assert!(matches!(StepperPhysics::new(Diffusion { nu: 0.1 }, &[], 2), Err(Error::ShapeMismatch { .. })));
    assert!(matches!(StepperPhysics::new(Diffusion { nu: 0.1 }, &[3, 0], 2), Err(Error::ShapeMismatch { .. })));

    let physics = StepperPhysics::new(Diffusion { nu: 0.1 }, &[3], 2).unwrap();
    let shape_err = |r: pbdl_optim::Result<()>| matches!(r, Err(Error::ShapeMismatch { .. }));
    let (mut y3, mut y2, mut j9, mut j8) = (vec![0.0; 3], vec![0.0; 2], vec![0.0; 9], vec![0.0; 8]);
    assert!(shape_err(physics.forward(&[], &[1.0, 2.0], &mut y3)));
    assert!(shape_err(physics.forward(&[1.0], &[1.0, 2.0, 3.0], &mut y3)));
    assert!(shape_err(physics.forward(&[], &[1.0, 2.0, 3.0], &mut y2)));
    assert!(shape_err(physics.jacobian(&[], &[1.0, 2.0, 3.0], &mut y3, &mut j8)));
    assert!(shape_err(physics.jacobian(&[], &[1.0, 2.0], &mut y3, &mut j9)));
    assert!(shape_err(physics.vjp(&[], &[1.0, 2.0, 3.0], &[1.0, 2.0], &mut y3)));
    assert!(shape_err(physics.vjp(&[], &[1.0, 2.0, 3.0], &[1.0, 2.0, 3.0], &mut y2)));
    assert!(shape_err(physics.vjp(&[0.0], &[1.0, 2.0, 3.0], &[1.0, 2.0, 3.0], &mut y3)));
    physics.jacobian(&[], &[1.0, 2.0, 3.0], &mut y3, &mut j9).unwrap();
}

/// A stepper that changes the state's size: caught as a shape error, not a panic.
struct Grows;

impl Stepper for Grows {
    type State = Tensor;
    type Error = candle_core::Error;
    fn dt(&self) -> f64 {
        1.0
    }
    fn operators(&self) -> Vec<&'static str> {
        vec!["grows"]
    }
    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }
    fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Tensor::cat(&[x, x], 0)
    }
}

#[test]
fn stepper_errors_and_size_changes_are_reported() {
    let physics = StepperPhysics::new(Grows, &[2], 1).unwrap();
    let mut y = vec![0.0; 2];
    assert!(matches!(physics.forward(&[], &[1.0, 2.0], &mut y), Err(Error::ShapeMismatch { .. })));
    // A stepper error (here: a shape the matmul rejects) comes back wrapped, not as a panic.
    let physics = StepperPhysics::new(linear(3, 1), &[2], 1).unwrap();
    assert!(matches!(physics.forward(&[], &[1.0, 2.0], &mut y), Err(Error::Candle(_))));
}

#[test]
fn hig_through_a_stepper_reduces_the_loss() {
    // Inverse problem: the network sees the target y* and must output the initial state whose
    // diffusion over 3 steps lands on it.
    let n = 6;
    let physics = StepperPhysics::new(Diffusion { nu: 0.15 }, &[n], 3).unwrap();
    let samples = 64;
    let targets = random(samples * n, 42);
    let data = Dataset::new(targets.clone(), Vec::new(), targets, samples).unwrap();
    let mut net = Mlp::new(&[n, 16, n], Activation::Tanh, 0).unwrap();
    let before = evaluate(&net, &physics, &data).unwrap();
    let mut hig = HigTrainer::new(HigConfig::hig(1.0, 1e-6)).unwrap();
    for step in 0..8 {
        hig.step(&mut net, &physics, data.batch(16 * (step % 4), 16)).unwrap();
    }
    let after = evaluate(&net, &physics, &data).unwrap();
    eprintln!("HIG through StepperPhysics: loss {before:.4e} -> {after:.4e}");
    assert!(after.is_finite() && after < 0.5 * before, "{before} -> {after}"); // 2.36 -> 0.328 when written
}
