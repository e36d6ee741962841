//! The full metric-training experiment (minutes): train from scratch on advection-diffusion +
//! Burgers, then compare Spearman correlations on kinds never trained on (smoke, shapes).
//! Prints the table of `docs/metric-training.md`.

use pbdl_metrics::train::experiment::UNSEEN;
use pbdl_metrics::train::{run_experiment, ExperimentConfig};

#[test]
#[ignore = "trains a metric from scratch: about 15 minutes on 2 busy cores (data ~5 min, training ~8 min, evaluation ~2 min)"]
fn trained_metric_beats_l2_and_ssim_on_unseen_kinds() {
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
    for set in UNSEEN {
        let ours = r.score("trained here", set).unwrap();
        for base in ["L2", "SSIM"] {
            let b = r.score(base, set).unwrap();
            assert!(ours > b, "{set}: trained {ours:.3} does not beat {base} {b:.3}");
        }
    }
}
