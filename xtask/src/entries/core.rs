//! pbdl-core's tour, bench and stress entries (see [`crate::registry`]).
//!
//! * tour: conv2d against candle (time and error), a field warped by a sub-cell shift and a
//!   rotation against the analytic result (PNG + GIF), a checkpoint round trip, the plots.
//! * bench: conv2d/conv3d forward+backward, against candle where it has the op; sampling.
//! * stress: randomised conv configurations against a direct sum, sampling at extreme
//!   coordinates, gradient checks over many seeds.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{conv2d, conv3d, Conv2dParams, Conv3dParams, ConvParams, PaddingMode};
use pbdl_core::io::{load_varmap, save_varmap, CheckpointMeta};
use pbdl_core::sample::{grid_sample, warp, Boundary};
use pbdl_core::viz;
use pbdl_core::{check_grad, seed, GradCheckOptions};
use std::f64::consts::PI;
use std::time::Instant;

/// The entries of `pbdl-core`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "core",
        tour: vec![
            Entry { name: "conv", about: "Our conv2d against candle's: forward+backward time and agreement.", run: tour_conv },
            Entry {
                name: "sampling",
                about: "A smooth field warped by a sub-cell shift and rotated by semi-Lagrangian steps, against the analytic fields.",
                run: tour_sampling,
            },
            Entry {
                name: "checkpoint",
                about: "A small conv net saved as safetensors + JSON sidecar and loaded back bit-exactly.",
                run: tour_checkpoint,
            },
        ],
        bench: vec![
            Entry { name: "conv", about: "conv2d/conv3d forward+backward, ours vs candle.", run: bench_conv },
            Entry { name: "sampling", about: "Bilinear/trilinear warp time and second-order error.", run: bench_sampling },
        ],
        stress: vec![
            Entry { name: "conv_fuzz", about: "Random conv configurations against a direct sum.", run: stress_conv_fuzz },
            Entry {
                name: "crash_resume",
                about: "kill -9 during training and inside checkpoint writes, 20 times, then resume: TrainLoop, ACDM, the weather forecaster, LSiM training and cart-pole controller training reproduce the uninterrupted run bit for bit (release, about 4 min).",
                run: stress_crash_resume,
            },
            Entry {
                name: "sampling_extremes",
                about: "Sampling at far-out coordinates stays finite and within the field's range.",
                run: stress_sampling,
            },
            Entry { name: "grad_seeds", about: "Gradient checks of conv and warp over many seeds.", run: stress_grad_seeds },
        ],
    }
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> candle_core::Result<f64> {
    (a.to_dtype(DType::F64)? - b.to_dtype(DType::F64)?)?.abs()?.max_all()?.to_scalar::<f64>()
}

fn max_abs(a: &Tensor) -> candle_core::Result<f64> {
    a.to_dtype(DType::F64)?.abs()?.max_all()?.to_scalar::<f64>()
}

/// Relative max-norm difference of outputs and gradients of our conv2d and candle's.
struct ConvComparison {
    ours_s: f64,
    candle_s: f64,
    rel_err: f64,
}

fn compare_conv2d(batch: usize, channels: usize, size: usize, reps: usize) -> TaskResult<ConvComparison> {
    let dev = Device::Cpu;
    let x = Var::from_tensor(&seed::randn((batch, channels, size, size), 0.0, 1.0, DType::F32, &dev, 1)?)?;
    let w = Var::from_tensor(&seed::randn((channels, channels, 3, 3), 0.0, 0.1, DType::F32, &dev, 2)?)?;
    let params = Conv2dParams::default().padding(1);
    let ours = || -> TaskResult<(Tensor, Tensor, Tensor)> {
        let y = conv2d(x.as_tensor(), w.as_tensor(), None, &params)?;
        let g = y.sqr()?.sum_all()?.backward()?;
        Ok((y, g.get(&x).ok_or("no dx")?.clone(), g.get(&w).ok_or("no dw")?.clone()))
    };
    let theirs = || -> TaskResult<(Tensor, Tensor, Tensor)> {
        let y = x.as_tensor().conv2d(w.as_tensor(), 1, 1, 1, 1)?;
        let g = y.sqr()?.sum_all()?.backward()?;
        Ok((y, g.get(&x).ok_or("no dx")?.clone(), g.get(&w).ok_or("no dw")?.clone()))
    };
    let (a, b) = (ours()?, theirs()?);
    let mut rel_err = 0.0f64;
    for (p, q) in [(&a.0, &b.0), (&a.1, &b.1), (&a.2, &b.2)] {
        rel_err = rel_err.max(max_abs_diff(p, q)? / max_abs(q)?.max(f64::MIN_POSITIVE));
    }
    let ours_s = median_seconds(1, reps, || ours().map(|_| ()).ok());
    let candle_s = median_seconds(1, reps, || theirs().map(|_| ()).ok());
    Ok(ConvComparison { ours_s, candle_s, rel_err })
}

fn tour_conv(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let (batch, reps) = if ctx.quick { (2, 3) } else { (8, 5) };
    let c = compare_conv2d(batch, 32, 64, reps)?;
    let item = format!("conv2d fwd+bwd {batch}x32x64x64 3x3");
    let rows = vec![
        TourRow {
            item: format!("{item}, pbdl"),
            seconds: c.ours_s,
            error: Some(c.rel_err),
            error_kind: "rel max diff vs candle (y, dx, dw)".into(),
            note: format!("{:.2}x faster than candle", c.candle_s / c.ours_s),
        },
        TourRow {
            item: format!("{item}, candle"),
            seconds: c.candle_s,
            error: None,
            error_kind: String::new(),
            note: "peer".into(),
        },
    ];
    let markdown = format!(
        "| implementation | median time | rel. difference |\n|---|---:|---:|\n| pbdl | {} | {:.2e} |\n| candle 0.11 | {} | (reference) |\n\nSpeed-up {:.2}x on {} threads.",
        crate::bench_schema::format_seconds(c.ours_s),
        c.rel_err,
        crate::bench_schema::format_seconds(c.candle_s),
        c.candle_s / c.ours_s,
        ctx.threads
    );
    Ok(TourOutcome { rows, files: vec![], markdown })
}

/// A smooth periodic test field on an n x n grid with unit spacing: f(x, y).
fn test_field(x: f64, y: f64, n: usize) -> f64 {
    let k = 2.0 * PI / n as f64;
    (k * x).sin() * (2.0 * k * y).cos() + 0.5 * (k * (x + y)).cos()
}

fn field_tensor(n: usize, shift: (f64, f64)) -> candle_core::Result<Tensor> {
    let data: Vec<f64> =
        (0..n * n).map(|i| test_field((i % n) as f64 + shift.0, (i / n) as f64 + shift.1, n)).collect();
    Tensor::from_vec(data, (1, 1, n, n), &Device::Cpu)
}

/// Relative L2 error of warping the test field by a constant sub-cell shift (periodic).
fn shift_error(n: usize, dtype: DType) -> TaskResult<(f64, f64, Tensor, Tensor)> {
    let shift = (0.37, -0.61);
    let f = field_tensor(n, (0.0, 0.0))?.to_dtype(dtype)?;
    let exact = field_tensor(n, shift)?;
    let disp = Tensor::cat(
        &[Tensor::full(shift.0, (1, 1, n, n), &Device::Cpu)?, Tensor::full(shift.1, (1, 1, n, n), &Device::Cpu)?],
        1,
    )?
    .to_dtype(dtype)?;
    let t = Instant::now();
    let warped = warp(&f, &disp, Boundary::Periodic)?;
    let secs = t.elapsed().as_secs_f64();
    let diff = (warped.to_dtype(DType::F64)? - &exact)?;
    let err = (diff.sqr()?.sum_all()?.sqrt()? / exact.sqr()?.sum_all()?.sqrt()?)?.to_scalar::<f64>()?;
    Ok((err, secs, warped, exact))
}

fn tour_sampling(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let mut rows = Vec::new();
    let mut files = Vec::new();
    // Convergence of a sub-cell shift: bilinear interpolation is second order.
    let sizes = [32usize, 64, 128, 256];
    let mut errs = Vec::new();
    for &n in &sizes {
        let (err, secs, warped, exact) = shift_error(n, DType::F64)?;
        errs.push(err);
        rows.push(TourRow {
            item: format!("warp by (0.37, -0.61) cells, {n}x{n}"),
            seconds: secs,
            error: Some(err),
            error_kind: "rel L2 vs analytic shift".into(),
            note: String::new(),
        });
        if n == 64 {
            let w = warped.to_dtype(DType::F32)?.squeeze(0)?.squeeze(0)?;
            let e = (warped.to_dtype(DType::F64)? - &exact)?.to_dtype(DType::F32)?.squeeze(0)?.squeeze(0)?;
            let p1 = ctx.out_dir.join("warped_64.png");
            viz::tensor_field_to_png(&p1, &w, &viz::FieldStyle { upscale: Some(5), ..Default::default() })?;
            let p2 = ctx.out_dir.join("warp_error_64.png");
            viz::tensor_field_to_png(&p2, &e, &viz::FieldStyle { upscale: Some(5), ..viz::FieldStyle::diverging() })?;
            files.push(p1);
            files.push(p2);
        }
    }
    let order = (errs[1] / errs[2]).log2();
    rows.last_mut().expect("rows").note = format!("observed order {order:.2} (64 -> 128)");
    let plot = ctx.out_dir.join("warp_convergence.png");
    let xs: Vec<f64> = sizes.iter().map(|&n| n as f64).collect();
    let slope: Vec<f64> = xs.iter().map(|&x| 2.0 * errs[0] * (sizes[0] as f64 / x).powi(2)).collect();
    viz::line_plot(
        &plot,
        &[
            viz::Series::new("bilinear warp", xs.clone(), errs.clone()),
            viz::Series::new("slope -2 (offset x2)", xs.clone(), slope),
        ],
        &viz::PlotStyle {
            title: "Sub-cell shift: error vs resolution".into(),
            x_label: "grid size n".into(),
            y_label: "relative L2 error".into(),
            log_x: true,
            log_y: true,
            ..Default::default()
        },
    )?;
    files.push(plot);

    // Rotation by repeated semi-Lagrangian steps, as a GIF; compared with the exact rotation.
    let n = if ctx.quick { 48 } else { 96 };
    let steps = if ctx.quick { 24 } else { 48 };
    let blob = |x: f64, y: f64| {
        let c = n as f64 / 2.0;
        let (dx, dy) = (x - c - n as f64 / 5.0, y - c);
        (-(dx * dx + dy * dy) / (2.0 * (n as f64 / 14.0).powi(2))).exp()
    };
    let angle = PI / steps as f64; // half a turn in total
    let c = (n as f64 - 1.0) / 2.0;
    // Displacement of one backward step: the point that rotates onto (x, y) within one step.
    let mut disp = vec![0f32; 2 * n * n];
    for y in 0..n {
        for x in 0..n {
            let (rx, ry) = (x as f64 - c, y as f64 - c);
            let (sx, sy) = (angle.cos() * rx + angle.sin() * ry, -angle.sin() * rx + angle.cos() * ry);
            disp[y * n + x] = (sx - rx) as f32;
            disp[n * n + y * n + x] = (sy - ry) as f32;
        }
    }
    let disp = Tensor::from_vec(disp, (1, 2, n, n), &Device::Cpu)?;
    let init: Vec<f32> = (0..n * n).map(|i| blob((i % n) as f64, (i / n) as f64) as f32).collect();
    let mut q = Tensor::from_vec(init, (1, 1, n, n), &Device::Cpu)?;
    let mut frames = vec![q.flatten_all()?.to_vec1::<f32>()?];
    let t = Instant::now();
    for _ in 0..steps {
        q = warp(&q, &disp, Boundary::Clamp)?;
        frames.push(q.flatten_all()?.to_vec1::<f32>()?);
    }
    let secs = t.elapsed().as_secs_f64() / steps as f64;
    // After half a turn the blob sits mirrored through the centre.
    let exact: Vec<f32> = (0..n * n)
        .map(|i| {
            let (x, y) = ((i % n) as f64, (i / n) as f64);
            blob(2.0 * c - x, 2.0 * c - y) as f32
        })
        .collect();
    let exact = Tensor::from_vec(exact, (1, 1, n, n), &Device::Cpu)?;
    let peak_kept = q.max_all()?.to_scalar::<f32>()? as f64;
    let rel = max_abs_diff(&q, &exact)? / max_abs(&exact)?;
    let gif = ctx.out_dir.join("rotation.gif");
    let style = viz::GifStyle {
        field: viz::FieldStyle { upscale: Some(3), range: viz::ColorRange::Fixed(0.0, 1.0), ..Default::default() },
        frame_delay_ms: 80,
        ..Default::default()
    };
    viz::rollout_to_gif(&gif, &frames, n, n, &style)?;
    files.push(gif);
    rows.push(TourRow {
        item: format!("semi-Lagrangian half turn, {n}x{n}, {steps} steps"),
        seconds: secs,
        error: Some(rel),
        error_kind: "max abs error / peak vs exact rotation".into(),
        note: format!("peak {peak_kept:.3} of 1 (numerical diffusion of linear interpolation)"),
    });
    let markdown = format!(
        "Bilinear warp of a smooth periodic field by a constant sub-cell shift; observed order {order:.2}.\n\n\
         ![warped](warped_64.png) ![error](warp_error_64.png)\n\n![convergence](warp_convergence.png)\n\n\
         A Gaussian blob rotated half a turn in {steps} semi-Lagrangian steps (linear interpolation \
         diffuses it; peak {peak_kept:.3}):\n\n![rotation](rotation.gif)"
    );
    Ok(TourOutcome { rows, files, markdown })
}

fn tour_checkpoint(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let dev = Device::Cpu;
    let varmap = candle_nn::VarMap::new();
    let vb = candle_nn::VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let cfg = pbdl_core::conv::ConvLayerConfig::new(4, 16, [3, 3]).with_params(ConvParams::default().padding(1));
    let _l1 = cfg.init(vb.pp("conv1"))?;
    let _l2 = pbdl_core::conv::ConvLayerConfig::new(16, 4, [3, 3])
        .with_params(ConvParams::default().padding(1))
        .init(vb.pp("conv2"))?;
    let path = ctx.out_dir.join("net.safetensors");
    let meta = CheckpointMeta { step: 42, seed: Some(7), config: serde_json::json!({"layers": [[4, 16], [16, 4]]}) };
    let t = Instant::now();
    let info = save_varmap(&path, &varmap, &meta)?;
    let save_s = t.elapsed().as_secs_f64();

    let restored = candle_nn::VarMap::new();
    let vb2 = candle_nn::VarBuilder::from_varmap(&restored, DType::F32, &dev);
    cfg.init(vb2.pp("conv1"))?;
    pbdl_core::conv::ConvLayerConfig::new(16, 4, [3, 3])
        .with_params(ConvParams::default().padding(1))
        .init(vb2.pp("conv2"))?;
    let t = Instant::now();
    let back = load_varmap(&path, &restored)?;
    let load_s = t.elapsed().as_secs_f64();
    let mut max_diff = 0.0f64;
    {
        let a = varmap.data().lock().expect("lock");
        let b = restored.data().lock().expect("lock");
        for (name, v) in a.iter() {
            max_diff = max_diff.max(max_abs_diff(v.as_tensor(), b[name].as_tensor())?);
        }
    }
    if max_diff != 0.0 || back.step != 42 {
        return Err(format!("round trip not exact: max diff {max_diff}, step {}", back.step).into());
    }
    let rows = vec![TourRow {
        item: format!("save + load checkpoint ({} tensors)", info.tensors.len()),
        seconds: save_s + load_s,
        error: Some(max_diff),
        error_kind: "max abs diff after round trip".into(),
        note: format!("step {} restored", back.step),
    }];
    let markdown = format!(
        "Saved `net.safetensors` + `net.json` (atomic writes) and loaded them into a fresh model: \
         max difference {max_diff}, step {} and seed {:?} restored.",
        back.step, back.seed
    );
    Ok(TourOutcome { rows, files: vec![path], markdown })
}

fn bench_conv(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let reps = if ctx.quick { 3 } else { 7 };
    let mut rows = Vec::new();
    let c = compare_conv2d(8, 32, 64, reps)?;
    let size = "b8_c32_64x64_k3".to_string();
    rows.push(BenchRow {
        error: Some(c.rel_err),
        error_kind: "rel_max_diff_vs_candle".into(),
        ..call_row(ctx, "conv2d_f32_fwd_bwd", size.clone(), c.ours_s)
    });
    rows.push(BenchRow {
        method: "candle".into(),
        peer: true,
        ..call_row(ctx, "conv2d_f32_fwd_bwd", size, c.candle_s)
    });
    // conv3d has no candle counterpart; its accuracy is covered by the tests (direct sum, FD).
    let dev = Device::Cpu;
    let x = Var::from_tensor(&seed::randn((2, 16, 32, 32, 32), 0.0, 1.0, DType::F32, &dev, 3)?)?;
    let w = Var::from_tensor(&seed::randn((16, 16, 3, 3, 3), 0.0, 0.1, DType::F32, &dev, 4)?)?;
    let p = Conv3dParams::default().padding(1).padding_mode(PaddingMode::Circular);
    let s = median_seconds(1, reps, || {
        let y = conv3d(x.as_tensor(), w.as_tensor(), None, &p).expect("conv3d");
        y.sqr().and_then(|t| t.sum_all()).and_then(|t| t.backward()).expect("backward")
    });
    rows.push(call_row(ctx, "conv3d_f32_fwd_bwd", "b2_c16_32^3_k3_circular", s));
    Ok(rows)
}

fn bench_sampling(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let reps = if ctx.quick { 3 } else { 11 };
    let mut rows = Vec::new();
    for n in [64usize, 128, 256] {
        let (err, _, _, _) = shift_error(n, DType::F32)?;
        let f = field_tensor(n, (0.0, 0.0))?.to_dtype(DType::F32)?;
        let disp = seed::rand_uniform((1, 2, n, n), -1.0, 1.0, DType::F32, &Device::Cpu, 5)?;
        let s = median_seconds(2, reps, || warp(&f, &disp, Boundary::Periodic).expect("warp"));
        rows.push(BenchRow {
            error: Some(err),
            error_kind: "rel_l2_vs_analytic_shift".into(),
            ..call_row(ctx, "warp2d_bilinear_periodic", format!("{n}x{n}"), s)
        });
    }
    let n = 64;
    let f = seed::randn((1, 3, n, n, n), 0.0, 1.0, DType::F32, &Device::Cpu, 6)?;
    let disp = seed::rand_uniform((1, 3, n, n, n), -1.0, 1.0, DType::F32, &Device::Cpu, 7)?;
    let s = median_seconds(1, reps, || warp(&f, &disp, Boundary::Clamp).expect("warp3d"));
    rows.push(call_row(ctx, "warp3d_trilinear_3ch", "64^3", s));
    Ok(rows)
}

/// A row of this crate's bench: pbdl's median seconds per call of `case` at `size`, with no
/// error measured (struct update syntax sets the fields that differ).
fn call_row(ctx: &TaskContext, case: &str, size: impl Into<String>, seconds: f64) -> BenchRow {
    BenchRow {
        case: case.into(),
        method: "pbdl".into(),
        size: size.into(),
        seconds,
        unit: "call".into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads: ctx.threads,
    }
}

/// Direct-sum 2D convolution in f64 (zero or circular padding), the reference of the fuzz test.
fn direct_conv2d(
    x: &[f64],
    xs: [usize; 4],
    w: &[f64],
    ws: [usize; 4],
    stride: usize,
    pad: usize,
    dil: usize,
    groups: usize,
    circular: bool,
) -> (Vec<f64>, [usize; 4]) {
    let [b, cin, h, wd] = xs;
    debug_assert_eq!(cin, ws[1] * groups);
    let [cout, cing, kh, kw] = ws;
    let oh = (h + 2 * pad - dil * (kh - 1) - 1) / stride + 1;
    let ow = (wd + 2 * pad - dil * (kw - 1) - 1) / stride + 1;
    let coutg = cout / groups;
    let mut y = vec![0.0; b * cout * oh * ow];
    for bi in 0..b {
        for co in 0..cout {
            let g = co / coutg;
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut acc = 0.0;
                    for ci in 0..cing {
                        let cin_idx = g * cing + ci;
                        for ky in 0..kh {
                            for kx in 0..kw {
                                let iy = (oy * stride + ky * dil) as isize - pad as isize;
                                let ix = (ox * stride + kx * dil) as isize - pad as isize;
                                let (iy, ix) = if circular {
                                    (iy.rem_euclid(h as isize), ix.rem_euclid(wd as isize))
                                } else if iy < 0 || ix < 0 || iy >= h as isize || ix >= wd as isize {
                                    continue;
                                } else {
                                    (iy, ix)
                                };
                                acc += x[((bi * cin + cin_idx) * h + iy as usize) * wd + ix as usize]
                                    * w[((co * cing + ci) * kh + ky) * kw + kx];
                            }
                        }
                    }
                    y[((bi * cout + co) * oh + oy) * ow + ox] = acc;
                }
            }
        }
    }
    (y, [b, cout, oh, ow])
}

fn stress_conv_fuzz(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let cases = if ctx.quick { 40 } else { 300 };
    let mut rng = seed::rng(2024);
    let mut worst = 0.0f64;
    let mut first_bad = None;
    use rand::Rng;
    for case in 0..cases {
        let groups = [1usize, 2, 4][rng.random_range(0..3)];
        let cin = groups * rng.random_range(1..4);
        let cout = groups * rng.random_range(1..4);
        let (kh, kw) = (rng.random_range(1..5), rng.random_range(1..5));
        let stride = rng.random_range(1..4);
        let dil = rng.random_range(1..3);
        let pad = rng.random_range(0..3);
        let circular = rng.random_bool(0.5);
        let h = dil * (kh - 1) + 1 + rng.random_range(0..9);
        let w = dil * (kw - 1) + 1 + rng.random_range(0..9);
        if circular && pad > h.min(w) {
            continue;
        }
        let b = rng.random_range(1..3);
        let x = seed::randn((b, cin, h, w), 0.0, 1.0, DType::F64, &Device::Cpu, case as u64)?;
        let wt = seed::randn((cout, cin / groups, kh, kw), 0.0, 1.0, DType::F64, &Device::Cpu, 10_000 + case as u64)?;
        let mut p = ConvParams::default().stride(stride).padding(pad).dilation(dil).groups(groups);
        if circular {
            p = p.circular();
        }
        let ours = conv2d(&x, &wt, None, &p)?;
        let (refy, shape) = direct_conv2d(
            &x.flatten_all()?.to_vec1()?,
            [b, cin, h, w],
            &wt.flatten_all()?.to_vec1()?,
            [cout, cin / groups, kh, kw],
            stride,
            pad,
            dil,
            groups,
            circular,
        );
        let refy = Tensor::from_vec(refy, shape.to_vec(), &Device::Cpu)?;
        let err = max_abs_diff(&ours, &refy)? / max_abs(&refy)?.max(1e-300);
        if err > 1e-12 && first_bad.is_none() {
            first_bad = Some(case as u64);
        }
        worst = worst.max(err);
    }
    // Huge but finite inputs in f32 must give finite outputs where the true result is finite.
    let x = (seed::randn((1, 4, 16, 16), 0.0, 1.0, DType::F32, &Device::Cpu, 1)? * 1e15)?;
    let w = (seed::randn((4, 4, 3, 3), 0.0, 1.0, DType::F32, &Device::Cpu, 2)? * 1e15)?;
    let y = conv2d(&x, &w, None, &Conv2dParams::default().padding(1))?;
    let finite = pbdl_core::error::check_finite("conv2d at 1e30 scale", &y).is_ok();
    Ok(vec![
        StressCheck {
            invariant: format!("conv2d = direct sum over {cases} random configs (f64, rel 1e-12)"),
            passed: first_bad.is_none(),
            first_broken_step: first_bad,
            detail: format!("worst relative difference {worst:.2e}"),
            measure: None,
        },
        StressCheck {
            invariant: "f32 conv2d at 1e30 product scale stays finite".into(),
            passed: finite,
            first_broken_step: None,
            detail: format!("max |y| = {:.3e}", max_abs(&y)?),
            measure: None,
        },
    ])
}

fn stress_sampling(_ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let n = 32;
    let f = seed::randn((1, 2, n, n), 0.0, 1.0, DType::F32, &Device::Cpu, 11)?;
    let (lo, hi) = (f.min_all()?.to_scalar::<f32>()?, f.max_all()?.to_scalar::<f32>()?);
    let mut checks = Vec::new();
    for (bname, boundary) in [("clamp", Boundary::Clamp), ("periodic", Boundary::Periodic)] {
        let mut first_bad = None;
        let scales = [1e0f64, 1e3, 1e6, 1e7, -1e7, 3.3e6];
        for (i, s) in scales.iter().enumerate() {
            let pts = (seed::rand_uniform((1, 1000, 2), -1.0, 1.0, DType::F32, &Device::Cpu, i as u64)? * *s)?;
            let v = grid_sample(&f, &pts, boundary)?;
            let ok = pbdl_core::error::check_finite("sample", &v).is_ok()
                && v.min_all()?.to_scalar::<f32>()? >= lo - 1e-5
                && v.max_all()?.to_scalar::<f32>()? <= hi + 1e-5;
            if !ok && first_bad.is_none() {
                first_bad = Some(i as u64);
            }
        }
        checks.push(StressCheck {
            invariant: format!("{bname}: samples at |coords| up to 1e7 are finite and within [min, max] of the field"),
            passed: first_bad.is_none(),
            first_broken_step: first_bad,
            detail: format!("scales {scales:?}"),
            measure: None,
        });
    }
    Ok(checks)
}

fn stress_grad_seeds(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let seeds = if ctx.quick { 5 } else { 40 };
    let opts = |s| GradCheckOptions { seed: s, max_probes: 24, ..Default::default() };
    let mut worst_conv = 0.0f64;
    let mut worst_warp = 0.0f64;
    let (mut bad_conv, mut bad_warp) = (None, None);
    for s in 0..seeds {
        let x = seed::randn((2, 3, 7, 6), 0.0, 1.0, DType::F64, &Device::Cpu, s)?;
        let w = seed::randn((4, 3, 3, 3), 0.0, 1.0, DType::F64, &Device::Cpu, 100 + s)?;
        let p = Conv2dParams::default().padding(1).stride(2).circular();
        let r = check_grad(|v| Ok(conv2d(&v[0], &v[1], None, &p)?), &[x, w], &opts(s))?;
        worst_conv = worst_conv.max(r.max_rel_error);
        if r.max_rel_error > 1e-6 && bad_conv.is_none() {
            bad_conv = Some(s);
        }
        let f = seed::randn((1, 2, 8, 9), 0.0, 1.0, DType::F64, &Device::Cpu, 200 + s)?;
        // Displacements kept away from integers so the FD step does not straddle a kink.
        let d = (seed::rand_uniform((1, 2, 8, 9), 0.1, 0.4, DType::F64, &Device::Cpu, 300 + s)? * 2.0)?;
        let r = check_grad(|v| Ok(warp(&v[0], &v[1], Boundary::Periodic)?), &[f, d], &opts(s))?;
        worst_warp = worst_warp.max(r.max_rel_error);
        if r.max_rel_error > 1e-6 && bad_warp.is_none() {
            bad_warp = Some(s);
        }
    }
    Ok(vec![
        StressCheck {
            invariant: format!("conv2d gradient matches FD over {seeds} seeds (rel 1e-6)"),
            passed: bad_conv.is_none(),
            first_broken_step: bad_conv,
            detail: format!("worst {worst_conv:.2e}"),
            measure: None,
        },
        StressCheck {
            invariant: format!("warp gradient matches FD over {seeds} seeds (rel 1e-6)"),
            passed: bad_warp.is_none(),
            first_broken_step: bad_warp,
            detail: format!("worst {worst_warp:.2e}"),
            measure: None,
        },
    ])
}

/// The 20-kill crash/resume tests of each crate that trains from a run directory (the default
/// test suite runs 3 kills each).
const CRASH_RESUME: &[crate::acceptance::AcceptanceTest] = &[
    crate::acceptance::AcceptanceTest {
        package: "pbdl-core",
        file: "crash_resume",
        test: "kill_9_twenty_times_then_resume_exactly",
        claim: "TrainLoop: 20 kill -9 (during training and inside checkpoint writes) then resume = the uninterrupted run, bit for bit; every checkpoint loads",
        minutes: 1.0,
        env: &[],
    },
    crate::acceptance::AcceptanceTest {
        package: "pbdl-diffusion",
        file: "crash_resume",
        test: "acdm_kill_9_twenty_times_then_resume_exactly",
        claim: "ACDM training: 20 kill -9 then resume = the uninterrupted run, bit for bit",
        minutes: 1.0,
        env: &[],
    },
    crate::acceptance::AcceptanceTest {
        package: "pbdl-weather",
        file: "crash_resume",
        test: "forecaster_kill_9_twenty_times_then_resume_exactly",
        claim: "weather forecaster: 20 kill -9 then resume = the uninterrupted run (weights, Adam state, plateau state), bit for bit",
        minutes: 1.0,
        env: &[],
    },
    crate::acceptance::AcceptanceTest {
        package: "pbdl-metrics",
        file: "crash_resume",
        test: "lsim_kill_9_twenty_times_then_resume_exactly",
        claim: "LSiM metric training: 20 kill -9 then resume = the uninterrupted run (weights, Adam state, normalisation statistics), bit for bit",
        minutes: 1.0,
        env: &[],
    },
    crate::acceptance::AcceptanceTest {
        package: "pbdl-optim",
        file: "crash_resume",
        test: "cartpole_kill_9_twenty_times_then_resume_exactly",
        claim: "cart-pole controller training (adjoint path): 20 kill -9 then resume = the uninterrupted run (parameters, Adam state, evaluations), bit for bit",
        minutes: 1.0,
        env: &[],
    },
];

fn stress_crash_resume(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, CRASH_RESUME)
}
