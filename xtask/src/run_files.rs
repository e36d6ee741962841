//! Files of a run directory that every `cargo xtask <method> train|eval` command writes: JSON
//! settings and results, written atomically (a crash leaves the old file or the new one, never
//! half of one), and read back with an error that names the file.

use anyhow::Context;
use std::path::Path;

/// Writes `value` as pretty JSON with a trailing newline to `path`, atomically, creating the
/// parent directory if needed.
pub fn write_json(path: impl AsRef<Path>, value: &impl serde::Serialize) -> anyhow::Result<()> {
    write_text(path, &(serde_json::to_string_pretty(value)? + "\n"))
}

/// Writes `text` to `path` atomically, creating the parent directory if needed.
pub fn write_text(path: impl AsRef<Path>, text: &str) -> anyhow::Result<()> {
    let path = path.as_ref();
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    pbdl_core::io::write_atomic(path, |w| std::io::Write::write_all(w, text.as_bytes()))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Reads `name` from the run directory `run` as JSON; `what` says which command makes such
/// directories (for the error when the file is missing).
pub fn read_json<T: serde::de::DeserializeOwned>(run: &Path, name: &str, what: &str) -> anyhow::Result<T> {
    let path = run.join(name);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("{}: not a `{what}` run directory (no {name})", run.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not valid JSON for this command", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip_and_missing_file_named() {
        let dir = std::env::temp_dir().join(format!("pbdl_run_files_{}", std::process::id()));
        let value = serde_json::json!({"seed": 3, "name": "x"});
        write_json(dir.join("sub").join("a.json"), &value).unwrap();
        let text = std::fs::read_to_string(dir.join("sub").join("a.json")).unwrap();
        assert!(text.ends_with("}\n"));
        let back: serde_json::Value = read_json(&dir.join("sub"), "a.json", "demo train").unwrap();
        assert_eq!(back, value);
        let err = read_json::<serde_json::Value>(&dir, "missing.json", "demo train").unwrap_err();
        assert!(format!("{err:#}").contains("no missing.json"), "{err:#}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
