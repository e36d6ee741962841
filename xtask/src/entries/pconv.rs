//! pbdl-pconv's entries: the learned filters of SFBC's test case I (even, odd and linear bases
//! against the analytic kernel gradient), and a long rollout of a momentum-conserving
//! (antisymmetric) update network.

use crate::bench_schema::BenchRow;
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_core::viz::{line_plot, PlotStyle, Series};
use pbdl_pconv::periodic_case::{
    density_gradient_filter, free_rollout, train_case, CaseConfig, CaseKind, Dataset, Task, TrainConfig,
};
use pbdl_pconv::Basis;

/// This crate's entries.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "pconv",
        tour: vec![Entry {
            name: "sfbc_symmetry",
            about: "SFBC test case I (small): one continuous convolution per basis learns the SPH density gradient (an odd function of the offset) on periodic 1D compressible SPH; the learned filters against the analytic one (PNG) and held-out errors: the even-only Fourier basis cannot represent it.",
            run: tour_symmetry,
        }],
        bench: vec![Entry {
            name: "bases_time_vs_error",
            about: "SFBC test case I (small: 256 particles, 3 + 1 simulations): every basis trained on the density gradient and the velocity update (quick: 150 steps, full: 1000); the network's median time per held-out frame against its held-out relative MSE.",
            run: bench_bases_time_vs_error,
        }],
        stress: vec![Entry {
            name: "antisymmetric_long_rollout",
            about: "An update network with an antisymmetric last layer (DMCF), trained briefly on test case I, rolled out 1000 frames (quick: 100) beyond its data: finite, momentum conserved to f32 round-off (drift <= 1e-5 of the initial total |v| plus the impulses applied), speeds within 10x the initial maximum.",
            run: stress_antisymmetric_rollout,
        }],
    }
}

fn tour_symmetry(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let data = Dataset::generate(&CaseConfig::small(CaseKind::Compressible1d))?;
    let train =
        TrainConfig { steps: if ctx.quick { 150 } else { 1000 }, ..TrainConfig::for_task(Task::DensityGradient) };
    let qs: Vec<f64> = (0..=200).map(|i| -1.0 + i as f64 / 100.0).collect();
    let mut series = Vec::new();
    let mut rows = Vec::new();
    let mut md = format!(
        "SFBC test case I, small: {} particles, {} + {} simulations of {} frames; one convolution layer of 6 basis \
         functions learns the SPH density gradient ({} Adam steps).\n\n| basis | held-out relative MSE | train s |\n|---|---:|---:|\n",
        data.config.particles,
        data.train.len(),
        data.test.len(),
        data.config.frames,
        train.steps
    );
    let mut truth = None;
    for basis in [Basis::Fourier, Basis::FourierEven, Basis::Linear, Basis::Chebyshev] {
        let t = train_case(&data, Task::DensityGradient, basis, &train, 0, None)?;
        if truth.is_none() {
            let y = qs.iter().map(|&q| density_gradient_filter(&data, &t.scales, q)).collect::<Result<Vec<_>, _>>()?;
            truth = Some(Series::new("analytic", qs.clone(), y));
        }
        // The single layer's filter: g(q) = sum_k W_k b_k(q) (one input, one output channel).
        let w = t.net.convolutions()[0].weight().flatten_all()?.to_dtype(candle_core::DType::F64)?.to_vec1::<f64>()?;
        let (mut b, mut db) = (vec![0.0; w.len()], vec![0.0; w.len()]);
        let y: Vec<f64> = qs
            .iter()
            .map(|&q| {
                basis.eval(q, &mut b, &mut db);
                b.iter().zip(&w).map(|(b, w)| b * w).sum()
            })
            .collect();
        series.push(Series::new(basis.name(), qs.clone(), y));
        rows.push(TourRow {
            item: format!("density gradient, {} basis", basis.name()),
            seconds: t.result.train_seconds,
            error: Some(t.result.test_rel_mse),
            error_kind: "held-out relative MSE".into(),
            note: String::new(),
        });
        md.push_str(&format!("| {} | {:.3} | {:.1} |\n", basis.name(), t.result.test_rel_mse, t.result.train_seconds));
    }
    series.insert(0, truth.expect("at least one basis"));
    let path = ctx.out_dir.join("sfbc_symmetry.png");
    let style = PlotStyle {
        title: "learned filters for the density gradient".into(),
        x_label: "q = (x_j - x_i) / R".into(),
        y_label: "filter value".into(),
        ..Default::default()
    };
    line_plot(&path, &series, &style)?;
    md.push_str("\n![learned filters](sfbc_symmetry.png)\n");
    Ok(TourOutcome { rows, files: vec![path], markdown: md })
}

fn bench_bases_time_vs_error(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let data = Dataset::generate(&CaseConfig::small(CaseKind::Compressible1d))?;
    let steps = if ctx.quick { 150 } else { 1000 };
    let mut rows = Vec::new();
    for task in [Task::DensityGradient, Task::Update] {
        for basis in Basis::ALL {
            let train = TrainConfig { steps, ..TrainConfig::for_task(task) };
            let r = train_case(&data, task, basis, &train, 0, None)?.result;
            rows.push(BenchRow {
                case: format!("sfbc_case1_{}", task.name()),
                method: format!("pbdl_{}", basis.name()),
                size: format!("n{}_steps{steps}", data.config.particles),
                seconds: r.forward_seconds,
                unit: "network evaluation per frame".into(),
                error: Some(r.test_rel_mse),
                error_kind: "held_out_rel_mse".into(),
                peer: false,
                threads: ctx.threads,
            });
        }
    }
    Ok(rows)
}

fn stress_antisymmetric_rollout(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let data = Dataset::generate(&CaseConfig::small(CaseKind::Compressible1d))?;
    let train = TrainConfig {
        steps: if ctx.quick { 60 } else { 500 },
        antisymmetric: true,
        ..TrainConfig::for_task(Task::Update)
    };
    let trained = train_case(&data, Task::Update, Basis::Fourier, &train, 0, None)?;
    let frames = if ctx.quick { 100 } else { 1000 };
    let r = free_rollout(&data, &trained, frames)?;
    let what = format!(
        "{frames} frames of {} particles (data: {} frames), Fourier update network with an antisymmetric last layer, {} Adam steps",
        data.config.particles, data.config.frames, train.steps
    );
    Ok(vec![
        StressCheck {
            invariant: "state finite".into(),
            passed: r.first_non_finite.is_none(),
            first_broken_step: r.first_non_finite.map(|f| f as u64),
            detail: what.clone(),
            measure: r.first_non_finite.is_none().then_some(StressMeasure::StableSteps(frames as u64)),
        },
        StressCheck {
            invariant: "momentum drift <= 1e-5 of (sum |v_0| + impulses)".into(),
            passed: r.momentum_drift <= 1e-5,
            first_broken_step: None,
            detail: format!("largest drift {:.2e} over {} frames", r.momentum_drift, r.frames),
            measure: None,
        },
        StressCheck {
            invariant: "max speed <= 10x the initial maximum".into(),
            passed: r.speed_growth <= 10.0,
            first_broken_step: r.first_speed_blowup.map(|f| f as u64),
            detail: format!("largest growth {:.2}x", r.speed_growth),
            measure: None,
        },
    ])
}
