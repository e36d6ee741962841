//! The toy's score network: a small `f64` MLP with hand-written backpropagation.
//!
//! Why not candle: the net has ~2.5k parameters and trains for 100k+ updates of batch 256, so
//! candle's per-op dispatch and allocation would dominate; here each layer is one `gemm` call
//! forward and two backward, into buffers that are reused. Measured: the same 1-step update
//! written with candle ops and candle-nn's AdamW took 4-9x longer (15-22 ms against 2-4 ms per
//! update at batch 256, on the 2-core machine under heavy load). The backward pass returns the
//! gradient with respect to the input `x` too, which the multi-step loss needs to backpropagate
//! through the rollout.
//!
//! Input: `(x, log(t + 1e-5))`; ELU after every layer but the last; output: the score `s`
//! (which absorbs `g^2`).

use crate::{Error, Result};
use pbdl_core::train::{AdamConfig, FlatAdam};
use rand_distr::{Distribution, StandardNormal};

/// Offset added to `t` before the logarithm of the time input.
pub const LOG_T_EPS: f64 = 1e-5;

/// The paper's layer widths.
pub const PAPER_WIDTHS: [usize; 6] = [30, 30, 25, 20, 10, 1];

/// An MLP `2 -> widths[0] -> ... -> widths[last] = 1` with ELU activations.
#[derive(Clone, Debug)]
pub struct ScoreMlp {
    /// Layer sizes including the input: `[2, w0, w1, ..., 1]`.
    sizes: Vec<usize>,
    /// All parameters: per layer the weight (`in x out`, row-major) then the bias.
    params: Vec<f64>,
    /// Start of each layer's weight in `params`.
    offsets: Vec<usize>,
    /// Output `(f(x, t) - f(-x, t)) / 2` of the plain MLP `f`: a score that is odd in `x`.
    odd: bool,
}

/// Per-layer values kept by the forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub struct MlpCache {
    batch: usize,
    /// `acts[0]` is the input (`batch x 2`), `acts[l + 1]` the output of layer `l`.
    acts: Vec<Vec<f64>>,
    /// Pre-activations of each layer.
    pre: Vec<Vec<f64>>,
    /// Scratch for the backward pass.
    grad_a: Vec<f64>,
    grad_b: Vec<f64>,
    /// Odd networks: the doubled batch `[x, -x]`, its times, outputs and gradients.
    odd_x: Vec<f64>,
    odd_t: Vec<f64>,
    odd_y: Vec<f64>,
}

fn elu(z: f64) -> f64 {
    if z > 0.0 {
        z
    } else {
        // exp(z) - 1 rather than the slower exp_m1: its absolute error (1e-16) is harmless here.
        z.exp() - 1.0
    }
}

fn elu_dz(z: f64, elu_z: f64) -> f64 {
    if z > 0.0 {
        1.0
    } else {
        elu_z + 1.0
    }
}

/// `dst (m x n, row stride n) = [dst +] a (m x k) * b (k x n)`, strides `(row, col)` given.
fn matmul(
    dst: &mut [f64],
    accumulate: bool,
    a: &[f64],
    (a_rs, a_cs): (usize, usize),
    b: &[f64],
    (b_rs, b_cs): (usize, usize),
    (m, n, k): (usize, usize, usize),
) {
    use pbdl_core::matmul::{matmul, Mat, Threads};
    matmul(dst, n, accumulate, Mat::new(a, a_rs, a_cs), Mat::new(b, b_rs, b_cs), (m, n, k), 1.0, Threads::Serial);
}

impl ScoreMlp {
    /// A network with the given hidden/output widths (the last must be 1), weights drawn from
    /// `N(0, 1/fan_in)` with `seed`, biases zero.
    pub fn new(widths: &[usize], seed: u64) -> Result<Self> {
        if widths.is_empty() || *widths.last().unwrap_or(&0) != 1 || widths.contains(&0) {
            return Err(Error::InvalidConfig {
                name: "widths",
                value: format!("{widths:?}"),
                hint: "give positive layer widths ending in 1, e.g. [30, 30, 25, 20, 10, 1]",
            });
        }
        let mut sizes = vec![2];
        sizes.extend_from_slice(widths);
        let mut offsets = vec![];
        let mut params = vec![];
        let mut rng = super::sde::chunk_rng(seed, 0);
        for l in 0..widths.len() {
            let (fan_in, fan_out) = (sizes[l], sizes[l + 1]);
            offsets.push(params.len());
            let std = 1.0 / (fan_in as f64).sqrt();
            for _ in 0..fan_in * fan_out {
                let z: f64 = StandardNormal.sample(&mut rng);
                params.push(std * z);
            }
            params.extend(std::iter::repeat_n(0.0, fan_out));
        }
        Ok(ScoreMlp { sizes, params, offsets, odd: false })
    }

    /// The same network made odd in `x`: it outputs `(f(x, t) - f(-x, t)) / 2`, for problems
    /// whose drift and data are symmetric under `x -> -x` (then the exact score is odd). The
    /// symmetry is exact by construction, so the learned posterior cannot favour one sign.
    pub fn with_odd_symmetry(mut self) -> Self {
        self.odd = true;
        self
    }

    /// Whether the output is odd in `x` ([`with_odd_symmetry`](Self::with_odd_symmetry)).
    pub fn is_odd(&self) -> bool {
        self.odd
    }

    /// The paper's `[30, 30, 25, 20, 10, 1]` network.
    pub fn paper(seed: u64) -> Self {
        Self::new(&PAPER_WIDTHS, seed).expect("the paper widths are valid")
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    /// The parameters as one flat vector.
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// Mutable access to the flat parameter vector (for optimisers and tests).
    pub fn params_mut(&mut self) -> &mut [f64] {
        &mut self.params
    }

    fn layers(&self) -> usize {
        self.sizes.len() - 1
    }

    /// Forward pass for states `x` at times `t` (one per state); writes the scores into `out`
    /// and keeps what the backward pass needs in `cache`.
    pub fn forward(&self, x: &[f64], t: &[f64], out: &mut [f64], cache: &mut MlpCache) {
        if !self.odd {
            return self.forward_plain(x, t, out, cache);
        }
        let b = x.len();
        let (mut xx, mut tt, mut yy) =
            (std::mem::take(&mut cache.odd_x), std::mem::take(&mut cache.odd_t), std::mem::take(&mut cache.odd_y));
        xx.clear();
        xx.extend(x.iter().copied().chain(x.iter().map(|v| -v)));
        tt.clear();
        tt.extend(t.iter().chain(t.iter()));
        yy.resize(2 * b, 0.0);
        self.forward_plain(&xx, &tt, &mut yy, cache);
        for i in 0..b {
            out[i] = 0.5 * (yy[i] - yy[b + i]);
        }
        (cache.odd_x, cache.odd_t, cache.odd_y) = (xx, tt, yy);
    }

    /// [`forward`](Self::forward) of the plain MLP `f`.
    fn forward_plain(&self, x: &[f64], t: &[f64], out: &mut [f64], cache: &mut MlpCache) {
        let b = x.len();
        debug_assert!(t.len() == b && out.len() == b);
        let nl = self.layers();
        cache.batch = b;
        cache.acts.resize_with(nl + 1, Vec::new);
        cache.pre.resize_with(nl, Vec::new);
        let input = &mut cache.acts[0];
        input.resize(2 * b, 0.0);
        for i in 0..b {
            input[2 * i] = x[i];
            input[2 * i + 1] = (t[i] + LOG_T_EPS).ln();
        }
        for l in 0..nl {
            let (fi, fo) = (self.sizes[l], self.sizes[l + 1]);
            let w = &self.params[self.offsets[l]..self.offsets[l] + fi * fo];
            let bias = &self.params[self.offsets[l] + fi * fo..self.offsets[l] + fi * fo + fo];
            let (lo, hi) = cache.acts.split_at_mut(l + 1);
            let a_in = &lo[l];
            let z = &mut cache.pre[l];
            z.resize(b * fo, 0.0);
            for r in 0..b {
                z[r * fo..(r + 1) * fo].copy_from_slice(bias);
            }
            matmul(z, true, a_in, (fi, 1), w, (fo, 1), (b, fo, fi));
            let a_out = &mut hi[0];
            a_out.resize(b * fo, 0.0);
            if l + 1 < nl {
                for (o, &zv) in a_out.iter_mut().zip(z.iter()) {
                    *o = elu(zv);
                }
            } else {
                a_out.copy_from_slice(z);
            }
        }
        out.copy_from_slice(&cache.acts[nl][..b]);
    }

    /// Scores without keeping a cache (allocates its own scratch).
    pub fn eval(&self, x: &[f64], t: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; x.len()];
        self.forward(x, t, &mut out, &mut MlpCache::default());
        out
    }

    /// Backward pass of the last [`forward`](Self::forward): given `d loss / d s` per sample in
    /// `grad_out`, adds `d loss / d params` into `grad_params` and writes `d loss / d x` into
    /// `grad_x` (same length as the batch).
    pub fn backward(&self, cache: &mut MlpCache, grad_out: &[f64], grad_params: &mut [f64], grad_x: &mut [f64]) {
        if !self.odd {
            return self.backward_plain(cache, grad_out, grad_params, grad_x);
        }
        let b = grad_out.len();
        // Reuse the doubled-batch buffers: y (no longer needed) takes d loss / d f, x then
        // d loss / d [x, -x].
        let (mut gy, mut gx) = (std::mem::take(&mut cache.odd_y), std::mem::take(&mut cache.odd_x));
        gy.clear();
        gy.extend(grad_out.iter().map(|g| 0.5 * g).chain(grad_out.iter().map(|g| -0.5 * g)));
        gx.resize(2 * b, 0.0);
        self.backward_plain(cache, &gy, grad_params, &mut gx);
        for i in 0..b {
            grad_x[i] = gx[i] - gx[b + i];
        }
        (cache.odd_y, cache.odd_x) = (gy, gx);
    }

    /// [`backward`](Self::backward) of the plain MLP `f`.
    fn backward_plain(&self, cache: &mut MlpCache, grad_out: &[f64], grad_params: &mut [f64], grad_x: &mut [f64]) {
        let b = cache.batch;
        let nl = self.layers();
        debug_assert!(grad_out.len() == b && grad_params.len() == self.params.len() && grad_x.len() == b);
        // grad_a holds d loss / d (pre-activation) of the current layer.
        let mut ga = std::mem::take(&mut cache.grad_a);
        let mut gb = std::mem::take(&mut cache.grad_b);
        ga.clear();
        ga.extend_from_slice(grad_out);
        for l in (0..nl).rev() {
            let (fi, fo) = (self.sizes[l], self.sizes[l + 1]);
            if l + 1 < nl {
                // ELU' from the stored output (exp(z) = elu(z) + 1 for z <= 0): no second exp.
                for ((g, &z), &a) in ga.iter_mut().zip(cache.pre[l].iter()).zip(cache.acts[l + 1].iter()) {
                    *g *= elu_dz(z, a);
                }
            }
            let off = self.offsets[l];
            {
                let (gw, gbias) = grad_params[off..off + fi * fo + fo].split_at_mut(fi * fo);
                // dW += A_in^T (fi x b) * G (b x fo)
                matmul(gw, true, &cache.acts[l], (1, fi), &ga, (fo, 1), (fi, fo, b));
                for r in 0..b {
                    for (gbv, &g) in gbias.iter_mut().zip(&ga[r * fo..(r + 1) * fo]) {
                        *gbv += g;
                    }
                }
            }
            // d A_in = G (b x fo) * W^T (fo x fi)
            let w = &self.params[off..off + fi * fo];
            gb.resize(b * fi, 0.0);
            matmul(&mut gb, false, &ga, (fo, 1), w, (1, fo), (b, fi, fo));
            std::mem::swap(&mut ga, &mut gb);
        }
        // ga is now d loss / d input (b x 2); only x is a state, log t is a constant.
        for i in 0..b {
            grad_x[i] = ga[2 * i];
        }
        cache.grad_a = ga;
        cache.grad_b = gb;
    }
}

/// Adam with the paper's `(beta1, beta2) = (0.9, 0.99)` and `eps = 1e-8` for `n` parameters:
/// pbdl-core's [`FlatAdam`] (candle-nn's update on a flat vector).
pub fn paper_adam(n: usize, lr: f64) -> FlatAdam {
    FlatAdam::new(AdamConfig { lr, beta1: 0.9, beta2: 0.99, eps: 1e-8 }, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Finite differences of `sum_i c_i s(x_i, t_i)` against the hand-written backward pass,
    /// for parameters and inputs.
    #[test]
    fn backward_matches_finite_differences() {
        check_backward(ScoreMlp::new(&[7, 5, 1], 3).unwrap(), 1e-6);
    }

    /// The odd network: exactly odd in `x`, and its backward pass matches finite differences.
    #[test]
    fn odd_network_is_odd_and_its_backward_matches_finite_differences() {
        let net = ScoreMlp::new(&[7, 5, 1], 3).unwrap().with_odd_symmetry();
        let (x, t) = ([0.3, 0.8, 0.0], [0.1, 2.0, 5.0]);
        let neg: Vec<f64> = x.iter().map(|v| -v).collect();
        let (a, b) = (net.eval(&x, &t), net.eval(&neg, &t));
        for i in 0..3 {
            assert_eq!(a[i], -b[i], "s(-x) = -s(x) at {i}");
        }
        assert!(a[0].abs() > 1e-6, "the odd part is not trivially zero: {a:?}");
        // Some gradients of the odd net are exactly zero (the last bias cancels in
        // f(x) - f(-x)), where the differences show only rounding (~1e-10): a larger floor.
        check_backward(net, 1e-4);
    }

    /// Finite differences of `sum_i c_i s(x_i, t_i)` for a perturbed copy of `net`; relative
    /// errors with `floor` added to the denominator.
    fn check_backward(mut net: ScoreMlp, floor: f64) {
        // Non-zero biases so every branch of ELU is exercised.
        for (i, p) in net.params_mut().iter_mut().enumerate() {
            *p += 0.05 * ((i as f64) * 0.7).sin();
        }
        let x = [0.3, -0.8, 0.05, 1.2];
        let t = [0.1, 2.0, 5.0, 0.02];
        let c = [0.7, -1.1, 0.4, 2.0];
        let f = |n: &ScoreMlp, x: &[f64]| n.eval(x, &t).iter().zip(&c).map(|(s, c)| s * c).sum::<f64>();
        let mut cache = MlpCache::default();
        let mut out = vec![0.0; 4];
        net.forward(&x, &t, &mut out, &mut cache);
        let mut gp = vec![0.0; net.num_params()];
        let mut gx = vec![0.0; 4];
        net.backward(&mut cache, &c, &mut gp, &mut gx);
        let h = 1e-6;
        let mut worst: f64 = 0.0;
        for i in 0..net.num_params() {
            let mut a = net.clone();
            a.params_mut()[i] += h;
            let mut b = net.clone();
            b.params_mut()[i] -= h;
            let fd = (f(&a, &x) - f(&b, &x)) / (2.0 * h);
            worst = worst.max((fd - gp[i]).abs() / (floor + fd.abs().max(gp[i].abs())));
        }
        for i in 0..4 {
            let (mut xp, mut xm) = (x, x);
            xp[i] += h;
            xm[i] -= h;
            let fd = (f(&net, &xp) - f(&net, &xm)) / (2.0 * h);
            worst = worst.max((fd - gx[i]).abs() / (floor + fd.abs().max(gx[i].abs())));
        }
        assert!(worst < 1e-5, "worst relative error {worst}");
    }

    #[test]
    fn paper_network_has_the_expected_size() {
        // 2*30+30 + 30*30+30 + 30*25+25 + 25*20+20 + 20*10+10 + 10+1
        assert_eq!(ScoreMlp::paper(0).num_params(), 2536);
        assert!(ScoreMlp::new(&[4, 2], 0).is_err());
    }
}
