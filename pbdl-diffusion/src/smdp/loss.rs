//! SMDP's training losses for the toy score network, with their gradients.
//!
//! * 1-step: `|| x_t - dt [P(x_t) - s/2] - x_{t-dt} ||^2 + (1/4) dt^2 ||s||^2`. The second term
//!   makes the minimiser the exact score `g^2 grad log p_t` instead of a multiple of it.
//! * multi-step: the probability-flow step is rolled `S` times from a data state and the squared
//!   error to the data path is summed over all steps; the gradient flows through the whole
//!   rollout (through `P` and through the network's input).
//!
//! Both return the batch-mean loss and add its parameter gradient into a buffer.
//!
//! Which sampler each loss calibrates: with `r = x_t - dt P(x_t) - x_{t-dt}`, the 1-step
//! minimiser is `s = -E[r | x_t] / dt`, so a reverse-SDE step (score weight 1) lands on
//! `E[x_{t-dt} | x_t]`, while a probability-flow step (weight 1/2) corrects only half of the
//! inverse physics' Euler error. The multi-step loss fits the ODE rollout itself, so its `s` is
//! calibrated for the ODE and over-corrects in an SDE step. On the quadratic toy, where that
//! Euler error is large near `t = 0`, this decides which sampler lands on `+-1`.

use super::mlp::{MlpCache, ScoreMlp};
use super::physics::ScalarDrift;

/// Reusable buffers for the losses (no allocation per update once warm).
#[derive(Clone, Debug, Default)]
pub struct LossWorkspace {
    caches: Vec<MlpCache>,
    s: Vec<f64>,
    gs: Vec<f64>,
    gx: Vec<f64>,
    xs: Vec<Vec<f64>>,
    ts: Vec<f64>,
}

/// The 1-step loss (with the regulariser) of a batch of transitions `x_t -> x_prev` (where
/// `x_prev` is the data state one step `dt` earlier), networks evaluated at times `t`.
/// Adds `d loss / d params` into `grad` when given.
#[allow(clippy::too_many_arguments)]
pub fn one_step_loss(
    net: &ScoreMlp,
    drift: &impl ScalarDrift,
    dt: f64,
    x_t: &[f64],
    t: &[f64],
    x_prev: &[f64],
    grad: Option<&mut [f64]>,
    ws: &mut LossWorkspace,
) -> f64 {
    steps_loss(net, drift, |_| (dt, 1.0), x_t, t, x_prev, grad, ws)
}

/// The 1-step loss on a graded time grid: sample `i` is a transition over its own step `h[i]`
/// (`x_prev[i]` lies `h[i]` before `x_t[i]`), weighted by `w[i]`. The plain loss scales with
/// `h^2`, so `w = (h_ref / h)^2` weighs every step length alike in units of the score. With all
/// `h[i] = h_ref` and `w[i] = 1` it is [`one_step_loss`]. Adds `d loss / d params` into `grad`
/// when given.
#[allow(clippy::too_many_arguments)]
pub fn graded_one_step_loss(
    net: &ScoreMlp,
    drift: &impl ScalarDrift,
    h: &[f64],
    w: &[f64],
    x_t: &[f64],
    t: &[f64],
    x_prev: &[f64],
    grad: Option<&mut [f64]>,
    ws: &mut LossWorkspace,
) -> f64 {
    steps_loss(net, drift, |i| (h[i], w[i]), x_t, t, x_prev, grad, ws)
}

/// The regularised 1-step loss with step and weight `step_weight(i)` for sample `i`.
#[allow(clippy::too_many_arguments)]
fn steps_loss(
    net: &ScoreMlp,
    drift: &impl ScalarDrift,
    step_weight: impl Fn(usize) -> (f64, f64),
    x_t: &[f64],
    t: &[f64],
    x_prev: &[f64],
    grad: Option<&mut [f64]>,
    ws: &mut LossWorkspace,
) -> f64 {
    let b = x_t.len();
    let inv_b = 1.0 / b as f64;
    ws.caches.resize_with(1, MlpCache::default);
    ws.s.resize(b, 0.0);
    net.forward(x_t, t, &mut ws.s, &mut ws.caches[0]);
    ws.gs.resize(b, 0.0);
    let mut loss = 0.0;
    for i in 0..b {
        let (dt, w) = step_weight(i);
        let s = ws.s[i];
        let r = x_t[i] - dt * (drift.drift(x_t[i]) - 0.5 * s) - x_prev[i];
        loss += w * (r * r + 0.25 * dt * dt * s * s);
        // d/ds of r^2 is 2 r (dt / 2); of the regulariser (1/2) dt^2 s.
        ws.gs[i] = w * inv_b * (dt * r + 0.5 * dt * dt * s);
    }
    if let Some(g) = grad {
        ws.gx.resize(b, 0.0);
        net.backward(&mut ws.caches[0], &ws.gs, g, &mut ws.gx);
    }
    loss * inv_b
}

/// The multi-step loss: from `x_start` at times `t_start`, `targets.len()` probability-flow steps
/// backward, `sum_m mean_i (xhat_{m,i} - targets[m][i])^2` where `targets[m]` is the data state
/// `(m + 1) dt` before the start. With `regularise`, each step also adds `(1/4) dt^2 mean s^2`
/// (so a window of one equals [`one_step_loss`]). Adds the parameter gradient into `grad`.
#[allow(clippy::too_many_arguments)]
pub fn multi_step_loss(
    net: &ScoreMlp,
    drift: &impl ScalarDrift,
    dt: f64,
    x_start: &[f64],
    t_start: &[f64],
    targets: &[Vec<f64>],
    regularise: bool,
    grad: Option<&mut [f64]>,
    ws: &mut LossWorkspace,
) -> f64 {
    let b = x_start.len();
    let steps = targets.len();
    let inv_b = 1.0 / b as f64;
    let reg = if regularise { 0.25 * dt * dt } else { 0.0 };
    ws.caches.resize_with(steps.max(1), MlpCache::default);
    ws.xs.resize_with(steps + 1, Vec::new);
    ws.xs[0].clear();
    ws.xs[0].extend_from_slice(x_start);
    // Scores of every step are kept: the regulariser's gradient needs them.
    let mut scores = vec![0.0; b * steps];
    ws.ts.resize(b, 0.0);
    let mut loss = 0.0;
    for m in 0..steps {
        for i in 0..b {
            ws.ts[i] = t_start[i] - m as f64 * dt;
        }
        let (lo, hi) = ws.xs.split_at_mut(m + 1);
        let x = &lo[m];
        let s = &mut scores[m * b..(m + 1) * b];
        net.forward(x, &ws.ts, s, &mut ws.caches[m]);
        let next = &mut hi[0];
        next.resize(b, 0.0);
        for i in 0..b {
            next[i] = x[i] - dt * (drift.drift(x[i]) - 0.5 * s[i]);
            let e = next[i] - targets[m][i];
            loss += inv_b * (e * e + reg * s[i] * s[i]);
        }
    }
    if let Some(g) = grad {
        // Adjoint of the state after step m (d loss / d xhat_{m+1}), walked backward.
        let mut lam = vec![0.0; b];
        let mut gs = vec![0.0; b];
        ws.gx.resize(b, 0.0);
        for m in (0..steps).rev() {
            let x = &ws.xs[m];
            let next = &ws.xs[m + 1];
            for i in 0..b {
                lam[i] += 2.0 * inv_b * (next[i] - targets[m][i]);
                gs[i] = lam[i] * 0.5 * dt + 2.0 * reg * inv_b * scores[m * b + i];
            }
            net.backward(&mut ws.caches[m], &gs, g, &mut ws.gx);
            for i in 0..b {
                lam[i] = lam[i] * (1.0 - dt * drift.drift_dx(x[i])) + ws.gx[i];
            }
        }
    }
    loss
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smdp::physics::ToyDrift;

    fn setup() -> (ScoreMlp, Vec<f64>, Vec<f64>, Vec<Vec<f64>>) {
        let mut net = ScoreMlp::new(&[8, 6, 1], 5).unwrap();
        for (i, p) in net.params_mut().iter_mut().enumerate() {
            *p += 0.1 * ((i as f64) * 1.3).cos();
        }
        let x = vec![0.9, -0.7, 0.2, -0.05, 0.6];
        let t = vec![0.3, 0.5, 2.0, 8.0, 0.1];
        let targets: Vec<Vec<f64>> =
            (0..4).map(|m| x.iter().map(|v| v * (1.05 + 0.02 * m as f64) + 0.003 * m as f64).collect()).collect();
        (net, x, t, targets)
    }

    fn fd_check(f: impl Fn(&ScoreMlp) -> f64, net: &ScoreMlp, analytic: &[f64]) -> f64 {
        let h = 1e-6;
        let mut worst: f64 = 0.0;
        for i in 0..net.num_params() {
            let (mut a, mut b) = (net.clone(), net.clone());
            a.params_mut()[i] += h;
            b.params_mut()[i] -= h;
            let fd = (f(&a) - f(&b)) / (2.0 * h);
            let scale = analytic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            worst = worst.max((fd - analytic[i]).abs() / scale);
        }
        worst
    }

    #[test]
    fn one_step_gradient_matches_finite_differences() {
        let (net, x, t, targets) = setup();
        for drift in [ToyDrift::quadratic(), ToyDrift::affine()] {
            let mut ws = LossWorkspace::default();
            let mut g = vec![0.0; net.num_params()];
            one_step_loss(&net, &drift, 0.02, &x, &t, &targets[0], Some(&mut g), &mut ws);
            let f =
                |n: &ScoreMlp| one_step_loss(n, &drift, 0.02, &x, &t, &targets[0], None, &mut LossWorkspace::default());
            let worst = fd_check(f, &net, &g);
            assert!(worst < 1e-6, "{drift:?}: worst error relative to the largest gradient {worst}");
        }
    }

    #[test]
    fn graded_one_step_gradient_matches_finite_differences() {
        let (net, x, t, targets) = setup();
        let drift = ToyDrift::quadratic();
        let h: Vec<f64> = (0..x.len()).map(|i| if i % 2 == 0 { 0.02 } else { 0.0025 }).collect();
        let w: Vec<f64> = h.iter().map(|v| (0.02 / v).powi(2)).collect();
        let mut g = vec![0.0; net.num_params()];
        let mut ws = LossWorkspace::default();
        graded_one_step_loss(&net, &drift, &h, &w, &x, &t, &targets[0], Some(&mut g), &mut ws);
        let f = |n: &ScoreMlp| {
            graded_one_step_loss(n, &drift, &h, &w, &x, &t, &targets[0], None, &mut LossWorkspace::default())
        };
        let err = fd_check(f, &net, &g);
        assert!(err < 1e-6, "relative error {err}");
        // Equal steps and weights: the plain 1-step loss.
        let (same, ones) = (vec![0.02; x.len()], vec![1.0; x.len()]);
        let a = graded_one_step_loss(&net, &drift, &same, &ones, &x, &t, &targets[0], None, &mut ws);
        let b = one_step_loss(&net, &drift, 0.02, &x, &t, &targets[0], None, &mut ws);
        assert_eq!(a, b);
    }

    #[test]
    fn multi_step_gradient_matches_finite_differences_through_the_rollout() {
        let (net, x, t, targets) = setup();
        // A large dt makes the coupling through P and through the network input matter.
        let dt = 0.1;
        for regularise in [false, true] {
            let drift = ToyDrift::quadratic();
            let mut ws = LossWorkspace::default();
            let mut g = vec![0.0; net.num_params()];
            multi_step_loss(&net, &drift, dt, &x, &t, &targets, regularise, Some(&mut g), &mut ws);
            let f = |n: &ScoreMlp| {
                multi_step_loss(n, &drift, dt, &x, &t, &targets, regularise, None, &mut LossWorkspace::default())
            };
            let worst = fd_check(f, &net, &g);
            assert!(worst < 1e-6, "regularise {regularise}: worst error {worst}");
        }
    }

    #[test]
    fn a_window_of_one_with_the_regulariser_is_the_one_step_loss() {
        let (net, x, t, targets) = setup();
        let d = ToyDrift::quadratic();
        let mut ws = LossWorkspace::default();
        let a = one_step_loss(&net, &d, 0.02, &x, &t, &targets[0], None, &mut ws);
        let b = multi_step_loss(&net, &d, 0.02, &x, &t, &targets[..1], true, None, &mut ws);
        assert!((a - b).abs() < 1e-15 * a.abs().max(1e-300), "{a} vs {b}");
    }
}
