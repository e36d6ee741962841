//! Keeping freed memory in the process under glibc's `malloc`, so that a training step does
//! not pay page faults for every tensor.
//!
//! candle allocates every op's output afresh. glibc serves blocks of 128 KiB and more with
//! `mmap` and returns them to the OS on `free` (and trims the heap top above 128 KiB), so the
//! next step's buffers come back as fresh pages that the kernel must zero on first touch.
//! Measured on the 2-core development machine with glibc's defaults against raised
//! thresholds (`cargo bench -p pbdl-core --bench conv_implicit`, glibc): a conv 64 -> 64
//! forward + backward at 4 x 64 x 32 x 32 15.1 vs 8.2 ms, 128 -> 128 at 4 x 128 x 32 x 64 81 vs
//! 47 ms; an LSTM step (batch 16, hidden 1024) 200 vs 100 ms. [`keep_freed_memory`] raises both
//! thresholds; [`crate::threads::init`] and [`crate::threads::init_with`] call it (library code
//! that only links pbdl does not). Binaries with another global allocator (mimalloc, as
//! `cargo xtask` uses) are unaffected: glibc's `malloc` then serves only what bypasses the Rust
//! allocator.
//!
//! The price is resident memory: the heap keeps its high-water mark instead of shrinking after
//! a large step. `PBDL_TUNE_MALLOC=0` leaves glibc's settings alone.

/// Environment variable: `0` turns [`keep_freed_memory`] off.
pub const TUNE_MALLOC_ENV: &str = "PBDL_TUNE_MALLOC";

/// Blocks from this size on are still `mmap`ed (glibc's upper limit for the threshold on
/// 64-bit targets, 32 MiB).
const MMAP_THRESHOLD: usize = 32 << 20;
/// Free memory at the heap top beyond this is returned to the OS.
const TRIM_THRESHOLD: usize = 1 << 30;

/// Raises glibc's `mmap` threshold to 32 MiB and its trim threshold to 1 GiB (unless
/// `PBDL_TUNE_MALLOC=0`); returns whether the settings were changed. Does nothing, and returns
/// `false`, on targets without glibc.
///
/// ```
/// // Either tuned (Linux with glibc) or a no-op elsewhere; safe to call more than once.
/// let _tuned: bool = pbdl_core::malloc::keep_freed_memory();
/// ```
pub fn keep_freed_memory() -> bool {
    if std::env::var(TUNE_MALLOC_ENV).is_ok_and(|v| v.trim() == "0") {
        return false;
    }
    tune()
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn tune() -> bool {
    // SAFETY: mallopt only changes allocator parameters; both values are in glibc's documented
    // ranges (it returns 0 and changes nothing otherwise).
    let (mmap, trim) = unsafe {
        (
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD as libc::c_int),
            libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD as libc::c_int),
        )
    };
    mmap == 1 && trim == 1
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn tune() -> bool {
    let _ = (MMAP_THRESHOLD, TRIM_THRESHOLD);
    false
}
