//! Padding with one ghost layer, and its adjoint.
//!
//! Every stencil kernel first pads its input (`(ny + 2) x (nx + 2)`, interior at `1..=n`) with the
//! ghost rules of its boundary conditions, then runs branch-free. Rows are filled before columns,
//! so corners see the row ghosts; the adjoint undoes the passes in reverse order.

use crate::boundary::{Ghost, Ghosts};
use crate::scratch::zeros;
use pbdl_core::Real;
use rayon::prelude::*;

/// Whether a field of `cells` cells is processed row-parallel: the process's
/// [`pbdl_core::threads`] policy (by default from 192^2 cells on; a step runs ~50 short parallel
/// regions, each waiting for a worker to wake up, so smaller grids stay serial).
pub(crate) fn parallel_cells(cells: usize) -> bool {
    pbdl_core::threads::parallel(cells)
}

/// Runs `f(row_index, row)` over the rows of `out`, in parallel for large grids.
pub(crate) fn for_rows<T: Send, F>(out: &mut [T], row_len: usize, parallel: bool, f: F)
where
    F: Fn(usize, &mut [T]) + Sync + Send,
{
    if parallel {
        out.par_chunks_mut(row_len).with_min_len(8).enumerate().for_each(|(j, r)| f(j, r));
    } else {
        out.chunks_mut(row_len).enumerate().for_each(|(j, r)| f(j, r));
    }
}

/// Runs `f(row, acc)` for `rows` rows, each adding into an accumulator as long as `acc`, and
/// adds everything into `acc`. In parallel for large grids: the rows are split into one block
/// per thread, each block adds into a private zeroed buffer, and the buffers are summed in
/// block order (deterministic for a given thread count). For scatter-adds (the adjoints of
/// gathers), whose rows write to overlapping places.
pub(crate) fn accumulate_rows<T: Real, F>(acc: &mut [T], rows: usize, parallel: bool, f: F)
where
    F: Fn(usize, &mut [T]) + Sync + Send,
{
    let parts = if parallel { rayon::current_num_threads().min(rows) } else { 1 };
    if parts <= 1 {
        for j in 0..rows {
            f(j, acc);
        }
        return;
    }
    let chunk = rows.div_ceil(parts);
    let len = acc.len();
    let partial: Vec<_> = (0..parts)
        .into_par_iter()
        .map(|p| {
            let mut b = zeros::<T>(len);
            for j in p * chunk..((p + 1) * chunk).min(rows) {
                f(j, &mut b);
            }
            b
        })
        .collect();
    for b in &partial {
        for (a, x) in acc.iter_mut().zip(b.iter()) {
            *a += *x;
        }
    }
}

/// Writes `x` (`ny x nx`) into `out` (`(ny + 2) x (nx + 2)`) and fills the ghosts.
/// With `affine = false` the constants `c` are dropped (the linear part, for tangents).
pub(crate) fn pad<T: Real>(x: &[T], nx: usize, ny: usize, g: &Ghosts, affine: bool, out: &mut [T]) {
    let w = nx + 2;
    debug_assert_eq!(x.len(), nx * ny);
    debug_assert_eq!(out.len(), w * (ny + 2));
    for j in 0..ny {
        out[(j + 1) * w + 1..(j + 1) * w + 1 + nx].copy_from_slice(&x[j * nx..(j + 1) * nx]);
    }
    fill_row(out, w, nx, 0, g.y_lo, affine);
    fill_row(out, w, nx, ny + 1, g.y_hi, affine);
    let (slo, clo) = coef::<T>(g.x_lo, affine);
    let (shi, chi) = coef::<T>(g.x_hi, affine);
    for jj in 0..ny + 2 {
        let r = jj * w;
        out[r] = slo * out[r + g.x_lo.src] + clo;
        out[r + nx + 1] = shi * out[r + g.x_hi.src] + chi;
    }
}

fn coef<T: Real>(g: Ghost, affine: bool) -> (T, T) {
    (T::c(g.s), if affine { T::c(g.c) } else { T::zero() })
}

fn fill_row<T: Real>(out: &mut [T], w: usize, nx: usize, dst: usize, g: Ghost, affine: bool) {
    let (s, c) = coef::<T>(g, affine);
    let (d, sr) = if dst < g.src {
        let (a, b) = out.split_at_mut(g.src * w);
        (&mut a[dst * w..dst * w + w], &b[..w])
    } else {
        let (a, b) = out.split_at_mut(dst * w);
        (&mut b[..w], &a[g.src * w..g.src * w + w])
    };
    for i in 1..=nx {
        d[i] = s * sr[i] + c;
    }
}

/// Adjoint of [`pad`] (its linear part): accumulates the padded gradient `gp` (destroyed) into
/// `gx` (`ny x nx`, overwritten).
pub(crate) fn pad_adjoint<T: Real>(gp: &mut [T], nx: usize, ny: usize, g: &Ghosts, gx: &mut [T]) {
    let w = nx + 2;
    let (slo, shi) = (T::c(g.x_lo.s), T::c(g.x_hi.s));
    for jj in 0..ny + 2 {
        let r = jj * w;
        let (a, b) = (gp[r], gp[r + nx + 1]);
        gp[r] = T::zero();
        gp[r + nx + 1] = T::zero();
        gp[r + g.x_lo.src] += slo * a;
        gp[r + g.x_hi.src] += shi * b;
    }
    for (dst, gh) in [(0, g.y_lo), (ny + 1, g.y_hi)] {
        let s = T::c(gh.s);
        for i in 1..=nx {
            let a = gp[dst * w + i];
            gp[dst * w + i] = T::zero();
            gp[gh.src * w + i] += s * a;
        }
    }
    for j in 0..ny {
        gx[j * nx..(j + 1) * nx].copy_from_slice(&gp[(j + 1) * w + 1..(j + 1) * w + 1 + nx]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boundary::{Bc, Boundaries, ScalarBc, ScalarBoundaries};

    /// <pad(x), y> == <x, pad_adjoint(y)> for the linear part, on mixed boundaries.
    #[test]
    fn pad_adjoint_is_the_transpose() {
        let (nx, ny) = (5, 4);
        let b = Boundaries::new(Bc::NoSlip, Bc::Outflow, Bc::FreeSlip, Bc::MovingWall { velocity: 1.0 }).unwrap();
        let mg = b.mac_ghosts(nx, ny);
        let sb = ScalarBoundaries {
            x_lo: ScalarBc::Periodic,
            x_hi: ScalarBc::Periodic,
            y_lo: ScalarBc::Neumann,
            y_hi: ScalarBc::Dirichlet { value: 2.0 },
        };
        for g in [mg.u, mg.v, sb.ghosts(nx, ny), ScalarBoundaries::periodic().ghosts(nx, ny)] {
            let x: Vec<f64> = (0..nx * ny).map(|k| ((k * 7 % 11) as f64) - 3.3).collect();
            let y: Vec<f64> = (0..(nx + 2) * (ny + 2)).map(|k| ((k * 5 % 13) as f64) * 0.37 - 1.0).collect();
            let mut px = vec![0.0; y.len()];
            pad(&x, nx, ny, &g, false, &mut px);
            let lhs: f64 = px.iter().zip(&y).map(|(a, b)| a * b).sum();
            let mut gy = y.clone();
            let mut ax = vec![0.0; x.len()];
            pad_adjoint(&mut gy, nx, ny, &g, &mut ax);
            let rhs: f64 = ax.iter().zip(&x).map(|(a, b)| a * b).sum();
            assert!((lhs - rhs).abs() < 1e-12 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
        }
    }
}
