//! The continuous convolution as a candle custom op with a hand-written backward pass:
//!
//! `out_i = Σ_{j ∈ N(i)} Σ_k v_k(x_j - x_i) (f_j W_k)` (CConv / SFBC), or with
//! [`FilterSpec::antisymmetric`] `out_i = Σ_j Σ_k v_k(x_j - x_i) ((f_i + f_j) W_k)` with an odd
//! filter (DMCF), where `v_k` are the filter's basis values ([`crate::filter`]) and `W_k` is a
//! `C_in x C_out` matrix. No normalisation; no bias (add it outside).
//!
//! How it runs: receivers are processed in blocks; a block gathers `G[i, (k, c)] = Σ_j v_k f_jc`
//! and multiplies it with the weights as one matrix product (`[rows, K C_in] x [K C_in, C_out]`),
//! so the inner loops are a gather and a GEMM. The gather visits only the `2^d` nonzero terms of
//! a pair for the linear basis (CConv), and for dense bases (all `K` terms nonzero) is one small
//! register-blocked product `V_i^T F_i` per receiver (its pairs' basis values `[pairs, K]` times
//! their features `[pairs, C_in]`). The backward pass recomputes `G` block by block (nothing of
//! size `pairs x K` is stored) and returns the gradients of the features, the weights and the
//! offsets (hence of positions, through [`crate::graph::PairGraph::offsets`]); for dense bases
//! its per-pair products are again small products per receiver (`F H_i^T`, `V H_i`, `V^T F`).
//! The pair loops run as AVX2 + FMA code where the CPU has it (detected at run time), and
//! prefetch the scattered sender rows ahead.
//! Partial sums are reduced in a fixed order, so results depend only on the thread count (and,
//! in the last bits, on whether the CPU has FMA).
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
        let fma = fma_available();
        let run = |(b, out_block): (usize, &mut [T]), scratch: &mut Scratch<T>| {
            let rows = block_rows(g, b);
            gather_block(fma, scratch, g, &dims, rows.clone(), f, d);
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
        // A few runs of blocks per thread, one scratch each (not one per rayon split: the
        // buffers are large and fresh allocations cost page faults).
        let per_run = BLOCK * dims.cout;
        if pbdl_core::threads::parallel(work) {
            let nblocks = g.n_receivers().div_ceil(BLOCK).max(1);
            let runs = (4 * pbdl_core::threads::count()).clamp(1, nblocks);
            let blocks_per_run = nblocks.div_ceil(runs);
            out.par_chunks_mut(blocks_per_run * per_run).enumerate().for_each(|(r, chunk)| {
                let mut s = Scratch::new(&self.spec, &dims, false);
                for (b, block) in chunk.chunks_mut(per_run).enumerate() {
                    run((r * blocks_per_run + b, block), &mut s);
                }
            });
        } else {
            let mut s = Scratch::new(&self.spec, &dims, false);
            out.chunks_mut(per_run).enumerate().for_each(|item| run(item, &mut s));
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
    h: Vec<T>,
    /// `H` of one receiver transposed, `[C_in, K]` (dense backward).
    ht: Vec<T>,
    /// Filter indices of one pair's terms (sparse filters).
    idx: Vec<u32>,
    /// Term values: one pair's (sparse), or `[pairs of a receiver, K]` (dense).
    vals: Vec<T>,
    /// Term gradients, `dim` per term, laid out as `vals`.
    grads: Vec<T>,
    /// The features of a receiver's pairs, `[pairs, C_in]` (dense).
    feats: Vec<T>,
    /// `E = F H^T`, `[pairs, K]` (dense backward).
    e: Vec<T>,
    /// `T = V H`, `[pairs, C_in]` (dense backward); one pair's `C_in` (sparse).
    t: Vec<T>,
    fsum: Vec<T>,
}

impl<T: Real> Scratch<T> {
    fn new(spec: &FilterSpec, dims: &Dims, backward: bool) -> Self {
        let filter = spec.evaluator();
        let m = filter.max_terms();
        Scratch {
            filter,
            gathered: vec![T::zero(); BLOCK * dims.kc],
            h: if backward { vec![T::zero(); BLOCK * dims.kc] } else { Vec::new() },
            ht: if backward { vec![T::zero(); dims.kc] } else { Vec::new() },
            idx: vec![0; m],
            vals: vec![T::zero(); m],
            grads: vec![T::zero(); m * dims.dim],
            feats: Vec::new(),
            e: Vec::new(),
            t: vec![T::zero(); dims.cin],
            fsum: vec![T::zero(); dims.cin],
        }
    }

    /// Room for `np` pairs of one receiver in the dense buffers (grown, never shrunk).
    fn reserve_dense(&mut self, np: usize, dims: &Dims, backward: bool) {
        let grow = |v: &mut Vec<T>, len: usize| {
            if v.len() < len {
                v.resize(len, T::zero());
            }
        };
        grow(&mut self.vals, np * dims.k);
        grow(&mut self.feats, np * dims.cin);
        if backward {
            grow(&mut self.grads, np * dims.k * dims.dim);
            grow(&mut self.e, np * dims.k);
            grow(&mut self.t, np * dims.cin);
        }
    }
}

fn block_rows(g: &PairGraph, b: usize) -> std::ops::Range<usize> {
    let r0 = b * BLOCK;
    r0..(r0 + BLOCK).min(g.n_receivers())
}

/// The most pairs of one receiver among `rows`.
fn max_row_len(g: &PairGraph, rows: std::ops::Range<usize>) -> usize {
    let ro = g.row_offsets();
    rows.map(|i| ro[i + 1] - ro[i]).max().unwrap_or(0)
}

/// Whether the CPU runs the AVX2 + FMA build of the block kernels.
fn fma_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `a * b + c`, fused when `FMA` (a libm call unless the CPU feature is enabled, so only
/// instantiated inside `#[target_feature(enable = "fma")]` functions).
#[inline(always)]
fn madd<T: Real, const FMA: bool>(a: T, b: T, c: T) -> T {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// Pairs ahead whose sender rows are prefetched (senders are scattered in memory).
const PREFETCH: usize = 8;

/// Hints the cache to fetch the sender row of pair `p + PREFETCH` (of `data`, `width` values
/// per sender).
#[inline(always)]
fn prefetch_sender<T>(g: &PairGraph, p: usize, data: &[T], width: usize) {
    if let Some(&j) = g.senders().get(p + PREFETCH) {
        prefetch_row(data, j as usize, width);
    }
}

/// Hints the cache to fetch row `j` of `data` (`width` values per row).
#[inline(always)]
fn prefetch_row<T>(data: &[T], j: usize, width: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        let row = &data[j * width..(j + 1) * width];
        for off in (0..std::mem::size_of_val(row)).step_by(64) {
            // SAFETY: SSE is part of every x86_64 CPU; a prefetch never faults, and the
            // address lies inside `row` anyway.
            unsafe {
                core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(
                    row.as_ptr().cast::<i8>().wrapping_add(off),
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, j, width);
}

/// `dst += v * src`.
#[inline(always)]
fn axpy<T: Real, const FMA: bool>(dst: &mut [T], v: T, src: &[T]) {
    for (o, &x) in dst.iter_mut().zip(src) {
        *o = madd::<T, FMA>(v, x, *o);
    }
}

/// `Σ a_c b_c`.
#[inline(always)]
fn dot<T: Real, const FMA: bool>(a: &[T], b: &[T]) -> T {
    let mut e = T::zero();
    for (&x, &y) in a.iter().zip(b) {
        e = madd::<T, FMA>(x, y, e);
    }
    e
}

/// A small matrix product with a register-blocked inner kernel:
/// `out[r, c] += Σ_l A(r, l) b[l, c]` for `r < m`, `c < n`, `l < len`, where
/// `A(r, l) = a[r * a_rs + l * a_cs]` and `b` is row-major `[len, n]`, `out` row-major `[m, n]`.
#[inline(always)]
fn small_gemm<T: Real, const FMA: bool>(
    out: &mut [T],
    a: &[T],
    a_rs: usize,
    a_cs: usize,
    b: &[T],
    m: usize,
    len: usize,
    n: usize,
) {
    if std::mem::size_of::<T>() <= 4 {
        small_gemm_nb::<T, 16, FMA>(out, a, a_rs, a_cs, b, m, len, n)
    } else {
        small_gemm_nb::<T, 8, FMA>(out, a, a_rs, a_cs, b, m, len, n)
    }
}

#[inline(always)]
fn small_gemm_nb<T: Real, const NB: usize, const FMA: bool>(
    out: &mut [T],
    a: &[T],
    a_rs: usize,
    a_cs: usize,
    b: &[T],
    m: usize,
    len: usize,
    n: usize,
) {
    const MR: usize = 4;
    let nfull = n / NB * NB;
    let mut r0 = 0;
    while r0 + MR <= m {
        for c0 in (0..nfull).step_by(NB) {
            tile::<T, MR, NB, FMA>(out, a, a_rs, a_cs, b, r0, c0, len, n);
        }
        r0 += MR;
    }
    for r in r0..m {
        for c0 in (0..nfull).step_by(NB) {
            tile::<T, 1, NB, FMA>(out, a, a_rs, a_cs, b, r, c0, len, n);
        }
    }
    if nfull < n {
        for r in 0..m {
            for l in 0..len {
                let av = a[r * a_rs + l * a_cs];
                let brow = &b[l * n + nfull..(l + 1) * n];
                axpy::<T, FMA>(&mut out[r * n + nfull..(r + 1) * n], av, brow);
            }
        }
    }
}

/// `R x NB` block of [`small_gemm`] at row `r0`, column `c0`, held in registers over `l`.
#[inline(always)]
fn tile<T: Real, const R: usize, const NB: usize, const FMA: bool>(
    out: &mut [T],
    a: &[T],
    a_rs: usize,
    a_cs: usize,
    b: &[T],
    r0: usize,
    c0: usize,
    len: usize,
    n: usize,
) {
    let mut acc = [[T::zero(); NB]; R];
    for l in 0..len {
        let brow: &[T; NB] = b[l * n + c0..l * n + c0 + NB].try_into().expect("NB columns");
        for r in 0..R {
            let av = a[(r0 + r) * a_rs + l * a_cs];
            for c in 0..NB {
                acc[r][c] = madd::<T, FMA>(av, brow[c], acc[r][c]);
            }
        }
    }
    for r in 0..R {
        let o = &mut out[(r0 + r) * n + c0..(r0 + r) * n + c0 + NB];
        for c in 0..NB {
            o[c] += acc[r][c];
        }
    }
}

/// The features a pair brings: `f_j`, or `f_i + f_j` for the antisymmetric filter.
#[inline(always)]
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

/// `G[i - r0, k * C_in + c] = Σ_p v_k(d_p) feat_p[c]` for the receivers `rows`, into
/// `s.gathered`: per pair over its nonzero terms (sparse filters), or per receiver as the
/// product `V^T F` of its pairs' values `[pairs, K]` and features `[pairs, C_in]` (dense).
fn gather_block<T: Real>(
    fma: bool,
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
) {
    #[cfg(target_arch = "x86_64")]
    if fma {
        // SAFETY: `fma` is `fma_available()`: the CPU supports AVX2 and FMA.
        unsafe { gather_block_avx2(s, g, dims, rows, f, d) };
        return;
    }
    let _ = fma;
    gather_block_impl::<T, false>(s, g, dims, rows, f, d)
}

/// [`gather_block_impl`] compiled for AVX2 with fused multiply-adds.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gather_block_avx2<T: Real>(
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
) {
    gather_block_impl::<T, true>(s, g, dims, rows, f, d)
}

#[inline(always)]
fn gather_block_impl<T: Real, const FMA: bool>(
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
) {
    let (r0, kc, cin, dim) = (rows.start, dims.kc, dims.cin, dims.dim);
    s.gathered[..rows.len() * kc].fill(T::zero());
    let sparse = s.filter.is_sparse();
    if !sparse {
        s.reserve_dense(max_row_len(g, rows.clone()), dims, false);
    }
    for i in rows {
        let row = &mut s.gathered[(i - r0) * kc..(i - r0 + 1) * kc];
        let pairs = g.row_offsets()[i]..g.row_offsets()[i + 1];
        if sparse {
            for p in pairs {
                prefetch_sender(g, p, f, cin);
                let j = g.senders()[p] as usize;
                let m = s.filter.terms(&d[p * dim..(p + 1) * dim], &mut s.idx, &mut s.vals, None);
                let feat = pair_features(f, i, j, dims, &mut s.fsum);
                for t in 0..m {
                    let k = s.idx[t] as usize;
                    axpy::<T, FMA>(&mut row[k * cin..(k + 1) * cin], s.vals[t], feat);
                }
            }
        } else {
            let np = pairs.len();
            let p0 = pairs.start;
            for p in pairs {
                prefetch_sender(g, p, f, cin);
                let (q, j) = (p - p0, g.senders()[p] as usize);
                s.filter.terms(&d[p * dim..(p + 1) * dim], &mut s.idx, &mut s.vals[q * dims.k..(q + 1) * dims.k], None);
                let feat = pair_features(f, i, j, dims, &mut s.fsum);
                for (o, &x) in s.feats[q * cin..(q + 1) * cin].iter_mut().zip(feat) {
                    *o = x;
                }
            }
            // G_i[k, c] += Σ_q V[q, k] F[q, c].
            small_gemm::<T, FMA>(row, &s.vals, 1, dims.k, &s.feats, dims.k, np, cin);
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
        let fma = fma_available();
        let run = |(blocks, p0, gd): (std::ops::Range<usize>, usize, &mut [T])| {
            let mut gf = vec![T::zero(); f.len()];
            let mut gw = vec![T::zero(); nw];
            let mut s = Scratch::new(&self.spec, &dims, true);
            for b in blocks {
                backward_block(fma, &mut s, g, &dims, block_rows(g, b), f, d, w, gy, &mut gf, &mut gw, gd, p0);
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
    fma: bool,
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
    let (r0, nb, kc) = (rows.start, rows.len(), dims.kc);
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
    #[cfg(target_arch = "x86_64")]
    if fma {
        // SAFETY: `fma` is `fma_available()`: the CPU supports AVX2 and FMA.
        unsafe { backward_pairs_avx2(s, g, dims, rows, f, d, gf, gd, p0) };
    } else {
        backward_pairs::<T, false>(s, g, dims, rows, f, d, gf, gd, p0);
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = fma;
        backward_pairs::<T, false>(s, g, dims, rows, f, d, gf, gd, p0);
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

/// [`backward_pairs`] compiled for AVX2 with fused multiply-adds.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn backward_pairs_avx2<T: Real>(
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
    gf: &mut [T],
    gd: &mut [T],
    p0: usize,
) {
    backward_pairs::<T, true>(s, g, dims, rows, f, d, gf, gd, p0)
}

/// The pair loop of one block's backward pass, with `s.h` holding `H` of the block: per pair
/// `e_k = feat · H_i[k]` (offset gradient `Σ_k ∇v_k e_k`), `t = Σ_k v_k H_i[k]` (feature
/// gradient of the sender, and of the receiver when antisymmetric), and `G` recomputed into
/// `s.gathered`. Sparse filters loop over each pair's nonzero terms; dense ones do the three
/// products per receiver as small matrix products over its pairs.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn backward_pairs<T: Real, const FMA: bool>(
    s: &mut Scratch<T>,
    g: &PairGraph,
    dims: &Dims,
    rows: std::ops::Range<usize>,
    f: &[T],
    d: &[T],
    gf: &mut [T],
    gd: &mut [T],
    p0: usize,
) {
    let (r0, kc, cin, dim, k_len) = (rows.start, dims.kc, dims.cin, dims.dim, dims.k);
    let sparse = s.filter.is_sparse();
    if !sparse {
        s.reserve_dense(max_row_len(g, rows.clone()), dims, true);
    }
    for i in rows {
        let h = &s.h[(i - r0) * kc..(i - r0 + 1) * kc];
        let grow = &mut s.gathered[(i - r0) * kc..(i - r0 + 1) * kc];
        let pairs = g.row_offsets()[i]..g.row_offsets()[i + 1];
        if sparse {
            for p in pairs {
                prefetch_sender(g, p, f, cin);
                prefetch_sender(g, p, gf, cin);
                let j = g.senders()[p] as usize;
                let m = s.filter.terms(&d[p * dim..(p + 1) * dim], &mut s.idx, &mut s.vals, Some(&mut s.grads));
                let feat = pair_features(f, i, j, dims, &mut s.fsum);
                let tv = &mut s.t[..cin];
                tv.fill(T::zero());
                let mut gdp = [T::zero(); 3];
                for t in 0..m {
                    let k = s.idx[t] as usize;
                    let v = s.vals[t];
                    let dv = &s.grads[t * dim..(t + 1) * dim];
                    let hk = &h[k * cin..(k + 1) * cin];
                    let e = dot::<T, FMA>(feat, hk);
                    axpy::<T, FMA>(tv, v, hk);
                    axpy::<T, FMA>(&mut grow[k * cin..(k + 1) * cin], v, feat);
                    for a in 0..dim {
                        gdp[a] += dv[a] * e;
                    }
                }
                let q = p - p0;
                for a in 0..dim {
                    gd[q * dim + a] = gdp[a];
                }
                for c in 0..cin {
                    gf[j * cin + c] += tv[c];
                }
                if dims.anti {
                    for c in 0..cin {
                        gf[i * cin + c] += tv[c];
                    }
                }
            }
        } else {
            let np = pairs.len();
            if np == 0 {
                continue;
            }
            let pstart = pairs.start;
            for p in pairs.clone() {
                prefetch_sender(g, p, f, cin);
                let (q, j) = (p - pstart, g.senders()[p] as usize);
                // Its feature-gradient row is written after the products below.
                prefetch_row(gf, j, cin);
                s.filter.terms(
                    &d[p * dim..(p + 1) * dim],
                    &mut s.idx,
                    &mut s.vals[q * k_len..(q + 1) * k_len],
                    Some(&mut s.grads[q * k_len * dim..(q + 1) * k_len * dim]),
                );
                let feat = pair_features(f, i, j, dims, &mut s.fsum);
                for (o, &x) in s.feats[q * cin..(q + 1) * cin].iter_mut().zip(feat) {
                    *o = x;
                }
            }
            let (vals, feats) = (&s.vals[..np * k_len], &s.feats[..np * cin]);
            // H_i^T, [C_in, K].
            for k in 0..k_len {
                for c in 0..cin {
                    s.ht[c * k_len + k] = h[k * cin + c];
                }
            }
            // E[q, k] = Σ_c F[q, c] H_i[k, c].
            let e = &mut s.e[..np * k_len];
            e.fill(T::zero());
            small_gemm::<T, FMA>(e, feats, cin, 1, &s.ht, np, cin, k_len);
            // T[q, c] = Σ_k V[q, k] H_i[k, c].
            let tm = &mut s.t[..np * cin];
            tm.fill(T::zero());
            small_gemm::<T, FMA>(tm, vals, k_len, 1, h, np, k_len, cin);
            // G_i[k, c] += Σ_q V[q, k] F[q, c].
            small_gemm::<T, FMA>(grow, vals, 1, k_len, feats, k_len, np, cin);
            for p in pairs {
                let (q, j) = (p - pstart, g.senders()[p] as usize);
                let mut gdp = [T::zero(); 3];
                let dv = &s.grads[q * k_len * dim..(q + 1) * k_len * dim];
                let eq = &e[q * k_len..(q + 1) * k_len];
                for k in 0..k_len {
                    for a in 0..dim {
                        gdp[a] += dv[k * dim + a] * eq[k];
                    }
                }
                let qq = p - p0;
                for a in 0..dim {
                    gd[qq * dim + a] = gdp[a];
                }
                let tq = &tm[q * cin..(q + 1) * cin];
                for c in 0..cin {
                    gf[j * cin + c] += tq[c];
                }
                if dims.anti {
                    for c in 0..cin {
                        gf[i * cin + c] += tq[c];
                    }
                }
            }
        }
    }
}
