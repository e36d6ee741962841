//! Shared helpers for xtask's outputs: where they go, how tables print.

use std::path::PathBuf;

/// `target/pbdl` of the workspace (or of `CARGO_TARGET_DIR`).
pub fn target_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
        root.canonicalize().unwrap_or(root).join("target")
    });
    target.join("pbdl")
}

/// Formats an optional error for a table.
pub fn fmt_error(e: Option<f64>) -> String {
    e.map(|e| format!("{e:.3e}")).unwrap_or_else(|| "-".into())
}

/// Prints rows as an aligned plain-text table.
pub fn print_table(header: &[&str], rows: &[Vec<String>]) {
    let mut width: Vec<usize> = header.iter().map(|h| h.len()).collect();
    for r in rows {
        for (w, c) in width.iter_mut().zip(r) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: Vec<String>| {
        let parts: Vec<String> = cells.iter().zip(&width).map(|(c, w)| format!("{c:<w$}")).collect();
        println!("{}", parts.join("  ").trim_end());
    };
    line(header.iter().map(|s| s.to_string()).collect());
    line(width.iter().map(|w| "-".repeat(*w)).collect());
    for r in rows {
        line(r.clone());
    }
}
