//! `cargo xtask metric <metric> A B [--weights PATH] [--native] [--joint-batch] [--resize64]`: a distance
//! between two fields in files, printed as one JSON object. The reading and the metrics live in
//! [`pbdl_metrics::files`]; this is the thin command-line side.

use pbdl_metrics::files::{compare, read_field, CompareOptions, Metric};
use std::path::PathBuf;

/// What `cargo xtask metric` was asked to do.
pub struct MetricArgs {
    /// The metric name (`lsim`, `volsim`, `mse`, ...).
    pub metric: String,
    /// First file.
    pub a: PathBuf,
    /// Second file.
    pub b: PathBuf,
    /// Weight file of a learned metric.
    pub weights: Option<PathBuf>,
    /// LSiM at native size.
    pub native: bool,
    /// Official whole-batch normalisation.
    pub joint_batch: bool,
    /// VolSiM: cubic-spline resize to 64^3.
    pub resize64: bool,
}

/// Prints `{"distance": d}` for one pair, `{"distance": [d0, d1, ...]}` for a batch.
pub fn run(args: MetricArgs) -> anyhow::Result<()> {
    let metric: Metric = args.metric.parse()?;
    let (a, b) = (read_field(&args.a)?, read_field(&args.b)?);
    let opts = CompareOptions {
        weights: args.weights,
        native: args.native,
        joint_batch: args.joint_batch,
        resize64: args.resize64,
    };
    let d = compare(metric, &a, &b, &opts)?;
    let value = match d.as_slice() {
        [x] => serde_json::json!(x),
        _ => serde_json::json!(d),
    };
    println!("{}", serde_json::json!({ "distance": value }));
    Ok(())
}
