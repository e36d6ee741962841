//! The aggregate stress report, `target/pbdl/stress/summary.{md,json}`: for every crate the
//! longest stable rollout, the largest stable time-step multiple and the broken checks (with the
//! first step at which they broke), and the fuzz counts per target.
//!
//! It is rebuilt after every `cargo xtask stress` run from the per-crate reports in the same
//! folder (`<crate>.json`, `<crate>_<entry>.json`, `fuzz.json`), taking each entry's newest
//! report, so runs of single crates or entries add up to one summary; each row says when its
//! newest report was written.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::SystemTime;
use xtask::registry::{self, StressCheck, StressMeasure};

/// One entry's report as `stress` writes it.
#[derive(Deserialize)]
struct EntryReport {
    entry: String,
    error_message: Option<String>,
    checks: Vec<StressCheck>,
}

/// One crate's line of the summary.
#[derive(Serialize)]
struct CrateSummary {
    krate: String,
    entries: Vec<String>,
    checks_passed: usize,
    checks_broken: usize,
    /// `(steps, "entry: invariant")` of the longest rollout that kept its invariants.
    longest_stable_rollout: Option<(u64, String)>,
    /// `(multiple, "entry: invariant")` of the largest stable time-step multiple.
    largest_stable_dt_multiple: Option<(f64, String)>,
    /// `"entry: invariant (first broken step N): detail"` of every broken check or failed entry.
    broken: Vec<String>,
    /// UTC time of the newest report that went in.
    newest_report: String,
}

/// Rebuilds the summary from the reports in `dir`; returns the files written.
pub fn write(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut crates = Vec::new();
    for c in registry::all() {
        // The newest report of each entry, from the crate's whole-run file or single-entry files.
        let mut newest: BTreeMap<String, (SystemTime, EntryReport)> = BTreeMap::new();
        let prefix = format!("{}_", c.crate_name);
        for file in std::fs::read_dir(dir)?.filter_map(|e| e.ok()).map(|e| e.path()) {
            let Some(name) = file.file_name().and_then(|n| n.to_str()) else { continue };
            let stem = name.strip_suffix(".json").unwrap_or("");
            if stem != c.crate_name && !stem.starts_with(&prefix) {
                continue;
            }
            let Ok(reports) = serde_json::from_str::<Vec<EntryReport>>(&std::fs::read_to_string(&file)?) else {
                continue; // not an entry report (e.g. another tool's JSON); skipped
            };
            let when = std::fs::metadata(&file)?.modified()?;
            for r in reports {
                if newest.get(&r.entry).is_none_or(|(t, _)| *t < when) {
                    newest.insert(r.entry.clone(), (when, r));
                }
            }
        }
        if newest.is_empty() {
            continue;
        }
        let mut s = CrateSummary {
            krate: c.crate_name.into(),
            entries: newest.keys().cloned().collect(),
            checks_passed: 0,
            checks_broken: 0,
            longest_stable_rollout: None,
            largest_stable_dt_multiple: None,
            broken: Vec::new(),
            newest_report: String::new(),
        };
        let mut latest = SystemTime::UNIX_EPOCH;
        for (entry, (when, r)) in &newest {
            latest = latest.max(*when);
            if let Some(msg) = &r.error_message {
                s.broken.push(format!("{entry}: entry failed: {msg}"));
            }
            for ch in &r.checks {
                let label = format!("{entry}: {}", ch.invariant);
                if ch.passed {
                    s.checks_passed += 1;
                } else {
                    s.checks_broken += 1;
                    let step = ch.first_broken_step.map(|k| format!(" (first broken step {k})")).unwrap_or_default();
                    s.broken.push(format!("{label}{step}: {}", ch.detail));
                }
                match ch.measure {
                    Some(StressMeasure::StableSteps(n))
                        if s.longest_stable_rollout.as_ref().is_none_or(|b| n > b.0) =>
                    {
                        s.longest_stable_rollout = Some((n, label));
                    }
                    Some(StressMeasure::DtMultiple(m))
                        if s.largest_stable_dt_multiple.as_ref().is_none_or(|b| m > b.0) =>
                    {
                        s.largest_stable_dt_multiple = Some((m, label));
                    }
                    _ => {}
                }
            }
        }
        s.newest_report = utc(latest);
        crates.push(s);
    }
    let fuzz: serde_json::Value = std::fs::read_to_string(dir.join("fuzz.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::Value::Null);
    let md = markdown(&crates, &fuzz);
    let json = serde_json::to_string_pretty(&serde_json::json!({ "crates": crates, "fuzz": fuzz }))?;
    let mut written = Vec::new();
    for (ext, text) in [("md", md), ("json", json)] {
        let path = dir.join(format!("summary.{ext}"));
        pbdl_core::io::write_atomic(&path, |w| w.write_all(text.as_bytes()))?;
        written.push(path);
    }
    Ok(written)
}

fn markdown(crates: &[CrateSummary], fuzz: &serde_json::Value) -> String {
    let mut md = String::from(
        "# pbdl stress summary\n\n| crate | entries | checks ok / broken | longest stable rollout | largest stable dt multiple | newest report (UTC) |\n|---|---|---:|---|---|---|\n",
    );
    for s in crates {
        let rollout =
            s.longest_stable_rollout.as_ref().map(|(n, w)| format!("{n} steps ({w})")).unwrap_or_else(|| "-".into());
        let dt =
            s.largest_stable_dt_multiple.as_ref().map(|(m, w)| format!("{m}x ({w})")).unwrap_or_else(|| "-".into());
        md.push_str(&format!(
            "| {} | {} | {} / {} | {rollout} | {dt} | {} |\n",
            s.krate,
            s.entries.join(", "),
            s.checks_passed,
            s.checks_broken,
            s.newest_report
        ));
    }
    let broken: Vec<String> =
        crates.iter().flat_map(|s| s.broken.iter().map(move |b| format!("- {}: {b}", s.krate))).collect();
    md.push_str("\n## Broken checks (first failing step under the entry's parameters)\n\n");
    md.push_str(&if broken.is_empty() { "none\n".to_string() } else { broken.join("\n") + "\n" });
    md.push_str("\n## Fuzzing (`cargo xtask stress fuzz`)\n\n");
    match fuzz.as_array() {
        Some(targets) => {
            md.push_str("| target | inputs | panics | hangs | over memory |\n|---|---:|---:|---:|---:|\n");
            for t in targets {
                let f = |k: &str| t.get(k).map(|v| v.to_string()).unwrap_or_else(|| "?".into());
                md.push_str(&format!(
                    "| {} | {} | {} | {} | {} |\n",
                    t.get("target").and_then(|v| v.as_str()).unwrap_or("?"),
                    f("inputs"),
                    f("panics"),
                    f("hangs"),
                    f("over_memory")
                ));
            }
        }
        None => md.push_str("not run yet\n"),
    }
    md
}

/// `YYYY-MM-DD HH:MM` of a file time.
fn utc(t: SystemTime) -> String {
    let secs = t.duration_since(SystemTime::UNIX_EPOCH).map(|d| d.as_secs() as i64).unwrap_or(0);
    let (y, m, d) = pbdl_weather::time::civil_from_days(secs.div_euclid(86_400));
    let rem = secs.rem_euclid(86_400);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}", rem / 3600, rem % 3600 / 60)
}
