//! The continuous convolution as a candle custom op with a hand-written backward pass:
//!
//! `out_i = Σ_{j ∈ N(i)} Σ_k v_k(x_j - x_i) (f_j W_k)` (CConv / SFBC), or with
//! [`FilterSpec::antisymmetric`] `out_i = Σ_j Σ_k v_k(x_j - x_i) ((f_i + f_j) W_k)` with an odd
//! filter (DMCF), where `v_k` are the filter's basis values ([`crate::filter`]) and `W_k` is a
//! `C_in x C_out` matrix. No normalisation; no bias (add it outside).
//!
//! How it runs: receivers are processed in blocks; a block gathers `G[i, (k, c)] = Σ_j v_k f_jc`
//! and multiplies it with the weights as one matrix product (`[rows, K C_in] x [K C_in, C_out]`),
//! so the inner loops are a gather and a GEMM. The backward pass recomputes `G` block by block
//! (nothing of size `pairs x K` is stored) and returns the gradients of the features, the
//! weights and the offsets (hence of positions, through [`crate::graph::PairGraph::offsets`]).
//! Partial sums are reduced in a fixed order, so results depend on the thread count only.
//! Second derivatives are not available (the backward is itself not differentiable).
//!
//! ```
//! use std::sync::Arc;
//! use candle_core::{Device, Tensor};
//! use pbdl_pconv::{basis::Basis, filter::FilterSpec, graph::PairGraph, op::continuous_conv};
//! use pbdl_particles::Domain;
//!
//! let x = [[0.1], [0.2], [0.35], [0.7]];
//! let graph = Arc::new(PairGraph::build_self(&Domain::periodic([0.0], [1.0]), 0.2, &x)?);
//! let spec = FilterSpec::sfbc(1, Basis::Fourier, 4, 0.2);
//! let dev = Device::Cpu;
//! let pos = Tensor::new(&[[0.1f64], [0.2], [0.35], [0.7]], &dev)?;
//! let features = Tensor::ones((4, 2), candle_core::DType::F64, &dev)?;
//! let weights = Tensor::ones((4, 2, 3), candle_core::DType::F64, &dev)?;
//! let out = continuous_conv(&features, &weights, &graph.offsets(&pos, &pos)?, &graph, &spec)?;
//! assert_eq!(out.dims(), &[4, 3]);
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::filter::{FilterSpec, PairFilter};
use crate::graph::PairGraph;
use candle_core::{Shape, Tensor};
use pbdl_core::matmul::{matmul, Mat, Threads};
use pbdl_core::op::{apply3, apply_kernel3, Kernel3, Op3};
use pbdl_core::Real;
use rayon::prelude::*;
use std::sync::Arc;

/// Receivers per block: the gathered block `G` is `BLOCK x K C_in`.
const BLOCK: usize = 64;

/// Applies the continuous convolution: `features [n_senders, C_in]`, `weights [K, C_in, C_out]`
/// (`K = spec.filter_size()`), `offsets [pairs, dim]` from [`PairGraph::offsets`]; returns
/// `[n_receivers, C_out]`. Differentiable in all three tensors.
pub fn continuous_conv(
    features: &Tensor,
    weights: &Tensor,
    offsets: &Tensor,
    graph: &Arc<PairGraph>,
    spec: &FilterSpec,
) -> Result<Tensor> {
    check(features, weights, offsets, graph, spec)?;
    Ok(apply3(features, weights, offsets, ConvOp { graph: graph.clone(), spec: *spec })?)
}

fn check(features: &Tensor, weights: &Tensor, offsets: &Tensor, graph: &PairGraph, spec: &FilterSpec) -> Result<()> {
    spec.validate()?;
    for (t, what) in [(features, "features"), (weights, "weights"), (offsets, "offsets")] {
        PairGraph::check_float(t, what)?;
    }
    if spec.dim != graph.dim() {
        return Err(Error::Shape(format!("filter dim {} but graph dim {}", spec.dim, graph.dim())));
    }
    if (spec.radius - graph.radius()).abs() > 1e-12 * spec.radius {
        return Err(Error::Config {
            field: "radius",
            reason: format!(
                "filter radius {} differs from the graph's search radius {}; build both with one",
                spec.radius,
                graph.radius()
            ),
        });
    }
    if spec.antisymmetric && !graph.is_self_graph() {
        return Err(Error::Config {
            field: "antisymmetric",
            reason: "an antisymmetric convolution needs senders = receivers (a self graph)".into(),
        });
    }
    let (ns, k) = (graph.n_senders(), spec.filter_size());
    let fd = features.dims();
    if fd.len() != 2 || fd[0] != ns {
        return Err(Error::Shape(format!("features {fd:?}; need [{ns} senders, channels]")));
    }
    let wd = weights.dims();
    if wd.len() != 3 || wd[0] != k || wd[1] != fd[1] {
        return Err(Error::Shape(format!(
            "weights {wd:?}; need [{k} filter values, {} in-channels, out-channels]",
            fd[1]
        )));
    }
    if offsets.dims() != [graph.num_pairs(), spec.dim] {
        return Err(Error::Shape(format!("offsets {:?}; need [{}, {}]", offsets.dims(), graph.num_pairs(), spec.dim)));
    }
    Ok(())
}

struct ConvOp {
    graph: Arc<PairGraph>,
    spec: FilterSpec,
}

impl Kernel3 for ConvOp {
    fn name(&self) -> &'static str {
        "continuous_conv"
    }

    fn output_shape(&self, f: &Shape, w: &Shape, _d: &Shape) -> candle_core::Result<Shape> {
        let _ = f;
        Ok(Shape::from((self.graph.n_receivers(), w.dims()[2])))
    }

    fn forward<T: Real>(
        &self,
        f: &[T],
        f_shape: &Shape,
        w: &[T],
        w_shape: &Shape,
        d: &[T],
        _d_shape: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let dims = Dims::new(&self.spec, f_shape.dims()[1], w_shape.dims()[2]);
        let g = &*self.graph;
        let work = g.num_pairs() * dims.kc;
        let run = |(b, out_block): (usize, &mut [T]), scratch: &mut Scratch<T>| {
            let rows = block_rows(g, b);
            gather_block(
                &mut scratch.filter,
                g,
                &dims,
                rows.clone(),
                f,
                d,
                &mut scratch.gathered,
                &mut scratch.vals,
                &mut scratch.fsum,
            );
            let nb = rows.len();
            let gb = Mat::row_major(&scratch.gathered[..nb * dims.kc], dims.kc);
            matmul(
                out_block,
                dims.cout,
                false,
                gb,
                Mat::row_major(w, dims.cout),
                (nb, dims.cout, dims.kc),
                T::one(),
                Threads::Serial,
            );
        };
        let init = || Scratch::new(&self.spec, &dims);
        if pbdl_core::threads::parallel(work) {
            out.par_chunks_mut(BLOCK * dims.cout).enumerate().for_each_init(init, |s, item| run(item, s));
        } else {
            let mut s = init();
            out.chunks_mut(BLOCK * dims.cout).enumerate().for_each(|item| run(item, &mut s));
        }
        Ok(())
    }
}

impl Op3 for ConvOp {
    fn backward(
        &self,
        f: &Tensor,
        w: &Tensor,
        d: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        // The backward kernel needs four inputs; weights and output gradient travel as one.
        let packed = Tensor::cat(&[w.flatten_all()?, gy.flatten_all()?], 0)?;
        let (ns, cin) = f.dims2()?;
        let (k, _, cout) = w.dims3()?;
        let flat =
            apply_kernel3(f, d, &packed, ConvBackward { graph: self.graph.clone(), spec: self.spec, cin, cout })?;
        let nw = k * cin * cout;
        let gf = flat.narrow(0, 0, ns * cin)?.reshape((ns, cin))?;
        let gw = flat.narrow(0, ns * cin, nw)?.reshape((k, cin, cout))?;
        let gd = flat.narrow(0, ns * cin + nw, d.elem_count())?.reshape(d.shape())?;
        Ok((gf, gw, gd))
    }
}

/// Sizes shared by the kernels.
struct Dims {
    dim: usize,
    k: usize,
    cin: usize,
    cout: usize,
    kc: usize,
    anti: bool,
}

impl Dims {
    fn new(spec: &FilterSpec, cin: usize, cout: usize) -> Self {
        let k = spec.filter_size();
        Dims { dim: spec.dim, k, cin, cout, kc: k * cin, anti: spec.antisymmetric }
    }
}

struct Scratch<T> {
    filter: PairFilter<T>,
    gathered: Vec<T>,
    vals: Vec<T>,
    grads: Vec<T>,
    h: Vec<T>,
    fsum: Vec<T>,
    t: Vec<T>,
}

impl<T: Real> Scratch<T> {
    fn new(spec: &FilterSpec, dims: &Dims) -> Self {
        Scratch {
            filter: spec.evaluator(),
            gathered: vec![T::zero(); BLOCK * dims.kc],
            vals: vec![T::zero(); dims.k],
            grads: vec![T::zero(); dims.k * dims.dim],
            h: vec![T::zero(); BLOCK * dims.kc],
            fsum: vec![T::zero(); dims.cin],
            t: vec![T::zero(); dims.cin],
        }
    }
}

fn block_rows(g: &PairGraph, b: usize) -> std::ops::Range<usize> {
    let r0 = b * BLOCK;
    r0..(r0 + BLOCK).min(g.n_receivers())
}

/// The features a pair brings: `f_j`, or `f_i + f_j` for the antisymmetric filter.
#[inline]
fn pair_features<'a, T: Real>(f: &'a [T], i: usize, j: usize, dims: &Dims, fsum: &'a mut [T]) -> &'a [T] {
    let fj = &f[j * dims.cin..(j + 1) * dims.cin];
    if !dims.anti {
        return fj;
    }
    let fi = &f[i * dims.cin..(i + 1) * dims.cin];
    for c in 0..dims.cin {
        fsum[c] = fi[c] + fj[c];
    }
    fsum
}

/// `G[i - r0, k * C_in + c] = Σ_p v_k(d_p) feat_p[c]` for the receivers `rows`.
#[allow(clippy::too_many_arguments)]
fn gather_block<T: Real>(
    filter: &mut PairFilter<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
    gathered: &mut [T],
    vals: &mut [T],
    fsum: &mut [T],
) {
    let r0 = rows.start;
    gathered[..rows.len() * dims.kc].fill(T::zero());
    for i in rows {
        let row = &mut gathered[(i - r0) * dims.kc..(i - r0 + 1) * dims.kc];
        for p in g.row_offsets()[i]..g.row_offsets()[i + 1] {
            let j = g.senders()[p] as usize;
            filter.values(&d[p * dims.dim..(p + 1) * dims.dim], vals);
            let feat = pair_features(f, i, j, dims, fsum);
            for k in 0..dims.k {
                let v = vals[k];
                if v == T::zero() {
                    continue;
                }
                let dst = &mut row[k * dims.cin..(k + 1) * dims.cin];
                for c in 0..dims.cin {
                    dst[c] += v * feat[c];
                }
            }
        }
    }
}

/// Forward-only kernel of the backward pass: inputs features, offsets and `[weights | grad_out]`;
/// output `[grad_features | grad_weights | grad_offsets]` flattened.
struct ConvBackward {
    graph: Arc<PairGraph>,
    spec: FilterSpec,
    cin: usize,
    cout: usize,
}

impl Kernel3 for ConvBackward {
    fn name(&self) -> &'static str {
        "continuous_conv_backward"
    }

    fn output_shape(&self, f: &Shape, d: &Shape, _packed: &Shape) -> candle_core::Result<Shape> {
        let n = f.elem_count() + self.spec.filter_size() * self.cin * self.cout + d.elem_count();
        Ok(Shape::from(n))
    }

    fn forward<T: Real>(
        &self,
        f: &[T],
        _f_shape: &Shape,
        d: &[T],
        _d_shape: &Shape,
        packed: &[T],
        _p_shape: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let dims = Dims::new(&self.spec, self.cin, self.cout);
        let g = &*self.graph;
        let nw = dims.kc * dims.cout;
        let (w, gy) = packed.split_at(nw);
        let (gf_out, rest) = out.split_at_mut(f.len());
        let (gw_out, gd_out) = rest.split_at_mut(nw);

        // Contiguous runs of blocks, one accumulator each, summed in order afterwards.
        let nblocks = g.n_receivers().div_ceil(BLOCK);
        let parallel = pbdl_core::threads::parallel(g.num_pairs() * dims.kc);
        let nchunks = if parallel { pbdl_core::threads::count().clamp(1, 8).min(nblocks.max(1)) } else { 1 };
        let per_chunk = nblocks.div_ceil(nchunks.max(1)).max(1);
        let mut jobs = Vec::with_capacity(nchunks);
        let mut gd_rest: &mut [T] = gd_out;
        let mut pair_start = 0;
        for c in 0..nchunks {
            let b0 = c * per_chunk;
            let b1 = ((c + 1) * per_chunk).min(nblocks);
            let r1 = (b1 * BLOCK).min(g.n_receivers());
            let pair_end = g.row_offsets()[r1.max(b0 * BLOCK).min(g.n_receivers())];
            let (mine, tail) = gd_rest.split_at_mut((pair_end - pair_start) * dims.dim);
            jobs.push((b0..b1, pair_start, mine));
            gd_rest = tail;
            pair_start = pair_end;
        }
        let run = |(blocks, p0, gd): (std::ops::Range<usize>, usize, &mut [T])| {
            let mut gf = vec![T::zero(); f.len()];
            let mut gw = vec![T::zero(); nw];
            let mut s = Scratch::new(&self.spec, &dims);
            for b in blocks {
                backward_block(&mut s, g, &dims, block_rows(g, b), f, d, w, gy, &mut gf, &mut gw, gd, p0);
            }
            (gf, gw)
        };
        let partial: Vec<(Vec<T>, Vec<T>)> =
            if parallel { jobs.into_par_iter().map(run).collect() } else { jobs.into_iter().map(run).collect() };
        for (gf, gw) in partial {
            for (o, v) in gf_out.iter_mut().zip(gf) {
                *o += v;
            }
            for (o, v) in gw_out.iter_mut().zip(gw) {
                *o += v;
            }
        }
        Ok(())
    }
}

/// One block of receivers: `H = gy W^T`, then per pair the offset gradient and the feature
/// gradient, and `G^T gy` into the weight gradient.
#[allow(clippy::too_many_arguments)]
fn backward_block<T: Real>(
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
    w: &[T],
    gy: &[T],
    gf: &mut [T],
    gw: &mut [T],
    gd: &mut [T],
    p0: usize,
) {
    let (r0, nb, kc, cin, dim) = (rows.start, rows.len(), dims.kc, dims.cin, dims.dim);
    if nb == 0 {
        return;
    }
    let gy_block = &gy[r0 * dims.cout..(r0 + nb) * dims.cout];
    // H[i, (k, c)] = Σ_o gy[i, o] W[(k, c), o].
    matmul(
        &mut s.h[..nb * kc],
        kc,
        false,
        Mat::row_major(gy_block, dims.cout),
        Mat::new(w, 1, dims.cout),
        (nb, kc, dims.cout),
        T::one(),
        Threads::Serial,
    );
    s.gathered[..nb * kc].fill(T::zero());
    for i in rows {
        let h = &s.h[(i - r0) * kc..(i - r0 + 1) * kc];
        let grow = &mut s.gathered[(i - r0) * kc..(i - r0 + 1) * kc];
        for p in g.row_offsets()[i]..g.row_offsets()[i + 1] {
            let j = g.senders()[p] as usize;
            s.filter.values_and_grads(&d[p * dim..(p + 1) * dim], &mut s.vals, &mut s.grads);
            let feat = pair_features(f, i, j, dims, &mut s.fsum);
            s.t.fill(T::zero());
            let mut gdp = [T::zero(); 3];
            for k in 0..dims.k {
                let v = s.vals[k];
                let dv = &s.grads[k * dim..(k + 1) * dim];
                if v == T::zero() && dv.iter().all(|&x| x == T::zero()) {
                    continue;
                }
                let hk = &h[k * cin..(k + 1) * cin];
                let mut e = T::zero();
                let dst = &mut grow[k * cin..(k + 1) * cin];
                for c in 0..cin {
                    e += feat[c] * hk[c];
                    s.t[c] += v * hk[c];
                    dst[c] += v * feat[c];
                }
                for a in 0..dim {
                    gdp[a] += dv[a] * e;
                }
            }
            let q = p - p0;
            gd[q * dim..(q + 1) * dim].copy_from_slice(&gdp[..dim]);
            for c in 0..cin {
                gf[j * cin + c] += s.t[c];
            }
            if dims.anti {
                for c in 0..cin {
                    gf[i * cin + c] += s.t[c];
                }
            }
        }
    }
    // grad W += G^T gy_block.
    matmul(
        gw,
        dims.cout,
        true,
        Mat::transposed(&s.gathered[..nb * kc], kc),
        Mat::row_major(gy_block, dims.cout),
        (kc, dims.cout, nb),
        T::one(),
        Threads::Serial,
    );
}
