//! Writing a run: the `.npz` trajectory and, with the `viz` feature, PNG/GIF renders.

use super::{Frame, Stepper};
use crate::error::{Error, Result};
use candle_core::{Device, Tensor};
use pbdl_core::Real;
use std::path::{Path, PathBuf};

/// Reads an optional per-particle array of a frame.
type OptionalArray = fn(&Frame) -> Option<&[f64]>;

/// Writes `<dir>/<stem>.npz` with `positions` `[T, N, D]`, `velocities` `[T, N, D]`,
/// `density` `[T, N]`, `mass` `[T, N]`, `time` `[T]`, for 1D compressible SPH (shock tubes,
/// periodic 1D) `pressure`, `internal_energy` (specific), `smoothing_length` and `viscosity_alpha` (the
/// viscosity switch's per-particle `α`) `[T, N]`, and
/// `fixed_positions` `[F, D]` (walls, ghosts or buffers at the last frame; absent when there are
/// none); plus, with the `viz` feature (on by default),
/// `<stem>.png` (last frame) and `<stem>.gif` (all frames): particles coloured by speed (2D) or
/// density against x coloured by velocity (1D), or a side view projected along z coloured by
/// speed (3D).
/// Returns the files written.
///
/// Dtypes: the particle arrays have the stepper's precision (`f64`, or `f32` for an `f32` run:
/// the solver's own values, so [`InitState::from_arrays`](super::InitState::from_arrays) and
/// [`Scene::build_as`](super::Scene::build_as) in the same precision restore positions,
/// velocities and densities exactly; the 2D solvers' mass is an `f64` constant, written rounded
/// to `f32`, the value the `f32` solver computes with).
/// `time` is always `f64` (the solvers keep time in `f64`).
pub fn write_trajectory<T: Real>(
    stepper: &Stepper<T>,
    frames: &[Frame],
    dir: &Path,
    stem: &str,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::Scene(format!("cannot create {}: {e}", dir.display())))?;
    let dim = stepper.dim();
    let t = frames.len();
    let n = frames.first().map(|f| f.mass.len()).unwrap_or(0);
    let dev = Device::Cpu;
    let stack = |get: &dyn Fn(&Frame) -> &[f64], shape: Vec<usize>| -> Result<Tensor> {
        let data: Vec<f64> = frames.iter().flat_map(|f| get(f).iter().copied()).collect();
        Ok(Tensor::from_vec(data, shape, &dev)?.to_dtype(T::DTYPE)?)
    };
    let mut arrays = vec![
        ("positions".to_string(), stack(&|f| &f.positions, vec![t, n, dim])?),
        ("velocities".to_string(), stack(&|f| &f.velocities, vec![t, n, dim])?),
        ("density".to_string(), stack(&|f| &f.density, vec![t, n])?),
        ("mass".to_string(), stack(&|f| &f.mass, vec![t, n])?),
        ("time".to_string(), Tensor::from_vec(frames.iter().map(|f| f.time).collect::<Vec<_>>(), t, &dev)?),
    ];
    // Per-particle scalars only some solvers have (1D compressible SPH), when every frame has them.
    for (name, get) in [
        ("pressure", (|f| f.pressure.as_deref()) as OptionalArray),
        ("internal_energy", |f| f.internal_energy.as_deref()),
        ("smoothing_length", |f| f.smoothing_length.as_deref()),
        ("viscosity_alpha", |f| f.viscosity_alpha.as_deref()),
    ] {
        if t > 0 && frames.iter().all(|f| get(f).is_some_and(|v| v.len() == n)) {
            arrays.push((name.to_string(), stack(&|f| get(f).unwrap_or(&[]), vec![t, n])?));
        }
    }
    let fixed = stepper.fixed_positions();
    if !fixed.is_empty() {
        let nf = fixed.len() / dim;
        let fixed_t = Tensor::from_vec(fixed.clone(), vec![nf, dim], &dev)?.to_dtype(T::DTYPE)?;
        arrays.push(("fixed_positions".to_string(), fixed_t));
    }
    let npz = dir.join(format!("{stem}.npz"));
    pbdl_core::io::write_npz(&npz, &arrays)?;
    #[cfg(not(feature = "viz"))]
    return Ok(vec![npz]);
    #[cfg(feature = "viz")]
    {
        let [png, gif] = render_png_gif(stepper, frames, &fixed, dir, stem)?;
        Ok(vec![npz, png, gif])
    }
}

/// The last frame as a PNG and the rollout as a GIF (scatter rasters, shared colour range).
#[cfg(feature = "viz")]
fn render_png_gif<T: Real>(
    stepper: &Stepper<T>,
    frames: &[Frame],
    fixed: &[f64],
    dir: &Path,
    stem: &str,
) -> Result<[PathBuf; 2]> {
    let rasters = render_frames(stepper, frames, fixed);
    let (h, w) = (rasters[0].h, rasters[0].w);
    let vmax = rasters.iter().flat_map(|r| r.data.iter()).filter(|v| v.is_finite()).fold(0.0f64, |a, &b| a.max(b));
    let vmin = rasters.iter().flat_map(|r| r.data.iter()).filter(|v| v.is_finite()).fold(vmax, |a, &b| a.min(b));
    let range = if vmax > vmin { (vmin, vmax) } else { (vmin - 1.0, vmin + 1.0) };
    let style = pbdl_core::viz::FieldStyle {
        range: pbdl_core::viz::ColorRange::Fixed(range.0, range.1),
        nan_color: [255, 255, 255],
        ..Default::default()
    };
    let png = dir.join(format!("{stem}.png"));
    let last = rasters.last().expect("at least one frame");
    pbdl_core::viz::field_to_png(&png, &last.data, h, w, &style)?;
    let gif = dir.join(format!("{stem}.gif"));
    let data: Vec<&[f64]> = rasters.iter().map(|r| r.data.as_slice()).collect();
    pbdl_core::viz::rollout_to_gif(
        &gif,
        &data,
        h,
        w,
        &pbdl_core::viz::GifStyle { field: style, frame_delay_ms: 80, repeat: true },
    )?;
    Ok([png, gif])
}

#[cfg(feature = "viz")]
/// Scatter rasters of the frames: 2D particles coloured by speed (walls at the lowest value);
/// 3D: the same, projected along z;
/// 1D: density against x, coloured by velocity.
fn render_frames<T: Real>(stepper: &Stepper<T>, frames: &[Frame], fixed: &[f64]) -> Vec<crate::render::Raster> {
    let [lo, hi] = stepper.view_box();
    if stepper.dim() == 1 {
        let (rmin, rmax) = frames
            .iter()
            .flat_map(|f| f.density.iter())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &r| (a.min(r), b.max(r)));
        let span = (rmax - rmin).max(1e-12 * rmax.abs().max(1.0));
        let width = hi[0] - lo[0];
        let height = 0.5 * width;
        let ppu = 400.0 / width;
        frames
            .iter()
            .map(|f| {
                let pts: Vec<[f64; 2]> = f
                    .positions
                    .iter()
                    .zip(&f.density)
                    .map(|(&x, &r)| [x, 0.05 * height + 0.9 * height * (r - rmin) / span])
                    .collect();
                crate::render::scatter(&pts, &f.velocities, [lo[0], 0.0], [hi[0], height], ppu, 1.0)
            })
            .collect()
    } else if let Some([clo, chi]) = stepper.container_3d() {
        // 3D: a side view projected along z (as `cargo xtask run particles3d`): the wall
        // particles seen edge-on (outside the tank's x-y outline, not the back plate) at the
        // lowest value, then the fluid far first so the nearest paint on top, coloured by speed.
        let ppu = 240.0 / (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let walls: Vec<[f64; 2]> = fixed
            .chunks(3)
            .filter(|c| c[0] < clo[0] || c[0] > chi[0] || c[1] < clo[1] || c[1] > chi[1])
            .map(|c| [c[0], c[1]])
            .collect();
        let r = (0.6 * stepper.spacing() * ppu).max(0.6);
        frames
            .iter()
            .map(|f| {
                let mut order: Vec<usize> = (0..f.positions.len() / 3).collect();
                order.sort_by(|&a, &b| f.positions[3 * b + 2].total_cmp(&f.positions[3 * a + 2]));
                let mut pts = walls.clone();
                let mut vals = vec![0.0; walls.len()];
                for i in order {
                    let (p, v) = (&f.positions[3 * i..3 * i + 3], &f.velocities[3 * i..3 * i + 3]);
                    pts.push([p[0], p[1]]);
                    vals.push((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt());
                }
                crate::render::scatter(&pts, &vals, lo, hi, ppu, r)
            })
            .collect()
    } else {
        let ppu = 240.0 / (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let walls: Vec<[f64; 2]> = fixed.chunks(2).map(|c| [c[0], c[1]]).collect();
        let r = (0.75 * stepper.spacing() * ppu).max(0.6);
        frames
            .iter()
            .map(|f| {
                let mut pts = walls.clone();
                let mut vals = vec![0.0; walls.len()];
                pts.extend(f.positions.chunks(2).map(|c| [c[0], c[1]]));
                vals.extend(f.velocities.chunks(2).map(|c| (c[0] * c[0] + c[1] * c[1]).sqrt()));
                crate::render::scatter(&pts, &vals, lo, hi, ppu, r)
            })
            .collect()
    }
}
