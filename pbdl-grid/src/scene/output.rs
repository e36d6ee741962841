//! Writing a trajectory: `.npz` arrays and PNG/GIF renders.

use super::{SceneResult, Simulation, Trajectory};
use crate::Error;
#[cfg(feature = "viz")]
use candle_core::DType;
use candle_core::{Device, Tensor};
#[cfg(feature = "viz")]
use pbdl_core::viz::{self, ColorRange, FieldStyle, GifStyle, PlotStyle, Series};
use std::path::{Path, PathBuf};

fn core<T>(r: pbdl_core::Result<T>) -> SceneResult<T> {
    r.map_err(|e| Error::from(e).into())
}

fn cdl<T>(r: candle_core::Result<T>) -> SceneResult<T> {
    r.map_err(|e| Error::from(e).into())
}

/// Writes `<dir>/<scene>.npz` with every field as `[T, C, ny, nx]` (plus `time` `[T]` and
/// `step` `[T]`, f64) and renders: for 2D scenes the last frame of each scalar as a PNG and its
/// trajectory as a GIF, for velocity scenes the speed `|u|` (PNG) and the vorticity (PNG + GIF, colours clipped
/// symmetrically at the 99.5th percentile of `|w|` of the last frame);
/// for 1D scenes a line plot of the frames and a space-time image (x across, time up); 3D
/// scenes write `[T, C, nz, ny, nx]` and render the middle z slice (vorticity: its z component).
/// Renders need the `viz` feature (on by default); without it only the `.npz` is written.
/// Returns the files written.
pub fn write_trajectory(sim: &Simulation, traj: &Trajectory, dir: &Path) -> SceneResult<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::from(pbdl_core::Error::io(dir, e)))?;
    let name = &sim.scene().name;
    let mut files = Vec::new();
    let mut arrays = traj.stacked()?;
    let nt = traj.times.len();
    arrays.push(("time".into(), cdl(Tensor::from_vec(traj.times.clone(), nt, &Device::Cpu))?));
    let steps: Vec<f64> = traj.steps.iter().map(|&s| s as f64).collect();
    arrays.push(("step".into(), cdl(Tensor::from_vec(steps, nt, &Device::Cpu))?));
    let npz = dir.join(format!("{name}.npz"));
    core(pbdl_core::io::write_npz(&npz, &arrays))?;
    files.push(npz);
    #[cfg(feature = "viz")]
    render_arrays(sim, traj, &arrays, dir, &mut files)?;
    Ok(files)
}

/// PNG and GIF renders of the stacked arrays (see [`write_trajectory`]).
#[cfg(feature = "viz")]
fn render_arrays(
    sim: &Simulation,
    traj: &Trajectory,
    arrays: &[(String, Tensor)],
    dir: &Path,
    files: &mut Vec<PathBuf>,
) -> SceneResult<()> {
    let name = &sim.scene().name;
    let nt = traj.times.len();
    let one_d = sim.scene().grid.ny == 1;
    for (field, t) in arrays {
        // A 3D field [T, C, Z, Y, X] is rendered as its middle z slice; for the vorticity its z
        // component (the rotation seen in that plane).
        let sliced;
        let t = if t.rank() == 5 {
            let nz = t.dims()[2];
            let mut s = cdl(t.narrow(2, nz / 2, 1).and_then(|x| x.squeeze(2)))?;
            if field == "vorticity" && s.dims()[1] == 3 {
                s = cdl(s.narrow(1, 2, 1))?;
            }
            sliced = s;
            &sliced
        } else {
            t
        };
        if t.rank() != 4 || field == "velocity_mac" {
            continue;
        }
        let t = cdl(t.to_dtype(DType::F32))?;
        let last = cdl(t.narrow(0, nt - 1, 1).and_then(|x| x.squeeze(0)))?;
        if one_d {
            let nx = t.dims()[3];
            let (x0, dx) = (sim.scene().grid.origin[0], sim.scene().grid.lx / nx as f64);
            let xs: Vec<f64> = (0..nx).map(|i| x0 + (i as f64 + 0.5) * dx).collect();
            let pick = (nt.saturating_sub(1) / 5).max(1);
            let mut series = Vec::new();
            for k in (0..nt).step_by(pick) {
                let y = cdl(t
                    .narrow(0, k, 1)
                    .and_then(|x| x.flatten_all())
                    .and_then(|x| x.to_dtype(DType::F64))
                    .and_then(|x| x.to_vec1::<f64>()))?;
                series.push(Series::new(format!("t = {:.3}", traj.times[k]), xs.clone(), y));
            }
            let png = dir.join(format!("{name}_{field}.png"));
            let style = PlotStyle {
                title: format!("{name}: {field}"),
                x_label: "x".into(),
                y_label: field.clone(),
                ..Default::default()
            };
            core(viz::line_plot(&png, &series, &style))?;
            files.push(png);
            let st = dir.join(format!("{name}_{field}_spacetime.png"));
            let img = cdl(t.reshape((nt, nx)))?;
            core(viz::tensor_field_to_png(&st, &img, &FieldStyle { upscale: Some(2), ..FieldStyle::diverging() }))?;
            files.push(st);
            continue;
        }
        if field == "velocity" {
            let speed = cdl(last.sqr().and_then(|x| x.sum_keepdim(0)).and_then(|x| x.sqrt()))?;
            let png = dir.join(format!("{name}_speed.png"));
            core(viz::tensor_field_to_png(&png, &speed, &FieldStyle::default()))?;
            files.push(png);
            continue;
        }
        let diverging = field == "vorticity";
        let style = if diverging {
            // Symmetric about 0, clipped at the 99.5th percentile of |w| of the last frame: the
            // thin wall layers (cylinder, lid corners) would otherwise wash out the wake.
            let mut a: Vec<f32> = cdl(last.abs().and_then(|x| x.flatten_all()).and_then(|x| x.to_vec1::<f32>()))?;
            a.retain(|v| v.is_finite());
            a.sort_by(f32::total_cmp);
            let clip = a.get(((a.len() as f64 - 1.0) * 0.995) as usize).copied().unwrap_or(0.0) as f64;
            let range = if clip > 0.0 { ColorRange::Symmetric(clip) } else { ColorRange::Auto };
            FieldStyle { range, ..FieldStyle::diverging() }
        } else {
            FieldStyle::default()
        };
        let png = dir.join(format!("{name}_{field}.png"));
        core(viz::tensor_field_to_png(&png, &last, &style))?;
        files.push(png);
        if nt > 1 {
            let gif = dir.join(format!("{name}_{field}.gif"));
            let gstyle = GifStyle { field: style, frame_delay_ms: 80, repeat: true };
            core(viz::tensor_rollout_to_gif(&gif, &t, &gstyle))?;
            files.push(gif);
        }
    }
    Ok(())
}
