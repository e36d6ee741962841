//! BPTT gradient modes on a linear toy against hand-derived gradients.
//!
//! Two independent scalar systems (one per component of the state and of `w`):
//! `s_{n+1} = a s_n + b u_n`, `u_n = w s_n`, loss `sum_i s_{N,i}^2`. With `lambda = a + b w`,
//! `s_n = lambda^n s_0` and, writing `d_n = ds_n/dw`:
//! * F: `d_{n+1} = lambda d_n + b s_n`  (so `d_N = N lambda^{N-1} b s_0`)
//! * P: `d_{n+1} = a d_n + b s_n`       (the network input is stopped)
//! * S: `d_N = b s_{N-1}`               (both stopped: only the last control acts)
//!
//! and `dL/dw = 2 s_N d_N`.

use candle_core::{Device, Tensor, Var};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{gradients, GradientMode};

const A: [f64; 2] = [0.9, 0.5];
const B: f64 = 1.0;
const W: [f64; 2] = [-1.5, 0.2];
const S0: [f64; 2] = [1.0, 0.8];
const N: usize = 4;

fn analytic(mode: GradientMode) -> [f64; 2] {
    let mut g = [0.0; 2];
    for i in 0..2 {
        let lam = A[i] + B * W[i];
        let s: Vec<f64> = (0..=N).map(|n| lam.powi(n as i32) * S0[i]).collect();
        let mut d = 0.0;
        for n in 0..N {
            d = match mode {
                GradientMode::F => lam * d + B * s[n],
                GradientMode::P => A[i] * d + B * s[n],
                GradientMode::S => B * s[n],
                GradientMode::C => unreachable!(),
            };
        }
        g[i] = 2.0 * s[N] * d;
    }
    g
}

fn ours(mode: GradientMode, clip: &ClipConfig) -> (Vec<f64>, Option<f64>) {
    let dev = Device::Cpu;
    let w = Var::new(&W, &dev).unwrap();
    let a = Tensor::new(&A, &dev).unwrap();
    let s0 = Tensor::new(&S0, &dev).unwrap();
    let net = |s: &Tensor| s.mul(w.as_tensor());
    let physics = |s: &Tensor, u: &Tensor| s.mul(&a)? + (u * B)?;
    let loss = |traj: &[Tensor]| traj.last().unwrap().sqr()?.sum_all();
    let out = gradients(mode, std::slice::from_ref(&w), &s0, N, &net, &physics, &loss, clip).unwrap();
    (out.grads.get(w.as_tensor()).unwrap().to_vec1::<f64>().unwrap(), out.agreement)
}

fn close(a: &[f64], b: &[f64]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12 * (1.0 + y.abs()))
}

#[test]
fn modes_f_p_s_match_analytic_gradients() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::S] {
        let (g, _) = ours(mode, &ClipConfig::None);
        let want = analytic(mode);
        assert!(close(&g, &want), "{mode:?}: ours {g:?}, analytic {want:?}");
    }
}

#[test]
fn mode_c_keeps_p_where_signs_agree_and_zeroes_the_rest() {
    let (f, p) = (analytic(GradientMode::F), analytic(GradientMode::P));
    // The toy is built so that component 0 disagrees and component 1 agrees.
    assert!(f[0] * p[0] < 0.0 && f[1] * p[1] > 0.0, "F {f:?}, P {p:?}");
    let (g, agreement) = ours(GradientMode::C, &ClipConfig::None);
    assert!(close(&g, &[0.0, p[1]]), "C {g:?}");
    assert_eq!(agreement, Some(0.5));
}

#[test]
fn clipping_by_value_and_global_norm() {
    let p = analytic(GradientMode::P);
    let (g, _) = ours(GradientMode::P, &ClipConfig::Value { max_value: 0.1 });
    let want: Vec<f64> = p.iter().map(|v| v.clamp(-0.1, 0.1)).collect();
    assert!(close(&g, &want), "value clip {g:?} vs {want:?}");
    let (g, _) = ours(GradientMode::F, &ClipConfig::Norm { max_norm: 1e-3 });
    let f = analytic(GradientMode::F);
    let norm = (f[0] * f[0] + f[1] * f[1]).sqrt();
    assert!(norm > 1e-3);
    let want: Vec<f64> = f.iter().map(|v| v * 1e-3 / norm).collect();
    assert!(close(&g, &want), "norm clip {g:?} vs {want:?}");
}
