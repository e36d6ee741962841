//! Acceptance runs: the `#[ignore]`d tests whose numbers the README quotes, run as child
//! processes by the stress entry `acceptance` of each crate (`cargo xtask stress <crate> --entry
//! acceptance`).
//!
//! Each test runs as `cargo test --release -p <package> --test <file> -- --ignored --exact <test>
//! --nocapture` from the workspace root (`$CARGO` if set, else `cargo`). Its output is echoed to
//! stderr and kept in `<out_dir>/acceptance_<test>.log`. Every such test prints one line
//! `ACCEPTANCE: <name> measured=<values> bar=<bar>` next to its assertion; the check's detail is
//! the measured values read from that line. A check passes only if cargo exited with success
//! *and* reported at least one passed test (an `--exact` name that matches nothing runs zero
//! tests and still exits 0).

use crate::registry::{StressCheck, TaskContext, TaskResult};
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Tests expected to take at most this many minutes run in `--quick` mode; longer ones only in
/// the full mode.
pub const QUICK_MINUTES: f64 = 5.0;

/// The prefix of the line an acceptance test prints.
pub const LINE_PREFIX: &str = "ACCEPTANCE: ";

/// One `#[ignore]`d test behind a README claim.
#[derive(Clone, Debug)]
pub struct AcceptanceTest {
    /// Cargo package, e.g. `"pbdl-grid"`.
    pub package: &'static str,
    /// Integration-test target (the file name under `tests/` without `.rs`), e.g. `"cavity"`.
    pub file: &'static str,
    /// The test function's name (matched with `--exact`).
    pub test: &'static str,
    /// The README claim and the bar the test asserts; becomes the check's invariant.
    pub claim: &'static str,
    /// Expected wall-clock minutes in release on 2 cores (decides what `--quick` runs).
    pub minutes: f64,
    /// Environment variables the README's numbers were measured with.
    pub env: &'static [(&'static str, &'static str)],
}

/// One parsed `ACCEPTANCE:` line.
#[derive(Clone, Debug, PartialEq)]
pub struct AcceptanceLine {
    /// The name the test printed.
    pub name: String,
    /// The measured value(s), as printed.
    pub measured: String,
    /// The bar, as printed.
    pub bar: String,
}

/// The workspace root (the parent of the `xtask` crate).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Parses one output line; `None` unless it is an `ACCEPTANCE:` line with `measured=` and
/// `bar=` (in that order). Leading whitespace is allowed.
pub fn parse_line(line: &str) -> Option<AcceptanceLine> {
    let rest = line.trim_start().strip_prefix(LINE_PREFIX)?;
    let (name, rest) = rest.split_once(" measured=")?;
    let (measured, bar) = rest.rsplit_once(" bar=")?;
    Some(AcceptanceLine { name: name.trim().into(), measured: measured.trim().into(), bar: bar.trim().into() })
}

/// The number of passed tests in libtest's `test result:` lines of `output` (summed).
pub fn passed_count(output: &str) -> usize {
    output
        .lines()
        .filter_map(|l| l.trim().strip_prefix("test result: "))
        .filter_map(|r| r.split(';').find_map(|p| p.trim().strip_suffix(" passed")))
        .filter_map(|n| n.rsplit(' ').next()?.parse::<usize>().ok())
        .sum()
}

/// The check for one finished test: `success` is cargo's exit status, `output` its stdout and
/// stderr. Passed = cargo succeeded and at least one test passed; the detail lists the measured
/// values of every `ACCEPTANCE:` line, or says why there are none.
pub fn check_from_output(t: &AcceptanceTest, success: bool, output: &str, minutes: f64) -> StressCheck {
    let lines: Vec<AcceptanceLine> = output.lines().filter_map(parse_line).collect();
    let passed_tests = passed_count(output);
    let passed = success && passed_tests >= 1;
    let mut detail = if lines.is_empty() {
        "no ACCEPTANCE line printed".to_string()
    } else {
        lines
            .iter()
            .map(|l| format!("{}: measured {} (bar {})", l.name, l.measured, l.bar))
            .collect::<Vec<_>>()
            .join("; ")
    };
    if !passed {
        // Why it failed: the panic message (the line after "panicked at"), or cargo's last error.
        let all: Vec<&str> = output.lines().collect();
        let why = all
            .iter()
            .position(|l| l.contains("panicked at"))
            .and_then(|i| all.get(i + 1))
            .map(|l| l.trim().to_string())
            .or_else(|| all.iter().rev().find(|l| l.starts_with("error")).map(|l| l.trim().to_string()))
            .unwrap_or_else(|| if success { "no test ran (name not found?)".into() } else { "cargo failed".into() });
        detail = format!("{detail}; FAILED: {why}");
    }
    StressCheck {
        invariant: format!("{} ({}::{})", t.claim, t.file, t.test),
        passed,
        first_broken_step: None,
        detail: format!("{detail}; {minutes:.1} min"),
        measure: None,
    }
}

/// Runs one test as a child process, echoing its output to stderr and saving it to
/// `out_dir/acceptance_<test>.log`; returns (exit success, stdout + stderr).
pub fn run_one(t: &AcceptanceTest, out_dir: &Path) -> TaskResult<(bool, String)> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut child = Command::new(cargo)
        .current_dir(workspace_root())
        .args(["test", "--release", "-p", t.package, "--test", t.file, "--", "--ignored", "--exact", t.test])
        .arg("--nocapture")
        .envs(t.env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()?;
    // Both pipes are drained at once (one thread each) so neither can fill and block the child.
    let echo = |r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut kept = String::new();
            for line in BufReader::new(r).lines().map_while(Result::ok) {
                eprintln!("  | {line}");
                kept.push_str(&line);
                kept.push('\n');
            }
            kept
        })
    };
    let out = echo(Box::new(child.stdout.take().ok_or("no stdout pipe")?));
    let err = echo(Box::new(child.stderr.take().ok_or("no stderr pipe")?));
    let status = child.wait()?;
    let text = format!(
        "{}{}",
        out.join().map_err(|_| "stdout reader panicked")?,
        err.join().map_err(|_| "stderr reader panicked")?
    );
    std::fs::write(out_dir.join(format!("acceptance_{}.log", t.test)), &text)?;
    Ok((status.success(), text))
}

/// Runs `tests` (in `--quick` mode only those expected within [`QUICK_MINUTES`]; the others are
/// left out, since a check cannot say "skipped", and a line names them) and returns one check
/// per test run.
pub fn run_tests(ctx: &TaskContext, tests: &[AcceptanceTest]) -> TaskResult<Vec<StressCheck>> {
    let (run, left_out): (Vec<&AcceptanceTest>, Vec<&AcceptanceTest>) =
        tests.iter().partition(|t| !ctx.quick || t.minutes <= QUICK_MINUTES);
    if !left_out.is_empty() {
        let names: Vec<String> =
            left_out.iter().map(|t| format!("{}::{} (~{} min)", t.file, t.test, t.minutes)).collect();
        println!("acceptance --quick: left out (not run, not passed): {}", names.join(", "));
    }
    let mut checks = Vec::new();
    for t in run {
        eprintln!("acceptance: {} {}::{} (expected ~{} min) ...", t.package, t.file, t.test, t.minutes);
        let start = std::time::Instant::now();
        let (success, output) = run_one(t, &ctx.out_dir)?;
        let check = check_from_output(t, success, &output, start.elapsed().as_secs_f64() / 60.0);
        eprintln!("acceptance: {} -> {}: {}", t.test, if check.passed { "passed" } else { "FAILED" }, check.detail);
        checks.push(check);
    }
    Ok(checks)
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: AcceptanceTest = AcceptanceTest {
        package: "pbdl-grid",
        file: "cavity",
        test: "cavity_re1000_128_matches_ghia_within_003",
        claim: "cavity Re 1000 at 128^2: max |u,v - Ghia| <= 0.03",
        minutes: 1.5,
        env: &[],
    };

    #[test]
    fn parses_the_acceptance_line() {
        let l = parse_line("  ACCEPTANCE: cavity_re1000 measured=u 0.0032, v 0.0118 bar=<= 0.03").unwrap();
        assert_eq!(l.name, "cavity_re1000");
        assert_eq!(l.measured, "u 0.0032, v 0.0118");
        assert_eq!(l.bar, "<= 0.03");
        assert!(parse_line("cavity Re1000 128^2: max |u - Ghia| 0.0032").is_none());
        assert!(parse_line("ACCEPTANCE: x measured=1").is_none(), "no bar");
    }

    #[test]
    fn counts_passed_tests() {
        assert_eq!(passed_count("test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 5 filtered out"), 1);
        assert_eq!(passed_count("test result: ok. 0 passed; 0 failed; 1 ignored"), 0);
        assert_eq!(passed_count("running 1 test\n"), 0);
    }

    #[test]
    fn verdict_follows_the_exit_status_and_the_passed_count() {
        let ok = "running 1 test\nACCEPTANCE: cavity measured=0.0118 bar=<= 0.03\ntest x ... ok\n\n\
                  test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 4 filtered out; finished in 81s\n";
        let c = check_from_output(&T, true, ok, 1.4);
        assert!(c.passed);
        assert!(c.detail.contains("measured 0.0118 (bar <= 0.03)"), "{}", c.detail);
        assert!(c.invariant.contains("<= 0.03") && c.invariant.contains("cavity::cavity_re1000"));

        let failed = "ACCEPTANCE: cavity measured=0.04 bar=<= 0.03\n\
                      thread 'x' panicked at tests/cavity.rs:109:5:\n128^2: u error 0.0300, v error 0.0400\n\
                      test result: FAILED. 0 passed; 1 failed; 0 ignored\n";
        let c = check_from_output(&T, false, failed, 1.4);
        assert!(!c.passed);
        assert!(c.detail.contains("measured 0.04") && c.detail.contains("FAILED: 128^2: u error"), "{}", c.detail);

        // Exit 0 with no test run (misspelt name under --exact) is not a pass.
        let none = "running 0 tests\n\ntest result: ok. 0 passed; 0 failed; 0 ignored; 0 measured; 5 filtered out\n";
        let c = check_from_output(&T, true, none, 0.1);
        assert!(!c.passed);
        assert!(c.detail.contains("no ACCEPTANCE line") && c.detail.contains("no test ran"), "{}", c.detail);

        let build = "error[E0425]: cannot find value `x`\nerror: could not compile `pbdl-grid`\n";
        let c = check_from_output(&T, false, build, 0.1);
        assert!(!c.passed && c.detail.contains("could not compile"), "{}", c.detail);
    }
}
