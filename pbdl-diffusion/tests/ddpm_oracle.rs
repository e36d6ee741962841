//! The samplers against the analytic optimum for Gaussian data.
//!
//! For `x_0 ~ N(mu, sigma^2)` per channel, the exact noise predictor is affine in `x_i`
//! ([`GaussianOracle`]), so every sampler is an affine map plus Gaussian noise and its output
//! mean and variance follow from a short recursion written out here independently of the
//! library. The tests check (a) the oracle against Monte-Carlo regression of the noise, (b) the
//! samplers' Monte-Carlo moments against these recursions, (c) the recursions against the data.

use candle_core::{DType, Device, Tensor};
use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle, Loss, NoisePredictor};
use pbdl_diffusion::schedule::{NoiseSchedule, COSINE_S};

const MU: [f64; 2] = [1.5, -0.5];
const STD: [f64; 2] = [0.5, 2.0];
/// Samples per channel: 64 x 16 x 16 = 16384 independent pixels.
const SHAPE: [usize; 4] = [64, 2, 16, 16];

/// Per-channel (mean, variance) of a `[B, C, H, W]` tensor and the number of values per channel.
fn moments(x: &Tensor) -> Vec<(f64, f64, usize)> {
    let (b, c, h, w) = x.dims4().unwrap();
    let v = x.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    (0..c)
        .map(|ch| {
            let vals: Vec<f64> =
                (0..b).flat_map(|bi| v[(bi * c + ch) * h * w..(bi * c + ch + 1) * h * w].to_vec()).collect();
            let n = vals.len() as f64;
            let m = vals.iter().sum::<f64>() / n;
            let var = vals.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, var, vals.len())
        })
        .collect()
}

/// Standard errors of the sample mean and variance of `n` draws of a Gaussian with variance `var`.
fn standard_errors(var: f64, n: usize) -> (f64, f64) {
    ((var / n as f64).sqrt(), var * (2.0 / (n as f64 - 1.0)).sqrt())
}

/// The exact output (mean, variance) of ancestral DDPM with the diagonal oracle, from `N(0, 1)`.
fn exact_ddpm(s: &NoiseSchedule, mu: f64, var: f64) -> (f64, f64) {
    let (mut m, mut v) = (0.0, 1.0);
    for i in (0..s.len()).rev() {
        let ab = s.alpha_bar(i);
        let s1 = (1.0 - ab).sqrt();
        let g = s1 / (ab * var + 1.0 - ab); // eps = g (x - sqrt(ab) mu)
        let k = s.beta(i) / s1;
        let a = (1.0 - k * g) / s.alpha(i).sqrt();
        let b = k * g * ab.sqrt() * mu / s.alpha(i).sqrt();
        m = a * m + b;
        v = a * a * v + s.posterior_variance(i);
    }
    (m, v)
}

/// The exact affine map `x_0 = a x_start + b` of deterministic DDIM on `steps` with the oracle.
fn exact_ddim(s: &NoiseSchedule, steps: &[usize], mu: f64, var: f64) -> (f64, f64) {
    let (mut a, mut b) = (1.0, 0.0);
    for j in (0..steps.len()).rev() {
        let ab = s.alpha_bar(steps[j]);
        let ab_p = if j > 0 { s.alpha_bar(steps[j - 1]) } else { 1.0 };
        let s1 = (1.0 - ab).sqrt();
        let g = s1 / (ab * var + 1.0 - ab);
        // x0_hat = (x - s1 eps) / sqrt(ab), x' = sqrt(ab_p) x0_hat + sqrt(1 - ab_p) eps.
        let eps_coef = (1.0 - ab_p).sqrt() - ab_p.sqrt() * s1 / ab.sqrt();
        let step_a = ab_p.sqrt() / ab.sqrt() + eps_coef * g;
        let step_b = -eps_coef * g * ab.sqrt() * mu;
        (a, b) = (step_a * a, step_a * b + step_b);
    }
    (a, b)
}

fn oracle(s: &NoiseSchedule) -> GaussianOracle {
    GaussianOracle::diagonal(s.clone(), &MU, &STD).unwrap()
}

#[test]
fn oracle_is_the_regression_of_the_noise_and_reaches_the_analytic_minimum() {
    let s = NoiseSchedule::cosine(200, COSINE_S).unwrap();
    let oracle = oracle(&s);
    let d = Diffusion::new(s.clone(), Conditioning::Clean);
    let dev = Device::Cpu;
    let n = 4096 * 16;
    let x0 = Tensor::cat(
        &[
            pbdl_core::seed::randn((4096, 1, 4, 4), MU[0], STD[0], DType::F64, &dev, 1).unwrap(),
            pbdl_core::seed::randn((4096, 1, 4, 4), MU[1], STD[1], DType::F64, &dev, 2).unwrap(),
        ],
        1,
    )
    .unwrap();
    for i in [0, 20, 100, 180, 199] {
        let eps = Diffusion::noise(&[4096, 2, 4, 4], DType::F64, &dev, 10 + i as u64).unwrap();
        let steps = vec![i; 4096];
        let xt = d.q_sample(&x0, &steps, &eps).unwrap();
        let pred = oracle.predict(&xt, &Diffusion::step_tensor(&steps, &dev).unwrap()).unwrap();
        // Independent estimate: least-squares slope of eps on x_i per channel vs the oracle's.
        let e = moments(&eps);
        let xm = moments(&xt);
        for ch in 0..2 {
            let ev = eps.narrow(1, ch, 1).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            let xv = xt.narrow(1, ch, 1).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            let cov = ev.iter().zip(&xv).map(|(a, b)| (a - e[ch].0) * (b - xm[ch].0)).sum::<f64>() / (n as f64 - 1.0);
            let slope_mc = cov / xm[ch].1;
            let ab = s.alpha_bar(i);
            let slope = (1.0 - ab).sqrt() / (ab * STD[ch].powi(2) + 1.0 - ab);
            // Slope SE of a regression with residual variance r and regressor variance V: sqrt(r / (n V)).
            let resid = ab * STD[ch].powi(2) / (ab * STD[ch].powi(2) + 1.0 - ab);
            let se = (resid / (n as f64 * xm[ch].1)).sqrt();
            assert!((slope_mc - slope).abs() < 4.0 * se + 1e-12, "step {i} ch {ch}: {slope_mc} vs {slope} (se {se})");
        }
        // Its loss is the closed-form minimum sigma_i^2 = abar s^2 / (abar s^2 + 1 - abar), averaged.
        let mc = Loss::Mse.compute(&pred, &eps).unwrap().to_scalar::<f64>().unwrap();
        let per_ch: Vec<f64> = STD
            .iter()
            .map(|sd| {
                let ab = s.alpha_bar(i);
                ab * sd * sd / (ab * sd * sd + 1.0 - ab)
            })
            .collect();
        let min = per_ch.iter().sum::<f64>() / 2.0;
        assert!((oracle.min_loss_at(i) - min).abs() < 1e-12);
        // Squared residuals r^2 with r ~ N(0, v): variance 2 v^2; 2n values.
        let se = (per_ch.iter().map(|v| 2.0 * v * v).sum::<f64>() / 2.0 / (2 * n) as f64).sqrt();
        assert!((mc - min).abs() < 4.0 * se, "step {i}: MC loss {mc} vs minimum {min} (se {se})");
    }
}

#[test]
fn ddpm_with_the_oracle_reproduces_the_data_moments() {
    let dev = Device::Cpu;
    for (name, s) in [
        ("linear T=1000", NoiseSchedule::linear(1000, 1e-4, 0.02).unwrap()),
        ("cosine T=200", NoiseSchedule::cosine(200, COSINE_S).unwrap()),
        ("acdm R=20", NoiseSchedule::acdm(20).unwrap()),
    ] {
        let d = Diffusion::new(s.clone(), Conditioning::Clean);
        let x_t = Diffusion::noise(&SHAPE, DType::F32, &dev, 5).unwrap();
        let x0 = d.sample_ddpm(&oracle(&s), None, &x_t, 6).unwrap();
        for (ch, &(m, v, n)) in moments(&x0).iter().enumerate() {
            let (em, ev) = exact_ddpm(&s, MU[ch], STD[ch].powi(2));
            let (se_m, se_v) = standard_errors(ev, n);
            println!(
                "DDPM {name} ch {ch}: MC mean {m:.4} var {v:.4} | exact sampler {em:.4} {ev:.4} (var bias {:+.2}%) \
                 | data {} {} | n = {n}, 4 SE = {:.4} {:.4}",
                100.0 * (ev / STD[ch].powi(2) - 1.0),
                MU[ch],
                STD[ch].powi(2),
                4.0 * se_m,
                4.0 * se_v
            );
            // (b) the sampler does what the recursion says, within 4 standard errors.
            assert!((m - em).abs() < 4.0 * se_m && (v - ev).abs() < 4.0 * se_v, "{name} ch {ch}");
            // (c) with Ho et al.'s 1000 steps the samples reproduce the data within 4 SE. With fewer
            // steps the small-variance sampler is biased low by O(1 / T) (checked below).
            if name.starts_with("linear") {
                assert!((m - MU[ch]).abs() < 4.0 * se_m, "{name} ch {ch}: mean {m}");
                assert!((v - STD[ch].powi(2)).abs() < 4.0 * se_v, "{name} ch {ch}: var {v}");
            }
        }
    }
    // The variance bias of ancestral DDPM with the exact predictor shrinks like 1 / T.
    let bias = |t: usize| (exact_ddpm(&NoiseSchedule::cosine(t, COSINE_S).unwrap(), MU[0], 0.25).1 / 0.25 - 1.0).abs();
    let (b50, b200, b1000) = (bias(50), bias(200), bias(1000));
    println!("DDPM cosine variance bias (std 0.5): T=50 {b50:.3e}, T=200 {b200:.3e}, T=1000 {b1000:.3e}");
    assert!(b200 < b50 && b1000 < b200);
    let order = (b200 / b1000).ln() / 5f64.ln();
    assert!((0.7..1.3).contains(&order), "observed order {order}");
}

#[test]
fn ddim_is_deterministic_exact_and_converges_with_the_step_count() {
    let dev = Device::Cpu;
    let s = NoiseSchedule::cosine(200, COSINE_S).unwrap();
    let d = Diffusion::new(s.clone(), Conditioning::Clean);
    let o = oracle(&s);
    // A grid of start values in f64: the sampler must be exactly the affine map of the recursion.
    let grid: Vec<f64> = (0..16).map(|i| -3.0 + 0.4 * i as f64).collect();
    let x_grid = Tensor::from_vec([grid.clone(), grid.clone()].concat(), (1, 2, 4, 4), &dev).unwrap();
    let mut prev_err = f64::INFINITY;
    for k in [5, 10, 20, 50] {
        let steps = d.ddim_steps(k).unwrap();
        let a = d.sample_ddim(&o, None, &x_grid, &steps, 0.0, 1).unwrap();
        let b = d.sample_ddim(&o, None, &x_grid, &steps, 0.0, 99).unwrap();
        assert_eq!(
            a.flatten_all().unwrap().to_vec1::<f64>().unwrap(),
            b.flatten_all().unwrap().to_vec1::<f64>().unwrap(),
            "eta = 0 must not depend on the seed"
        );
        let out = a.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let mut err = 0.0;
        for ch in 0..2 {
            let (ea, eb) = exact_ddim(&s, &steps, MU[ch], STD[ch].powi(2));
            for (j, x) in grid.iter().enumerate() {
                assert!((out[ch * 16 + j] - (ea * x + eb)).abs() < 1e-9, "k {k} ch {ch}");
            }
            // x_start ~ N(0, 1): output mean eb, variance ea^2; relative error against the data.
            let (mean_err, var_err) = ((eb - MU[ch]).abs() / STD[ch], (ea * ea / STD[ch].powi(2) - 1.0).abs());
            println!("DDIM k = {k:>2} ch {ch}: mean error {mean_err:.3e} (in std), variance rel. error {var_err:.3e}");
            err += mean_err + var_err;
        }
        assert!(err < prev_err, "error must fall with the step count: {err} at k = {k} after {prev_err}");
        prev_err = err;
    }
    // Monte-Carlo samples of the 50-step sampler have the recursion's moments.
    let steps = d.ddim_steps(50).unwrap();
    let x0 = d.sample_ddim(&o, None, &Diffusion::noise(&SHAPE, DType::F32, &dev, 8).unwrap(), &steps, 0.0, 0).unwrap();
    for (ch, &(m, v, n)) in moments(&x0).iter().enumerate() {
        let (ea, eb) = exact_ddim(&s, &steps, MU[ch], STD[ch].powi(2));
        let (se_m, se_v) = standard_errors(ea * ea, n);
        assert!(
            (m - eb).abs() < 4.0 * se_m && (v - ea * ea).abs() < 4.0 * se_v,
            "ch {ch}: {m} {v} vs {eb} {}",
            ea * ea
        );
    }
}

#[test]
fn ddim_with_eta_one_on_all_steps_is_ddpm() {
    let dev = Device::Cpu;
    let s = NoiseSchedule::acdm(20).unwrap();
    let joint = GaussianOracle::joint(s.clone(), vec![0.0, 1.0], vec![1.0, 0.8, 0.8, 0.73]).unwrap();
    let clean = joint.clone().with_clean_condition(1).unwrap();
    let c = pbdl_core::seed::randn((4, 1, 3, 3), 0.0, 1.0, DType::F64, &dev, 3).unwrap();
    let x = Diffusion::noise(&[4, 1, 3, 3], DType::F64, &dev, 4).unwrap();
    let all: Vec<usize> = (0..20).collect();
    for (mode, model, cond) in [
        (Conditioning::Noisy, &joint, Some(&c)),
        (Conditioning::Clean, &clean, Some(&c)),
        (Conditioning::Clean, &oracle_1d(&s), None),
    ] {
        let d = Diffusion::new(s.clone(), mode);
        let a = d.sample_ddpm(model, cond, &x, 11).unwrap();
        let b = d.sample_ddim(model, cond, &x, &all, 1.0, 11).unwrap();
        let diff = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
        assert!(diff < 1e-10, "{mode:?}: max difference {diff}");
    }
}

fn oracle_1d(s: &NoiseSchedule) -> GaussianOracle {
    GaussianOracle::diagonal(s.clone(), &[1.0], &[0.5]).unwrap()
}

/// Least-squares fit `x = slope c + intercept` and the residual variance.
fn regress(c: &Tensor, x: &Tensor) -> (f64, f64, f64, usize) {
    let cv = c.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let xv = x.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let n = cv.len() as f64;
    let (mc, mx) = (cv.iter().sum::<f64>() / n, xv.iter().sum::<f64>() / n);
    let scc = cv.iter().map(|c| (c - mc).powi(2)).sum::<f64>();
    let scx = cv.iter().zip(&xv).map(|(c, x)| (c - mc) * (x - mx)).sum::<f64>();
    let slope = scx / scc;
    let intercept = mx - slope * mc;
    let resid = cv.iter().zip(&xv).map(|(c, x)| (x - intercept - slope * c).powi(2)).sum::<f64>() / (n - 2.0);
    (slope, intercept, resid, cv.len())
}

/// Data of the conditional tests: `c ~ N(0, 1)`, `x = 1 + 0.8 c + 0.3 n`.
const SLOPE: f64 = 0.8;
const INTERCEPT: f64 = 1.0;
const RESID: f64 = 0.09;

fn conditional_oracle(s: &NoiseSchedule) -> GaussianOracle {
    let cov = vec![1.0, SLOPE, SLOPE, SLOPE * SLOPE + RESID];
    GaussianOracle::joint(s.clone(), vec![0.0, INTERCEPT], cov).unwrap()
}

#[test]
fn clean_conditioning_samples_the_conditional_distribution() {
    let dev = Device::Cpu;
    let s = NoiseSchedule::cosine(200, COSINE_S).unwrap();
    let d = Diffusion::new(s.clone(), Conditioning::Clean);
    let o = conditional_oracle(&s).with_clean_condition(1).unwrap();
    let c = pbdl_core::seed::randn((64, 1, 16, 16), 0.0, 1.0, DType::F32, &dev, 21).unwrap();
    let x_t = Diffusion::noise(&[64, 1, 16, 16], DType::F32, &dev, 22).unwrap();
    let x0 = d.sample_ddpm(&o, Some(&c), &x_t, 23).unwrap();
    let (slope, intercept, resid, n) = regress(&c, &x0);
    // Given c the target is N(1 + 0.8 c, 0.09): the diagonal recursion gives the sampler's exact
    // output, E[x | c] = kappa (1 + 0.8 c) (the mean map is linear in the data mean).
    let (kappa, ev) = exact_ddpm(&s, 1.0, RESID);
    let se = (ev / n as f64).sqrt();
    let (_, se_resid) = standard_errors(ev, n);
    println!(
        "clean conditioning, DDPM T=200, n = {n}: slope {slope:.4} intercept {intercept:.4} residual variance \
         {resid:.4} | exact sampler {:.4} {kappa:.4} {ev:.4} | true conditional {SLOPE} {INTERCEPT} {RESID} | \
         4 SE {:.4} (slope, intercept) {:.4} (variance)",
        kappa * SLOPE,
        4.0 * se,
        4.0 * se_resid
    );
    assert!((slope - kappa * SLOPE).abs() < 4.0 * se);
    assert!((intercept - kappa * INTERCEPT).abs() < 4.0 * se);
    assert!((resid - ev).abs() < 4.0 * se_resid);
    // The conditional mean is reproduced within 4 SE of the truth.
    assert!((slope - SLOPE).abs() < 4.0 * se && (intercept - INTERCEPT).abs() < 4.0 * se);
    // DDIM (50 of the 200 steps, eta = 0) with the same condition: its mean map is exact up to
    // the start-noise mismatch, so the conditional mean is right; its variance is biased low
    // (first-order in 1 / k, see the unconditional test) and only printed.
    let x0 = d.sample_ddim(&o, Some(&c), &x_t, &d.ddim_steps(50).unwrap(), 0.0, 0).unwrap();
    let (slope, intercept, resid, _) = regress(&c, &x0);
    let (a, b) = exact_ddim(&s, &d.ddim_steps(50).unwrap(), 1.0, RESID);
    println!(
        "clean conditioning, DDIM 50 of 200: slope {slope:.4} intercept {intercept:.4} residual variance {resid:.4} \
         (exact sampler: variance {:.4}, mean map b = {b:.4} x (1 + 0.8 c))",
        a * a
    );
    assert!((slope - SLOPE).abs() < 4.0 * se && (intercept - INTERCEPT).abs() < 4.0 * se);
    let (_, se_a) = standard_errors(a * a, n);
    assert!((resid - a * a).abs() < 4.0 * se_a);
}

/// Exact `E[x | c] = p c + q` and `Var[x | c]` of ACDM's noisy-conditioning DDPM with the joint oracle.
fn exact_noisy_conditioning(s: &NoiseSchedule) -> (f64, f64, f64) {
    let (mc, mx) = (0.0, INTERCEPT);
    let (s_cc, s_cx, s_xx) = (1.0, SLOPE, SLOPE * SLOPE + RESID);
    // x = p c + q + r n_c + (independent noise of variance v); n_c is the fixed condition noise.
    let (mut p, mut q, mut r, mut v) = (0.0, 0.0, 0.0, 1.0);
    for i in (0..s.len()).rev() {
        let ab = s.alpha_bar(i);
        let (sa, s1) = (ab.sqrt(), (1.0 - ab).sqrt());
        // Row of s1 (ab S + (1 - ab) I)^{-1} for the target channel.
        let (m00, m01, m11) = (ab * s_cc + 1.0 - ab, ab * s_cx, ab * s_xx + 1.0 - ab);
        let det = m00 * m11 - m01 * m01;
        let (a10, a11) = (-s1 * m01 / det, s1 * m00 / det);
        let k = s.beta(i) / s1;
        let sq = s.alpha(i).sqrt();
        // eps_x = a10 (sa c + s1 n_c - sa mc) + a11 (x - sa mx)
        p = (p - k * (a10 * sa + a11 * p)) / sq;
        q = (q - k * (-a10 * sa * mc + a11 * q - a11 * sa * mx)) / sq;
        r = (r - k * (a10 * s1 + a11 * r)) / sq;
        v = v * (1.0 - k * a11).powi(2) / s.alpha(i) + s.posterior_variance(i);
    }
    (p, q, r * r + v)
}

#[test]
fn noisy_conditioning_follows_the_acdm_procedure() {
    let dev = Device::Cpu;
    let s = NoiseSchedule::acdm(20).unwrap();
    let d = Diffusion::new(s.clone(), Conditioning::Noisy);
    let o = conditional_oracle(&s);
    let c = pbdl_core::seed::randn((64, 1, 16, 16), 0.0, 1.0, DType::F32, &dev, 31).unwrap();
    let x_t = Diffusion::noise(&[64, 1, 16, 16], DType::F32, &dev, 32).unwrap();
    let x0 = d.sample_ddpm(&o, Some(&c), &x_t, 33).unwrap();
    let (slope, intercept, resid, n) = regress(&c, &x0);
    let (p, q, var) = exact_noisy_conditioning(&s);
    let se = (var / n as f64).sqrt();
    let (_, se_var) = standard_errors(var, n);
    println!(
        "noisy conditioning (ACDM), R=20, n = {n}: MC slope {slope:.4} intercept {intercept:.4} resid var {resid:.4} \
         | exact sampler {p:.4} {q:.4} {var:.4} | true conditional {SLOPE} {INTERCEPT} {RESID}"
    );
    assert!((slope - p).abs() < 4.0 * se && (intercept - q).abs() < 4.0 * se && (resid - var).abs() < 4.0 * se_var);
    // The procedure must carry the condition: the slope is far from the unconditional 0.
    assert!(slope > 0.5 * SLOPE, "slope {slope}");
}

#[test]
fn huber_and_mse_losses_have_their_closed_forms_and_gradients() {
    let dev = Device::Cpu;
    let pred = Tensor::new(&[0.5f64, 2.0, -3.0, 0.0], &dev).unwrap();
    let target = Tensor::zeros(4, DType::F64, &dev).unwrap();
    let mse = Loss::Mse.compute(&pred, &target).unwrap().to_scalar::<f64>().unwrap();
    let huber = Loss::Huber.compute(&pred, &target).unwrap().to_scalar::<f64>().unwrap();
    assert!((mse - (0.25 + 4.0 + 9.0) / 4.0).abs() < 1e-15);
    assert!((huber - (0.125 + 1.5 + 2.5) / 4.0).abs() < 1e-15);
    let x = pbdl_core::seed::randn(64, 0.0, 2.0, DType::F64, &dev, 1).unwrap();
    let y = pbdl_core::seed::randn(64, 0.0, 1.0, DType::F64, &dev, 2).unwrap();
    for loss in [Loss::Mse, Loss::Huber] {
        let report = pbdl_core::check_grad(
            |v| loss.compute(&v[0], &v[1]).map_err(|e| candle_core::Error::Msg(e.to_string())),
            &[x.clone(), y.clone()],
            &Default::default(),
        )
        .unwrap();
        assert!(report.max_rel_error < 1e-6, "{loss:?}: {report:?}");
    }
}
