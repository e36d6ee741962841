//! The shared benchmark schema: run time next to error, one row per measurement.
//!
//! Every `cargo xtask bench <crate>` entry produces [`BenchRow`]s; [`BenchReport::write`] stores
//! them as `target/pbdl/bench/<crate>.json` in this schema:
//!
//! ```text
//! {"rows": [{"case": str, "method": str, "size": str, "seconds": f64 (median per unit),
//!            "unit": str, "error": f64|null, "error_kind": str, "peer": bool, "threads": int}]}
//! ```
//!
//! plus a markdown table beside it. Peers (PhiFlow, JAX-CFD, candle, PyTorch, ...) use the same
//! rows with `peer = true`, so one plot can show everybody's time against error.

use pbdl_core::{io::write_atomic, Error, Result};
use serde::{Deserialize, Serialize};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One measurement: the median time of one unit of work and the error it reached.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchRow {
    /// The problem, e.g. `"taylor_green"` or `"conv2d_f32_fwd_bwd"`.
    pub case: String,
    /// Who solved it, e.g. `"pbdl"`, `"candle"`, `"jax_cfd_fv"`.
    pub method: String,
    /// Problem size, e.g. `"64x64"` or `"b8_c32_64x64_k3"`.
    pub size: String,
    /// Median wall-clock seconds per unit.
    pub seconds: f64,
    /// What one unit is: `"step"`, `"call"`, `"rollout"`, ...
    pub unit: String,
    /// The error reached, if the case has a reference.
    pub error: Option<f64>,
    /// What `error` measures, e.g. `"rel_l2_vs_analytic"`; empty when `error` is `None`.
    pub error_kind: String,
    /// `true` for other libraries measured for comparison.
    pub peer: bool,
    /// Number of threads the measurement ran with.
    pub threads: usize,
}

/// A set of rows, as stored in `target/pbdl/bench/<crate>.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BenchReport {
    /// The measurements.
    pub rows: Vec<BenchRow>,
    /// Where the peer rows come from: one entry per peer method and measurement run.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub peer_sources: Vec<PeerSource>,
}

/// Who measured a peer row, when, with what: written by the peer scripts (`bench/peers/`) into
/// every row of `target/pbdl/bench/<crate>_peers.json` as `"measured": {...}`. A peer row without
/// it is not merged, so that a number nobody can date never sits beside pbdl's.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PeerSource {
    /// The peer method the source is for (filled in from the row when merging).
    #[serde(default)]
    pub method: String,
    /// The script that measured it, relative to the repository root.
    pub script: String,
    /// When: an ISO 8601 UTC time stamp (`2026-11-27T08:15:00Z`).
    pub date: String,
    /// The peer's packages and their versions, e.g. `"torch 2.5.1, numpy 2.1.3"`.
    pub versions: String,
    /// The CPU model the script ran on.
    #[serde(default)]
    pub cpu: String,
}

/// One row of a peer file: the shared row plus its [`PeerSource`] (absent in undated files).
#[derive(Clone, Debug, Deserialize)]
pub struct PeerRow {
    /// The measurement.
    #[serde(flatten)]
    pub row: BenchRow,
    /// Who measured it and when.
    #[serde(default)]
    pub measured: Option<PeerSource>,
}

/// The dated peer row of `<bench_dir>/<krate>_peers.json` for `case` and `size` whose method
/// contains `method`, with its source; `None` when no such row was measured (or it is undated).
pub fn measured_peer(
    bench_dir: &Path,
    krate: &str,
    case: &str,
    method: &str,
    size: &str,
) -> Option<(BenchRow, PeerSource)> {
    let (rows, sources, _) = PeerFile::read(&bench_dir.join(format!("{krate}_peers.json"))).ok()?.into_dated();
    let row = rows.into_iter().find(|r| r.case == case && r.size == size && r.method.contains(method))?;
    let source = sources.into_iter().find(|s| s.method == row.method)?;
    Some((row, source))
}

/// A peer script's output file, `target/pbdl/bench/<crate>_peers.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct PeerFile {
    /// The rows, each with its source.
    pub rows: Vec<PeerRow>,
}

impl PeerFile {
    /// Reads a peer file.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| Error::Format { path: path.to_path_buf(), reason: format!("not a pbdl peer file: {e}") })
    }

    /// The dated rows as peer [`BenchRow`]s with their sources (one per method and run), and
    /// the methods whose rows were refused because they carry no source.
    pub fn into_dated(self) -> (Vec<BenchRow>, Vec<PeerSource>, Vec<String>) {
        let (mut rows, mut sources, mut undated) = (Vec::new(), Vec::new(), Vec::new());
        for PeerRow { row, measured } in self.rows {
            match measured {
                Some(src) if !src.date.is_empty() && !src.versions.is_empty() => {
                    let src = PeerSource { method: row.method.clone(), ..src };
                    if !sources.contains(&src) {
                        sources.push(src);
                    }
                    rows.push(BenchRow { peer: true, ..row });
                }
                _ => {
                    if !undated.contains(&row.method) {
                        undated.push(row.method);
                    }
                }
            }
        }
        (rows, sources, undated)
    }
}

/// Measures the median seconds of `f` over `reps` runs after `warmup` unmeasured runs.
pub fn median_seconds<F: FnMut() -> R, R>(warmup: usize, reps: usize, mut f: F) -> f64 {
    for _ in 0..warmup {
        std::hint::black_box(f());
    }
    let mut times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(|a, b| a.total_cmp(b));
    let n = times.len();
    if n % 2 == 1 {
        times[n / 2]
    } else {
        0.5 * (times[n / 2 - 1] + times[n / 2])
    }
}

impl BenchReport {
    /// Reads a report written by [`BenchReport::write`].
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| Error::Format { path: path.to_path_buf(), reason: format!("not a pbdl bench report: {e}") })
    }

    /// Writes `<dir>/<name>.json` and `<dir>/<name>.md` atomically; returns both paths.
    pub fn write(&self, dir: &Path, name: &str) -> Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let json_path = dir.join(format!("{name}.json"));
        let json = serde_json::to_string_pretty(self).expect("bench rows serialise");
        write_atomic(&json_path, |w| w.write_all(json.as_bytes()))?;
        let md_path = dir.join(format!("{name}.md"));
        let md = self.markdown();
        write_atomic(&md_path, |w| w.write_all(md.as_bytes()))?;
        Ok(vec![json_path, md_path])
    }

    /// The rows as a markdown table.
    pub fn markdown(&self) -> String {
        let mut s = String::from(
            "| case | method | size | median time | unit | error | error kind | peer | threads |\n|---|---|---|---:|---|---:|---|---|---:|\n",
        );
        for r in &self.rows {
            let err = r.error.map(|e| format!("{e:.3e}")).unwrap_or_else(|| "-".into());
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.case,
                r.method,
                r.size,
                format_seconds(r.seconds),
                r.unit,
                err,
                r.error_kind,
                if r.peer { "yes" } else { "no" },
                r.threads
            ));
        }
        if !self.peer_sources.is_empty() {
            s.push_str("\nPeer rows, measured by the scripts in `bench/peers/` (each on the CPU it names):\n\n");
            s.push_str("| peer method | script | measured (UTC) | versions | CPU |\n|---|---|---|---|---|\n");
            for p in &self.peer_sources {
                s.push_str(&format!("| {} | {} | {} | {} | {} |\n", p.method, p.script, p.date, p.versions, p.cpu));
            }
        }
        s
    }
}

/// Formats seconds with a readable unit (s, ms, us).
pub fn format_seconds(s: f64) -> String {
    if s >= 1.0 {
        format!("{s:.3} s")
    } else if s >= 1e-3 {
        format!("{:.3} ms", s * 1e3)
    } else {
        format!("{:.2} us", s * 1e6)
    }
}

/// Draws time against error (a Pareto plot) for every case that has rows with an error, one
/// PNG per case (`<stem>_<case>.png`, one colour per method, sizes as labels), because a Pareto
/// front across different problems means nothing. `<stem>.png` repeats the case with the most
/// such rows; with no error rows at all it shows the median times instead. Returns the paths.
pub fn plot_report(report: &BenchReport, dir: &Path, stem: &str) -> Result<Vec<PathBuf>> {
    use pbdl_core::viz::{line_plot, pareto_plot, ParetoPoint, PlotStyle, Series};
    let mut cases: Vec<&str> = Vec::new();
    for r in &report.rows {
        if !cases.contains(&r.case.as_str()) {
            cases.push(&r.case);
        }
    }
    let mut written = Vec::new();
    let mut best: Option<(usize, PathBuf)> = None;
    for case in cases {
        let points: Vec<ParetoPoint> = report
            .rows
            .iter()
            .filter(|r| r.case == case && r.seconds > 0.0)
            .filter_map(|r| {
                let e = r.error.filter(|e| e.is_finite() && *e > 0.0)?;
                Some(ParetoPoint::new(r.method.clone(), r.seconds, e).with_label(r.size.clone()))
            })
            .collect();
        if points.is_empty() {
            continue;
        }
        let kind = report
            .rows
            .iter()
            .find(|r| r.case == case && r.error.is_some())
            .map(|r| r.error_kind.clone())
            .unwrap_or_default();
        let style = PlotStyle {
            title: format!("{stem}: {case}"),
            x_label: "median seconds per unit".into(),
            y_label: format!("error ({kind})"),
            ..PlotStyle::pareto()
        };
        let path = dir.join(format!("{stem}_{case}.png"));
        pareto_plot(&path, &points, &style)?;
        if best.as_ref().is_none_or(|(n, _)| points.len() > *n) {
            best = Some((points.len(), path.clone()));
        }
        written.push(path);
    }
    let main = dir.join(format!("{stem}.png"));
    match best {
        Some((_, path)) => {
            std::fs::copy(&path, &main).map_err(|e| Error::io(&main, e))?;
        }
        None => {
            // No errors to plot against: show the median times so the run is still visible.
            let series: Vec<Series> = report
                .rows
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    Series::new(
                        format!("{} / {} ({})", r.case, r.method, r.size),
                        vec![i as f64, i as f64 + 0.8],
                        vec![r.seconds; 2],
                    )
                })
                .collect();
            if series.is_empty() {
                return Err(Error::invalid("plot_report", "report", "no rows to plot"));
            }
            let style = PlotStyle {
                title: format!("{stem}: median time per unit"),
                y_label: "seconds".into(),
                log_y: true,
                ..Default::default()
            };
            line_plot(&main, &series, &style)?;
        }
    }
    written.insert(0, main);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_round_trips_in_the_shared_schema() {
        let dir = tempfile::tempdir().unwrap();
        let report = BenchReport {
            rows: vec![BenchRow {
                case: "taylor_green".into(),
                method: "pbdl".into(),
                size: "64x64".into(),
                seconds: 2.5e-4,
                unit: "step".into(),
                error: Some(1.2e-5),
                error_kind: "rel_l2_vs_analytic".into(),
                peer: false,
                threads: 2,
            }],
            peer_sources: vec![],
        };
        let paths = report.write(dir.path(), "grid").unwrap();
        assert_eq!(BenchReport::read(&paths[0]).unwrap(), report);
        // The schema's field names are a contract with other tools: check them literally.
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&paths[0]).unwrap()).unwrap();
        let row = &v["rows"][0];
        for key in ["case", "method", "size", "seconds", "unit", "error", "error_kind", "peer", "threads"] {
            assert!(row.get(key).is_some(), "missing key {key}");
        }
        assert!(std::fs::read_to_string(&paths[1]).unwrap().contains("250.00 us"));
    }

    #[test]
    fn peer_rows_without_a_source_are_refused() {
        let text = r#"{"rows": [
            {"case": "tg", "method": "jax", "size": "64", "seconds": 1e-3, "unit": "step", "error": null,
             "error_kind": "", "peer": true, "threads": 2,
             "measured": {"script": "bench/peers/grid_peers.py", "date": "2026-11-27T08:00:00Z",
                          "versions": "jax 0.4.30", "cpu": "test cpu"}},
            {"case": "tg", "method": "old", "size": "64", "seconds": 1e-3, "unit": "step", "error": null,
             "error_kind": "", "peer": true, "threads": 2}]}"#;
        let file: PeerFile = serde_json::from_str(text).unwrap();
        let (rows, sources, undated) = file.into_dated();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].method, "jax");
        assert_eq!(sources.len(), 1);
        assert_eq!(sources[0].method, "jax");
        assert_eq!(undated, ["old"]);
        let report = BenchReport { rows, peer_sources: sources };
        assert!(report.markdown().contains("| jax | bench/peers/grid_peers.py | 2026-11-27T08:00:00Z | jax 0.4.30 |"));
    }

    #[test]
    fn median_of_runs() {
        let mut k = 0;
        let m = median_seconds(1, 5, || {
            k += 1;
            k
        });
        assert!(m >= 0.0);
        assert_eq!(k, 6);
    }
}
