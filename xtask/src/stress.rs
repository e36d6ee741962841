//! `cargo xtask stress [crate]`: long and extreme runs, invariants checked.

use crate::report;
use serde::Serialize;
use std::io::Write as _;
use xtask::registry;
use xtask::registry::{StressCheck, TaskContext};

#[derive(Serialize)]
struct StressEntryReport {
    entry: String,
    error_message: Option<String>,
    checks: Vec<StressCheck>,
}

/// Runs the stress entries of the selected crates (or only the entry named `only`); fails if an
/// invariant broke.
pub fn run(krate: Option<&str>, quick: bool, only: Option<&str>) -> anyhow::Result<()> {
    let dir = report::target_dir().join("stress");
    std::fs::create_dir_all(&dir)?;
    let threads = rayon::current_num_threads();
    let mut broken = Vec::new();
    let crates = registry::select(krate)?;
    registry::check_entry(&crates, only, |c| c.stress.iter().map(|e| e.name).collect())?;
    for c in crates {
        let mut entries = Vec::new();
        let mut table = Vec::new();
        for entry in c.stress.iter().filter(|e| only.is_none_or(|n| n == e.name)) {
            let out_dir = dir.join(c.crate_name);
            std::fs::create_dir_all(&out_dir)?;
            let ctx = TaskContext { out_dir, quick, threads };
            eprintln!("stress: {}/{} ...", c.crate_name, entry.name);
            let (checks, error_message) = match (entry.run)(&ctx) {
                Ok(checks) => (checks, None),
                Err(e) => (vec![], Some(e.to_string())),
            };
            if let Some(msg) = &error_message {
                broken.push(format!("{}/{} (error: {msg})", c.crate_name, entry.name));
                table.push(vec![entry.name.to_string(), "ERROR".into(), "-".into(), msg.clone()]);
            }
            for ch in &checks {
                if !ch.passed {
                    broken.push(format!("{}/{}: {}", c.crate_name, entry.name, ch.invariant));
                }
                table.push(vec![
                    format!("{}: {}", entry.name, ch.invariant),
                    if ch.passed { "ok".into() } else { "BROKEN".into() },
                    ch.first_broken_step.map(|s| s.to_string()).unwrap_or_else(|| "-".into()),
                    ch.detail.clone(),
                ]);
            }
            entries.push(StressEntryReport { entry: entry.name.into(), error_message, checks });
        }
        if entries.is_empty() && only.is_some() {
            continue;
        }
        println!("\n{}:", c.crate_name);
        report::print_table(&["invariant", "verdict", "first broken step", "detail"], &table);
        let json = serde_json::to_string_pretty(&entries)?;
        let stem = match only {
            Some(name) => format!("{}_{name}", c.crate_name),
            None => c.crate_name.to_string(),
        };
        let path = dir.join(format!("{stem}.json"));
        pbdl_core::io::write_atomic(&path, |w| w.write_all(json.as_bytes()))?;
        println!("wrote {}", path.display());
    }
    anyhow::ensure!(broken.is_empty(), "invariants broke: {}", broken.join("; "));
    Ok(())
}
