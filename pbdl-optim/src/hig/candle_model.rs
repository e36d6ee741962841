//! [`CandleModel`]: any candle model (its `Var`s and a forward closure) as a [`JacobianModel`].
//!
//! The forward pass runs the closure once on the whole batch and keeps candle's graph. Jacobian
//! row `r` of sample `s` is one backward pass of `<cot_r, out[s]>` (the physics Jacobian's row
//! as the cotangent of sample `s`'s output); rows run in parallel (rayon). Two ways to get the
//! graph those passes run through ([`JacobianMode`]):
//!
//! - [`JacobianMode::Batch`] (default): the forward pass's batch graph. Exact for any
//!   differentiable model, including ones whose samples interact (batch statistics), but every
//!   pass walks the whole batch, so a Jacobian costs `O(b^2 dim(y))`.
//! - [`JacobianMode::PerSample`]: the closure is run again on each sample alone (`[1, in_dim]`)
//!   and the passes walk that graph: `O(b dim(y))`. Valid only when samples do not interact.
//!
//! The hand-written [`crate::mlp::Mlp`] is still faster (timings in `tests/hig_candle_tests.rs`):
//! candle's per-op overhead dominates on small layers. Set `RAYON_NUM_THREADS` when timing or
//! training on the CPU: without it candle 0.11 re-reads `/proc/cpuinfo` on every CPU matmul,
//! which made the per-sample Jacobian about 5x slower in that test.
//!
//! The flat parameter vector is the `Var`s in the order given, each flattened row-major.

use super::model::JacobianModel;
use crate::error::{check_finite, check_len, Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use rayon::prelude::*;

/// A candle model `u = f(i)` given by its trainable `Var`s and a forward closure mapping an
/// `f64` input `[b, in_dim]` to an output `[b, out_dim]` (any float dtype; it is read as `f64`).
///
/// The closure must compute with (clones of) the same `Var`s: a `Var` clone shares its
/// storage, so parameter updates written through the adapter are seen by the closure.
pub struct CandleModel<F> {
    vars: Vec<Var>,
    /// `offsets[i]..offsets[i + 1]` is `vars[i]` in the flat parameter vector.
    offsets: Vec<usize>,
    in_dim: usize,
    out_dim: usize,
    device: Device,
    mode: JacobianMode,
    forward: F,
}

/// Which graph [`CandleModel`]'s Jacobian rows are back-propagated through.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum JacobianMode {
    /// The whole batch's forward graph: exact for every model, `O(b)` per row. The default.
    #[default]
    Batch,
    /// One forward graph per sample (the closure is called again on `[1, in_dim]`): `O(1)` per
    /// row. Use it only when the model treats samples independently (no batch statistics);
    /// otherwise the rows are those of a batch of one.
    PerSample,
}

impl<F> std::fmt::Debug for CandleModel<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CandleModel")
            .field("vars", &self.vars.len())
            .field("n_params", &self.offsets.last())
            .field("in_dim", &self.in_dim)
            .field("out_dim", &self.out_dim)
            .finish()
    }
}

/// What [`CandleModel`]'s forward pass keeps: the output tensor (with its graph) and its
/// values as `f64`.
#[derive(Clone, Debug, Default)]
pub struct CandleCache {
    batch: usize,
    input: Option<Tensor>,
    out: Option<Tensor>,
    host: Vec<f64>,
}

impl<F> CandleModel<F>
where
    F: Fn(&Tensor) -> candle_core::Result<Tensor>,
{
    /// The model with trainable `vars` (floating point, all on one device), input width
    /// `in_dim` and output width `out_dim`, computed by `forward`.
    ///
    /// Errors: an empty `vars` list, a non-float `Var`, `Var`s on different devices, or a zero
    /// width ([`Error::ShapeMismatch`] / [`Error::InvalidConfig`], saying what to pass instead).
    pub fn new(vars: Vec<Var>, in_dim: usize, out_dim: usize, forward: F) -> Result<Self> {
        let Some(first) = vars.first() else {
            return Err(Error::shape(
                "CandleModel variable list (pass the model's trainable Vars, in a fixed order)",
                "at least one Var",
                "an empty list",
            ));
        };
        if in_dim == 0 || out_dim == 0 {
            return Err(Error::shape(
                "CandleModel input and output widths",
                "both > 0",
                format!("{in_dim}, {out_dim}"),
            ));
        }
        let device = first.device().clone();
        let mut offsets = vec![0];
        for (i, v) in vars.iter().enumerate() {
            if !v.dtype().is_float() {
                return Err(Error::shape(
                    format!("dtype of CandleModel Var {i} (trainable parameters must be floating point)"),
                    "f64 (or f32, f16, bf16)",
                    format!("{:?}", v.dtype()),
                ));
            }
            if !v.device().same_device(&device) {
                return Err(Error::shape(
                    format!("device of CandleModel Var {i} (move all Vars to one device)"),
                    format!("{device:?}"),
                    format!("{:?}", v.device()),
                ));
            }
            offsets.push(offsets[i] + v.elem_count());
        }
        Ok(Self { vars, offsets, in_dim, out_dim, device, mode: JacobianMode::Batch, forward })
    }

    /// The same model with its Jacobian rows computed in `mode` (default [`JacobianMode::Batch`]).
    pub fn with_mode(mut self, mode: JacobianMode) -> Self {
        self.mode = mode;
        self
    }

    /// How the Jacobian rows are computed.
    pub fn mode(&self) -> JacobianMode {
        self.mode
    }

    /// The trainable `Var`s, in the order of the flat parameter vector.
    pub fn vars(&self) -> &[Var] {
        &self.vars
    }

    /// Runs the closure on `input: [batch, in_dim]` and checks the output shape.
    fn run(&self, input: &Tensor) -> Result<Tensor> {
        let batch = input.dim(0)?;
        let out = (self.forward)(input)?;
        if out.dims() != [batch, self.out_dim] {
            return Err(Error::shape(
                "CandleModel forward output shape (the closure must map [b, in_dim] to [b, out_dim]; \
                 out_dim is the physics control length)",
                format!("[{batch}, {}]", self.out_dim),
                format!("{:?}", out.dims()),
            ));
        }
        Ok(out)
    }

    /// The input and output tensors of the last forward pass.
    fn cached<'c>(&self, cache: &'c CandleCache) -> Result<(&'c Tensor, &'c Tensor)> {
        match (&cache.input, &cache.out) {
            (Some(x), Some(y)) => Ok((x, y)),
            _ => Err(Error::shape(
                "CandleModel cache (run forward before asking for Jacobian rows or gradients)",
                "a forward pass",
                "none",
            )),
        }
    }
}

/// One backward pass of `sum(out * cot)` (`cot` of `out`'s shape), written flat into
/// `row` (Vars the output does not depend on get zeros). A free function so that rows can run in
/// parallel without requiring the forward closure to be `Sync`.
fn backward_into(vars: &[Var], offsets: &[usize], out: &Tensor, cot: &Tensor, row: &mut [f64]) -> Result<()> {
    let grads = out.mul(cot)?.sum_all()?.backward()?;
    for (i, v) in vars.iter().enumerate() {
        let dst = &mut row[offsets[i]..offsets[i + 1]];
        match grads.get(v.as_tensor()) {
            Some(g) => dst.copy_from_slice(&g.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?),
            None => dst.fill(0.0),
        }
    }
    Ok(())
}

impl<F> JacobianModel for CandleModel<F>
where
    F: Fn(&Tensor) -> candle_core::Result<Tensor>,
{
    type Cache = CandleCache;

    fn in_dim(&self) -> usize {
        self.in_dim
    }

    fn out_dim(&self) -> usize {
        self.out_dim
    }

    fn n_params(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
    }

    fn read_params(&self, out: &mut [f64]) -> Result<()> {
        check_len("parameter buffer length (CandleModel parameter count)", self.n_params(), out.len())?;
        for (i, v) in self.vars.iter().enumerate() {
            let values = v.as_tensor().flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
            out[self.offsets[i]..self.offsets[i + 1]].copy_from_slice(&values);
        }
        Ok(())
    }

    fn write_params(&mut self, params: &[f64]) -> Result<()> {
        check_len("parameter vector length (CandleModel parameter count)", self.n_params(), params.len())?;
        for (i, v) in self.vars.iter().enumerate() {
            let t = Tensor::from_slice(&params[self.offsets[i]..self.offsets[i + 1]], v.shape(), &self.device)?;
            v.set(&t.to_dtype(v.dtype())?)?;
        }
        Ok(())
    }

    fn forward(&self, x: &[f64], batch: usize, cache: &mut CandleCache) -> Result<()> {
        check_len("CandleModel input length (batch * in_dim)", batch * self.in_dim, x.len())?;
        let input = Tensor::from_slice(x, (batch, self.in_dim), &self.device)?;
        let out = self.run(&input)?;
        cache.host = out.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
        cache.batch = batch;
        cache.out = Some(out);
        cache.input = Some(input);
        Ok(())
    }

    fn output<'c>(&self, cache: &'c CandleCache) -> &'c [f64] {
        &cache.host
    }

    /// One backward pass per row, in parallel: row `r` of sample `s` back-propagates
    /// `<cot_r, out[s]>`. Errors: buffer lengths, a missing forward pass, NaN/Inf in a row
    /// ([`Error::NonFinite`] with its row and parameter index).
    fn jacobian_rows(&self, cache: &CandleCache, cot: &[f64], rows_per_sample: usize, out: &mut [f64]) -> Result<()> {
        let (p, m) = (self.n_params(), self.out_dim);
        let rows = cache.batch * rows_per_sample;
        check_len("cotangent length (batch * rows_per_sample * out_dim)", rows * m, cot.len())?;
        check_len("Jacobian buffer length (rows * n_params)", rows * p, out.len())?;
        let (x, y) = self.cached(cache)?;
        // The graph of each sample's output: a slice of the batch graph, or its own graph.
        let per_sample: Vec<Tensor> = match self.mode {
            JacobianMode::Batch => (0..cache.batch).map(|s| y.narrow(0, s, 1)).collect::<candle_core::Result<_>>()?,
            JacobianMode::PerSample => {
                (0..cache.batch).map(|s| self.run(&x.narrow(0, s, 1)?)).collect::<Result<_>>()?
            }
        };
        let dtype = y.dtype();
        let (vars, offsets, device) = (&self.vars, &self.offsets, &self.device);
        out.par_chunks_mut(p).enumerate().try_for_each(|(r, row)| -> Result<()> {
            let c = Tensor::from_slice(&cot[r * m..(r + 1) * m], (1, m), device)?.to_dtype(dtype)?;
            backward_into(vars, offsets, &per_sample[r / rows_per_sample], &c, row)
        })?;
        check_finite("CandleModel Jacobian (a NaN/Inf derivative of the forward closure)", out, p)
    }

    /// One ordinary backward pass of `<cot, out>` over the whole batch.
    fn gradient(&self, cache: &CandleCache, cot: &[f64], grad: &mut [f64]) -> Result<()> {
        check_len("cotangent length (batch * out_dim)", cache.batch * self.out_dim, cot.len())?;
        check_len("gradient length (n_params)", self.n_params(), grad.len())?;
        let (_, y) = self.cached(cache)?;
        let c = Tensor::from_slice(cot, (cache.batch, self.out_dim), &self.device)?.to_dtype(y.dtype())?;
        backward_into(&self.vars, &self.offsets, y, &c, grad)
    }
}

/// The forward closure of [`from_mlp`].
pub type MlpForward = Box<dyn Fn(&Tensor) -> candle_core::Result<Tensor> + Send + Sync>;

/// `net` as a candle model with the same weights: `W_l` as `Var`s of shape `[out, in]` and `b_l`
/// layer after layer (the `Mlp`'s own flat order, so parameter vectors carry over unchanged),
/// the `Mlp`'s hidden activation, linear output. A starting point for your own candle
/// variants of a network trained with the hand-written `Mlp`, and the reference the adapter is
/// tested against.
pub fn from_mlp(net: &crate::mlp::Mlp) -> Result<CandleModel<MlpForward>> {
    use crate::mlp::Activation;
    let (sizes, p) = (net.sizes().to_vec(), net.params());
    let mut vars = Vec::with_capacity(2 * (sizes.len() - 1));
    let mut off = 0;
    for w in sizes.windows(2) {
        vars.push(Var::from_slice(&p[off..off + w[0] * w[1]], (w[1], w[0]), &Device::Cpu)?);
        off += w[0] * w[1];
        vars.push(Var::from_slice(&p[off..off + w[1]], w[1], &Device::Cpu)?);
        off += w[1];
    }
    let (layers, act) = (vars.clone(), net.activation());
    let forward: MlpForward = Box::new(move |x: &Tensor| {
        let mut h = x.clone();
        let n = layers.len() / 2;
        for l in 0..n {
            h = h.matmul(&layers[2 * l].t()?)?.broadcast_add(&layers[2 * l + 1])?;
            if l + 1 < n {
                h = match act {
                    Activation::Tanh => h.tanh()?,
                    Activation::Relu => h.relu()?,
                };
            }
        }
        Ok(h)
    });
    CandleModel::new(vars, sizes[0], sizes[sizes.len() - 1], forward)
}
