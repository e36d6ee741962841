//! `cargo xtask ci`: what CI checks, runnable locally.

use std::process::Command;

fn step(name: &str, args: &[&str]) -> anyhow::Result<()> {
    println!("==> cargo {}", args.join(" "));
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into())).args(args).status()?;
    anyhow::ensure!(status.success(), "{name} failed ({status})");
    Ok(())
}

/// Runs the format check, clippy with `-D warnings` and the test suite.
pub fn run() -> anyhow::Result<()> {
    step("format check", &["fmt", "--all", "--check"])?;
    step("clippy", &["clippy", "--workspace", "--all-targets", "--", "-D", "warnings"])?;
    step("tests", &["test", "--workspace"])?;
    println!("ci: all steps passed");
    Ok(())
}
