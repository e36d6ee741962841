//! Velocity output and input shared by the velocity kinds: centred velocity and vorticity from
//! MAC faces, and face values from an init file.

use super::{c, FieldInput};
use crate::scene::SceneResult;
use crate::{Bc, Boundaries, CenteredField, MacField};
use candle_core::{DType, Device, Tensor};

/// The output fields of a velocity (and density) state: `density` (when given), `velocity`,
/// `velocity_mac`, `vorticity`.
pub(crate) fn velocity_fields(u: &MacField, density: Option<&CenteredField>) -> SceneResult<Vec<(String, Tensor)>> {
    let (centred, vort) = centre_velocity(u)?;
    let mut out = Vec::new();
    if let Some(rho) = density {
        out.push(("density".into(), c(rho.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?));
    }
    out.extend([
        ("velocity".into(), centred),
        ("velocity_mac".into(), c(u.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?),
        ("vorticity".into(), vort),
    ]);
    Ok(out)
}

/// The velocity of an init file on the grid and boundaries of `like` (not projected), and the
/// name of the array used: `velocity_mac` when its shape matches the grid (last frame of a
/// trajectory), otherwise the centred `velocity` resampled and averaged to the faces. `also`
/// lists other accepted arrays in the error.
pub(crate) fn read_velocity(
    input: &FieldInput<'_>,
    like: &MacField,
    also: &str,
) -> SceneResult<(MacField, &'static str)> {
    let (grid, bc) = (*like.grid(), *like.bc());
    let (ny, nx) = input.shape;
    let mac = input.find("velocity_mac").and_then(|t| {
        let t = t.to_dtype(DType::F64).ok()?;
        let t = if t.rank() == 3 { t.unsqueeze(0).ok()? } else { t };
        let t = t.narrow(0, t.dims().first().copied()?.checked_sub(1)?, 1).ok()?;
        (t.dims() == [1, 2, ny, nx]).then_some(t)
    });
    let (mac, name) = if let Some(t) = mac {
        (t, "velocity_mac")
    } else if let Some(t) = input.find("velocity") {
        (faces_from_centres(&input.to4("velocity", &t, 2)?, &bc)?, "velocity")
    } else {
        return Err(input.invalid(
            "velocity",
            format!("the file has no array `velocity` or `velocity_mac`{also}; it has {:?}", input.names()),
        ));
    };
    Ok((MacField::new(c(mac.to_dtype(input.dtype))?, grid, bc)?, name))
}

/// The normal face value at a lower face that is not stored (wall 0, inflow given).
fn lower_normal(b: Bc, comp: usize) -> f64 {
    match b {
        Bc::Inflow { velocity } => velocity[comp],
        _ => 0.0,
    }
}

/// Cell-centred velocity `[2, ny, nx]` and corner vorticity `[1, ny, nx]` of a MAC field
/// (batch 0).
fn centre_velocity(u: &MacField) -> SceneResult<(Tensor, Tensor)> {
    let g = *u.grid();
    let bc = *u.bc();
    let (nx, ny, n) = (g.nx, g.ny, g.cells());
    let vals = c(u
        .values()
        .narrow(0, 0, 1)
        .and_then(|t| t.to_dtype(DType::F64))
        .and_then(|t| t.flatten_all())
        .and_then(|t| t.to_vec1::<f64>()))?;
    let (uu, vv) = vals.split_at(n);
    let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
    let mut out = vec![0.0; 2 * n];
    let mut w = vec![0.0; n];
    for j in 0..ny {
        for i in 0..nx {
            let left = if i > 0 {
                uu[j * nx + i - 1]
            } else if px {
                uu[j * nx + nx - 1]
            } else {
                lower_normal(bc.x_lo, 0)
            };
            let below = if j > 0 {
                vv[(j - 1) * nx + i]
            } else if py {
                vv[(ny - 1) * nx + i]
            } else {
                lower_normal(bc.y_lo, 1)
            };
            out[j * nx + i] = 0.5 * (left + uu[j * nx + i]);
            out[n + j * nx + i] = 0.5 * (below + vv[j * nx + i]);
            // Corner ((i+1) dx, (j+1) dy); one-sided (clamped) at non-periodic upper faces.
            let ir = next_index(i, nx, px);
            let ju = next_index(j, ny, py);
            w[j * nx + i] = (vv[j * nx + ir] - vv[j * nx + i]) / g.dx() - (uu[ju * nx + i] - uu[j * nx + i]) / g.dy();
        }
    }
    let dtype = u.values().dtype();
    let v = c(Tensor::from_vec(out, (2, ny, nx), &Device::Cpu).and_then(|t| t.to_dtype(dtype)))?;
    let w = c(Tensor::from_vec(w, (1, ny, nx), &Device::Cpu).and_then(|t| t.to_dtype(dtype)))?;
    Ok((v, w))
}

/// Face values of a cell-centred velocity `[1, 2, ny, nx]` (f64): the mean of the two cells
/// beside each face; stored boundary faces fixed by a condition get its value.
fn faces_from_centres(t: &Tensor, bc: &Boundaries) -> SceneResult<Tensor> {
    let (_, _, ny, nx) = c(t.dims4())?;
    let n = nx * ny;
    let vals = c(t.flatten_all().and_then(|t| t.to_vec1::<f64>()))?;
    let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
    let mut out = vec![0.0; 2 * n];
    let fixed = |b: Bc, comp: usize| match b {
        Bc::Inflow { velocity } => Some(velocity[comp]),
        Bc::NoSlip | Bc::FreeSlip | Bc::MovingWall { .. } => Some(0.0),
        _ => None,
    };
    for j in 0..ny {
        for i in 0..nx {
            let ir = next_index(i, nx, px);
            let ju = next_index(j, ny, py);
            out[j * nx + i] = 0.5 * (vals[j * nx + i] + vals[j * nx + ir]);
            out[n + j * nx + i] = 0.5 * (vals[n + j * nx + i] + vals[n + ju * nx + i]);
            if i + 1 == nx {
                if let Some(v) = fixed(bc.x_hi, 0) {
                    out[j * nx + i] = v;
                }
            }
            if j + 1 == ny {
                if let Some(v) = fixed(bc.y_hi, 1) {
                    out[n + j * nx + i] = v;
                }
            }
        }
    }
    c(Tensor::from_vec(out, (1, 2, ny, nx), &Device::Cpu))
}

/// Typed error when a velocity is not finite.
pub(crate) fn check_finite_velocity(u: &MacField) -> SceneResult<()> {
    let m = u.max_abs()?;
    if !m.is_finite() {
        return Err(crate::Error::NonFinite { what: "velocity", value: m }.into());
    }
    Ok(())
}

/// The index after `k` on an axis of `n` cells: wraps to 0 when `periodic`, else stays at the
/// last cell (one-sided at a wall).
fn next_index(k: usize, n: usize, periodic: bool) -> usize {
    if k + 1 < n {
        k + 1
    } else if periodic {
        0
    } else {
        k
    }
}
