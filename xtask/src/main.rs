//! `cargo xtask`: pbdl's task runner.
//!
//! * `tour`: runs every available method on its embedded default scene and writes
//!   `target/pbdl/tour/` (`report.md`, PNG/GIF files, `summary.json`), printing a table of time
//!   and error. This is the main job.
//! * `bench [crate]`: time against error in the shared schema, `target/pbdl/bench/<crate>.json`
//!   plus a markdown table and a PNG plot.
//! * `stress [crate]`: long and extreme runs; reports the first step at which an invariant breaks.
//! * `ci`: format check, clippy with `-D warnings`, the test suite.

mod bench;
mod ci;
mod registry;
mod report;
mod stress;
mod tour;

use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "cargo xtask", about = "pbdl's task runner: tour, bench, stress, ci")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run every method on its embedded default scene; write target/pbdl/tour/.
    Tour {
        /// Smaller sizes and fewer repetitions.
        #[arg(long)]
        quick: bool,
        /// Output directory (default: target/pbdl/tour).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Measure time against error; write target/pbdl/bench/<crate>.{json,md,png}.
    Bench {
        /// Only this crate (core, grid, ...); all when omitted.
        krate: Option<String>,
        /// Smaller sizes and fewer repetitions.
        #[arg(long)]
        quick: bool,
    },
    /// Long and extreme runs; exits non-zero when an invariant breaks.
    Stress {
        /// Only this crate; all when omitted.
        krate: Option<String>,
        /// Smaller sizes and fewer steps.
        #[arg(long)]
        quick: bool,
    },
    /// fmt check, clippy -D warnings, tests.
    Ci,
    /// List the registered tour, bench and stress entries.
    List,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Tour { quick, out } => tour::run(quick, out.unwrap_or_else(|| report::target_dir().join("tour"))),
        Command::Bench { krate, quick } => bench::run(krate.as_deref(), quick),
        Command::Stress { krate, quick } => stress::run(krate.as_deref(), quick),
        Command::Ci => ci::run(),
        Command::List => {
            registry::print_list();
            Ok(())
        }
    }
}
