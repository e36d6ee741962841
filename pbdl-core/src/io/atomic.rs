//! Atomic file writes: a reader sees the old file or the new one, never half of either.
//!
//! The data goes to a hidden temporary file in the target's own directory
//! (`.<name>.<pid>.<n>.tmp`), is flushed and `fsync`ed, and is then renamed over the target.
//! A rename within one directory is atomic on POSIX file systems and on NTFS, so an error, a
//! panic or a crash part-way leaves the old file untouched. On an error or a panic the
//! temporary file is removed; only a killed process can leave one behind, and readers in
//! pbdl ignore hidden `.tmp` files (see [`is_temp_file`]).
//!
//! For kill -9 tests, [`CRASH_HOLD_ENV`] makes one chosen write stop for good between its
//! complete temporary file and the rename, so that a test can kill the process exactly there
//! (see [`crate::train::crash`]).

use crate::error::{Error, Result};
use std::fs::{self, File, OpenOptions};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temporary files of concurrent writers within one process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Test hook for kill -9 tests: `<n>:<marker path>` makes the `n`-th atomic write of the
/// process (counted from 0, across all files) stop after its temporary file is complete and
/// synced, create the marker file, and wait there until the process is killed. Unset (the
/// normal case) it costs one environment lookup per write.
pub const CRASH_HOLD_ENV: &str = "PBDL_CRASH_TEST_HOLD";

/// Atomic writes committed (or about to be) so far, for [`CRASH_HOLD_ENV`].
static COMMITS: AtomicU64 = AtomicU64::new(0);

/// Writes `path` atomically: `write` fills a buffered writer on a temporary file, which then
/// replaces `path` in one rename.
///
/// If `write` returns an error or panics, the temporary file is deleted and `path` keeps its
/// old content (or stays absent). The parent directory must exist.
///
/// ```
/// use std::io::Write;
/// # fn main() -> pbdl_core::Result<()> {
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("notes.txt");
/// pbdl_core::io::write_atomic(&path, |w| w.write_all(b"first"))?;
/// // A failing writer leaves the previous content in place.
/// let failed = pbdl_core::io::write_atomic(&path, |w| {
///     w.write_all(b"half of the sec")?;
///     Err(std::io::Error::other("disk full"))
/// });
/// assert!(failed.is_err());
/// assert_eq!(std::fs::read(&path).unwrap(), b"first");
/// # Ok(())
/// # }
/// ```
pub fn write_atomic<F>(path: impl AsRef<Path>, write: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    let path = path.as_ref();
    let (tmp, file) = create_temp(path)?;
    let guard = TempGuard(Some(tmp));
    let mut w = BufWriter::new(file);
    write(&mut w).map_err(|e| Error::io(path, e))?;
    let file = w.into_inner().map_err(|e| Error::io(path, e.into_error()))?;
    commit(path, file, guard)
}

/// Like [`write_atomic`], for writers that insist on a file name: `write` receives the path of
/// the temporary file (already created, empty) and must write the whole content there.
///
/// ```
/// # fn main() -> pbdl_core::Result<()> {
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("data.bin");
/// pbdl_core::io::write_atomic_path(&path, |tmp| {
///     std::fs::write(tmp, [1u8, 2, 3]).map_err(|e| pbdl_core::Error::io(tmp, e))
/// })?;
/// assert_eq!(std::fs::read(&path).unwrap(), [1, 2, 3]);
/// # Ok(())
/// # }
/// ```
pub fn write_atomic_path<F>(path: impl AsRef<Path>, write: F) -> Result<()>
where
    F: FnOnce(&Path) -> Result<()>,
{
    let path = path.as_ref();
    let (tmp, file) = create_temp(path)?;
    // The writer reopens the file by name; ours is closed so that it works on Windows too.
    drop(file);
    let guard = TempGuard(Some(tmp));
    write(guard.path())?;
    let file = OpenOptions::new().write(true).open(guard.path()).map_err(|e| Error::io(guard.path(), e))?;
    commit(path, file, guard)
}

/// Whether `path` looks like a temporary file of [`write_atomic`] (hidden, ending in `.tmp`).
///
/// Such a file is left behind only when a process is killed during a write; it is never a
/// complete file and can be deleted once no writer runs.
pub fn is_temp_file(path: impl AsRef<Path>) -> bool {
    path.as_ref().file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with('.') && n.ends_with(".tmp"))
}

/// Removes the temporary file on drop unless the write was committed.
struct TempGuard(Option<PathBuf>);

impl TempGuard {
    fn path(&self) -> &Path {
        self.0.as_deref().expect("temporary path is present until commit")
    }
}

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            // Best effort: the write already failed, and this error would hide the first one.
            let _ = fs::remove_file(p);
        }
    }
}

fn create_temp(path: &Path) -> Result<(PathBuf, File)> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| Error::invalid("write_atomic", "path", format!("{} has no UTF-8 file name", path.display())))?;
    let dir = parent_dir(path);
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
        // `create_new` so that a stale file of a killed process with our pid is never reused.
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(Error::io(path, e)),
        }
    }
}

fn commit(path: &Path, file: File, mut guard: TempGuard) -> Result<()> {
    // Data must be on disk before the rename makes it visible, or a power cut could expose an
    // empty file under the final name.
    file.sync_all().map_err(|e| Error::io(path, e))?;
    drop(file);
    crash_test_hold(path);
    let tmp = guard.0.take().expect("temporary path is present until commit");
    if let Err(e) = fs::rename(&tmp, path) {
        let _ = fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    sync_dir(&parent_dir(path));
    Ok(())
}

/// Atomic writes this process has committed (or is committing) so far: what a kill -9 test
/// picks the write to interrupt from ([`CRASH_HOLD_ENV`]).
pub fn atomic_write_count() -> u64 {
    COMMITS.load(Ordering::Relaxed)
}

/// Where [`CRASH_HOLD_ENV`] names this write, announce it and wait to be killed.
fn crash_test_hold(path: &Path) {
    let n = COMMITS.fetch_add(1, Ordering::Relaxed);
    let Some(spec) = std::env::var_os(CRASH_HOLD_ENV) else { return };
    let spec = spec.to_string_lossy();
    let Some((at, marker)) = spec.split_once(':') else { return };
    if at.parse::<u64>().ok() != Some(n) {
        return;
    }
    // The marker appears only after the temporary file is complete: the test kills after it.
    // Written under another name and renamed, so that the test never reads it half-written.
    let part = format!("{marker}.part");
    if fs::write(&part, path.display().to_string()).is_ok() && fs::rename(&part, marker).is_ok() {
        loop {
            std::thread::sleep(std::time::Duration::from_secs(1));
        }
    }
}

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Makes the rename itself durable. Not every platform can open a directory, so failures are
/// ignored: the file content is already safe, only the rename might be replayed.
fn sync_dir(dir: &Path) {
    #[cfg(unix)]
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    #[cfg(not(unix))]
    let _ = dir;
}
