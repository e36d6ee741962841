//! `cargo xtask stress [crate]`: long and extreme runs, invariants checked; `cargo xtask stress
//! fuzz`: mutation fuzzing of the file readers ([`xtask::fuzz`]).

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
    for f in crate::stress_summary::write(&dir)? {
        println!("wrote {}", f.display());
    }
    anyhow::ensure!(broken.is_empty(), "invariants broke: {}", broken.join("; "));
    Ok(())
}

/// Options of `cargo xtask stress fuzz`.
#[derive(clap::Args, Debug, Default)]
pub struct FuzzArgs {
    /// Fuzz: only this target (npy, npz, checkpoint, grid_scene, particles_scene, legacy_pth,
    /// grid_init, particles_init).
    #[arg(long)]
    target: Option<String>,
    /// Fuzz: seconds per target (default 60, 5 with --quick).
    #[arg(long)]
    seconds: Option<f64>,
    /// Fuzz: seed of the mutation engine (default 0).
    #[arg(long)]
    seed: Option<u64>,
    /// Fuzz: per-input time limit in seconds before an input counts as a hang (default 2).
    #[arg(long)]
    time_limit: Option<f64>,
    /// Fuzz: run this one input file of --target (a saved finding) and print what it did.
    #[arg(long)]
    replay: Option<std::path::PathBuf>,
    /// Fuzz: regenerate the seed corpus fuzz/corpus/ with pbdl's writers, then stop.
    #[arg(long)]
    write_corpus: bool,
}

impl FuzzArgs {
    /// Whether no fuzz option was given.
    pub fn is_empty(&self) -> bool {
        self.target.is_none()
            && self.seconds.is_none()
            && self.seed.is_none()
            && self.time_limit.is_none()
            && self.replay.is_none()
            && !self.write_corpus
    }
}

/// `cargo xtask stress fuzz`: runs every target (or one) for its budget, writes
/// `target/pbdl/stress/fuzz.{json,md}`, saves findings under `target/pbdl/fuzz/crashes/`, and fails
/// if any input panicked, hung or went over its memory allowance.
pub fn fuzz(args: FuzzArgs, quick: bool) -> anyhow::Result<()> {
    use xtask::fuzz;
    let corpus = fuzz::corpus_dir();
    if args.write_corpus {
        let files = fuzz::write_corpus(&corpus)?;
        let bytes: u64 = files.iter().filter_map(|f| std::fs::metadata(f).ok()).map(|m| m.len()).sum();
        println!("wrote {} corpus files ({bytes} bytes) to {}", files.len(), corpus.display());
        return Ok(());
    }
    let all = fuzz::targets();
    let names: Vec<&str> = all.iter().map(|t| t.name).collect();
    if let Some(t) = &args.target {
        anyhow::ensure!(names.contains(&t.as_str()), "unknown fuzz target `{t}`; targets: {}", names.join(", "));
    }
    if let Some(file) = &args.replay {
        let name = args.target.as_deref().ok_or_else(|| anyhow::anyhow!("--replay needs --target"))?;
        let t = all.iter().find(|t| t.name == name).expect("checked above");
        let input = std::fs::read(file)?;
        let (panic, peak) = fuzz::replay(t, &input);
        println!(
            "{name}: {} bytes, peak allocation {peak} bytes (allowance {})",
            input.len(),
            fuzz::memory_limit(input.len())
        );
        anyhow::ensure!(panic.is_none(), "panicked: {}", panic.unwrap_or_default());
        return Ok(());
    }
    let seed = args.seed.unwrap_or(0);
    let opts = fuzz::FuzzOptions {
        seconds: args.seconds.unwrap_or(if quick { 5.0 } else { 60.0 }),
        seed,
        time_limit: std::time::Duration::from_secs_f64(args.time_limit.unwrap_or(2.0)),
        crash_dir: Some(report::target_dir().join("fuzz").join("crashes")),
    };
    let mut reports = Vec::new();
    for t in all.iter().filter(|t| args.target.as_ref().is_none_or(|n| n == t.name)) {
        eprintln!("fuzz: {} for {:.0} s ...", t.name, opts.seconds);
        let inputs = fuzz::load_corpus(&corpus, t.name)?;
        reports.push(fuzz::fuzz_target(t, &inputs, &opts)?);
    }
    let rows: Vec<Vec<String>> = reports
        .iter()
        .map(|r| {
            vec![
                r.target.clone(),
                r.inputs.to_string(),
                format!("{:.0}", r.inputs_per_s),
                r.panics.to_string(),
                r.hangs.to_string(),
                r.over_memory.to_string(),
                r.unique_crashes.to_string(),
            ]
        })
        .collect();
    report::print_table(&["target", "inputs", "inputs/s", "panics", "hangs", "over-memory", "unique"], &rows);
    for r in &reports {
        for f in &r.findings {
            println!("{} {:?}: {} ({} bytes, {:?})", r.target, f.kind, f.message, f.input_len, f.saved);
        }
    }
    let dir = report::target_dir().join("stress");
    std::fs::create_dir_all(&dir)?;
    let stem = match &args.target {
        Some(t) => format!("fuzz_{t}"),
        None => "fuzz".into(),
    };
    let json = serde_json::to_string_pretty(&reports)?;
    let md = fuzz::markdown(&reports, seed);
    for (ext, text) in [("json", json), ("md", md)] {
        let path = dir.join(format!("{stem}.{ext}"));
        pbdl_core::io::write_atomic(&path, |w| w.write_all(text.as_bytes()))?;
        println!("wrote {}", path.display());
    }
    for f in crate::stress_summary::write(&dir)? {
        println!("wrote {}", f.display());
    }
    let bad: Vec<String> = reports.iter().filter(|r| !r.clean()).map(|r| r.target.clone()).collect();
    anyhow::ensure!(bad.is_empty(), "fuzzing found panics, hangs or over-memory inputs in: {}", bad.join(", "));
    Ok(())
}
