//! The cart-pole experiment with a hand-written adjoint in `f64`: forward rollout and
//! reverse-mode adjoint of the dense tanh controller plus the semi-implicit Euler cart-pole
//! step, with the gradient modes of [`crate::bptt`], clipping as
//! [`pbdl_core::train::ClipConfig`] and Adam as [`pbdl_core::train::AdamConfig`] (candle-nn's
//! update, operation for operation).
//!
//! The candle autograd path ([`super::train`]) spends its time in per-op overhead on tiny tensors
//! (`b = 8`, 100 steps): about 100 ms per update (200 ms in mode C) on the 2-core development
//! machine. Here the rollout is plain loops and faer GEMMs over buffers allocated once per run:
//! 2-7 ms per update there (20-60x; the machine was shared, so the spread is load), so the
//! paper's 32,000 Adam steps take minutes. Same data, same initial weights, same gradients
//! (tests compare every mode with the candle path to `1e-10` relative), same optimiser.
//! The bench `cartpole` (`benches/cartpole.rs`) times one gradient on both paths;
//! `examples/cartpole_modes.rs` runs the paper-length sweep.
//!
//! Because the controller outputs one scalar per sample, every mode's gradient is
//! `sum_(n, b) a_u[n, b] grad_theta u(s_n^b)`: the modes differ only in the force adjoints
//! `a_u` (see [`AdjointBptt`]), so mode C costs one forward rollout, the shared backward vectors
//! and two cheap adjoint recursions, not two full backward passes.
//!
//! Adjoint of one step (per pole `i`, `p_i = sin th_i th_d_i^2`, `den_i = l (4/3 - m cos^2 th_i / M)`,
//! `num_i = g sin th_i - cos th_i A_i`): given the adjoints `X', TH'_i, XD', THD'_i` of the new
//! state, the semi-implicit update gives `a(xd') = XD' + dt X'`, `a(thd'_i) = THD'_i + dt TH'_i`,
//! `a(x_dd) = dt a(xd')`, `a(th_dd_i) = dt a(thd'_i) - a(sum) cos th_i` with
//! `a(sum) = a(x_dd) m l / M`; the rest is the chain rule through `th_dd_i = num_i / den_i` and
//! `A_i = (F + m l p_i) / M`, written out in [`step_adjoint`].
//!
//! ```
//! use pbdl_optim::bptt::GradientMode;
//! use pbdl_optim::cartpole::adjoint::{AdjointBptt, AdjointController};
//! use pbdl_optim::cartpole::CartPole;
//! use pbdl_core::train::ClipConfig;
//!
//! let mut phys = CartPole::new(2);
//! phys.steps = 10;
//! let net = AdjointController::with_zero_last_layer(phys.state_dim(), 16, 42)?;
//! let s0 = phys.initial_states(4, 0)?.flatten_all()?.to_vec1::<f64>()?;
//! let mut bptt = AdjointBptt::new(&phys, 16, 4);
//! let info = bptt.gradients(&net, &s0, GradientMode::C, &ClipConfig::Norm { max_norm: 1.0 })?;
//! assert!(info.loss > 1.8 && info.agreement.is_some());
//! assert_eq!(bptt.grad().len(), net.params().len());
//! # Ok::<(), pbdl_optim::Error>(())
//! ```

use super::{CartPole, CartPoleConfig, CartPoleRun, Controller};
use crate::bptt::{run_schedule, schedule_loop, GradientMode, RunDir};
use crate::error::{check_len, Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Init, VarMap};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use pbdl_core::train::{clip_in_place, AdamConfig, ClipConfig, FlatAdam, TrainLoop};
use std::cell::RefCell;

/// Offsets of the six parameter blocks in a flat vector, in the order of
/// [`DenseController::vars`](crate::controller::DenseController::vars): `w0 [inputs, width]`,
/// `b0 [width]`, `w1 [width, width]`, `b1 [width]`, `w2 [width, 1]`, `b2 [1]` (row-major).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Layout {
    d: usize,
    h: usize,
}

impl Layout {
    fn sizes(&self) -> [usize; 6] {
        let (d, h) = (self.d, self.h);
        [d * h, h, h * h, h, h, 1]
    }

    fn len(&self) -> usize {
        self.sizes().iter().sum()
    }
}

/// The six blocks of a flat parameter (or gradient) vector.
struct Parts<'a> {
    w0: &'a [f64],
    b0: &'a [f64],
    w1: &'a [f64],
    b1: &'a [f64],
    w2: &'a [f64],
    b2: f64,
}

/// The six blocks of a flat gradient vector, mutable.
struct PartsMut<'a> {
    w0: &'a mut [f64],
    b0: &'a mut [f64],
    w1: &'a mut [f64],
    b1: &'a mut [f64],
    w2: &'a mut [f64],
    b2: &'a mut f64,
}

fn split(p: &[f64], l: Layout) -> Parts<'_> {
    let [a, b, c, d, e, _] = l.sizes();
    let (w0, r) = p.split_at(a);
    let (b0, r) = r.split_at(b);
    let (w1, r) = r.split_at(c);
    let (b1, r) = r.split_at(d);
    let (w2, r) = r.split_at(e);
    Parts { w0, b0, w1, b1, w2, b2: r[0] }
}

fn split_mut(p: &mut [f64], l: Layout) -> PartsMut<'_> {
    let [a, b, c, d, e, _] = l.sizes();
    let (w0, r) = p.split_at_mut(a);
    let (b0, r) = r.split_at_mut(b);
    let (w1, r) = r.split_at_mut(c);
    let (b1, r) = r.split_at_mut(d);
    let (w2, r) = r.split_at_mut(e);
    PartsMut { w0, b0, w1, b1, w2, b2: &mut r[0] }
}

/// The cart-pole controller `inputs -> width -> width -> 1` (tanh) as one flat `f64` vector in
/// the layout of [`DenseController`](crate::controller::DenseController).
#[derive(Clone, Debug, PartialEq)]
pub struct AdjointController {
    layout: Layout,
    params: Vec<f64>,
}

impl AdjointController {
    /// The same weights as [`DenseController::with_zero_last_layer`](crate::controller::DenseController::with_zero_last_layer)
    /// with this seed (Glorot-uniform hidden weights, zero last layer and biases).
    pub fn with_zero_last_layer(inputs: usize, width: usize, seed: u64) -> Result<Self> {
        Self::from_dense(&Controller::with_zero_last_layer(inputs, width, 1, seed)?)
    }

    /// Copies the weights of a candle controller with one output.
    pub fn from_dense(net: &Controller) -> Result<Self> {
        let vars = net.vars();
        check_len("controller vars (w0, b0, w1, b1, w2, b2)", 6, vars.len())?;
        let (inputs, width) = vars[0].as_tensor().dims2()?;
        let layout = Layout { d: inputs, h: width };
        let mut params = Vec::with_capacity(layout.len());
        for (k, (v, n)) in vars.iter().zip(layout.sizes()).enumerate() {
            let flat = v.as_tensor().flatten_all()?.to_dtype(candle_core::DType::F64)?.to_vec1::<f64>()?;
            check_len(["w0", "b0", "w1", "b1", "w2 (one output only)", "b2"][k], n, flat.len())?;
            params.extend(flat);
        }
        Ok(Self { layout, params })
    }

    /// Input length.
    pub fn inputs(&self) -> usize {
        self.layout.d
    }

    /// Hidden width.
    pub fn width(&self) -> usize {
        self.layout.h
    }

    /// The flat parameters `[w0, b0, w1, b1, w2, b2]` (row-major, `w` as `[in, out]`).
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// The flat parameters, mutable (for an optimiser).
    pub fn params_mut(&mut self) -> &mut [f64] {
        &mut self.params
    }

    /// The start offsets of the six blocks `w0, b0, w1, b1, w2, b2` in [`Self::params`].
    pub fn offsets(&self) -> [usize; 6] {
        let s = self.layout.sizes();
        let mut o = [0; 6];
        for k in 1..6 {
            o[k] = o[k - 1] + s[k - 1];
        }
        o
    }
}

/// `y += a x`.
#[inline(always)]
fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// A dot product with four partial sums (so that it vectorises).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// `out [n, dout] = tanh(input [n, din] w [din, dout] + bias)`.
#[inline(always)]
fn dense_tanh(input: &[f64], n: usize, din: usize, w: &[f64], bias: &[f64], out: &mut [f64]) {
    let dout = bias.len();
    // faer's SIMD GEMM: the axpy loops this replaced were load/store bound.
    gemm(view_mut(out, n, dout), false, view(input, n, din), view(w, din, dout));
    bias_tanh(&mut out[..n * dout], bias);
}

/// `z = tanh(z + bias)` for every row of `z`, with AVX2 where the CPU has it (the same IEEE
/// operations, so the same numbers, four lanes wide instead of SSE2's two).
fn bias_tanh(z: &mut [f64], bias: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { bias_tanh_avx2(z, bias) };
        return;
    }
    bias_tanh_generic(z, bias);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bias_tanh_avx2(z: &mut [f64], bias: &[f64]) {
    bias_tanh_generic(z, bias);
}

#[inline(always)]
fn bias_tanh_generic(z: &mut [f64], bias: &[f64]) {
    for row in z.chunks_exact_mut(bias.len()) {
        for (v, bj) in row.iter_mut().zip(bias) {
            *v = tanh(*v + bj);
        }
    }
}

/// `tanh` to about `2e-16` absolute, branch-free so that loops over it vectorise (libm's
/// `tanh` was 40 % of a training step). `tanh |x| = (1 - z) / (1 + z)` with `z = exp(-2 |x|)`
/// from a range reduction `z = 2^k exp(r)`, `|r| <= ln 2 / 2`, and the degree-13 Taylor
/// polynomial of `exp(r)` (truncation below `1e-17`). NaN stays NaN.
#[inline(always)]
pub fn tanh(x: f64) -> f64 {
    // 1.5 * 2^52: adding it rounds to an integer, kept in the low mantissa bits.
    const MAGIC: f64 = 6755399441055744.0;
    // ln 2 split so that k * LN2_HI is exact (fdlibm's constants).
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    let y = -2.0 * x.abs();
    // exp(-40) is below half an ulp of 1: tanh is +-1 there. (`<` keeps NaN.)
    let y = if y < -40.0 { -40.0 } else { y };
    let t = y * std::f64::consts::LOG2_E + MAGIC;
    let k = t - MAGIC;
    let r = (y - k * LN2_HI) - k * LN2_LO;
    let mut p = 1.0 / 6_227_020_800.0;
    for c in [
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    // 2^k from the integer in t's low bits: (k + 1023) into the exponent field.
    let z = p * f64::from_bits(t.to_bits().wrapping_add(1023) << 52);
    ((1.0 - z) / (1.0 + z)).copysign(x)
}

/// The controller's forces `u [n]` for states `s [n, d]`; `h0`, `h1` receive the hidden
/// activations `[n, width]`.
#[inline(always)]
fn controller_forward(p: &Parts, l: Layout, s: &[f64], n: usize, h0: &mut [f64], h1: &mut [f64], u: &mut [f64]) {
    dense_tanh(s, n, l.d, p.w0, p.b0, h0);
    dense_tanh(h0, n, l.h, p.w1, p.b1, h1);
    for b in 0..n {
        u[b] = dot(&h1[b * l.h..(b + 1) * l.h], p.w2) + p.b2;
    }
}

/// `dst [m, n] = lhs [m, k] rhs [k, n]` (`accumulate`: `dst +=`), sequential faer GEMM.
fn gemm(dst: MatMut<'_, f64>, accumulate: bool, lhs: MatRef<'_, f64>, rhs: MatRef<'_, f64>) {
    let beta = if accumulate { Accum::Add } else { Accum::Replace };
    matmul(dst, beta, lhs, rhs, 1.0, Par::Seq);
}

/// Row-major `rows x cols` view.
fn view(data: &[f64], rows: usize, cols: usize) -> MatRef<'_, f64> {
    MatRef::from_row_major_slice(&data[..rows * cols], rows, cols)
}

/// Row-major `rows x cols` mutable view.
fn view_mut(data: &mut [f64], rows: usize, cols: usize) -> MatMut<'_, f64> {
    MatMut::from_row_major_slice_mut(&mut data[..rows * cols], rows, cols)
}

/// One semi-implicit Euler step of one sample (the operations of [`CartPole::step`], in its
/// order): `s [d]` and force `f` to `out [d]`.
#[inline(always)]
pub fn step(p: &CartPole, s: &[f64], f: f64, out: &mut [f64]) {
    let nc = p.poles;
    let (m, big_m, l, g, dt) = (p.pole_mass, p.total_mass, p.half_length, p.gravity, p.dt);
    let mut sum = 0.0;
    for i in 0..nc {
        let (th, thd) = (s[1 + i], s[2 + nc + i]);
        let (sn, cs) = th.sin_cos();
        let pq = sn * (thd * thd);
        let a = (pq * (m * l) + f) / big_m;
        let den = (cs * cs * (-m / big_m) + 4.0 / 3.0) * l;
        let thdd = (sn * g - cs * a) / den;
        sum += pq - thdd * cs;
        let thd_new = thd + thdd * dt;
        out[2 + nc + i] = thd_new;
        out[1 + i] = th + thd_new * dt;
    }
    let xdd = (f + sum * (m * l)) / big_m;
    let xd_new = s[1 + nc] + xdd * dt;
    out[1 + nc] = xd_new;
    out[0] = s[0] + xd_new * dt;
}

/// Reverse mode of [`step`]: given the adjoint `a_out [d]` of the new state, writes the adjoint
/// of the old state `s` into `a_in [d]` and returns the adjoint of the force `f`.
#[inline(always)]
pub fn step_adjoint(p: &CartPole, s: &[f64], f: f64, a_out: &[f64], a_in: &mut [f64]) -> f64 {
    let nc = p.poles;
    let (m, big_m, l, g, dt) = (p.pole_mass, p.total_mass, p.half_length, p.gravity, p.dt);
    let ml = m * l;
    // x' = x + dt xd', xd' = xd + dt x_dd, x_dd = (F + m l sum) / M
    let axd = a_out[1 + nc] + dt * a_out[0];
    a_in[0] = a_out[0];
    a_in[1 + nc] = axd;
    let axdd = dt * axd;
    let mut af = axdd / big_m;
    let asum = axdd * ml / big_m;
    for i in 0..nc {
        let (th, thd) = (s[1 + i], s[2 + nc + i]);
        let (sn, cs) = th.sin_cos();
        let q = thd * thd;
        let pq = sn * q;
        let a = (pq * ml + f) / big_m;
        let den = (cs * cs * (-m / big_m) + 4.0 / 3.0) * l;
        let num = sn * g - cs * a;
        let thdd = num / den;
        // th' = th + dt thd', thd' = thd + dt th_dd
        let athd = a_out[2 + nc + i] + dt * a_out[1 + i];
        // sum += p - th_dd cos
        let athdd = dt * athd - asum * cs;
        let mut acs = -asum * thdd;
        let mut ap = asum;
        let anum = athdd / den;
        let aden = -athdd * thdd / den;
        let mut asn = g * anum;
        acs -= a * anum;
        let aa = -cs * anum;
        acs += aden * l * (-m / big_m) * 2.0 * cs;
        af += aa / big_m;
        ap += aa * ml / big_m;
        asn += ap * q;
        let aq = ap * sn;
        a_in[2 + nc + i] = athd + 2.0 * thd * aq;
        a_in[1 + i] = a_out[1 + i] + cs * asn - sn * acs;
    }
    af
}

/// What [`AdjointBptt::gradients`] measured; the gradient itself is [`AdjointBptt::grad`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdjointGradInfo {
    /// The loss `1 - mean cos th` of the rollout.
    pub loss: f64,
    /// Global norm of the (combined) gradient before clipping.
    pub norm_before_clip: f64,
    /// Mode C only: fraction of components whose signs of `g_P` and `g_F` agreed.
    pub agreement: Option<f64>,
}

/// Buffers of rollouts and adjoints for one physics, width and batch size, allocated once.
///
/// The controller's output is a scalar, so the gradient of any mode is
/// `sum_(n, b) a_u[n, b] grad_theta u(s_n^b)`: the modes differ only in the force adjoints
/// `a_u`. After the forward rollout the per-sample backward vectors that do not depend on
/// `a_u` (`c = w2 (1 - h1^2)`, `e = (W1 c) (1 - h0^2)`, `du/ds = W0 e`) are computed for all
/// steps at once (GEMMs); each mode then needs only its cheap adjoint recursion through the
/// physics and one weighted sum over all steps (GEMMs again).
#[derive(Debug)]
pub struct AdjointBptt {
    phys: CartPole,
    layout: Layout,
    batch: usize,
    /// States `[steps + 1, batch, d]`.
    s: Vec<f64>,
    /// Hidden activations `[steps * batch, width]`.
    h0: Vec<f64>,
    h1: Vec<f64>,
    /// Forces `[steps * batch]`.
    u: Vec<f64>,
    /// `c = w2 (1 - h1^2)` and `e = (W1 c) (1 - h0^2)`, `[steps * batch, width]`.
    c: Vec<f64>,
    e: Vec<f64>,
    /// `du/ds = W0 e`, `[steps * batch, d]`.
    js: Vec<f64>,
    /// Force adjoints `[steps * batch]` of the mode being computed.
    au: Vec<f64>,
    /// `a_u`-weighted `c` and `e`.
    wc: Vec<f64>,
    we: Vec<f64>,
    lam: Vec<f64>,
    lam_prev: Vec<f64>,
    grad: Vec<f64>,
    grad_f: Vec<f64>,
}

impl AdjointBptt {
    /// Buffers for `phys`, a controller of hidden width `width`, and batches of `batch` samples.
    pub fn new(phys: &CartPole, width: usize, batch: usize) -> Self {
        let layout = Layout { d: phys.state_dim(), h: width };
        let (d, n, h) = (layout.d, phys.steps, width);
        let rows = n * batch;
        Self {
            phys: *phys,
            layout,
            batch,
            s: vec![0.0; (n + 1) * batch * d],
            h0: vec![0.0; rows * h],
            h1: vec![0.0; rows * h],
            u: vec![0.0; rows],
            c: vec![0.0; rows * h],
            e: vec![0.0; rows * h],
            js: vec![0.0; rows * d],
            au: vec![0.0; rows],
            wc: vec![0.0; rows * h],
            we: vec![0.0; rows * h],
            lam: vec![0.0; batch * d],
            lam_prev: vec![0.0; batch * d],
            grad: vec![0.0; layout.len()],
            grad_f: vec![0.0; layout.len()],
        }
    }

    /// The gradient of the last [`Self::gradients`] call (combined and clipped), in the layout
    /// of [`AdjointController::params`].
    pub fn grad(&self) -> &[f64] {
        &self.grad
    }

    fn check(&self, net: &AdjointController, s0: &[f64]) -> Result<()> {
        if net.layout != self.layout {
            return Err(Error::shape(
                "controller (inputs, width) for these AdjointBptt buffers",
                format!("({}, {})", self.layout.d, self.layout.h),
                format!("({}, {})", net.layout.d, net.layout.h),
            ));
        }
        check_len("s0 length (batch * state_dim)", self.batch * self.layout.d, s0.len())
    }

    /// Forward rollout from `s0 [batch, d]`, keeping what the adjoint needs; returns the loss.
    fn forward(&mut self, net: &AdjointController, s0: &[f64]) -> f64 {
        let (l, b, nsteps) = (self.layout, self.batch, self.phys.steps);
        let (d, h) = (l.d, l.h);
        let p = split(&net.params, l);
        self.s[..b * d].copy_from_slice(s0);
        for n in 0..nsteps {
            let (cur, next) = self.s[n * b * d..(n + 2) * b * d].split_at_mut(b * d);
            let (h0, h1) = (&mut self.h0[n * b * h..(n + 1) * b * h], &mut self.h1[n * b * h..(n + 1) * b * h]);
            let u = &mut self.u[n * b..(n + 1) * b];
            controller_forward(&p, l, cur, b, h0, h1, u);
            for k in 0..b {
                step(&self.phys, &cur[k * d..(k + 1) * d], u[k], &mut next[k * d..(k + 1) * d]);
            }
        }
        loss_of(&self.phys, &self.s[nsteps * b * d..])
    }

    /// The backward vectors that every mode shares: `c`, `e` and `du/ds` for all steps.
    fn shared_backward(&mut self, net: &AdjointController) {
        let l = self.layout;
        let (d, h, rows) = (l.d, l.h, self.phys.steps * self.batch);
        let p = split(&net.params, l);
        for (crow, hrow) in self.c.chunks_exact_mut(h).zip(self.h1.chunks_exact(h)) {
            for ((c, w), hv) in crow.iter_mut().zip(p.w2).zip(hrow) {
                *c = w * (1.0 - hv * hv);
            }
        }
        // e = (c W1^T) (1 - h0^2); du/ds = e W0^T
        gemm(view_mut(&mut self.e, rows, h), false, view(&self.c, rows, h), view(p.w1, h, h).transpose());
        for (v, hv) in self.e.iter_mut().zip(&self.h0) {
            *v *= 1.0 - hv * hv;
        }
        gemm(view_mut(&mut self.js, rows, d), false, view(&self.e, rows, h), view(p.w0, d, h).transpose());
    }

    /// The force adjoints `au` of `mode` (F, P or S) by the adjoint recursion through the physics.
    fn force_adjoints(&mut self, mode: GradientMode) {
        let (d, b, nsteps) = (self.layout.d, self.batch, self.phys.steps);
        let nc = self.phys.poles;
        // d loss / d th_i = sin th_i / (batch * poles)
        let count = (b * nc) as f64;
        let last = &self.s[nsteps * b * d..(nsteps + 1) * b * d];
        for k in 0..b * d {
            let j = k % d;
            self.lam[k] = if (1..=nc).contains(&j) { last[k].sin() / count } else { 0.0 };
        }
        self.au.fill(0.0);
        for n in (0..nsteps).rev() {
            let cur = &self.s[n * b * d..(n + 1) * b * d];
            for k in 0..b {
                let (r, row) = (k * d..(k + 1) * d, n * b + k);
                let au = step_adjoint(
                    &self.phys,
                    &cur[r.clone()],
                    self.u[row],
                    &self.lam[r.clone()],
                    &mut self.lam_prev[r.clone()],
                );
                self.au[row] = au;
                if mode == GradientMode::F {
                    // The network path: s_n -> u_n.
                    axpy(&mut self.lam_prev[r], au, &self.js[row * d..(row + 1) * d]);
                }
            }
            if mode == GradientMode::S {
                // Both paths stopped: only the last control reaches the loss.
                break;
            }
            std::mem::swap(&mut self.lam, &mut self.lam_prev);
        }
    }

    /// `sum_(n, b) au[n, b] grad_theta u(s_n^b)` into `grad_f` (`into_f`) or `grad`.
    fn weighted_sum(&mut self, into_f: bool) {
        let l = self.layout;
        let (d, h, rows) = (l.d, l.h, self.phys.steps * self.batch);
        for (r, &a) in self.au.iter().enumerate() {
            let span = r * h..(r + 1) * h;
            for ((wc, we), (c, e)) in self.wc[span.clone()]
                .iter_mut()
                .zip(&mut self.we[span.clone()])
                .zip(self.c[span.clone()].iter().zip(&self.e[span]))
            {
                *wc = a * c;
                *we = a * e;
            }
        }
        let out = if into_f { &mut self.grad_f } else { &mut self.grad };
        let g = split_mut(out, l);
        *g.b2 = self.au.iter().sum();
        g.w2.fill(0.0);
        g.b1.fill(0.0);
        g.b0.fill(0.0);
        for r in 0..rows {
            axpy(g.w2, self.au[r], &self.h1[r * h..(r + 1) * h]);
            axpy(g.b1, 1.0, &self.wc[r * h..(r + 1) * h]);
            axpy(g.b0, 1.0, &self.we[r * h..(r + 1) * h]);
        }
        gemm(view_mut(g.w1, h, h), false, view(&self.h0, rows, h).transpose(), view(&self.wc, rows, h));
        gemm(view_mut(g.w0, d, h), false, view(&self.s, rows, d).transpose(), view(&self.we, rows, h));
    }

    /// Gradients of the rollout loss from `s0 [batch, state_dim]` (row-major) with respect to
    /// the controller's parameters in `mode` ([`crate::bptt::gradients`]'s definitions), then
    /// clipped by `clip`; read them with [`Self::grad`].
    pub fn gradients(
        &mut self,
        net: &AdjointController,
        s0: &[f64],
        mode: GradientMode,
        clip: &ClipConfig,
    ) -> Result<AdjointGradInfo> {
        self.check(net, s0)?;
        check_clip(clip)?;
        // Stops change no values: one forward rollout serves every mode.
        let loss = self.forward(net, s0);
        self.shared_backward(net);
        let agreement = match mode {
            GradientMode::C => {
                self.force_adjoints(GradientMode::P);
                self.weighted_sum(false);
                self.force_adjoints(GradientMode::F);
                self.weighted_sum(true);
                let mut agree = 0usize;
                for (p, f) in self.grad.iter_mut().zip(&self.grad_f) {
                    if sign(*p) == sign(*f) {
                        agree += 1;
                    } else {
                        *p = 0.0;
                    }
                }
                Some(agree as f64 / self.grad.len().max(1) as f64)
            }
            m => {
                self.force_adjoints(m);
                self.weighted_sum(false);
                None
            }
        };
        if !loss.is_finite() {
            return Err(Error::Diverged { step: 0, loss, last_good: 0 });
        }
        let norm_before_clip = clip_in_place(&mut self.grad, clip);
        Ok(AdjointGradInfo { loss, norm_before_clip, agreement })
    }
}

/// `-1`, `0` or `1` (NaN gives `0`, as the candle path's comparisons do).
fn sign(v: f64) -> i8 {
    (v > 0.0) as i8 - (v < 0.0) as i8
}

/// `1 - mean cos th` of states `[n, d]`.
fn loss_of(phys: &CartPole, s: &[f64]) -> f64 {
    let d = phys.state_dim();
    let mut sum = 0.0;
    for row in s.chunks_exact(d) {
        for th in &row[1..=phys.poles] {
            sum += th.cos();
        }
    }
    1.0 - sum / (s.len() / d * phys.poles) as f64
}

fn check_clip(clip: &ClipConfig) -> Result<()> {
    let bad =
        |name, value| Error::InvalidConfig { name, value, hint: "clipping bounds must be finite and > 0, e.g. 1.0" };
    match *clip {
        ClipConfig::None => Ok(()),
        ClipConfig::Value { max_value } if !(max_value > 0.0 && max_value.is_finite()) => {
            Err(bad("max_value", max_value))
        }
        ClipConfig::Norm { max_norm } if !(max_norm > 0.0 && max_norm.is_finite()) => Err(bad("max_norm", max_norm)),
        _ => Ok(()),
    }
}

/// Test loss `1 - mean cos th` of `net` on the episodes `states [n, d]` (forward only).
pub fn evaluate(phys: &CartPole, net: &AdjointController, states: &[f64]) -> Result<f64> {
    let (l, d) = (net.layout, phys.state_dim());
    check_len("controller inputs (state_dim)", d, l.d)?;
    if states.len() % d != 0 {
        return Err(Error::shape("test states length (a multiple of state_dim)", d, states.len()));
    }
    // Chunks of 32 episodes keep the hidden activations in cache.
    const CHUNK: usize = 32;
    let p = split(&net.params, l);
    let (mut s, mut next) = (states.to_vec(), states.to_vec());
    let mut h0 = vec![0.0; CHUNK * l.h];
    let mut h1 = vec![0.0; CHUNK * l.h];
    let mut u = vec![0.0; CHUNK];
    for (cur, nxt) in s.chunks_mut(CHUNK * d).zip(next.chunks_mut(CHUNK * d)) {
        let n = cur.len() / d;
        for _ in 0..phys.steps {
            controller_forward(&p, l, cur, n, &mut h0, &mut h1, &mut u);
            for k in 0..n {
                step(phys, &cur[k * d..(k + 1) * d], u[k], &mut nxt[k * d..(k + 1) * d]);
            }
            cur.copy_from_slice(nxt);
        }
    }
    Ok(loss_of(phys, &s))
}

/// [`super::train`] on the hand-written adjoint path: the same data, initial weights, batches, gradients, clipping
/// and Adam. `on_eval(step, test_loss)` is called at every evaluation (for progress output).
pub fn train_with(cfg: &CartPoleConfig, on_eval: &mut dyn FnMut(usize, f64)) -> Result<CartPoleRun> {
    train_checkpointed(cfg, None, on_eval)
}

/// The name of the controller's flat parameter vector in a checkpoint of
/// [`train_checkpointed`] (`f64`, the layout of [`AdjointController::params`]).
pub const PARAMS_NAME: &str = "controller.params";

/// The checkpoint entry that records the configuration of a [`train_checkpointed`] run (its
/// `Debug` text as bytes): a resume with another configuration is refused.
const CONFIG_NAME: &str = "cartpole/config";

/// Checkpoint entries of the flat Adam's first and second moments and its update count (`f64`).
const ADAM_M_NAME: &str = "cartpole/adam/m";
const ADAM_V_NAME: &str = "cartpole/adam/v";
const ADAM_STEPS_NAME: &str = "cartpole/adam/steps";

/// [`train_with`], optionally checkpointed into `run_dir` for an exact resume: a run that was
/// stopped or killed (`kill -9` included, at any moment) and is started again with the same
/// `cfg` and directory continues from its newest checkpoint and returns, and leaves in the
/// directory, what the uninterrupted run does, bit for bit (the test losses, their steps and
/// the sign agreement; `loss.csv`; every checkpoint). [`BpttRun::seconds`](crate::bptt::BpttRun)
/// counts the training time of this call only, and `on_eval` sees the evaluations of this call
/// only (those before the resume point are in the returned run).
///
/// One checkpoint (one atomic commit, every `run_dir.checkpoint_every` updates and after the
/// last) holds everything the rest of the run depends on: the controller's parameters
/// ([`PARAMS_NAME`]), Adam's moments and update count, the evaluations and agreement sums so
/// far, and the configuration (a different `cfg` is an error, not a silent mix). Nothing
/// random is drawn while training: the episodes and the initial weights follow from
/// `cfg.seed`, the batches from the step.
///
/// The update is the same [`FlatAdam`] step with or without a directory; with one, the flat
/// parameters are copied into the checkpoint's variable, and Adam's moments and count into
/// tensors of the same commit, only when a checkpoint is written.
pub fn train_checkpointed(
    cfg: &CartPoleConfig,
    run_dir: Option<&RunDir>,
    on_eval: &mut dyn FnMut(usize, f64),
) -> Result<CartPoleRun> {
    let phys = cfg.physics;
    if cfg.batch == 0 || cfg.train < cfg.batch {
        return Err(Error::InvalidConfig {
            name: "batch",
            value: cfg.batch as f64,
            hint: "the batch must be >= 1 and at most the number of training episodes",
        });
    }
    check_clip(&cfg.clip)?;
    let mut net = AdjointController::with_zero_last_layer(phys.state_dim(), cfg.width, cfg.seed)?;
    let train = phys.initial_states(cfg.train, cfg.seed)?.flatten_all()?.to_vec1::<f64>()?;
    let test = phys.initial_states(cfg.test, cfg.seed + 1)?.flatten_all()?.to_vec1::<f64>()?;
    let mut bptt = AdjointBptt::new(&phys, cfg.width, cfg.batch);
    let d = phys.state_dim();
    let batch = |first: usize| &train[first * d..(first + cfg.batch) * d];
    let test_loss = |net: &AdjointController, step: usize| -> Result<f64> {
        let loss = evaluate(&phys, net, &test)?;
        on_eval(step, loss);
        Ok(loss)
    };
    let schedule = cfg.schedule();
    let adam = AdamConfig { lr: cfg.lr, ..Default::default() };
    let Some(run_dir) = run_dir else {
        let mut opt = FlatAdam::new(adam, net.params.len());
        let step = |net: &mut AdjointController, first: usize| -> Result<(f64, Option<f64>)> {
            let info = bptt.gradients(net, batch(first), cfg.mode, &cfg.clip)?;
            opt.step(&mut net.params, &bptt.grad)?;
            Ok((info.loss, info.agreement))
        };
        let run = TrainLoop::in_memory(Vec::new(), schedule_loop(&schedule, None))?;
        return run_schedule(&schedule, cfg.train, &mut net, run, |_| Ok(Vec::new()), step, test_loss);
    };

    let n = net.params.len();
    // The checkpoint holds the parameters as one f64 variable; training updates the flat
    // vector (FlatAdam, as without a directory) and copies it into the variable only when a
    // checkpoint is written.
    let varmap = VarMap::new();
    let theta = Var::from_tensor(&varmap.get(n, PARAMS_NAME, Init::Const(0.0), DType::F64, &Device::Cpu)?)?;
    theta.set(&Tensor::from_slice(&net.params, n, &Device::Cpu)?)?;
    let config = format!("{cfg:?}");
    let config_tensor = Tensor::from_slice(config.as_bytes(), config.len(), &Device::Cpu)?;
    // Loads the newest checkpoint's parameters into `theta`.
    let run = TrainLoop::resume(&varmap, schedule_loop(&schedule, Some(run_dir)))?;
    let mut opt = FlatAdam::new(adam, n);
    if let Some(ck) = run.resumed() {
        let stored = String::from_utf8_lossy(&ck.extra_tensor(CONFIG_NAME)?.to_vec1::<u8>()?).into_owned();
        if stored != config {
            return Err(pbdl_core::Error::invalid(
                "cartpole::adjoint::train_checkpointed",
                "cfg",
                format!(
                    "{} holds a run of `{stored}`, not of `{config}`: resume with the configuration it was started with, or use another directory",
                    run_dir.dir.display()
                ),
            )
            .into());
        }
        let read = |name: &str| -> Result<Vec<f64>> { Ok(ck.extra_tensor(name)?.to_vec1::<f64>()?) };
        // The count is stored as an f64 (exact below 2^53).
        let steps = read(ADAM_STEPS_NAME)?.first().copied().unwrap_or(0.0) as u64;
        opt.restore(&read(ADAM_M_NAME)?, &read(ADAM_V_NAME)?, steps)?;
        net.params.copy_from_slice(&theta.as_tensor().to_vec1::<f64>()?);
    }
    let opt = RefCell::new(opt);
    let step = |net: &mut AdjointController, first: usize| -> Result<(f64, Option<f64>)> {
        let info = bptt.gradients(net, batch(first), cfg.mode, &cfg.clip)?;
        opt.borrow_mut().step(&mut net.params, &bptt.grad)?;
        Ok((info.loss, info.agreement))
    };
    // Called right before each checkpoint is written: the variable takes the current
    // parameters, Adam's state rides along as extra tensors of the same commit.
    let state = |net: &AdjointController| -> Result<Vec<(String, Tensor)>> {
        theta.set(&Tensor::from_slice(&net.params, n, &Device::Cpu)?)?;
        let opt = opt.borrow();
        let (m, v) = opt.moments();
        Ok(vec![
            (ADAM_M_NAME.into(), Tensor::from_slice(m, n, &Device::Cpu)?),
            (ADAM_V_NAME.into(), Tensor::from_slice(v, n, &Device::Cpu)?),
            (ADAM_STEPS_NAME.into(), Tensor::from_slice(&[opt.steps() as f64], 1, &Device::Cpu)?),
            (CONFIG_NAME.into(), config_tensor.clone()),
        ])
    };
    run_schedule(&schedule, cfg.train, &mut net, run, state, step, test_loss)
}

/// [`train_with`] without progress output.
pub fn train(cfg: &CartPoleConfig) -> Result<CartPoleRun> {
    train_with(cfg, &mut |_, _| {})
}

#[cfg(test)]
mod tests {
    #[test]
    fn tanh_matches_libm() {
        let mut worst = 0.0f64;
        for i in -200_000..=200_000 {
            let x = i as f64 * 1.37e-4 + 1e-9;
            worst = worst.max((super::tanh(x) - x.tanh()).abs());
        }
        for x in [0.0, -0.0, 1e-300, -1e-12, 19.0, 20.0, 25.0, 700.0, -1e10, f64::INFINITY, f64::NEG_INFINITY] {
            worst = worst.max((super::tanh(x) - x.tanh()).abs());
        }
        println!("max |tanh - libm tanh| = {worst:e}");
        assert!(worst <= 4e-16, "max |tanh - libm tanh| = {worst:e}");
        assert!(super::tanh(f64::NAN).is_nan());
    }
}
