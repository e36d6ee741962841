//! Fixed-radius neighbour search: 100k uniform random points in the unit square/cube, radius
//! chosen for about 40 neighbours, full CSR lists (build + query, buffers reused).
//! Peers (Open3D fixed_radius_search, SciPy cKDTree) are measured on the machine at hand by
//! `bench/peers/particles_run.sh`; `cargo xtask bench particles` shows them with their date.

#![allow(missing_docs)] // criterion_group! generates undocumented items

use criterion::{criterion_group, Criterion};
use pbdl_core::Real;
use pbdl_particles::neighbors::{CellList, Domain, NeighborList};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::hint::black_box;

const N: usize = 100_000;

fn points<T: Real, const D: usize>(seed: u64) -> Vec<[T; D]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..N).map(|_| std::array::from_fn(|_| T::c(rng.random::<f64>()))).collect()
}

fn radius(dim: usize) -> f64 {
    let n = N as f64;
    match dim {
        2 => (40.0 / (std::f64::consts::PI * n)).sqrt(),
        _ => (40.0 * 3.0 / (4.0 * std::f64::consts::PI * n)).cbrt(),
    }
}

fn bench_case<T: Real, const D: usize>(c: &mut Criterion, name: &str) {
    let pos = points::<T, D>(42);
    let mut cells = CellList::new(Domain::bounded([T::zero(); D], [T::one(); D]), T::c(radius(D))).unwrap();
    let mut nl = NeighborList::default();
    cells.neighbors(&pos, &mut nl).unwrap();
    eprintln!("{name}: {:.1} neighbours per point", nl.num_entries() as f64 / N as f64);
    c.bench_function(name, |b| {
        b.iter(|| {
            cells.neighbors(black_box(&pos), &mut nl).unwrap();
            black_box(nl.indices.len())
        })
    });
}

fn neighbors(c: &mut Criterion) {
    bench_case::<f32, 2>(c, "neighbors_f32_2d_n100k_k40");
    bench_case::<f32, 3>(c, "neighbors_f32_3d_n100k_k40");
    bench_case::<f64, 2>(c, "neighbors_f64_2d_n100k_k40");
    bench_case::<f64, 3>(c, "neighbors_f64_3d_n100k_k40");
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = neighbors
}
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
