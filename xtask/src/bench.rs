//! `cargo xtask bench [crate]`: time against error in the shared schema.

use crate::report;
use xtask::bench_schema::{BenchReport, BenchRow, PeerFile, PeerSource};
use xtask::registry;
use xtask::registry::TaskContext;

/// Runs the bench entries of the selected crates (or only the entry named `only`) and writes one
/// report per crate.
pub fn run(krate: Option<&str>, quick: bool, only: Option<&str>) -> anyhow::Result<()> {
    let dir = report::target_dir().join("bench");
    std::fs::create_dir_all(&dir)?;
    let threads = rayon::current_num_threads();
    let mut failed = Vec::new();
    let crates = registry::select(krate)?;
    registry::check_entry(&crates, only, |c| c.bench.iter().map(|e| e.name).collect())?;
    for c in crates {
        if c.bench.is_empty() {
            println!("bench: {} has no bench entries", c.crate_name);
            continue;
        }
        let mut rows: Vec<BenchRow> = Vec::new();
        for entry in c.bench.iter().filter(|e| only.is_none_or(|n| n == e.name)) {
            let out_dir = dir.join(c.crate_name);
            std::fs::create_dir_all(&out_dir)?;
            let ctx = TaskContext { out_dir, quick, threads };
            eprintln!("bench: {}/{} ...", c.crate_name, entry.name);
            match (entry.run)(&ctx) {
                Ok(r) => rows.extend(r),
                Err(e) => {
                    eprintln!("bench: {}/{} failed: {e}", c.crate_name, entry.name);
                    failed.push(format!("{}/{}", c.crate_name, entry.name));
                }
            }
        }
        if rows.is_empty() && only.is_some() {
            continue;
        }
        let mut peer_sources = Vec::new();
        let stem = match only {
            Some(name) => format!("{}_{name}", c.crate_name),
            None => {
                let (peers, sources) = peer_rows(&dir, c.crate_name);
                rows.extend(peers);
                peer_sources = sources;
                c.crate_name.to_string()
            }
        };
        let report = BenchReport { rows, peer_sources };
        let mut files = report.write(&dir, &stem)?;
        files.extend(xtask::bench_schema::plot_report(&report, &dir, &stem)?);
        let table: Vec<Vec<String>> = report
            .rows
            .iter()
            .map(|r| {
                vec![
                    r.case.clone(),
                    r.method.clone(),
                    r.size.clone(),
                    xtask::bench_schema::format_seconds(r.seconds),
                    r.unit.clone(),
                    report::fmt_error(r.error),
                    r.error_kind.clone(),
                ]
            })
            .collect();
        println!("\n{}:", c.crate_name);
        report::print_table(&["case", "method", "size", "median", "unit", "error", "error kind"], &table);
        for f in files {
            println!("wrote {}", f.display());
        }
    }
    anyhow::ensure!(failed.is_empty(), "bench entries failed: {}", failed.join(", "));
    Ok(())
}

/// Rows measured by the peer scripts (`bench/peers/`), read from
/// `target/pbdl/bench/<crate>_peers.json` when that file exists, with their sources; a message
/// otherwise. Rows that do not say who measured them, when and with which versions are refused.
fn peer_rows(dir: &std::path::Path, krate: &str) -> (Vec<BenchRow>, Vec<PeerSource>) {
    let path = dir.join(format!("{krate}_peers.json"));
    if !path.is_file() {
        let how = match krate {
            "grid" => Some("`bench/peers/run.sh` measures PhiFlow and JAX-CFD"),
            "particles" => Some("`bench/peers/particles_run.sh` measures SciPy, Open3D and PySPH"),
            "metrics" => Some("`bench/peers/metrics_run.sh` measures the official LSiM/VolSiM code"),
            _ => None,
        };
        if let Some(how) = how {
            eprintln!("bench: no peer results at {} ({how}); peers skipped", path.display());
        }
        return (Vec::new(), Vec::new());
    }
    match PeerFile::read(&path) {
        Ok(file) => {
            let (rows, sources, undated) = file.into_dated();
            if !undated.is_empty() {
                eprintln!(
                    "bench: refused the rows of {} in {}: no date/versions (written before peer rows were dated); \
                     rerun the peer script in bench/peers/",
                    undated.join(", "),
                    path.display()
                );
            }
            eprintln!("bench: merged {} dated peer rows from {}", rows.len(), path.display());
            for s in &sources {
                eprintln!("bench:   {} measured {} by {} ({})", s.method, s.date, s.script, s.versions);
            }
            (rows, sources)
        }
        Err(e) => {
            eprintln!("bench: ignoring {}: {e}", path.display());
            (Vec::new(), Vec::new())
        }
    }
}
