//! Published reference data to validate solvers against.
//!
//! * [`GhiaTable`]: the lid-driven cavity centreline velocities of Ghia, Ghia & Shin (1982),
//!   J. Comput. Phys. 48(3):387-411, Tables I and II (Re 100, 400, 1000; embedded, citation in
//!   `tests/data/ghia1982_*.csv`), and [`CavityCentrelines`] to compare a [`MacField`] with them.
//! * [`ARMALY_1983_X1_OVER_S`]: the measured primary reattachment length behind a
//!   backward-facing step of Armaly, Durst, Pereira & Schoenung (1983), digitised.
//!
//! ```
//! use pbdl_grid::validation::{cavity_centrelines, GhiaTable};
//! use pbdl_grid::{Boundaries, Grid, MacField};
//!
//! let table = GhiaTable::for_reynolds(100.0)?;
//! // A fluid at rest is far from the cavity's vortex: v misses Ghia's extreme v = -0.24533
//! // (at x = 0.8047) entirely, u at least its minimum -0.2109 (at y = 0.4531).
//! let u = MacField::zeros(Grid::square(16, 1.0)?, Boundaries::lid_driven_cavity(1.0), 1, candle_core::DType::F64)?;
//! let (err_u, err_v) = cavity_centrelines(&u)?.max_errors(&table);
//! assert!((err_v - 0.24533).abs() < 1e-12 && err_u >= 0.2109);
//! # Ok::<(), pbdl_grid::Error>(())
//! ```

use crate::{Error, MacField, Result};
use candle_core::DType;

/// Primary reattachment length `x1 / S` against `Re` measured by Armaly, Durst, Pereira &
/// Schoenung (1983), "Experimental and theoretical investigation of backward-facing step flow",
/// J. Fluid Mech. 127:473-496 (laser-Doppler, air; expansion ratio `H / h = 1.9423`, step
/// height `S = 0.9423 h`, `Re = U_mean 2 h / nu` with `U_mean` the mean inlet speed and `2 h`
/// the inlet hydraulic diameter), as `(Re, x1 / S)` pairs.
///
/// The paper gives these only as points in a figure; the values are a *digitisation* of that
/// figure, quoted from the benchmark data of the Lethe project
/// (`chaos-polymtl/lethe`, `examples/incompressible-flow/2d-backward-facing-step/benchmark-data.txt`,
/// section "ARMALY (1983)"), not read off the paper here. Only the points with `Re <= 400` are
/// kept: Armaly et al. and Biswas, Breuer & Durst (2004), J. Fluids Eng. 126:362, find the flow
/// two-dimensional there and three-dimensional above (where two-dimensional simulations
/// underpredict `x1`). Digitisation error is a few percent at best.
pub const ARMALY_1983_X1_OVER_S: [(f64, f64); 4] =
    [(100.3369, 3.0353), (151.5253, 4.0000), (300.6079, 6.6118), (389.6823, 8.6118)];

/// A polyline of `(coordinate, value)` points, ascending in the coordinate.
pub type Polyline = Vec<(f64, f64)>;

const GHIA_U: &str = include_str!("../tests/data/ghia1982_u_vertical_centerline.csv");
const GHIA_V: &str = include_str!("../tests/data/ghia1982_v_horizontal_centerline.csv");

/// Ghia et al.'s centreline velocities for one Reynolds number.
#[derive(Clone, Debug, PartialEq)]
pub struct GhiaTable {
    /// The Reynolds number (100, 400 or 1000).
    pub reynolds: f64,
    /// `u(0.5, y)`: `(y, u)` on the vertical centreline, ascending in `y`.
    pub u_vertical: Polyline,
    /// `v(x, 0.5)`: `(x, v)` on the horizontal centreline, ascending in `x`.
    pub v_horizontal: Polyline,
}

impl GhiaTable {
    /// The table for `reynolds` = 100, 400 or 1000; any other value is an error naming these.
    pub fn for_reynolds(reynolds: f64) -> Result<Self> {
        let column = if reynolds == 100.0 {
            1
        } else if reynolds == 400.0 {
            2
        } else if reynolds == 1000.0 {
            3
        } else {
            return Err(Error::Invalid {
                field: "reynolds",
                reason: format!("Ghia et al. (1982) tabulate Re = 100, 400 and 1000; got {reynolds}"),
            });
        };
        Ok(Self { reynolds, u_vertical: parse_column(GHIA_U, column), v_horizontal: parse_column(GHIA_V, column) })
    }
}

/// `(coordinate, column)` pairs of a table, sorted by the coordinate.
fn parse_column(text: &str, column: usize) -> Polyline {
    let mut v: Polyline = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with('x') && !l.starts_with('y') && !l.trim().is_empty())
        .filter_map(|l| {
            let f: Vec<f64> = l.split(',').filter_map(|s| s.trim().parse().ok()).collect();
            (f.len() > column).then(|| (f[0], f[column]))
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

/// Linear interpolation of an ascending polyline at `x` (extrapolating from the last segment
/// outside it). The polyline needs at least two points.
pub fn interpolate(line: &[(f64, f64)], x: f64) -> f64 {
    let k = line.windows(2).position(|w| x >= w[0].0 && x <= w[1].0).unwrap_or(line.len() - 2);
    let (a, b) = (line[k], line[k + 1]);
    a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)
}

/// A unit cavity's centrelines: `u(0.5, y)` and `v(x, 0.5)` at the cell centres, with the wall
/// values at the ends (lid speed 1 at the top).
#[derive(Clone, Debug, PartialEq)]
pub struct CavityCentrelines {
    /// `(y, u)` on the vertical centreline `x = 0.5`.
    pub u: Polyline,
    /// `(x, v)` on the horizontal centreline `y = 0.5`.
    pub v: Polyline,
}

impl CavityCentrelines {
    /// The largest deviations `(max |u - u_Ghia|, max |v - v_Ghia|)` over the table's points,
    /// the centrelines interpolated linearly.
    pub fn max_errors(&self, table: &GhiaTable) -> (f64, f64) {
        let err = |line: &[(f64, f64)], refs: &[(f64, f64)]| {
            refs.iter().map(|&(x, r)| (interpolate(line, x) - r).abs()).fold(0.0, f64::max)
        };
        (err(&self.u, &table.u_vertical), err(&self.v, &table.v_horizontal))
    }
}

/// The centrelines of the first batch entry of a cavity velocity on a square `n x n` grid of
/// the unit box (`n` even: the centrelines lie on faces).
pub fn cavity_centrelines(u: &MacField) -> Result<CavityCentrelines> {
    let g = u.grid();
    let n = g.nx;
    if g.ny != n || n % 2 != 0 {
        return Err(Error::Invalid {
            field: "grid",
            reason: format!("cavity centrelines need a square grid with an even cell count; got {}x{}", g.nx, g.ny),
        });
    }
    let vals = u.values().narrow(0, 0, 1)?.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let (nn, h) = (n * n, 1.0 / n as f64);
    // u on the face column x = 0.5 at the cell centres in y; v on the face row y = 0.5.
    let mut ul = vec![(0.0, 0.0)];
    ul.extend((0..n).map(|j| ((j as f64 + 0.5) * h, vals[j * n + n / 2 - 1])));
    ul.push((1.0, 1.0));
    let mut vl = vec![(0.0, 0.0)];
    vl.extend((0..n).map(|i| ((i as f64 + 0.5) * h, vals[nn + (n / 2 - 1) * n + i])));
    vl.push((1.0, 0.0));
    Ok(CavityCentrelines { u: ul, v: vl })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_hold_ghias_points_and_other_reynolds_numbers_are_errors() {
        let t = GhiaTable::for_reynolds(1000.0).unwrap();
        assert_eq!(t.u_vertical.len(), 17);
        assert_eq!(t.v_horizontal.len(), 17);
        assert!(t.u_vertical.windows(2).all(|w| w[0].0 < w[1].0));
        assert_eq!(t.u_vertical.last(), Some(&(1.0, 1.0)));
        assert!(t.u_vertical.contains(&(0.5, -0.0608)));
        let e = GhiaTable::for_reynolds(200.0).unwrap_err().to_string();
        assert!(e.contains("100, 400 and 1000"), "{e}");
        assert_eq!(interpolate(&[(0.0, 1.0), (2.0, 3.0)], 0.5), 1.5);
    }
}
