//! Fuzz smoke test: every target of `xtask::fuzz` runs for a few seconds from the committed seed
//! corpus (`fuzz/corpus/`) and must show no panic, no hang and no input over its memory
//! allowance. The long campaign is `cargo xtask stress fuzz`.
//!
//! This binary installs the counting allocator, so memory is measured. Allocation is counted
//! process-wide: the other tests here are small (kilobytes) next to the 64 MiB allowance.

use std::time::{Duration, Instant};
use xtask::fuzz;

#[global_allocator]
static GLOBAL: fuzz::CountingAlloc<mimalloc::MiMalloc> = fuzz::CountingAlloc(mimalloc::MiMalloc);

/// Seconds per target: 8 targets, about 60 s in all (`PBDL_FUZZ_SECONDS` overrides).
const SECONDS_PER_TARGET: f64 = 7.0;

#[test]
fn every_target_survives_a_short_campaign() {
    assert!(fuzz::counting_allocator_installed(), "the counting allocator must be the global allocator");
    let seconds = std::env::var("PBDL_FUZZ_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(SECONDS_PER_TARGET);
    let crash_dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"))
        .join("pbdl/fuzz/crashes");
    let opts = fuzz::FuzzOptions { seconds, seed: 1, time_limit: Duration::from_secs(5), crash_dir: Some(crash_dir) };
    let started = Instant::now();
    let mut failures = Vec::new();
    for t in fuzz::targets() {
        let corpus = fuzz::load_corpus(&fuzz::corpus_dir(), t.name).unwrap();
        let r = fuzz::fuzz_target(&t, &corpus, &opts).unwrap();
        eprintln!(
            "fuzz {:<16} {:>7} inputs ({} seeds) in {:.1} s, {:.0}/s; panics {}, hangs {}, over-memory {}, max peak {:.1} MiB",
            r.target,
            r.inputs,
            r.corpus_inputs,
            r.seconds,
            r.inputs_per_s,
            r.panics,
            r.hangs,
            r.over_memory,
            r.max_peak_bytes as f64 / 1048576.0
        );
        assert!(r.memory_measured);
        // A campaign that ran only its seeds would prove nothing about damaged inputs.
        assert!(r.inputs as usize > 10 * r.corpus_inputs, "{}: only {} inputs", r.target, r.inputs);
        for f in &r.findings {
            failures
                .push(format!("{} {:?}: {} ({} bytes, saved {:?})", r.target, f.kind, f.message, f.input_len, f.saved));
        }
    }
    eprintln!("fuzz smoke: {:.1} s in all", started.elapsed().as_secs_f64());
    assert!(failures.is_empty(), "fuzzing found:\n{}", failures.join("\n"));
}

/// The engine is deterministic: the same seed gives the same mutants.
#[test]
fn mutations_are_seeded() {
    let seed_input = b"[grid]\nnx = 64\nlx = 1.0\n".to_vec();
    let run = |seed| {
        let mut m = fuzz::Mutator::new(seed, true);
        (0..50).map(|_| m.mutate(&seed_input, b"other")).collect::<Vec<_>>()
    };
    assert_eq!(run(3), run(3));
    assert_ne!(run(3), run(4));
    assert!(run(3).iter().any(|v| v != &seed_input));
}

/// The seeds are valid files: fuzzing starts from inputs the loaders accept, so mutants reach
/// past the first format check.
#[test]
fn seed_corpus_files_are_valid() {
    use pbdl_core::io::{load_checkpoint, read_npy, read_npz};
    let dir = fuzz::corpus_dir();
    let tmp = tempfile::tempdir().unwrap();
    let mut total = 0u64;
    for t in fuzz::targets() {
        let mut paths: Vec<_> = std::fs::read_dir(dir.join(t.name)).unwrap().map(|e| e.unwrap().path()).collect();
        paths.sort();
        assert!(!paths.is_empty(), "{}: no seeds", t.name);
        for p in paths {
            let bytes = std::fs::read(&p).unwrap();
            total += bytes.len() as u64;
            assert!(bytes.len() < 20_000, "{}: seeds stay small", p.display());
            let what = p.display().to_string();
            match t.name {
                "npy" => drop(read_npy(&p).expect(&what)),
                "npz" => drop(read_npz(&p).expect(&what)),
                "checkpoint" => {
                    let (w, j) = fuzz::split_checkpoint_input(&bytes);
                    let ck = tmp.path().join("ck");
                    std::fs::write(tmp.path().join("ck.safetensors"), w).unwrap();
                    std::fs::write(tmp.path().join("ck.json"), j).unwrap();
                    let (tensors, info) = load_checkpoint(&ck, &candle_core::Device::Cpu).expect(&what);
                    assert_eq!((tensors.len(), info.step), (2, 100));
                }
                "grid_scene" => drop(
                    pbdl_grid::scene::Scene::from_toml_str(std::str::from_utf8(&bytes).unwrap(), &what).expect(&what),
                ),
                "particles_scene" => drop(
                    pbdl_particles::scene::Scene::from_toml_str(std::str::from_utf8(&bytes).unwrap(), &what)
                        .expect(&what),
                ),
                "legacy_pth" => {
                    let c = pbdl_metrics::convert::convert_checkpoint(&bytes, &p).expect(&what);
                    assert_eq!(c.tensors.len(), 4, "lin.weight, lin.bias, norm.mean.0, norm.m2.0");
                }
                "grid_init" => {
                    let arrays = read_npz(&p).expect(&what);
                    let mut sim =
                        pbdl_grid::scene::Scene::builtin(what.rsplit('/').next().unwrap().rsplit_once('_').unwrap().0)
                            .unwrap()
                            .with_resolution(8)
                            .build()
                            .unwrap();
                    sim.set_fields(&arrays).expect(&what);
                }
                "particles_init" => {
                    let init = pbdl_particles::scene::InitState::from_arrays(&read_npz(&p).expect(&what)).expect(&what);
                    assert!(!init.is_empty());
                }
                other => panic!("no check for target {other}"),
            }
        }
    }
    assert!(total < 300_000, "the corpus holds {total} bytes");
}
