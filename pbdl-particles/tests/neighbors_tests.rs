//! Cell-list neighbour lists against a brute-force O(N^2) search on random sets.

use pbdl_particles::neighbors::{brute_force, CellList, Domain, NeighborList};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn random_points<const D: usize>(n: usize, lo: [f64; D], hi: [f64; D], spill: f64, seed: u64) -> Vec<[f64; D]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            std::array::from_fn(|d| {
                let l = hi[d] - lo[d];
                lo[d] - spill * l + rng.random::<f64>() * l * (1.0 + 2.0 * spill)
            })
        })
        .collect()
}

fn check<const D: usize>(domain: Domain<f64, D>, radius: f64, pos: &[[f64; D]]) -> usize {
    let mut cells = CellList::new(domain, radius).unwrap();
    let mut nl = NeighborList::default();
    cells.neighbors(pos, &mut nl).unwrap();
    nl.sort_rows();
    let reference = brute_force(&domain, radius, pos);
    assert_eq!(nl, reference, "cell list differs from brute force (D = {D}, radius = {radius})");
    // Symmetry and pair list.
    for i in 0..nl.len() {
        for &j in nl.neighbors(i) {
            assert!(nl.neighbors(j as usize).contains(&(i as u32)));
        }
    }
    assert_eq!(nl.pairs().len() * 2, nl.num_entries());
    nl.num_entries()
}

#[test]
fn matches_brute_force_1d_2d_3d_bounded_and_periodic() {
    for (seed, periodic) in [(1u64, false), (2, true)] {
        let pos = random_points(600, [-1.0], [2.0], 0.0, seed);
        let dom = Domain { lo: [-1.0], hi: [2.0], periodic: [periodic] };
        assert!(check(dom, 0.02, &pos) > 0);
        let pos = random_points(1500, [0.0, -0.5], [1.0, 0.7], 0.0, seed + 10);
        let dom = Domain { lo: [0.0, -0.5], hi: [1.0, 0.7], periodic: [periodic; 2] };
        assert!(check(dom, 0.07, &pos) > 1500);
        let pos = random_points(2000, [0.0; 3], [1.0, 1.3, 0.8], 0.0, seed + 20);
        let dom = Domain { lo: [0.0; 3], hi: [1.0, 1.3, 0.8], periodic: [periodic; 3] };
        assert!(check(dom, 0.15, &pos) > 2000);
    }
}

#[test]
fn mixed_periodicity_and_few_cells() {
    // Periodic in x only; 2 and 3 cells per periodic direction (neighbour cells coincide).
    let pos = random_points(800, [0.0, 0.0], [1.0, 1.0], 0.0, 5);
    let dom = Domain { lo: [0.0, 0.0], hi: [1.0, 1.0], periodic: [true, false] };
    check(dom, 0.1, &pos);
    check(Domain::periodic([0.0, 0.0], [1.0, 1.0]), 0.45, &pos);
    check(Domain::periodic([0.0, 0.0], [1.0, 1.0]), 0.34, &pos);
    check(Domain::bounded([0.0, 0.0], [1.0, 1.0]), 0.9, &pos);
}

#[test]
fn points_outside_the_box() {
    // Bounded: outside points collect in the edge cells and are still found.
    let pos = random_points(1000, [0.0, 0.0], [1.0, 1.0], 0.2, 7);
    check(Domain::bounded([0.0, 0.0], [1.0, 1.0]), 0.08, &pos);
    // Periodic: outside points are wrapped.
    check(Domain::periodic([0.0, 0.0], [1.0, 1.0]), 0.08, &pos);
}

#[test]
fn f32_and_buffer_reuse() {
    let dom = Domain::<f32, 2>::periodic([0.0, 0.0], [1.0, 1.0]);
    let mut cells = CellList::new(dom, 0.05f32).unwrap();
    let mut nl = NeighborList::default();
    for (n, seed) in [(3000usize, 1u64), (500, 2), (4000, 3)] {
        let pos: Vec<[f32; 2]> =
            random_points(n, [0.0, 0.0], [1.0, 1.0], 0.0, seed).iter().map(|p| [p[0] as f32, p[1] as f32]).collect();
        cells.neighbors(&pos, &mut nl).unwrap();
        nl.sort_rows();
        assert_eq!(nl, brute_force(&dom, 0.05f32, &pos));
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    assert!(CellList::new(Domain::periodic([0.0, 0.0], [1.0, 1.0]), 0.6).is_err());
    assert!(CellList::new(Domain::bounded([0.0, 0.0], [1.0, 1.0]), 0.0).is_err());
    assert!(CellList::new(Domain::bounded([0.0, 0.0], [1.0, 1.0]), f64::NAN).is_err());
    assert!(CellList::new(Domain::bounded([0.0, 1.0], [1.0, 1.0]), 0.1).is_err());
    assert!(CellList::new(Domain::bounded([0.0, 0.0], [1.0, 1.0]), 1e-6).is_err());
    // An empty set is fine.
    let mut c = CellList::new(Domain::bounded([0.0], [1.0]), 0.1).unwrap();
    let mut nl = NeighborList::default();
    c.neighbors(&[], &mut nl).unwrap();
    assert!(nl.is_empty());
}

/// `query_first(n)` lists the first `n` particles' neighbours among all particles: equal to the
/// first `n` rows of the brute-force lists (periodic 2D box, so wrapped pairs are included).
#[test]
fn query_first_equals_the_first_rows_of_brute_force() {
    let pos = random_points::<2>(600, [0.0; 2], [1.0; 2], 0.0, 11);
    let domain = Domain::periodic([0.0; 2], [1.0; 2]);
    let radius = 0.08;
    let mut reference = brute_force(&domain, radius, &pos);
    reference.sort_rows();
    let mut cells = CellList::new(domain, radius).unwrap();
    let mut nl = NeighborList::default();
    cells.build(&pos).unwrap();
    cells.query_first(250, &mut nl);
    nl.sort_rows();
    assert_eq!(nl.len(), 250);
    for i in 0..250 {
        assert_eq!(nl.neighbors(i), reference.neighbors(i), "row {i}");
    }
    assert!(nl.num_entries() > 250, "too few pairs to mean anything: {}", nl.num_entries());
}
