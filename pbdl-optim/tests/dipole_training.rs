//! HIG vs Adam vs Gauss-Newton on the quantum dipole at equal training wall-clock (the paper's
//! Fig. 3 setup with a CPU-minutes budget instead of 5400 s). Not asserted: the test prints the
//! curves so the numbers can be reported; `cargo xtask bench optim` runs the same as the
//! `dipole` bench entry.
//!
//! Measured (dev profile, 2 rayon threads on a shared 2-core machine, one seed, test set 1024,
//! initial test loss 0.9998), test loss after 180 s of training each:
//! HIG (b 16, 207 steps, 0.82 s/step) 0.0376, Adam (b 256, 602 steps, 0.29 s/step) 0.0516,
//! Gauss-Newton (b 16, 147 steps, 1.12 s/step) 0.00027. At 120 s: HIG 0.155, Adam 0.30,
//! GN 0.0070. So HIG ends below Adam but far above Gauss-Newton with the f64 solve.
//! With the solve in f32 (the paper's TensorFlow precision; diagnostic below), 120 s each:
//! HIG 0.0106 (260 steps), Gauss-Newton 0.29 (231 steps, non-monotone): in f32 GN stalls.

use pbdl_optim::hig::{run_curve_with_loss, Budget, HigConfig, Loss, Method};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::QuantumDipole;

#[test]
#[ignore = "training run: 3 x PBDL_DIPOLE_SECONDS (default 60) s of training plus evaluations, ~4-6 min on 2 busy cores"]
fn dipole_hig_adam_gauss_newton_at_equal_wall_clock() {
    let seconds: f64 = std::env::var("PBDL_DIPOLE_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(60.0);
    let physics = QuantumDipole::hig_paper();
    let train = physics.dataset(1024, 5).unwrap();
    let test = physics.dataset(1024, 6).unwrap();
    let net0 = Mlp::new(&[28, 20, 20, 20, 384], Activation::Tanh, 0).unwrap();
    assert_eq!(net0.n_params(), 9484);
    let contenders = [
        ("hig", Method::Hig(HigConfig::hig(0.5, 1e-5)), 16usize),
        ("adam", Method::Adam { lr: 5e-4 }, 256),
        ("gauss_newton", Method::Hig(HigConfig::gauss_newton(0.5, 1e-5)), 16),
    ];
    let threads = rayon::current_num_threads();
    eprintln!("dipole, {seconds} s of training each, {threads} rayon threads, test set 1024");
    for (name, method, batch) in contenders {
        let mut net = net0.clone();
        let budget = Budget { seconds, max_steps: u64::MAX };
        // About every 5 % of the budget, judged from a first guess of the step time.
        let every = match method {
            Method::Hig(_) => 4,
            Method::Adam { .. } => 4,
        };
        let c = run_curve_with_loss(&mut net, &physics, Loss::Infidelity, method, &train, &test, batch, budget, every)
            .unwrap();
        let points: Vec<String> =
            c.seconds.iter().zip(&c.steps).zip(&c.loss).map(|((t, k), l)| format!("{t:.1}s/{k}:{l:.4}")).collect();
        eprintln!(
            "{name}: b {batch}, steps {}, median step {:.3} s, final test loss {:.5}, diverged {:?}\n  {}",
            c.steps.last().unwrap(),
            c.median_step_seconds(),
            c.final_loss(),
            c.diverged_at,
            points.join(" ")
        );
    }
}

/// Diagnostic for the report: the paper's TensorFlow code ran the (half-)inverse in float32.
/// This repeats HIG and Gauss-Newton with the exact f64 Jacobian and loss gradient rounded to
/// f32 and the truncated SVD solve done in f32 (faer), everything else unchanged, to see how
/// much the solve's precision matters for each. Prints test loss against training seconds.
#[test]
#[ignore = "diagnostic training run: 2 x PBDL_DIPOLE_SECONDS (default 60) s plus evaluations"]
fn dipole_hig_and_gauss_newton_with_f32_solve() {
    use pbdl_optim::hig::{composed_jacobian, evaluate_with_loss};
    let seconds: f64 = std::env::var("PBDL_DIPOLE_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(60.0);
    let physics = QuantumDipole::hig_paper();
    let train = physics.dataset(1024, 5).unwrap();
    let test = physics.dataset(1024, 6).unwrap();
    let net0 = Mlp::new(&[28, 20, 20, 20, 384], Activation::Tanh, 0).unwrap();
    let (b, eta, tau) = (16usize, 0.5f64, 1e-5f32);
    for (name, kappa) in [("hig_f32_solve", 0.5f32), ("gauss_newton_f32_solve", 1.0f32)] {
        let mut net = net0.clone();
        let (mut elapsed, mut step) = (0.0, 0usize);
        let mut points =
            vec![format!("0.0s/0:{:.4}", evaluate_with_loss(&net, &physics, Loss::Infidelity, &test).unwrap())];
        while elapsed < seconds {
            let batch = train.batch((step % (1024 / b)) * b, b);
            let t = std::time::Instant::now();
            let (j, y) = composed_jacobian(&net, &physics, batch).unwrap();
            let (rows, p) = (b * 28, net.n_params());
            let mut g = vec![0.0; rows];
            for s in 0..b {
                let r = s * 28..(s + 1) * 28;
                Loss::Infidelity.value_and_gradient(&y[r.clone()], &batch.targets[r.clone()], &mut g[r]).unwrap();
            }
            let jm = faer::Mat::<f32>::from_fn(rows, p, |r, c| j[r * p + c] as f32);
            let svd = jm.thin_svd().unwrap();
            let s = svd.S().column_vector();
            let s_max = (0..rows).map(|i| s[i]).fold(0.0f32, f32::max);
            let mut update = vec![0.0f32; p];
            for i in 0..rows {
                if s[i] > tau * s_max {
                    let ui = svd.U().col(i);
                    let c: f32 = (0..rows).map(|r| ui[r] * (g[r] / b as f64) as f32).sum::<f32>() * s[i].powf(-kappa);
                    let vi = svd.V().col(i);
                    update.iter_mut().enumerate().for_each(|(k, d)| *d += vi[k] * c);
                }
            }
            net.params_mut().iter_mut().zip(&update).for_each(|(t, d)| *t -= eta * *d as f64);
            elapsed += t.elapsed().as_secs_f64();
            step += 1;
            if step % 8 == 0 || elapsed >= seconds {
                let l = evaluate_with_loss(&net, &physics, Loss::Infidelity, &test).unwrap();
                points.push(format!("{elapsed:.1}s/{step}:{l:.4}"));
            }
        }
        eprintln!("{name}: {step} steps in {elapsed:.1} s\n  {}", points.join(" "));
    }
}
