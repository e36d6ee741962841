//! This part's `cargo xtask` entries (tour, bench, stress).
//!
//! * bench `ddpm_oracle_sampling`: sampling time against error for ancestral DDPM (cosine
//!   schedules with R = 20, 100, 1000 steps) and deterministic DDIM (k = 5, 10, 20, 50 steps of a
//!   T = 1000 cosine schedule) with the exact noise predictor for Gaussian data
//!   ([`pbdl_diffusion::ddpm::GaussianOracle`]), so every error is the sampler's own discretisation error.
//!   `error` is the largest relative error of the output variance over two channels
//!   (`N(1.5, 0.5^2)` and `N(-0.5, 2^2)`), computed exactly: the samplers are affine maps plus
//!   Gaussian noise for this predictor (DDIM: the sampler itself run on start values 0 and 1;
//!   DDPM: the moment recursion of the ancestral step). `seconds` is the median time of one full
//!   sample of a `[64, 2, 16, 16]` batch.
//! * tour `ddpm_vs_ddim`: the same rows (quick sizes) and their time-vs-error plot (PNG).

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{Entry, StressCheck, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::viz::{pareto_plot, ParetoPoint, PlotStyle};
use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle};
use pbdl_diffusion::schedule::{NoiseSchedule, COSINE_S};

/// Tour, bench and stress entries of this part.
pub type Entries = (Vec<Entry<TourOutcome>>, Vec<Entry<Vec<BenchRow>>>, Vec<Entry<Vec<StressCheck>>>);

/// This part's entries.
pub fn entries() -> Entries {
    (
        vec![Entry {
            name: "ddpm_vs_ddim",
            about: "DDPM and DDIM with the exact Gaussian noise predictor: sampling time vs the sampler's own variance error (PNG).",
            run: tour_ddpm_vs_ddim,
        }],
        vec![Entry {
            name: "ddpm_oracle_sampling",
            about: "DDPM (R = 20, 100, 1000) and DDIM (5, 10, 20, 50 of T = 1000) with the exact Gaussian noise predictor: time per batch sample vs exact output-variance error.",
            run: bench_oracle_sampling,
        }],
        vec![],
    )
}

const MU: [f64; 2] = [1.5, -0.5];
const STD: [f64; 2] = [0.5, 2.0];
const SHAPE: [usize; 4] = [64, 2, 16, 16];

/// Exact output variance of ancestral DDPM with the diagonal oracle for one channel, from `N(0, 1)`.
fn ddpm_output_variance(s: &NoiseSchedule, var: f64) -> f64 {
    let mut v = 1.0;
    for i in (0..s.len()).rev() {
        let ab = s.alpha_bar(i);
        let s1 = (1.0 - ab).sqrt();
        let g = s1 / (ab * var + 1.0 - ab);
        let a = (1.0 - s.beta(i) / s1 * g) / s.alpha(i).sqrt();
        v = a * a * v + s.posterior_variance(i);
    }
    v
}

fn variance_error(out_var: [f64; 2]) -> f64 {
    out_var.iter().zip(STD).map(|(v, sd)| (v / (sd * sd) - 1.0).abs()).fold(0.0, f64::max)
}

fn bench_oracle_sampling(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let dev = Device::Cpu;
    let x = Diffusion::noise(&SHAPE, DType::F32, &dev, 0)?;
    let reps = if ctx.quick { 1 } else { 5 };
    let mut rows = Vec::new();
    let row = |method: &str, size: String, seconds: f64, error: f64| BenchRow {
        case: "gaussian_oracle_sampling".into(),
        method: method.into(),
        size,
        seconds,
        unit: "sample_b64_c2_16x16".into(),
        error: Some(error),
        error_kind: "max_rel_err_output_variance_exact".into(),
        peer: false,
        threads: ctx.threads,
    };
    for r in [20, 100, 1000] {
        let s = NoiseSchedule::cosine(r, COSINE_S)?;
        let oracle = GaussianOracle::diagonal(s.clone(), &MU, &STD)?;
        let d = Diffusion::new(s.clone(), Conditioning::Clean);
        let mut failure = None;
        let seconds = median_seconds(usize::from(!ctx.quick), reps, || {
            if let Err(e) = d.sample_ddpm(&oracle, None, &x, 1) {
                failure = Some(e);
            }
        });
        if let Some(e) = failure {
            return Err(e.into());
        }
        let err =
            variance_error([ddpm_output_variance(&s, STD[0] * STD[0]), ddpm_output_variance(&s, STD[1] * STD[1])]);
        rows.push(row("ddpm", format!("R{r}_cosine"), seconds, err));
    }
    let s = NoiseSchedule::cosine(1000, COSINE_S)?;
    let oracle = GaussianOracle::diagonal(s.clone(), &MU, &STD)?;
    let d = Diffusion::new(s, Conditioning::Clean);
    let probe = Tensor::cat(
        &[Tensor::zeros((1, 2, 1, 1), DType::F64, &dev)?, Tensor::ones((1, 2, 1, 1), DType::F64, &dev)?],
        0,
    )?;
    for k in [5, 10, 20, 50] {
        let steps = d.ddim_steps(k)?;
        let mut failure = None;
        let seconds = median_seconds(usize::from(!ctx.quick), reps, || {
            if let Err(e) = d.sample_ddim(&oracle, None, &x, &steps, 0.0, 1) {
                failure = Some(e);
            }
        });
        if let Some(e) = failure {
            return Err(e.into());
        }
        // x_0 = a x_start + b per channel: the outputs at 0 and 1 give b and a + b exactly.
        let out = d.sample_ddim(&oracle, None, &probe, &steps, 0.0, 1)?.flatten_all()?.to_vec1::<f64>()?;
        let a = [out[2] - out[0], out[3] - out[1]];
        rows.push(row(
            "ddim_eta0",
            format!("k{k}_of_T1000_cosine"),
            seconds,
            variance_error([a[0] * a[0], a[1] * a[1]]),
        ));
    }
    Ok(rows)
}

fn tour_ddpm_vs_ddim(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let rows = bench_oracle_sampling(&TaskContext { quick: true, ..ctx.clone() })?;
    let points: Vec<ParetoPoint> = rows
        .iter()
        .map(|r| ParetoPoint {
            method: r.method.clone(),
            time: r.seconds,
            error: r.error.unwrap_or(f64::NAN),
            label: Some(r.size.split('_').next().unwrap_or("").to_string()),
        })
        .collect();
    let png = ctx.out_dir.join("ddpm_vs_ddim.png");
    let style = PlotStyle {
        title: "DDPM vs DDIM, exact Gaussian noise predictor".into(),
        x_label: "seconds per sample of [64, 2, 16, 16]".into(),
        y_label: "relative error of the output variance".into(),
        ..PlotStyle::pareto()
    };
    pareto_plot(&png, &points, &style)?;
    let tour_rows = rows
        .iter()
        .map(|r| TourRow {
            item: format!("{} {}", r.method, r.size),
            seconds: r.seconds,
            error: r.error,
            error_kind: "rel. error of the output variance (exact, oracle predictor)".into(),
            note: String::new(),
        })
        .collect();
    let markdown = "Samplers against the exact noise predictor of Gaussian data: every error is the sampler's own \
                    discretisation error (DDPM: cosine schedules with R steps; DDIM: k of T = 1000 steps, eta = 0).\n\n\
                    ![DDPM vs DDIM](ddpm_vs_ddim.png)\n"
        .to_string();
    Ok(TourOutcome { rows: tour_rows, files: vec![png], markdown })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quick_bench_rows_have_falling_errors() {
        let ctx = TaskContext { out_dir: std::env::temp_dir(), quick: true, threads: 1 };
        let rows = bench_oracle_sampling(&ctx).unwrap();
        assert_eq!(rows.len(), 7);
        for r in &rows {
            println!("{} {}: {:.4} s per sample, error {:.3e}", r.method, r.size, r.seconds, r.error.unwrap());
        }
        for group in [&rows[..3], &rows[3..]] {
            let errs: Vec<f64> = group.iter().map(|r| r.error.unwrap()).collect();
            assert!(errs.windows(2).all(|w| w[1] < w[0]), "{errs:?}");
        }
    }
}
