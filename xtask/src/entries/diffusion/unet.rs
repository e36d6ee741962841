//! This part's `cargo xtask` entries (tour, bench, stress): the ACDM U-Net's training and
//! sampling steps.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{Entry, StressCheck, TaskContext, TaskResult, TourOutcome};
use pbdl_diffusion::unet::workload::{UnetFixture, UnetWorkload};

/// Tour, bench and stress entries of this part.
pub type Entries = (Vec<Entry<TourOutcome>>, Vec<Entry<Vec<BenchRow>>>, Vec<Entry<Vec<StressCheck>>>);

/// This part's entries: one bench.
pub fn entries() -> Entries {
    let bench = vec![Entry {
        name: "acdm_unet",
        about: "ACDM U-Net, f32: training step (forward, smooth-L1, backward, Adam) and sampling step (forward)",
        run: bench_acdm_unet,
    }];
    (vec![], bench, vec![])
}

/// Median seconds of a training step and of a sampling step at CPU sizes (dim 16 and 32,
/// 64x32, batch 16, 12 channels) and, unless `quick`, at full size (dim 128, 128x64, batch 4).
fn bench_acdm_unet(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let reps = if ctx.quick { 2 } else { 5 };
    let mut sizes: Vec<UnetWorkload> =
        [16, 32].into_iter().map(|dim| UnetWorkload { dim, channels: 12, batch: 16, height: 64, width: 32 }).collect();
    if !ctx.quick {
        sizes.push(UnetWorkload { dim: 128, channels: 12, batch: 4, height: 128, width: 64 });
    }
    let mut rows = Vec::new();
    for w in sizes {
        let mut fx = UnetFixture::new(&w, 0)?;
        let reps = if w.dim >= 128 { reps.min(3) } else { reps };
        let mut failure = None;
        let train = median_seconds(1, reps, || {
            if let Err(e) = fx.train_step() {
                failure.get_or_insert(e);
            }
        });
        let sample = median_seconds(1, reps, || {
            if let Err(e) = fx.sample_step() {
                failure.get_or_insert(e);
            }
        });
        if let Some(e) = failure {
            return Err(e.into());
        }
        for (case, seconds) in [("acdm_unet_train_step_f32", train), ("acdm_unet_sample_step_f32", sample)] {
            rows.push(BenchRow {
                case: case.into(),
                method: "pbdl".into(),
                size: w.label(),
                seconds,
                unit: "step".into(),
                error: None,
                error_kind: String::new(),
                peer: false,
                threads: ctx.threads,
            });
        }
    }
    Ok(rows)
}
