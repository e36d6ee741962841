//! `pbdl_core::malloc::keep_freed_memory`: tunes glibc (Linux/gnu) unless switched off. One test
//! in its own binary, because it changes the environment.

#[test]
fn tunes_glibc_unless_switched_off() {
    std::env::set_var(pbdl_core::malloc::TUNE_MALLOC_ENV, "0");
    assert!(!pbdl_core::malloc::keep_freed_memory(), "PBDL_TUNE_MALLOC=0 must leave malloc alone");
    std::env::remove_var(pbdl_core::malloc::TUNE_MALLOC_ENV);
    let tuned = pbdl_core::malloc::keep_freed_memory();
    assert_eq!(tuned, cfg!(all(target_os = "linux", target_env = "gnu")), "glibc accepts both thresholds");
}
