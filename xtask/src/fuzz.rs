//! Mutation fuzzing of pbdl's file readers on stable Rust (`cargo xtask stress fuzz`).
//!
//! cargo-fuzz needs a nightly toolchain; this is a small equivalent without coverage feedback:
//! a seeded mutation engine ([`Mutator`]) turns the committed seed corpus (`fuzz/corpus/<target>/`,
//! small valid files written by pbdl's own writers, see [`write_corpus`]) into damaged inputs,
//! and each [`Target`] feeds them to a real public loader, ignoring its `Err` results. What counts
//! as a finding ([`FindingKind`]):
//!
//! * **panic**: the loader panicked (caught with `catch_unwind`, message and location kept);
//! * **hang**: one input ran longer than [`FuzzOptions::time_limit`] (inputs run on a worker
//!   thread; a hung worker is abandoned and the target stops);
//! * **over-memory**: the input's peak allocation exceeded `64 x input length + 64 MiB`, measured
//!   by [`CountingAlloc`], which the binary that fuzzes must install as its global allocator
//!   (the xtask binary and `tests/fuzz_smoke.rs` do; without it memory is reported as not measured).
//!
//! Each finding's input is saved as `<crash_dir>/<target>/<hash>.bin` (with a `.txt` holding the
//! message) after a quick minimisation, so that it can become a regression test.
//!
//! Limits: allocation is counted process-wide, so run one fuzz campaign per process; an abort
//! (stack overflow, failed allocation) ends the process rather than being caught.

use pbdl_core::stepper::Evolve;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::alloc::{GlobalAlloc, Layout};
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{mpsc, Mutex, OnceLock};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------
// Allocation counting
// ---------------------------------------------------------------------------------------------

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static INSTALLED: AtomicBool = AtomicBool::new(false);
/// Abandoned (hung) workers still running: while any is, their allocations would be charged to
/// the inputs being measured, so memory is not judged.
static ABANDONED_RUNNING: AtomicUsize = AtomicUsize::new(0);

/// A global allocator that forwards to `A` and counts the bytes live and their peak, so that
/// the fuzzer can flag inputs that make a reader allocate far more than the input's size.
///
/// ```ignore
/// #[global_allocator]
/// static GLOBAL: xtask::fuzz::CountingAlloc<mimalloc::MiMalloc> = xtask::fuzz::CountingAlloc(mimalloc::MiMalloc);
/// ```
pub struct CountingAlloc<A>(pub A);

fn grew(n: usize) {
    let now = CURRENT.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every call is forwarded unchanged to the wrapped allocator; the counters are atomics
// and never allocate.
unsafe impl<A: GlobalAlloc> GlobalAlloc for CountingAlloc<A> {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract is passed on as is.
        let p = unsafe { self.0.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
            if !INSTALLED.load(Ordering::Relaxed) {
                INSTALLED.store(true, Ordering::Relaxed);
            }
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as `alloc`.
        let p = unsafe { self.0.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as `alloc`.
        unsafe { self.0.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as `alloc`.
        let p = unsafe { self.0.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                CURRENT.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

/// Whether a [`CountingAlloc`] is the global allocator of this process (it has counted an
/// allocation).
pub fn counting_allocator_installed() -> bool {
    // Allocate once so that the flag is set even if nothing has been allocated yet.
    drop(std::hint::black_box(Box::new(0u64)));
    INSTALLED.load(Ordering::Relaxed)
}

/// The allowance of one input: `64 x its length + 64 MiB`.
pub fn memory_limit(input_len: usize) -> usize {
    input_len.saturating_mul(64).saturating_add(64 << 20)
}

// ---------------------------------------------------------------------------------------------
// Targets
// ---------------------------------------------------------------------------------------------

/// One fuzz target: a reader and how its inputs look.
pub struct Target {
    /// Short name (`--target`, corpus and crash folder).
    pub name: &'static str,
    /// What it feeds and to which loader.
    pub about: &'static str,
    /// Whether the inputs are text (TOML, JSON): token-level mutations are used more.
    pub text: bool,
    /// Runs one input; errors are ignored, only panics, hangs and memory count.
    pub run: fn(&[u8]),
}

/// Every target, in a fixed order.
pub fn targets() -> Vec<Target> {
    vec![
        Target { name: "npy", about: "pbdl_core::io::read_npy of a .npy file", text: false, run: target_npy },
        Target {
            name: "npz",
            about: "pbdl_core::io::read_npz and read_npz_array of a .npz archive",
            text: false,
            run: target_npz,
        },
        Target {
            name: "checkpoint",
            about: "read_checkpoint_info + load_checkpoint of a safetensors file and its JSON sidecar \
                    (input: u32 LE length of the safetensors part, the safetensors bytes, the JSON bytes)",
            text: true,
            run: target_checkpoint,
        },
        Target {
            name: "grid_scene",
            about: "pbdl_grid::scene::Scene::from_toml_str; valid scenes built at <= 16 cells along x, one step",
            text: true,
            run: target_grid_scene,
        },
        Target {
            name: "particles_scene",
            about: "pbdl_particles::scene::Scene::from_toml_str; valid scenes built at small particle counts, one step",
            text: true,
            run: target_particles_scene,
        },
        Target {
            name: "legacy_pth",
            about: "pbdl_metrics::convert::convert_checkpoint of a legacy PyTorch .pth file",
            text: false,
            run: target_legacy_pth,
        },
        Target {
            name: "grid_init",
            about: "`sim grid --init`: read_npz + Simulation::set_fields on a 16x16 built-in scene, one step",
            text: false,
            run: target_grid_init,
        },
        Target {
            name: "particles_init",
            about: "`sim particles --init`: read_npz + InitState::from_arrays + Scene::build, one step",
            text: false,
            run: target_particles_init,
        },
    ]
}

thread_local! {
    /// A scratch directory per worker thread for targets that read files.
    static SCRATCH: PathBuf = {
        let dir = scratch_root().join(format!("{:?}", std::thread::current().id()).replace(['(', ')'], ""));
        let _ = std::fs::create_dir_all(&dir);
        dir
    };
}

fn scratch_root() -> PathBuf {
    std::env::temp_dir().join(format!("pbdl-fuzz-{}", std::process::id()))
}

/// Writes `bytes` to `name` in this thread's scratch directory; `None` if the disk refuses.
fn scratch_file(name: &str, bytes: &[u8]) -> Option<PathBuf> {
    let path = SCRATCH.with(|d| d.join(name));
    std::fs::write(&path, bytes).ok().map(|_| path)
}

fn target_npy(bytes: &[u8]) {
    if let Some(p) = scratch_file("input.npy", bytes) {
        let _ = pbdl_core::io::read_npy(&p);
    }
}

fn target_npz(bytes: &[u8]) {
    if let Some(p) = scratch_file("input.npz", bytes) {
        let _ = pbdl_core::io::read_npz(&p);
        for name in ["a", "velocity"] {
            let _ = pbdl_core::io::read_npz_array(&p, name);
        }
    }
}

/// The checkpoint target's input: `u32` LE length of the safetensors part, then the safetensors
/// bytes, then the sidecar JSON. A mutated length simply moves the split.
pub fn checkpoint_input(weights: &[u8], sidecar: &[u8]) -> Vec<u8> {
    let mut out = (weights.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(weights);
    out.extend_from_slice(sidecar);
    out
}

/// The two parts of a checkpoint-target input: `(safetensors bytes, sidecar JSON bytes)`.
pub fn split_checkpoint_input(bytes: &[u8]) -> (&[u8], &[u8]) {
    if bytes.len() < 4 {
        return (bytes, &[]);
    }
    let n = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as usize;
    let rest = &bytes[4..];
    rest.split_at(n.min(rest.len()))
}

fn target_checkpoint(bytes: &[u8]) {
    let (weights, sidecar) = split_checkpoint_input(bytes);
    let (Some(_), Some(_)) = (scratch_file("ck.safetensors", weights), scratch_file("ck.json", sidecar)) else {
        return;
    };
    let path = SCRATCH.with(|d| d.join("ck"));
    let _ = pbdl_core::io::read_checkpoint_info(&path);
    let _ = pbdl_core::io::load_checkpoint(&path, &candle_core::Device::Cpu);
}

/// Largest grid (cells) the grid targets build: the build allocates per cell.
const MAX_BUILD_CELLS: usize = 4096;

fn target_grid_scene(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    let Ok(scene) = pbdl_grid::scene::Scene::from_toml_str(&text, "fuzz.toml") else { return };
    // Validated at its declared size; built small (the declared size may be any number of cells).
    let scene = if scene.grid.nx > 16 { scene.with_resolution(16) } else { scene };
    if scene.grid.nx.checked_mul(scene.grid.ny).is_none_or(|c| c > MAX_BUILD_CELLS) {
        return;
    }
    if let Ok(mut sim) = scene.build() {
        if sim.step().is_ok() {
            let _ = sim.check();
        }
    }
}

/// Largest particle count the particle targets build or step.
const MAX_PARTICLES: f64 = 4096.0;

fn target_particles_scene(bytes: &[u8]) {
    use pbdl_particles::scene::{Precision, Scene};
    let text = String::from_utf8_lossy(bytes);
    let Ok(mut scene) = Scene::from_toml_str(&text, "fuzz.toml") else { return };
    // Validated as declared; built at small counts (a scene may ask for any number of particles).
    if let Some(s) = &mut scene.shock_tube {
        s.n = s.n.min(64);
    }
    if let Some(s) = &mut scene.periodic_1d {
        s.n = s.n.min(64);
    }
    if let Some(s) = &mut scene.periodic_2d {
        s.n = s.n.min(12);
    }
    if let Some(d) = &mut scene.dam_break {
        let g = &mut d.geometry;
        if g.dx.is_finite() && g.dx > 0.0 {
            g.dx = g.dx.max(0.1);
            // Fluid, tank and wall layers, counted generously.
            let layers = g.wall_layers.unwrap_or(4) as f64;
            let (w, h) = (g.tank_width.abs() + 2.0 * layers * g.dx, g.tank_height.abs() + 2.0 * layers * g.dx);
            let count = (w * h + g.height_ratio.abs()) / (g.dx * g.dx);
            if count.is_nan() || count > MAX_PARTICLES {
                return;
            }
        }
    }
    // 3D kinds: skip any whose lattice (box plus wall layers, counted generously) is large; a
    // non-positive or non-finite spacing goes on to the build's typed error.
    let too_big_3d = |size: [f64; 3], dx: f64, layers: Option<usize>| {
        let l = layers.unwrap_or(4) as f64;
        let count = size.iter().map(|s| s.abs() + 2.0 * l * dx.abs()).product::<f64>() / dx.abs().powi(3);
        dx != 0.0 && dx.is_finite() && (count.is_nan() || count > MAX_PARTICLES)
    };
    if let Some(d) = &scene.dam_break_3d {
        let g = &d.geometry;
        if too_big_3d([g.tank_width, g.tank_height, g.depth], g.dx, g.wall_layers) {
            return;
        }
    }
    if let Some(b) = &scene.block_drop_3d {
        let g = &b.geometry;
        if too_big_3d(g.box_size, g.dx, g.wall_layers) {
            return;
        }
    }
    match scene.precision {
        Precision::F64 => step_particles(scene.build_as::<f64>(0, None)),
        Precision::F32 => step_particles(scene.build_as::<f32>(0, None)),
    }
}

/// One step at the stable time step and a frame read-out, if the build succeeded.
fn step_particles<T: pbdl_core::Real>(built: pbdl_particles::Result<pbdl_particles::scene::Stepper<T>>) {
    if let Ok(mut s) = built {
        let dt = s.stable_dt();
        let _ = s.step(dt).and_then(|_| s.frame());
    }
}

fn target_legacy_pth(bytes: &[u8]) {
    let _ = pbdl_metrics::convert::convert_checkpoint(bytes, Path::new("fuzz.pth"));
}

/// The small built-in grid scenes that init files are applied to, by the array that selects them.
fn grid_init_scenes() -> &'static [(&'static str, pbdl_grid::scene::Scene)] {
    static SCENES: OnceLock<Vec<(&'static str, pbdl_grid::scene::Scene)>> = OnceLock::new();
    SCENES.get_or_init(|| {
        [
            ("density", "smoke_plume"),
            ("temperature", "heat"),
            ("u", "burgers_1d"),
            ("source", "poisson"),
            ("concentration", "advection_diffusion"),
            ("velocity", "taylor_green"),
        ]
        .into_iter()
        .filter_map(|(array, name)| {
            let s = pbdl_grid::scene::Scene::builtin(name).ok()?;
            Some((array, s.with_resolution(16).with_steps(1)))
        })
        .collect()
    })
}

fn target_grid_init(bytes: &[u8]) {
    let Some(p) = scratch_file("init.npz", bytes) else { return };
    let Ok(arrays) = pbdl_core::io::read_npz(&p) else { return };
    let scenes = grid_init_scenes();
    // The first scene whose field the file has; the velocity scene otherwise.
    let Some((_, scene)) = scenes.iter().find(|(a, _)| arrays.iter().any(|(n, _)| n == a)).or(scenes.last()) else {
        return;
    };
    let Ok(mut sim) = scene.build() else { return };
    if sim.set_fields(&arrays).is_ok() && sim.step().is_ok() {
        let _ = sim.check();
    }
}

/// The particle scenes that init files are applied to: 1D periodic, 2D periodic, dam break.
fn particle_init_scenes() -> &'static [pbdl_particles::scene::Scene] {
    static SCENES: OnceLock<Vec<pbdl_particles::scene::Scene>> = OnceLock::new();
    SCENES.get_or_init(|| {
        let mut out = Vec::new();
        for name in ["periodic_1d_noise", "periodic_2d_box", "dam_break"] {
            let Ok(mut s) = pbdl_particles::scene::Scene::builtin(name) else { continue };
            if let Some(p) = &mut s.periodic_1d {
                p.n = 64;
            }
            if let Some(p) = &mut s.periodic_2d {
                p.n = 8;
            }
            if let Some(d) = &mut s.dam_break {
                d.geometry.dx = 0.1;
            }
            out.push(s);
        }
        out
    })
}

fn target_particles_init(bytes: &[u8]) {
    use pbdl_particles::scene::InitState;
    let Some(p) = scratch_file("init.npz", bytes) else { return };
    let Ok(arrays) = pbdl_core::io::read_npz(&p) else { return };
    let Ok(init) = InitState::from_arrays(&arrays) else { return };
    let scenes = particle_init_scenes();
    // 1D files go to the 1D scene; 2D ones alternate between the periodic box and the dam break.
    let pick = if init.dim == 1 { 0 } else { 1 + bytes.len() % 2 };
    let Some(scene) = scenes.get(pick.min(scenes.len().saturating_sub(1))) else { return };
    let built = scene.build(0, Some(&init));
    if (init.len() as f64) <= MAX_PARTICLES {
        step_particles(built);
    }
}

// ---------------------------------------------------------------------------------------------
// Mutation
// ---------------------------------------------------------------------------------------------

/// Inputs never grow beyond this (bytes).
pub const MAX_INPUT: usize = 1 << 20;

const INTERESTING: &[u64] = &[
    0,
    1,
    0x7f,
    0x80,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x1_0000_0000,
    0x7fff_ffff_ffff_ffff,
    0x8000_0000_0000_0000,
    u64::MAX,
];

const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "-0.0",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "NaN",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "99999999999999999999999",
    "1000000",
    "65536",
    "0.5",
];

/// A seeded mutation engine: the same seed gives the same inputs.
pub struct Mutator {
    rng: StdRng,
    text: bool,
}

impl Mutator {
    /// A mutator for text (`text = true`: token mutations favoured) or binary inputs.
    pub fn new(seed: u64, text: bool) -> Self {
        Mutator { rng: StdRng::seed_from_u64(seed), text }
    }

    /// A random index below `n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        self.rng.random_range(0..n.max(1))
    }

    /// One to four stacked mutations of `input`; `other` is a second corpus input for splicing.
    pub fn mutate(&mut self, input: &[u8], other: &[u8]) -> Vec<u8> {
        let mut v = input.to_vec();
        let rounds = 1 + self.below(4);
        for _ in 0..rounds {
            let op = if self.text && self.rng.random_bool(0.5) { 10 + self.below(4) } else { self.below(14) };
            self.apply(op, &mut v, other);
            v.truncate(MAX_INPUT);
        }
        v
    }

    fn apply(&mut self, op: usize, v: &mut Vec<u8>, other: &[u8]) {
        let len = v.len();
        match op {
            // Bit flip.
            0 if len > 0 => {
                let i = self.below(len);
                v[i] ^= 1 << self.below(8);
            }
            // Random byte.
            1 if len > 0 => {
                let i = self.below(len);
                v[i] = self.rng.random();
            }
            // Insert random bytes, or a run of one byte.
            2 => {
                let at = self.below(len + 1);
                let most = if self.rng.random_bool(0.2) { 256 } else { 16 };
                let n = 1 + self.below(most);
                let bytes: Vec<u8> = if self.rng.random_bool(0.5) {
                    (0..n).map(|_| self.rng.random()).collect()
                } else {
                    vec![self.rng.random(); n]
                };
                v.splice(at..at, bytes);
            }
            // Delete a range.
            3 if len > 0 => {
                let at = self.below(len);
                let n = 1 + self.below((len - at).min(64));
                v.drain(at..at + n);
            }
            // Truncate.
            4 if len > 0 => v.truncate(self.below(len)),
            // Duplicate a chunk somewhere else.
            5 if len > 0 => {
                let at = self.below(len);
                let n = 1 + self.below((len - at).min(256));
                let chunk = v[at..at + n].to_vec();
                let to = self.below(len + 1);
                v.splice(to..to, chunk);
            }
            // An interesting integer, 1/2/4/8 bytes, either byte order, at a random offset.
            6 | 7 if len > 0 => {
                let x = INTERESTING[self.below(INTERESTING.len())];
                let x = if self.rng.random_bool(0.3) { x.wrapping_neg() } else { x };
                let width = [1, 2, 4, 8][self.below(4)];
                let bytes = if self.rng.random_bool(0.8) { x.to_le_bytes() } else { x.to_be_bytes() };
                let bytes = if self.rng.random_bool(0.8) { &bytes[..width] } else { &bytes[8 - width..] };
                let at = self.below(len);
                let end = (at + width).min(len);
                v[at..end].copy_from_slice(&bytes[..end - at]);
            }
            // Splice: a prefix of this input and a suffix of another.
            8 if !other.is_empty() => {
                let cut = self.below(len + 1);
                let from = self.below(other.len());
                v.truncate(cut);
                v.extend_from_slice(&other[from..]);
            }
            // Copy a chunk of the other input over this one.
            9 if !other.is_empty() && len > 0 => {
                let from = self.below(other.len());
                let n = 1 + self.below((other.len() - from).min(64));
                let at = self.below(len);
                let end = (at + n).min(len);
                v[at..end].copy_from_slice(&other[from..from + (end - at)]);
            }
            // Text: replace a number by a huge, negative, NaN or infinite one.
            10 => self.replace_number(v),
            // Text: drop a line.
            11 => {
                let lines = line_spans(v);
                if !lines.is_empty() {
                    let (a, b) = lines[self.below(lines.len())];
                    v.drain(a..b);
                }
            }
            // Text: duplicate a line.
            12 => {
                let lines = line_spans(v);
                if !lines.is_empty() {
                    let (a, b) = lines[self.below(lines.len())];
                    let line = v[a..b].to_vec();
                    let (c, _) = lines[self.below(lines.len())];
                    v.splice(c..c, line);
                }
            }
            // Text: replace a word by another word of the input (keys, enum values).
            13 => {
                let words = word_spans(v);
                if words.len() > 1 {
                    let (a, b) = words[self.below(words.len())];
                    let (c, d) = words[self.below(words.len())];
                    let word = v[c..d].to_vec();
                    v.splice(a..b, word);
                }
            }
            // An op that did not apply to this input (e.g. empty): insert a byte instead.
            _ => {
                let at = self.below(len + 1);
                v.insert(at, self.rng.random());
            }
        }
    }

    fn replace_number(&mut self, v: &mut Vec<u8>) {
        let spans = number_spans(v);
        let new = NUMBERS[self.below(NUMBERS.len())].as_bytes().to_vec();
        if spans.is_empty() {
            let at = self.below(v.len() + 1);
            v.splice(at..at, new);
        } else {
            let (a, b) = spans[self.below(spans.len())];
            v.splice(a..b, new);
        }
    }
}

/// Byte ranges of the lines of `v` (newline included).
fn line_spans(v: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &b) in v.iter().enumerate() {
        if b == b'\n' {
            out.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < v.len() {
        out.push((start, v.len()));
    }
    out
}

/// Byte ranges of the numbers in `v` (runs of digits, `.`, `e`, `+`, `-` holding a digit).
fn number_spans(v: &[u8]) -> Vec<(usize, usize)> {
    spans(v, |b| b.is_ascii_digit() || matches!(b, b'.' | b'e' | b'E' | b'+' | b'-'))
        .into_iter()
        .filter(|&(a, b)| v[a..b].iter().any(u8::is_ascii_digit))
        .collect()
}

/// Byte ranges of the identifiers in `v`.
fn word_spans(v: &[u8]) -> Vec<(usize, usize)> {
    spans(v, |b| b.is_ascii_alphanumeric() || b == b'_')
        .into_iter()
        .filter(|&(a, _)| v[a].is_ascii_alphabetic())
        .collect()
}

fn spans(v: &[u8], inside: impl Fn(u8) -> bool) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, &b) in v.iter().enumerate() {
        match (inside(b), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((s, i));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, v.len()));
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Running inputs
// ---------------------------------------------------------------------------------------------

/// What one input did.
#[derive(Clone, Debug)]
struct RunResult {
    /// The panic message with its location, if it panicked.
    panic: Option<String>,
    /// Peak bytes allocated above the level at the start (process-wide).
    peak_bytes: usize,
    /// Whether `peak_bytes` is this input's alone (no abandoned worker ran meanwhile).
    peak_valid: bool,
}

/// Where the last panic happened (set by the silent hook; the payload gives the message).
static LAST_PANIC: Mutex<Option<String>> = Mutex::new(None);

fn run_one(run: fn(&[u8]), input: &[u8]) -> RunResult {
    *LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()) = None;
    let quiet = ABANDONED_RUNNING.load(Ordering::SeqCst) == 0;
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| run(input)));
    let peak_bytes = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    let peak_valid = quiet && ABANDONED_RUNNING.load(Ordering::SeqCst) == 0;
    let panic = outcome.err().map(|payload| {
        let msg = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "non-string panic payload".into());
        match LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()).take() {
            Some(at) => format!("{msg} (at {at})"),
            None => msg,
        }
    });
    RunResult { panic, peak_bytes, peak_valid }
}

/// A thread that runs inputs one at a time, so that the caller can give up on a hung one.
struct Worker {
    run: fn(&[u8]),
    inputs: mpsc::Sender<Vec<u8>>,
    results: mpsc::Receiver<RunResult>,
    abandoned: std::sync::Arc<AtomicBool>,
}

impl Worker {
    fn spawn(run: fn(&[u8])) -> anyhow::Result<Self> {
        let (inputs, rx) = mpsc::channel::<Vec<u8>>();
        let (tx, results) = mpsc::channel();
        let abandoned = std::sync::Arc::new(AtomicBool::new(false));
        let flag = abandoned.clone();
        // The main thread's stack size, so that a recursion that would overflow in the CLI
        // overflows here too (an overflow aborts the process: it is not caught).
        std::thread::Builder::new().name("pbdl-fuzz".into()).stack_size(8 << 20).spawn(move || {
            for input in rx {
                let r = run_one(run, &input);
                if flag.load(Ordering::SeqCst) {
                    ABANDONED_RUNNING.fetch_sub(1, Ordering::SeqCst);
                    break;
                }
                if tx.send(r).is_err() {
                    break;
                }
            }
        })?;
        Ok(Worker { run, inputs, results, abandoned })
    }

    /// Runs `input`; `None` if it did not finish within `limit`. A hung thread cannot be
    /// stopped: it is abandoned (it ends after its input) and a fresh one takes its place.
    fn run(&mut self, input: &[u8], limit: Duration) -> anyhow::Result<Option<RunResult>> {
        if self.inputs.send(input.to_vec()).is_ok() {
            if let Ok(r) = self.results.recv_timeout(limit) {
                return Ok(Some(r));
            }
        }
        ABANDONED_RUNNING.fetch_add(1, Ordering::SeqCst);
        self.abandoned.store(true, Ordering::SeqCst);
        *self = Worker::spawn(self.run)?;
        Ok(None)
    }
}

type PanicHook = Box<dyn Fn(&std::panic::PanicHookInfo<'_>) + Sync + Send>;

/// Installs a panic hook that records the location silently; the old hook comes back on drop.
struct SilentPanics {
    previous: Option<PanicHook>,
}

impl SilentPanics {
    fn install() -> Self {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(|info| {
            let at = info.location().map(|l| format!("{}:{}:{}", l.file(), l.line(), l.column()));
            *LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()) = at;
        }));
        SilentPanics { previous: Some(previous) }
    }
}

impl Drop for SilentPanics {
    fn drop(&mut self) {
        if let Some(p) = self.previous.take() {
            std::panic::set_hook(p);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Campaigns and reports
// ---------------------------------------------------------------------------------------------

/// How long and how to fuzz one target.
#[derive(Clone, Debug)]
pub struct FuzzOptions {
    /// Wall-clock budget of the target (seconds), the seed corpus included.
    pub seconds: f64,
    /// Seed of the mutation engine.
    pub seed: u64,
    /// Longest an input may run before it counts as a hang.
    pub time_limit: Duration,
    /// Where findings are saved (`<dir>/<target>/<hash>.bin`); `None`: not saved.
    pub crash_dir: Option<PathBuf>,
}

impl Default for FuzzOptions {
    fn default() -> Self {
        FuzzOptions { seconds: 60.0, seed: 0, time_limit: Duration::from_secs(2), crash_dir: None }
    }
}

/// Kinds of findings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FindingKind {
    /// The loader panicked.
    Panic,
    /// One input ran past the time limit.
    Hang,
    /// The peak allocation exceeded [`memory_limit`].
    OverMemory,
}

/// One unique finding (the first input that showed it, minimised).
#[derive(Clone, Debug, Serialize)]
pub struct Finding {
    /// What happened.
    pub kind: FindingKind,
    /// Panic message and location, or the time / bytes.
    pub message: String,
    /// Length of the (minimised) input.
    pub input_len: usize,
    /// FNV-1a hash of the input, hex (the file stem).
    pub hash: String,
    /// Where the input was saved.
    pub saved: Option<PathBuf>,
    /// The input itself (not serialised; for tests and minimisation).
    #[serde(skip)]
    pub input: Vec<u8>,
}

/// What fuzzing one target found.
#[derive(Clone, Debug, Serialize)]
pub struct TargetReport {
    /// Target name.
    pub target: String,
    /// Inputs run (seed corpus included).
    pub inputs: u64,
    /// Of which seed-corpus inputs.
    pub corpus_inputs: usize,
    /// Wall-clock seconds spent.
    pub seconds: f64,
    /// Inputs per second.
    pub inputs_per_s: f64,
    /// Inputs that panicked.
    pub panics: u64,
    /// Inputs that hung (the target stops at the first).
    pub hangs: u64,
    /// Inputs over the memory allowance.
    pub over_memory: u64,
    /// Distinct findings (by kind and panic location).
    pub unique_crashes: usize,
    /// Whether allocation was measured ([`CountingAlloc`] installed).
    pub memory_measured: bool,
    /// The largest peak allocation of one input, bytes.
    pub max_peak_bytes: usize,
    /// Inputs whose memory was not judged because a hung input of an earlier target was still
    /// running (its allocations would have been counted).
    pub unmeasured_inputs: u64,
    /// The findings.
    pub findings: Vec<Finding>,
}

impl TargetReport {
    /// Whether nothing was found.
    pub fn clean(&self) -> bool {
        self.panics == 0 && self.hangs == 0 && self.over_memory == 0
    }
}

/// FNV-1a, 64 bit: a stable file name for an input.
pub fn hash_hex(bytes: &[u8]) -> String {
    let h = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3));
    format!("{h:016x}")
}

/// The dedup key of a panic: its location, or the message when there is none.
fn panic_key(msg: &str) -> String {
    msg.rsplit_once(" (at ").map(|(_, at)| at.trim_end_matches(')').to_string()).unwrap_or_else(|| msg.to_string())
}

/// Classifies one result: `(kind, key, message)` if it is a finding.
fn classify(r: &RunResult, input_len: usize, measured: bool) -> Option<(FindingKind, String, String)> {
    if let Some(msg) = &r.panic {
        return Some((FindingKind::Panic, format!("panic {}", panic_key(msg)), msg.clone()));
    }
    let limit = memory_limit(input_len);
    if measured && r.peak_valid && r.peak_bytes > limit {
        let msg = format!("peak allocation {} bytes > allowance {limit} for {input_len} input bytes", r.peak_bytes);
        return Some((FindingKind::OverMemory, "over-memory".into(), msg));
    }
    None
}

/// Shrinks `input` while it still shows the finding `key` (chunk removal, at most ~300 runs).
fn minimize(
    worker: &mut Worker,
    mut input: Vec<u8>,
    key: &str,
    limit: Duration,
    measured: bool,
) -> anyhow::Result<Vec<u8>> {
    let mut tries = 0;
    let mut chunk = input.len().div_ceil(2).max(1);
    while chunk >= 1 && tries < 300 {
        let mut at = 0;
        let mut shrunk = false;
        while at < input.len() && tries < 300 {
            let mut candidate = input.clone();
            candidate.drain(at..(at + chunk).min(input.len()));
            tries += 1;
            let Some(r) = worker.run(&candidate, limit)? else { return Ok(input) };
            if classify(&r, candidate.len(), measured).is_some_and(|(_, k, _)| k == key) {
                input = candidate;
                shrunk = true;
            } else {
                at += chunk;
            }
        }
        if !shrunk {
            if chunk == 1 {
                break;
            }
            chunk /= 2;
        }
    }
    Ok(input)
}

/// Runs one input of `target` on this thread (a saved finding, for debugging): the panic message,
/// if it panicked, and the peak allocation in bytes (0 without [`CountingAlloc`]).
pub fn replay(target: &Target, input: &[u8]) -> (Option<String>, usize) {
    let _silent = SilentPanics::install();
    let r = run_one(target.run, input);
    (r.panic, r.peak_bytes)
}

/// Reads the seed corpus of `target` (`<dir>/<target>/*`, sorted by name).
pub fn load_corpus(dir: &Path, target: &str) -> anyhow::Result<Vec<Vec<u8>>> {
    let dir = dir.join(target);
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| anyhow::anyhow!("cannot read the seed corpus {}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    paths.sort();
    paths.iter().map(|p| Ok(std::fs::read(p)?)).collect()
}

/// Fuzzes `target` for `opts.seconds`, starting from `corpus` (every corpus input runs first,
/// unmutated).
pub fn fuzz_target(target: &Target, corpus: &[Vec<u8>], opts: &FuzzOptions) -> anyhow::Result<TargetReport> {
    anyhow::ensure!(!corpus.is_empty(), "target {}: the seed corpus is empty", target.name);
    let measured = counting_allocator_installed();
    let _silent = SilentPanics::install();
    let mut worker = Worker::spawn(target.run)?;
    let mut mutator = Mutator::new(opts.seed ^ hash_u64(target.name), target.text);
    // Recent mutants, mutated again for deeper chains of changes.
    let mut pool: Vec<Vec<u8>> = Vec::new();
    let mut report = TargetReport {
        target: target.name.into(),
        inputs: 0,
        corpus_inputs: corpus.len(),
        seconds: 0.0,
        inputs_per_s: 0.0,
        panics: 0,
        hangs: 0,
        over_memory: 0,
        unique_crashes: 0,
        memory_measured: measured,
        max_peak_bytes: 0,
        unmeasured_inputs: 0,
        findings: vec![],
    };
    let mut seen = std::collections::HashSet::new();
    let started = Instant::now();
    let budget = Duration::from_secs_f64(opts.seconds.max(0.0));
    let mut k = 0usize;
    loop {
        let input = if k < corpus.len() {
            corpus[k].clone()
        } else {
            if started.elapsed() >= budget {
                break;
            }
            let base = if !pool.is_empty() && mutator.rng.random_bool(0.3) {
                &pool[mutator.below(pool.len())]
            } else {
                &corpus[mutator.below(corpus.len())]
            };
            let other = &corpus[mutator.below(corpus.len())];
            let v = mutator.mutate(base, other);
            if pool.len() < 64 {
                pool.push(v.clone());
            } else {
                let i = mutator.below(pool.len());
                pool[i] = v.clone();
            }
            v
        };
        k += 1;
        report.inputs += 1;
        let Some(r) = worker.run(&input, opts.time_limit)? else {
            report.hangs += 1;
            let msg = format!("no result within {:.1} s", opts.time_limit.as_secs_f64());
            report.findings.push(save_finding(target.name, FindingKind::Hang, msg, input, opts)?);
            report.unique_crashes += 1;
            // The abandoned thread still runs and allocates: the target ends here.
            break;
        };
        if r.peak_valid {
            report.max_peak_bytes = report.max_peak_bytes.max(r.peak_bytes);
        } else {
            report.unmeasured_inputs += 1;
        }
        if let Some((kind, key, msg)) = classify(&r, input.len(), measured) {
            match kind {
                FindingKind::Panic => report.panics += 1,
                FindingKind::OverMemory => report.over_memory += 1,
                FindingKind::Hang => report.hangs += 1,
            }
            if seen.insert(key.clone()) {
                let small = minimize(&mut worker, input, &key, opts.time_limit, measured)?;
                let msg = worker
                    .run(&small, opts.time_limit)?
                    .and_then(|r| classify(&r, small.len(), measured))
                    .map(|(_, _, m)| m)
                    .unwrap_or(msg);
                report.findings.push(save_finding(target.name, kind, msg, small, opts)?);
                report.unique_crashes += 1;
            }
        }
    }
    report.seconds = started.elapsed().as_secs_f64();
    report.inputs_per_s = report.inputs as f64 / report.seconds.max(1e-9);
    let _ = std::fs::remove_dir_all(scratch_root());
    Ok(report)
}

fn hash_u64(s: &str) -> u64 {
    u64::from_str_radix(&hash_hex(s.as_bytes()), 16).unwrap_or(0)
}

fn save_finding(
    target: &str,
    kind: FindingKind,
    message: String,
    input: Vec<u8>,
    opts: &FuzzOptions,
) -> anyhow::Result<Finding> {
    let hash = hash_hex(&input);
    let saved = match &opts.crash_dir {
        Some(dir) => {
            let dir = dir.join(target);
            std::fs::create_dir_all(&dir)?;
            let path = dir.join(format!("{hash}.bin"));
            std::fs::write(&path, &input)?;
            std::fs::write(dir.join(format!("{hash}.txt")), format!("{kind:?}: {message}\n"))?;
            Some(path)
        }
        None => None,
    };
    Ok(Finding { kind, message, input_len: input.len(), hash, saved, input })
}

/// The report as a markdown table plus the findings.
pub fn markdown(reports: &[TargetReport], seed: u64) -> String {
    let mut s = format!(
        "# Fuzzing pbdl's file readers\n\nSeed {seed}. Findings: panics, hangs (> time limit), inputs whose peak \
         allocation exceeded 64 x input length + 64 MiB.\n\n\
         | target | inputs | inputs/s | panics | hangs | over-memory | unique | max peak alloc |\n\
         |---|---|---|---|---|---|---|---|\n"
    );
    for r in reports {
        let peak =
            if r.memory_measured { format!("{:.1} MiB", r.max_peak_bytes as f64 / 1048576.0) } else { "-".into() };
        s.push_str(&format!(
            "| {} | {} | {:.0} | {} | {} | {} | {} | {} |\n",
            r.target, r.inputs, r.inputs_per_s, r.panics, r.hangs, r.over_memory, r.unique_crashes, peak
        ));
    }
    for r in reports {
        for f in &r.findings {
            s.push_str(&format!(
                "\n- `{}` {:?} ({} bytes{}): {}\n",
                r.target,
                f.kind,
                f.input_len,
                f.saved.as_ref().map(|p| format!(", {}", p.display())).unwrap_or_default(),
                f.message
            ));
        }
    }
    s
}

// ---------------------------------------------------------------------------------------------
// Seed corpus
// ---------------------------------------------------------------------------------------------

/// The committed seed corpus: `fuzz/corpus` of the workspace.
pub fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("fuzz").join("corpus")
}

/// Writes the seed corpus (small valid files made by pbdl's own writers) to `dir/<target>/`,
/// replacing what is there; returns the files written.
pub fn write_corpus(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    use candle_core::{DType, Device, Tensor};
    let cpu = &Device::Cpu;
    let tmp = scratch_root().join("corpus");
    std::fs::create_dir_all(&tmp)?;
    let mut files: Vec<(String, String, Vec<u8>)> = Vec::new();
    let mut add = |target: &str, name: &str, bytes: Vec<u8>| files.push((target.into(), name.into(), bytes));
    let ramp = |n: usize| Tensor::arange(0f32, n as f32, cpu);

    // npy: several dtypes and ranks, a 0-d and an empty array.
    let npy = |t: &Tensor| -> anyhow::Result<Vec<u8>> {
        let p = tmp.join("x.npy");
        pbdl_core::io::write_npy(&p, t)?;
        Ok(std::fs::read(&p)?)
    };
    add("npy", "f32_2x3.npy", npy(&ramp(6)?.reshape((2, 3))?)?);
    add("npy", "f64_4.npy", npy(&ramp(4)?.to_dtype(DType::F64)?)?);
    add("npy", "u8_3x2x2.npy", npy(&ramp(12)?.to_dtype(DType::U8)?.reshape((3, 2, 2))?)?);
    add("npy", "i64_scalar.npy", npy(&Tensor::new(7i64, cpu)?)?);
    add("npy", "f16_5.npy", npy(&ramp(5)?.to_dtype(DType::F16)?)?);
    add("npy", "u32_empty_0x3.npy", npy(&Tensor::zeros((0, 3), DType::U32, cpu)?)?);

    // npz: a trajectory-like archive and a one-array archive.
    let npz = |arrays: &[(&str, Tensor)]| -> anyhow::Result<Vec<u8>> {
        let p = tmp.join("x.npz");
        pbdl_core::io::write_npz(&p, arrays)?;
        Ok(std::fs::read(&p)?)
    };
    let density = ramp(18)?.reshape((2, 1, 3, 3))?;
    let velocity = ramp(36)?.to_dtype(DType::F64)?.reshape((2, 2, 3, 3))?;
    add("npz", "two_arrays.npz", npz(&[("density", density.clone()), ("velocity", velocity.clone())])?);
    add("npz", "one_array.npz", npz(&[("a", ramp(4)?.reshape((2, 2))?)])?);

    // checkpoint: two tensors and a config, in the target's combined layout.
    let ck = tmp.join("ck");
    let tensors = [("net.w", ramp(6)?.reshape((2, 3))?), ("net.b", ramp(2)?.to_dtype(DType::F64)?)];
    let meta = pbdl_core::io::CheckpointMeta {
        config: serde_json::json!({"lr": 1e-3, "layers": [2, 3]}),
        ..pbdl_core::io::CheckpointMeta::at(100)
    };
    pbdl_core::io::save_checkpoint(&ck, tensors.iter().map(|(n, t)| (*n, t)), &meta)?;
    let (w, j) = pbdl_core::io::checkpoint_files(&ck);
    add("checkpoint", "step100.bin", checkpoint_input(&std::fs::read(w)?, &std::fs::read(j)?));

    // Scenes: the built-in TOML files.
    for (name, text) in pbdl_grid::scene::BUILTIN {
        add("grid_scene", &format!("{name}.toml"), text.as_bytes().to_vec());
    }
    for (name, text) in pbdl_particles::scene::BUILTIN {
        add("particles_scene", &format!("{name}.toml"), text.as_bytes().to_vec());
    }

    // legacy_pth: a tiny legacy checkpoint in the layout of the official metric files.
    add("legacy_pth", "tiny_metric.pth", tiny_legacy_pth());

    // grid_init: the fields of small built-in scenes, as a state and as a 2-frame trajectory.
    for name in ["taylor_green", "heat", "smoke_plume", "burgers_1d"] {
        let sim = pbdl_grid::scene::Scene::builtin(name)?.with_resolution(8).build()?;
        let fields = sim.fields()?;
        add(
            "grid_init",
            &format!("{name}_state.npz"),
            npz(&fields.iter().map(|(n, t)| (n.as_str(), t.clone())).collect::<Vec<_>>())?,
        );
        let traj: Vec<(&str, Tensor)> = fields
            .iter()
            .map(|(n, t)| Ok((n.as_str(), Tensor::stack(&[t, t], 0)?)))
            .collect::<candle_core::Result<_>>()?;
        add("grid_init", &format!("{name}_trajectory.npz"), npz(&traj)?);
    }

    // particles_init: 2D lattice (trajectory of 2 frames, with velocities, mass and density) and
    // a 1D row of particles.
    let (side, n2) = (4usize, 16usize);
    let pos2: Vec<f64> = (0..n2).flat_map(|k| [0.1 + 0.2 * (k % side) as f64, 0.1 + 0.2 * (k / side) as f64]).collect();
    let p2 = Tensor::from_vec(pos2, (n2, 2), cpu)?;
    add(
        "particles_init",
        "lattice_2d.npz",
        npz(&[
            ("positions", Tensor::stack(&[&p2, &p2], 0)?),
            ("velocities", Tensor::zeros((2, n2, 2), DType::F64, cpu)?),
            ("mass", Tensor::full(0.04f64, (2, n2), cpu)?),
            ("density", Tensor::full(1000f64, (2, n2), cpu)?),
        ])?,
    );
    add("particles_init", "lattice_2d_f32_positions.npz", npz(&[("positions", p2.to_dtype(DType::F32)?)])?);
    let pos1: Vec<f64> = (0..32).map(|k| -0.95 + 0.06 * k as f64).collect();
    add(
        "particles_init",
        "row_1d.npz",
        npz(&[("positions", Tensor::from_vec(pos1, (32, 1), cpu)?), ("mass", Tensor::full(0.06f64, 32, cpu)?)])?,
    );

    let mut written = Vec::new();
    for t in targets() {
        let d = dir.join(t.name);
        if d.is_dir() {
            std::fs::remove_dir_all(&d)?;
        }
        std::fs::create_dir_all(&d)?;
    }
    for (target, name, bytes) in files {
        let p = dir.join(target).join(name);
        std::fs::write(&p, bytes)?;
        written.push(p);
    }
    let _ = std::fs::remove_dir_all(&tmp);
    Ok(written)
}

/// A small legacy (pre-1.6) PyTorch checkpoint shaped like the official LSiM file: a dict with
/// `stateDict` (an `OrderedDict` of two tensors), `normAcc`, `normM2`, `normCount` and
/// `hyperparams`, then the storage keys and the raw storages.
pub fn tiny_legacy_pth() -> Vec<u8> {
    let mut b = Vec::new();
    let s = |b: &mut Vec<u8>, t: &str| {
        b.push(b'X');
        b.extend_from_slice(&(t.len() as u32).to_le_bytes());
        b.extend_from_slice(t.as_bytes());
    };
    let int = |b: &mut Vec<u8>, i: u16| {
        b.push(b'M');
        b.extend_from_slice(&i.to_le_bytes());
    };
    // A `_rebuild_tensor_v2((storage, key, cpu, len), offset, size, stride, False, OrderedDict())`
    // with the callable in memo slot 1, `torch.FloatStorage` in 2, `OrderedDict` in 3.
    let tensor = |b: &mut Vec<u8>, key: &str, len: u16, offset: u16, size: &[u16], stride: &[u16]| {
        b.extend_from_slice(b"h\x01((");
        s(b, "storage");
        b.extend_from_slice(b"h\x02");
        s(b, key);
        s(b, "cpu");
        int(b, len);
        b.extend_from_slice(b"NtQ");
        int(b, offset);
        b.push(b'(');
        for &n in size {
            int(b, n);
        }
        b.extend_from_slice(b"t(");
        for &n in stride {
            int(b, n);
        }
        b.extend_from_slice(b"t\x89h\x03)Rt"); // False, OrderedDict(), end of args
        b.push(b'R');
    };
    // 1. magic number 0x1950a86a20f9469cfc6c (LONG1, 10 bytes); 2. version 1001; 3. sys info.
    b.extend_from_slice(&[0x80, 2, 0x8a, 10, 0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19, b'.']);
    b.extend_from_slice(&[0x80, 2]);
    int(&mut b, 1001);
    b.push(b'.');
    b.extend_from_slice(&[0x80, 2, b'}', b'(']);
    s(&mut b, "little_endian");
    b.extend_from_slice(&[0x88, b'u', b'.']);
    // 4. the object.
    b.extend_from_slice(&[0x80, 2, b'}', b'q', 0, b'(']);
    s(&mut b, "stateDict");
    b.extend_from_slice(b"ccollections\nOrderedDict\nq\x03)R(");
    b.extend_from_slice(b"ctorch._utils\n_rebuild_tensor_v2\nq\x010ctorch\nFloatStorage\nq\x020");
    s(&mut b, "lin.weight");
    tensor(&mut b, "0", 6, 0, &[2, 3], &[3, 1]);
    s(&mut b, "lin.bias");
    tensor(&mut b, "1", 2, 0, &[2], &[1]);
    b.push(b'u');
    for key in ["normAcc", "normM2"] {
        s(&mut b, key);
        b.extend_from_slice(b"](");
        tensor(&mut b, "0", 6, 2, &[2, 2], &[1, 2]);
        b.push(b'e');
    }
    s(&mut b, "normCount");
    b.extend_from_slice(b"](");
    int(&mut b, 500);
    b.push(b'e');
    s(&mut b, "hyperparams");
    b.extend_from_slice(b"}(");
    s(&mut b, "lr");
    b.push(b'G');
    b.extend_from_slice(&0.001f64.to_be_bytes());
    s(&mut b, "name");
    s(&mut b, "tiny");
    b.extend_from_slice(b"uu.");
    // 5. storage keys; 6. raw storages (u64 element count, then the elements).
    b.extend_from_slice(&[0x80, 2, b']', b'(']);
    s(&mut b, "0");
    s(&mut b, "1");
    b.extend_from_slice(b"e.");
    for (n, first) in [(6u64, 0.0f32), (2, 10.0)] {
        b.extend_from_slice(&n.to_le_bytes());
        for k in 0..n {
            b.extend_from_slice(&(first + k as f32).to_le_bytes());
        }
    }
    b
}
