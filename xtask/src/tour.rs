//! `cargo xtask tour`: every method on its embedded default scene, one report.

use crate::report;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use xtask::registry;
use xtask::registry::{TaskContext, TourRow};

#[derive(Serialize)]
struct SummaryEntry {
    krate: String,
    entry: String,
    ok: bool,
    error_message: Option<String>,
    wall_seconds: f64,
    rows: Vec<TourRow>,
    files: Vec<PathBuf>,
}

/// Runs all tour entries and writes `report.md`, `summary.json` and the entries' files to `out`.
pub fn run(krate: Option<&str>, only: Option<&str>, quick: bool, out: PathBuf) -> anyhow::Result<()> {
    let crates = registry::select(krate)?;
    registry::check_entry(&crates, only, |c| c.tour.iter().map(|e| e.name).collect())?;
    std::fs::create_dir_all(&out)?;
    let threads = rayon::current_num_threads();
    let mut summary = Vec::new();
    let mut md = format!(
        "# pbdl tour\n\nEvery available method on its embedded default scene ({} threads{}).\n\n",
        threads,
        if quick { ", quick mode" } else { "" }
    );
    let started = Instant::now();
    for krate in crates {
        for entry in krate.tour.iter().filter(|e| only.is_none_or(|n| n == e.name)) {
            let dir = out.join(krate.crate_name).join(entry.name);
            std::fs::create_dir_all(&dir)?;
            let ctx = TaskContext { out_dir: dir.clone(), quick, threads };
            eprintln!("tour: {}/{} ...", krate.crate_name, entry.name);
            let t = Instant::now();
            let result = (entry.run)(&ctx);
            let wall = t.elapsed().as_secs_f64();
            md.push_str(&format!("## {} / {}\n\n{}\n\n", krate.crate_name, entry.name, entry.about));
            match result {
                Ok(outcome) => {
                    md.push_str(&relink(&outcome.markdown, &dir, &out));
                    md.push_str("\n\n");
                    let files = outcome
                        .files
                        .iter()
                        .map(|f| f.strip_prefix(&out).map(|p| p.to_path_buf()).unwrap_or_else(|_| f.clone()))
                        .collect();
                    summary.push(SummaryEntry {
                        krate: krate.crate_name.into(),
                        entry: entry.name.into(),
                        ok: true,
                        error_message: None,
                        wall_seconds: wall,
                        rows: outcome.rows,
                        files,
                    });
                }
                Err(e) => {
                    md.push_str(&format!("**FAILED**: {e}\n\n"));
                    summary.push(SummaryEntry {
                        krate: krate.crate_name.into(),
                        entry: entry.name.into(),
                        ok: false,
                        error_message: Some(e.to_string()),
                        wall_seconds: wall,
                        rows: vec![],
                        files: vec![],
                    });
                }
            }
        }
    }
    let total = started.elapsed().as_secs_f64();
    md.push_str(&format!("Total wall time: {total:.1} s.\n"));
    pbdl_core::io::write_atomic(out.join("report.md"), |w| w.write_all(md.as_bytes()))?;
    let json = serde_json::to_string_pretty(
        &serde_json::json!({ "total_seconds": total, "threads": threads, "entries": summary }),
    )?;
    pbdl_core::io::write_atomic(out.join("summary.json"), |w| w.write_all(json.as_bytes()))?;

    let mut rows = Vec::new();
    for s in &summary {
        if !s.ok {
            rows.push(vec![
                format!("{}/{}", s.krate, s.entry),
                "FAILED".into(),
                "-".into(),
                "-".into(),
                s.error_message.clone().unwrap_or_default(),
            ]);
        }
        for r in &s.rows {
            rows.push(vec![
                format!("{}/{}: {}", s.krate, s.entry, r.item),
                xtask::bench_schema::format_seconds(r.seconds),
                report::fmt_error(r.error),
                r.error_kind.clone(),
                r.note.clone(),
            ]);
        }
    }
    println!();
    report::print_table(&["item", "time", "error", "error kind", "note"], &rows);
    println!("\ntour: {:.1} s; report in {}", total, out.join("report.md").display());
    let failed: Vec<String> = summary.iter().filter(|s| !s.ok).map(|s| format!("{}/{}", s.krate, s.entry)).collect();
    anyhow::ensure!(failed.is_empty(), "tour entries failed: {}", failed.join(", "));
    Ok(())
}

use std::io::Write as _;

/// Rewrites the markdown links of one entry so that they work from `report.md` in `out`: an
/// entry links its files by absolute path or relative to its own folder `entry_dir`; the report
/// links them relative to `out`, so that the folder can be moved, zipped or shared. Links to
/// web pages (`scheme://...`) and anchors stay as they are.
fn relink(markdown: &str, entry_dir: &Path, out: &Path) -> String {
    let mut result = String::with_capacity(markdown.len());
    let mut rest = markdown;
    while let Some(at) = rest.find("](") {
        let (head, tail) = rest.split_at(at + 2);
        result.push_str(head);
        let Some(end) = tail.find(')') else {
            rest = tail;
            break;
        };
        let target = &tail[..end];
        let linked = if target.contains("://") || target.starts_with('#') || target.is_empty() {
            target.to_string()
        } else {
            let path = Path::new(target);
            let full = if path.is_absolute() { path.to_path_buf() } else { entry_dir.join(path) };
            match full.strip_prefix(out) {
                Ok(rel) => rel.to_string_lossy().replace(std::path::MAIN_SEPARATOR, "/"),
                // A file outside the report's folder: an absolute link is all that can work.
                Err(_) => full.display().to_string(),
            }
        };
        result.push_str(&linked);
        rest = &tail[end..];
    }
    result.push_str(rest);
    result
}

#[cfg(test)]
mod tests {
    use super::relink;
    use std::path::Path;

    #[test]
    fn report_links_are_relative_to_the_report() {
        let out = Path::new("/tmp/pbdl/tour");
        let entry = out.join("grid/cavity");
        let md = "see ![a](/tmp/pbdl/tour/grid/cavity/a.png) and ![b](b.gif), [web](https://x.org/y) [top](#t)";
        assert_eq!(
            relink(md, &entry, out),
            "see ![a](grid/cavity/a.png) and ![b](grid/cavity/b.gif), [web](https://x.org/y) [top](#t)"
        );
        // Text without links, and an unclosed link, pass through unchanged.
        assert_eq!(relink("no links (here)", &entry, out), "no links (here)");
        assert_eq!(relink("broken ](x", &entry, out), "broken ](x");
    }
}
