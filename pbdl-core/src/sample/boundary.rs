//! Boundary handling of the sampling ops: where a coordinate lands along one axis.

use crate::{Error, Result};

/// How [`grid_sample`](super::grid_sample) and [`warp`](super::warp) treat a coordinate outside
/// the samples `0..n` of an axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Boundary {
    /// Border replicate: the coordinate is clamped to `[0, n-1]` first, so a point outside takes
    /// the value at the nearest border point. The derivative with respect to such a clamped
    /// coordinate is 0 (it is the derivative inside on the border itself, like PyTorch's
    /// `padding_mode="border"`).
    #[default]
    Clamp,
    /// Periodic with period `n`: coordinate `x` and `x + n` are the same point, and between
    /// `n-1` and `n` the interpolation blends the last and the first sample.
    Periodic,
}

/// A [`Boundary`] for every axis: one for all axes, or one per axis in coordinate order
/// (x first). Built implicitly from a `Boundary`, a `[Boundary; 2]` (x, y) or a
/// `[Boundary; 3]` (x, y, z), e.g. `[Boundary::Periodic, Boundary::Clamp]` for a channel that is
/// periodic in x and walled in y.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Boundaries {
    /// The same boundary on every axis.
    All(Boundary),
    /// Per axis of a 2D field, `[x, y]`.
    Xy([Boundary; 2]),
    /// Per axis of a 3D field, `[x, y, z]`.
    Xyz([Boundary; 3]),
}

impl From<Boundary> for Boundaries {
    fn from(b: Boundary) -> Self {
        Boundaries::All(b)
    }
}

impl From<[Boundary; 2]> for Boundaries {
    fn from(b: [Boundary; 2]) -> Self {
        Boundaries::Xy(b)
    }
}

impl From<[Boundary; 3]> for Boundaries {
    fn from(b: [Boundary; 3]) -> Self {
        Boundaries::Xyz(b)
    }
}

impl Boundaries {
    /// The boundary of each axis (x first) for a field with `dims` spatial axes; entries past
    /// `dims` are unused. A per-axis list of the wrong length is an [`Error::InvalidArgument`].
    pub(crate) fn per_axis(self, op: &'static str, dims: usize) -> Result<[Boundary; 3]> {
        match (self, dims) {
            (Boundaries::All(b), _) => Ok([b; 3]),
            (Boundaries::Xy([x, y]), 2) => Ok([x, y, Boundary::Clamp]),
            (Boundaries::Xyz(b), 3) => Ok(b),
            (other, _) => Err(Error::invalid(
                op,
                "boundary",
                format!("{other:?} does not fit a {dims}D field: give one Boundary, or one per axis [x, y] (2D) / [x, y, z] (3D)"),
            )),
        }
    }
}

/// Where a coordinate lands along one axis: the two neighbouring samples `i0`, `i1`, the weight
/// `t` of `i1` (`1 - t` is that of `i0`) and `slope`, the derivative of the effective
/// coordinate with respect to the given one (0 where [`Boundary::Clamp`] flattens it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Cell {
    pub i0: usize,
    pub i1: usize,
    pub t: f64,
    pub slope: f64,
}

/// Locates coordinate `x` on an axis of `n >= 1` samples.
///
/// Never panics and never indexes out of range: a NaN coordinate gives `t = NaN` (so the sample
/// is NaN, which the caller's finiteness checks catch) with in-range indices.
#[inline(always)]
pub(crate) fn locate(x: f64, n: usize, boundary: Boundary) -> Cell {
    debug_assert!(n >= 1);
    match boundary {
        Boundary::Clamp => {
            if n == 1 {
                return Cell { i0: 0, i1: 0, t: 0.0, slope: 0.0 };
            }
            let last = (n - 1) as f64;
            let slope = if (0.0..=last).contains(&x) { 1.0 } else { 0.0 };
            let xc = x.clamp(0.0, last);
            // `as usize` truncates (= floor for xc >= 0) and maps NaN to 0; the last sample
            // belongs to the last cell with t = 1 so that i1 stays in range.
            let i0 = (xc as usize).min(n - 2);
            Cell { i0, i1: i0 + 1, t: xc - i0 as f64, slope }
        }
        Boundary::Periodic => {
            let nf = n as f64;
            let xw = x - nf * (x / nf).floor();
            let mut i0 = xw as usize;
            let mut t = xw - i0 as f64;
            // Rounding can give xw == n for tiny negative x: that is sample 0.
            if i0 >= n {
                i0 = 0;
                t = 0.0;
            }
            let i1 = if i0 + 1 == n { 0 } else { i0 + 1 };
            Cell { i0, i1, t, slope: 1.0 }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamp_locates_inside_on_the_border_and_outside() {
        assert_eq!(locate(1.25, 4, Boundary::Clamp), Cell { i0: 1, i1: 2, t: 0.25, slope: 1.0 });
        assert_eq!(locate(3.0, 4, Boundary::Clamp), Cell { i0: 2, i1: 3, t: 1.0, slope: 1.0 });
        assert_eq!(locate(0.0, 4, Boundary::Clamp), Cell { i0: 0, i1: 1, t: 0.0, slope: 1.0 });
        assert_eq!(locate(-0.5, 4, Boundary::Clamp), Cell { i0: 0, i1: 1, t: 0.0, slope: 0.0 });
        assert_eq!(locate(7.5, 4, Boundary::Clamp), Cell { i0: 2, i1: 3, t: 1.0, slope: 0.0 });
        assert_eq!(locate(0.7, 1, Boundary::Clamp), Cell { i0: 0, i1: 0, t: 0.0, slope: 0.0 });
    }

    #[test]
    fn periodic_wraps_in_both_directions() {
        assert_eq!(locate(3.5, 4, Boundary::Periodic), Cell { i0: 3, i1: 0, t: 0.5, slope: 1.0 });
        assert_eq!(locate(-0.25, 4, Boundary::Periodic), Cell { i0: 3, i1: 0, t: 0.75, slope: 1.0 });
        assert_eq!(locate(9.5, 4, Boundary::Periodic), Cell { i0: 1, i1: 2, t: 0.5, slope: 1.0 });
        assert_eq!(locate(-4.0, 4, Boundary::Periodic), Cell { i0: 0, i1: 1, t: 0.0, slope: 1.0 });
        assert_eq!(locate(0.5, 1, Boundary::Periodic), Cell { i0: 0, i1: 0, t: 0.5, slope: 1.0 });
        // x / n rounds to -0.0 here, but x + n rounds to n: must land on sample 0, not n.
        let c = locate(-1e-17, 4, Boundary::Periodic);
        assert!(c.i0 < 4 && c.i1 < 4, "{c:?}");
    }

    #[test]
    fn nan_and_infinite_coordinates_stay_in_range() {
        for b in [Boundary::Clamp, Boundary::Periodic] {
            for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300] {
                let c = locate(x, 5, b);
                assert!(c.i0 < 5 && c.i1 < 5, "{b:?} {x}: {c:?}");
            }
        }
    }

    #[test]
    fn per_axis_list_must_match_the_dimension() {
        let b = Boundaries::from([Boundary::Periodic, Boundary::Clamp]);
        assert_eq!(b.per_axis("t", 2).unwrap()[..2], [Boundary::Periodic, Boundary::Clamp]);
        assert!(matches!(b.per_axis("t", 3), Err(Error::InvalidArgument { .. })));
        assert_eq!(Boundaries::from(Boundary::Periodic).per_axis("t", 3).unwrap(), [Boundary::Periodic; 3]);
    }
}
