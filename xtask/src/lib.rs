//! The library half of `cargo xtask`: the tour, bench and stress entries of every pbdl crate and
//! the registry that collects them. They live here, not in the library crates, so a user who
//! depends on one pbdl crate compiles none of them.
//!
//! | module | what it holds |
//! |---|---|
//! | [`bench_schema`] | the shared bench schema ([`bench_schema::BenchRow`]: time next to error), its JSON/markdown/PNG report, [`bench_schema::median_seconds`] |
//! | [`registry`] | the entry types ([`registry::Entry`], [`registry::CrateTasks`], ...) and the list of crates |
//! | [`entries`] | one module per library crate with its tour, bench and stress entries |
//! | [`acceptance`] | runs the `#[ignore]`d tests behind README numbers as child processes (stress entries `acceptance`) |
//! | [`latent`] | `cargo xtask latent train\|eval` (latent-space physics on 2D smoke), shared with its entries |
//! | [`temporal`] | `cargo xtask temporal train\|eval\|upscale` (temporally coherent super-resolution of smoke), shared with its entries |
//! | [`run_files`] | JSON settings and results of a run directory, written atomically, read back with errors that name the file |
//! | [`fuzz`] | mutation fuzzing of pbdl's file readers on stable Rust (`cargo xtask stress fuzz`) |

pub mod acceptance;
pub mod bench_schema;
pub mod entries;
pub mod fuzz;
pub mod latent;
pub mod registry;
pub mod run_files;
pub mod temporal;
