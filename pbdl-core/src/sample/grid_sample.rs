//! Bilinear (2D) and trilinear (3D) sampling of a field at arbitrary points, with backward for
//! the values and the coordinates.

use super::boundary::{locate, Boundaries, Boundary, Cell};
use crate::op::{apply2, apply_kernel2, apply_kernel3, grad_if_tracked, Kernel2, Kernel3, Op2};
use crate::{Error, Real, Result};
use candle_core::{Shape, Tensor, WithDType};
use rayon::prelude::*;
use std::ops::Range;

/// Points per parallel task: large enough to amortise rayon's overhead.
const CHUNK: usize = 2048;

/// Calls `$kernel::<T, D, K>(args)` for a field of `$dims` spatial dimensions: `D = 2` with its
/// `K = 4` corners, or `D = 3` with `K = 8`, the only instances the sampling kernels have.
macro_rules! per_dim {
    ($dims:expr, $kernel:ident::<$t:ty>($($arg:expr),* $(,)?)) => {
        match $dims {
            2 => $kernel::<$t, 2, 4>($($arg),*),
            _ => $kernel::<$t, 3, 8>($($arg),*),
        }
    };
}

/// Samples `field` at `points` by bilinear (2D) or trilinear (3D) interpolation.
///
/// * `field`: `[batch, channel, y, x]` (2D) or `[batch, channel, z, y, x]` (3D), x fastest.
/// * `points`: `[batch, ..., D]` with `D = 2` coordinates `(x, y)` or `D = 3` coordinates
///   `(x, y, z)` (x first, the reverse of the axis order of `field`). The middle axes `...`
///   can be any shape, including none.
/// * Returns `[batch, channel, ...]`: every channel of batch item `b` sampled at the points of
///   batch item `b`.
///
/// Coordinates are in **index space**: coordinate `i` is the sample at index `i` (the cell centre
/// of a cell-centred grid), `i + 0.5` lies halfway between samples `i` and `i + 1`. This differs
/// from PyTorch's `grid_sample`, whose coordinates are normalised to `[-1, 1]`. Outside
/// `[0, n-1]` the `boundary` decides (see [`Boundary`]); give one boundary for all axes or one per
/// axis, x first (`[Boundary::Periodic, Boundary::Clamp]`).
///
/// Differentiable with respect to both inputs: the gradient for `field` scatters the output
/// gradient back with the interpolation weights (the transpose of the interpolation), the
/// gradient for `points` is that of the interpolant, which is continuous inside a cell and jumps
/// where a coordinate crosses an integer (the interpolant has a kink there); with
/// [`Boundary::Clamp`] it is 0 for a coordinate outside `[0, n-1]`. Only inputs that track a
/// gradient (variables, or results of ops on them) get one computed; the other input's gradient
/// is returned as zeros, so a constant field or constant points cost no backward work. The
/// backward kernels are not differentiable themselves (a second derivative is an error, not a
/// silent zero).
///
/// Both inputs must have the same dtype (`f32` or `f64`); on other input a typed [`Error`].
pub fn grid_sample(field: &Tensor, points: &Tensor, boundary: impl Into<Boundaries>) -> Result<Tensor> {
    sample_op(Kind::Points, field, points, boundary.into())
}

/// How the second input of a sampling op gives the points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    /// `[batch, ..., D]` coordinates, x first ([`grid_sample`]).
    Points,
    /// `[batch, D, spatial...]` displacements from the field's own grid points ([`warp`](super::warp)).
    Displacement,
}

impl Kind {
    fn op(self) -> &'static str {
        match self {
            Kind::Points => "grid_sample",
            Kind::Displacement => "warp",
        }
    }

    fn arg(self) -> &'static str {
        match self {
            Kind::Points => "points",
            Kind::Displacement => "displacement",
        }
    }
}

/// Checks the inputs of [`grid_sample`] or [`warp`](super::warp) and applies the op.
pub(super) fn sample_op(kind: Kind, field: &Tensor, second: &Tensor, boundary: Boundaries) -> Result<Tensor> {
    let op = kind.op();
    crate::error::check_float(op, "field", field)?;
    crate::error::check_float(op, kind.arg(), second)?;
    if field.dtype() != second.dtype() {
        return Err(Error::DType {
            op,
            arg: kind.arg(),
            expected: "the dtype of `field` (convert one of them)",
            got: second.dtype(),
        });
    }
    let g = Geom::new(kind, field.dims(), second.dims())?;
    let bc = boundary.per_axis(op, g.dims)?;
    Ok(apply2(field, second, SampleOp { bc, kind })?)
}

/// Sizes of one sampling call, shared by the forward and both backward kernels.
#[derive(Clone, Copy, Debug)]
struct Geom {
    kind: Kind,
    /// Number of spatial axes, 2 or 3.
    dims: usize,
    batch: usize,
    channels: usize,
    /// Spatial sizes, x first; 1 past `dims`.
    size: [usize; 3],
    /// Points per batch item.
    points: usize,
}

impl Geom {
    fn new(kind: Kind, field: &[usize], second: &[usize]) -> Result<Self> {
        let op = kind.op();
        let dims = match field.len() {
            4 => 2,
            5 => 3,
            _ => {
                return Err(Error::Shape {
                    op,
                    arg: "field",
                    expected: "rank 4 [batch, channel, y, x] or rank 5 [batch, channel, z, y, x]".into(),
                    got: field.to_vec(),
                })
            }
        };
        if field[2..].contains(&0) {
            return Err(Error::Shape {
                op,
                arg: "field",
                expected: "at least one sample along every spatial axis".into(),
                got: field.to_vec(),
            });
        }
        let mut size = [1; 3];
        for d in 0..dims {
            size[d] = field[field.len() - 1 - d];
        }
        let coords = if dims == 2 { "(x, y)" } else { "(x, y, z)" };
        let points = match kind {
            Kind::Points => {
                if second.len() < 2 || second[second.len() - 1] != dims || second[0] != field[0] {
                    return Err(Error::Shape {
                        op,
                        arg: "points",
                        expected: format!(
                            "[{}, ..., {dims}]: batch as in `field`, last axis the {coords} coordinates",
                            field[0]
                        ),
                        got: second.to_vec(),
                    });
                }
                second[1..second.len() - 1].iter().product()
            }
            Kind::Displacement => {
                let mut expected = vec![field[0], dims];
                expected.extend_from_slice(&field[2..]);
                if second != expected {
                    return Err(Error::Shape {
                        op,
                        arg: "displacement",
                        expected: format!("{expected:?}: [batch, {dims} components {coords}, spatial axes of `field`]"),
                        got: second.to_vec(),
                    });
                }
                size.iter().product()
            }
        };
        Ok(Geom { kind, dims, batch: field[0], channels: field[1], size, points })
    }

    fn volume(&self) -> usize {
        self.size.iter().product()
    }

    /// Output shape: `[batch, channel, ...points' middle axes]`, or the field's for a warp.
    fn output_shape(&self, field: &[usize], second: &[usize]) -> Shape {
        match self.kind {
            Kind::Points => {
                let mut s = vec![self.batch, self.channels];
                s.extend_from_slice(&second[1..second.len() - 1]);
                Shape::from(s)
            }
            Kind::Displacement => Shape::from(field),
        }
    }
}

/// Reads the coordinates of point `p` of batch item `b` from the second input of an op.
#[derive(Clone, Copy)]
struct Coords<'a, T> {
    data: &'a [T],
    g: &'a Geom,
}

impl<T: Real> Coords<'_, T> {
    #[inline(always)]
    fn at<const D: usize>(&self, b: usize, p: usize) -> [f64; D] {
        let np = self.g.points;
        let mut q = [0.0; D];
        match self.g.kind {
            Kind::Points => {
                let s = &self.data[(b * np + p) * D..][..D];
                for d in 0..D {
                    q[d] = <T as WithDType>::to_f64(s[d]);
                }
            }
            Kind::Displacement => {
                // Point p is grid point p (x fastest) plus its displacement.
                let mut rest = p;
                for d in 0..D {
                    let n = self.g.size[d];
                    q[d] = (rest % n) as f64 + <T as WithDType>::to_f64(self.data[(b * D + d) * np + p]);
                    rest /= n;
                }
            }
        }
        q
    }
}

/// The `K = 2^D` corners around a point: flat offsets into one channel and weights, plus the
/// per-axis cells (for the coordinate derivative).
struct Corners<const D: usize, const K: usize> {
    off: [usize; K],
    w: [f64; K],
    cells: [Cell; D],
}

#[inline(always)]
fn corners<const D: usize, const K: usize>(q: [f64; D], g: &Geom, bc: &[Boundary; 3]) -> Corners<D, K> {
    let mut cells = [Cell { i0: 0, i1: 0, t: 0.0, slope: 0.0 }; D];
    for d in 0..D {
        cells[d] = locate(q[d], g.size[d], bc[d]);
    }
    let stride = [1, g.size[0], g.size[0] * g.size[1]];
    let mut off = [0; K];
    let mut w = [1.0; K];
    for k in 0..K {
        for d in 0..D {
            let c = &cells[d];
            if (k >> d) & 1 == 1 {
                off[k] += c.i1 * stride[d];
                w[k] *= c.t;
            } else {
                off[k] += c.i0 * stride[d];
                w[k] *= 1.0 - c.t;
            }
        }
    }
    Corners { off, w, cells }
}

impl<const D: usize, const K: usize> Corners<D, K> {
    /// Weights of the derivative of the interpolant with respect to coordinate `d`.
    #[inline(always)]
    fn dweights(&self, d: usize) -> [f64; K] {
        let mut dw = [self.cells[d].slope; K];
        for k in 0..K {
            for e in 0..D {
                let c = &self.cells[e];
                let hi = (k >> e) & 1 == 1;
                dw[k] *= match (e == d, hi) {
                    (true, true) => 1.0,
                    (true, false) => -1.0,
                    (false, true) => c.t,
                    (false, false) => 1.0 - c.t,
                };
            }
        }
        dw
    }

    /// The interpolated value in one channel.
    #[inline(always)]
    fn interpolate<T: Real>(&self, f: &[T]) -> f64 {
        let mut acc = 0.0;
        for k in 0..K {
            acc += self.w[k] * <T as WithDType>::to_f64(f[self.off[k]]);
        }
        acc
    }
}

/// Splits `out`, laid out `[groups, rows, len]`, into parallel tasks: for every group and every
/// chunk of `chunk` elements along `len`, the `rows` pieces of that chunk (disjoint slices), with
/// the group index and the offset of the chunk in `len`. Lets one task compute the weights of a
/// point once and write all channels (or coordinate components) of it.
#[allow(clippy::type_complexity)]
fn tasks<T>(out: &mut [T], rows: usize, len: usize, chunk: usize) -> Vec<(usize, usize, Vec<&mut [T]>)> {
    let mut tasks = Vec::new();
    if rows == 0 || len == 0 {
        return tasks;
    }
    let per_group = len.div_ceil(chunk);
    for (group, block) in out.chunks_mut(rows * len).enumerate() {
        let first = tasks.len();
        tasks.extend((0..per_group).map(|k| (group, k * chunk, Vec::with_capacity(rows))));
        for row in block.chunks_mut(len) {
            for (k, piece) in row.chunks_mut(chunk).enumerate() {
                tasks[first + k].2.push(piece);
            }
        }
    }
    tasks
}

/// The differentiable sampling op: `(field, points or displacement) -> values`.
struct SampleOp {
    bc: [Boundary; 3],
    kind: Kind,
}

impl Kernel2 for SampleOp {
    fn name(&self) -> &'static str {
        self.kind.op()
    }

    fn output_shape(&self, field: &Shape, second: &Shape) -> candle_core::Result<Shape> {
        Ok(Geom::new(self.kind, field.dims(), second.dims())?.output_shape(field.dims(), second.dims()))
    }

    fn forward<T: Real>(
        &self,
        field: &[T],
        fs: &Shape,
        second: &[T],
        ss: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let g = Geom::new(self.kind, fs.dims(), ss.dims())?;
        let coords = Coords { data: second, g: &g };
        per_dim!(g.dims, sample_forward::<T>(field, coords, &self.bc, out));
        Ok(())
    }
}

impl Op2 for SampleOp {
    fn backward(
        &self,
        field: &Tensor,
        second: &Tensor,
        _y: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        // An input that tracks no gradient (a constant field or constant points) gets zeros
        // instead of a kernel run: nothing downstream can read its gradient.
        let gf = grad_if_tracked(field, || {
            apply_kernel2(second, grad, FieldGrad { bc: self.bc, kind: self.kind, field_shape: field.shape().clone() })
        })?;
        let gp = grad_if_tracked(second, || {
            apply_kernel3(field, second, grad, PointsGrad { bc: self.bc, kind: self.kind })
        })?;
        Ok((gf, gp))
    }
}

fn sample_forward<T: Real, const D: usize, const K: usize>(
    field: &[T],
    coords: Coords<T>,
    bc: &[Boundary; 3],
    out: &mut [T],
) {
    let g = coords.g;
    let (vol, nc) = (g.volume(), g.channels);
    // out is [batch, channel, points]: each task takes a chunk of points in all channels.
    tasks(out, nc, g.points, CHUNK).into_par_iter().for_each(|(b, first, mut outs)| {
        for j in 0..outs[0].len() {
            let c = corners::<D, K>(coords.at::<D>(b, first + j), g, bc);
            for (ch, o) in outs.iter_mut().enumerate() {
                o[j] = T::c(c.interpolate(&field[(b * nc + ch) * vol..][..vol]));
            }
        }
    });
}

/// Gradient with respect to the field: `(points or displacement, grad_out) -> grad_field`, the
/// scatter-add transpose of the interpolation. Forward-only.
struct FieldGrad {
    bc: [Boundary; 3],
    kind: Kind,
    field_shape: Shape,
}

impl Kernel2 for FieldGrad {
    fn name(&self) -> &'static str {
        match self.kind {
            Kind::Points => "grid_sample_field_grad",
            Kind::Displacement => "warp_field_grad",
        }
    }

    fn output_shape(&self, second: &Shape, _grad: &Shape) -> candle_core::Result<Shape> {
        Geom::new(self.kind, self.field_shape.dims(), second.dims())?;
        Ok(self.field_shape.clone())
    }

    fn forward<T: Real>(
        &self,
        second: &[T],
        ss: &Shape,
        grad: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let g = Geom::new(self.kind, self.field_shape.dims(), ss.dims())?;
        let coords = Coords { data: second, g: &g };
        per_dim!(g.dims, field_grad::<T>(coords, grad, &self.bc, out));
        Ok(())
    }
}

fn field_grad<T: Real, const D: usize, const K: usize>(
    coords: Coords<T>,
    grad: &[T],
    bc: &[Boundary; 3],
    out: &mut [T],
) {
    let g = coords.g;
    let np = g.points;
    scatter_rows(out, g.volume(), np, |row, range, acc| {
        let b = row / g.channels;
        let gy = &grad[row * np..(row + 1) * np];
        for p in range {
            let c = corners::<D, K>(coords.at::<D>(b, p), g, bc);
            let gp = <T as WithDType>::to_f64(gy[p]);
            for k in 0..K {
                acc[c.off[k]] += T::c(c.w[k] * gp);
            }
        }
    });
}

/// Runs `body(row, points, acc)` for every row of `out` (rows of length `vol`, one per batch and
/// channel), adding the contributions of points `points` of that row into `acc`. Rows go in
/// parallel; when there are fewer rows than threads, the points of a row are split instead, each
/// part into its own buffer, and the buffers are summed (a fixed order: deterministic).
fn scatter_rows<T: Real, F>(out: &mut [T], vol: usize, np: usize, body: F)
where
    F: Fn(usize, Range<usize>, &mut [T]) + Sync,
{
    let rows = out.len() / vol.max(1);
    let threads = rayon::current_num_threads();
    let parts = threads.min(np / CHUNK);
    if rows >= threads || parts < 2 {
        out.par_chunks_mut(vol).enumerate().for_each(|(row, acc)| body(row, 0..np, acc));
        return;
    }
    for (row, acc) in out.chunks_mut(vol).enumerate() {
        let part = |k: usize| k * np / parts..(k + 1) * np / parts;
        let ((), bufs) = rayon::join(
            || body(row, part(0), acc),
            || {
                (1..parts)
                    .into_par_iter()
                    .map(|k| {
                        let mut buf = vec![T::zero(); vol];
                        body(row, part(k), &mut buf);
                        buf
                    })
                    .collect::<Vec<_>>()
            },
        );
        for buf in bufs {
            for (a, b) in acc.iter_mut().zip(&buf) {
                *a += *b;
            }
        }
    }
}

/// Gradient with respect to the points (or displacements):
/// `(field, points or displacement, grad_out) -> grad` of the second input's shape. Forward-only.
struct PointsGrad {
    bc: [Boundary; 3],
    kind: Kind,
}

impl Kernel3 for PointsGrad {
    fn name(&self) -> &'static str {
        match self.kind {
            Kind::Points => "grid_sample_points_grad",
            Kind::Displacement => "warp_displacement_grad",
        }
    }

    fn output_shape(&self, field: &Shape, second: &Shape, _grad: &Shape) -> candle_core::Result<Shape> {
        Geom::new(self.kind, field.dims(), second.dims())?;
        Ok(second.clone())
    }

    fn forward<T: Real>(
        &self,
        field: &[T],
        fs: &Shape,
        second: &[T],
        ss: &Shape,
        grad: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let g = Geom::new(self.kind, fs.dims(), ss.dims())?;
        let coords = Coords { data: second, g: &g };
        per_dim!(g.dims, points_grad::<T>(field, coords, grad, &self.bc, out));
        Ok(())
    }
}

fn points_grad<T: Real, const D: usize, const K: usize>(
    field: &[T],
    coords: Coords<T>,
    grad: &[T],
    bc: &[Boundary; 3],
    out: &mut [T],
) {
    let g = coords.g;
    let (vol, np, nc) = (g.volume(), g.points, g.channels);
    // d(sum_c grad_c * value_c) / d(coordinate d) at point p of batch item b.
    let grad_at = |b: usize, p: usize| -> [f64; D] {
        let c = corners::<D, K>(coords.at::<D>(b, p), g, bc);
        let mut dw = [[0.0; K]; D];
        for d in 0..D {
            dw[d] = c.dweights(d);
        }
        let mut acc = [0.0; D];
        for ch in 0..nc {
            let row = b * nc + ch;
            let gy = <T as WithDType>::to_f64(grad[row * np + p]);
            if gy == 0.0 {
                continue;
            }
            let f = &field[row * vol..(row + 1) * vol];
            let mut v = [0.0; K];
            for k in 0..K {
                v[k] = <T as WithDType>::to_f64(f[c.off[k]]);
            }
            for d in 0..D {
                let mut s = 0.0;
                for k in 0..K {
                    s += dw[d][k] * v[k];
                }
                acc[d] += gy * s;
            }
        }
        acc
    };
    match g.kind {
        // out is [batch, points, D]: a task is a run of whole points.
        Kind::Points => tasks(out, 1, np * D, CHUNK * D).into_par_iter().for_each(|(b, first, mut outs)| {
            for (j, o) in outs[0].chunks_mut(D).enumerate() {
                let acc = grad_at(b, first / D + j);
                for d in 0..D {
                    o[d] = T::c(acc[d]);
                }
            }
        }),
        // out is [batch, D, points]: a task writes a chunk of points in every component.
        Kind::Displacement => tasks(out, D, np, CHUNK).into_par_iter().for_each(|(b, first, mut outs)| {
            for j in 0..outs[0].len() {
                let acc = grad_at(b, first + j);
                for d in 0..D {
                    outs[d][j] = T::c(acc[d]);
                }
            }
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    #[test]
    fn corner_weights_sum_to_one_and_derivative_weights_to_zero() {
        let g = Geom::new(Kind::Points, &[1, 1, 4, 5, 6], &[1, 3]).unwrap();
        let c = corners::<3, 8>([1.3, 2.6, 0.2], &g, &[Boundary::Clamp; 3]);
        assert!((c.w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        for d in 0..3 {
            assert!(c.dweights(d).iter().sum::<f64>().abs() < 1e-15);
        }
        // Corner 0 is (x=1, y=2, z=0): offset 0*30 + 2*6 + 1.
        assert_eq!(c.off[0], 13);
        assert!((c.w[0] - 0.7 * 0.4 * 0.8).abs() < 1e-15);
    }

    #[test]
    fn displacement_coordinates_add_the_grid_point() {
        // 2D field [1, 1, 2, 3]: point 4 is (x=1, y=1); the displacement is [1, 2, 2, 3].
        let g = Geom::new(Kind::Displacement, &[1, 1, 2, 3], &[1, 2, 2, 3]).unwrap();
        let disp: Vec<f64> = (0..12).map(|i| i as f64 * 0.1).collect();
        let q = Coords { data: &disp, g: &g }.at::<2>(0, 4);
        assert!((q[0] - 1.4).abs() < 1e-12 && (q[1] - 2.0).abs() < 1e-12, "{q:?}");
    }

    #[test]
    fn tasks_cover_every_element_once() {
        let mut out = vec![0u32; 2 * 3 * 10];
        for (group, first, pieces) in tasks(&mut out, 3, 10, 4) {
            assert_eq!(pieces.len(), 3);
            for (row, piece) in pieces.into_iter().enumerate() {
                for (j, v) in piece.iter_mut().enumerate() {
                    *v += (100 * group + 10 * row + first + j) as u32 + 1;
                }
            }
        }
        let expect: Vec<u32> = (0..60).map(|i| (100 * (i / 30) + 10 * (i / 10 % 3) + i % 10) as u32 + 1).collect();
        assert_eq!(out, expect);
    }

    #[test]
    fn split_scatter_equals_row_scatter() {
        // Enough points that scatter_rows splits one row into parts on a multi-core machine.
        let n = 4 * CHUNK * rayon::current_num_threads().max(2);
        let pts: Vec<f64> = (0..n * 2).map(|i| ((i * 7919) % 1000) as f64 * 0.01 - 1.0).collect();
        let gy: Vec<f64> = (0..n).map(|i| ((i * 31) % 17) as f64 - 8.0).collect();
        let g = Geom::new(Kind::Points, &[1, 1, 6, 7], &[1, n, 2]).unwrap();
        let coords = Coords { data: &pts, g: &g };
        let mut split = vec![0.0; 42];
        field_grad::<f64, 2, 4>(coords, &gy, &[Boundary::Periodic; 3], &mut split);
        let mut serial = vec![0.0; 42];
        for p in 0..n {
            let c = corners::<2, 4>(coords.at::<2>(0, p), &g, &[Boundary::Periodic; 3]);
            for k in 0..4 {
                serial[c.off[k]] += c.w[k] * gy[p];
            }
        }
        for (a, b) in split.iter().zip(&serial) {
            assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}");
        }
    }

    #[test]
    fn empty_point_set_gives_empty_output() {
        let field = Tensor::ones((2, 3, 4, 5), DType::F32, &Device::Cpu).unwrap();
        let points = Tensor::zeros((2, 0, 2), DType::F32, &Device::Cpu).unwrap();
        let y = grid_sample(&field, &points, Boundary::Clamp).unwrap();
        assert_eq!(y.dims(), &[2, 3, 0]);
    }
}
