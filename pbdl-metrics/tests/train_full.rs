//! The full metric-training experiment (minutes): train from scratch on advection-diffusion +
//! Burgers, then compare Spearman correlations on kinds never trained on (smoke, shapes).
//! Prints the table of `docs/metric-training.md`.
//!
//! The data follow the authors' generation scripts (noise injected into the velocity at every
//! step, their parameter steps, their shapes; `docs/metric-training.md`). The test prints the
//! whole table and then checks the acceptance: on at least one unseen kind the trained
//! metric beats both L2 and SSIM. Run it with `RAYON_NUM_THREADS=1` on a shared machine (the
//! small tensor ops of the generators are several times slower with contended worker threads).

use pbdl_metrics::train::experiment::{CONTROL, UNSEEN, VALIDATION};
use pbdl_metrics::train::{run_experiment, ExperimentConfig};

#[test]
#[ignore = "trains a metric from scratch: ~7-8 min with RAYON_NUM_THREADS=1 on the shared 2-core machine (previous default: data 168 s, training 182 s, evaluation 77 s; the current default trains at 0.035 s/step, 169 s, plus a validation set and the control)"]
fn trained_metric_on_unseen_kinds() {
    let cfg = ExperimentConfig {
        out_dir: Some(std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("metric-training")),
        ..Default::default()
    };
    let r = run_experiment(&cfg).unwrap();
    println!("{cfg:?}");
    println!(
        "data {:.1} s, calibration {:.1} s, training {:.1} s ({} parameters, {} sequences x {} epochs), evaluation {:.1} s",
        r.data_seconds,
        r.training.calibration_seconds,
        r.training.train_seconds,
        r.parameters,
        r.train_sequences,
        cfg.epochs,
        r.eval_seconds
    );
    println!("epoch losses {:?}", r.training.epoch_loss);
    println!("{}", r.table);
    let mut wins = Vec::new();
    for set in UNSEEN {
        let ours = r.score("trained here", set).unwrap();
        let l2 = r.score("L2", set).unwrap();
        let ssim = r.score("SSIM", set).unwrap();
        println!(
            "{set}: trained {ours:.3}, L2 {l2:.3} ({}), SSIM {ssim:.3} ({})",
            if ours > l2 { "beats L2" } else { "does NOT beat L2" },
            if ours > ssim { "beats SSIM" } else { "does NOT beat SSIM" }
        );
        println!(
            "ACCEPTANCE: metric_{set} measured=trained {ours:.3}, L2 {l2:.3}, SSIM {ssim:.3} \
             bar=above L2 and SSIM on at least one unseen kind"
        );
        if ours > l2 && ours > ssim {
            wins.push(set);
        }
    }
    for set in VALIDATION {
        println!(
            "{set}: trained {:.3}, untrained control {:.3}",
            r.score("trained here", set).unwrap(),
            r.score(CONTROL, set).unwrap()
        );
    }
    assert!(!wins.is_empty(), "the trained metric beats L2 and SSIM on no unseen kind");
}
