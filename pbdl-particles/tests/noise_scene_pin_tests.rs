//! The noise scenes' initial particles are pinned bit for bit: their Perlin noise lives in
//! `pbdl_core::noise`, and a change there must not move the built-in scenes.

use pbdl_particles::scene::Scene;

/// FNV-1a over the f64 bits of `v`.
fn fnv(v: &[f64]) -> u64 {
    v.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, x| {
        x.to_bits().to_le_bytes().iter().fold(h, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
    })
}

/// `(hash of positions, hash of velocities, hash of masses, bits of the first three
/// noise-driven values)` of the initial frame of built-in `name` with run seed `seed`.
fn initial(name: &str, seed: u64) -> (u64, u64, u64, [u64; 3]) {
    let mut sim = Scene::builtin(name).unwrap().build(seed, None).unwrap();
    let f = sim.frame().unwrap();
    // 1D: the density noise places the particles; 2D: it drives the velocities.
    let first = if sim.dim() == 1 { &f.positions } else { &f.velocities };
    let first = [first[0].to_bits(), first[1].to_bits(), first[2].to_bits()];
    (fnv(&f.positions), fnv(&f.velocities), fnv(&f.mass), first)
}

#[test]
fn noise_scenes_initial_particles_are_pinned_bit_for_bit() {
    // Recorded from the scenes before the Perlin noise moved to pbdl-core.
    let pins = [
        (
            "periodic_1d_noise",
            0,
            (0x365cea763a150d1d, 0x9c1bda7f8c872325, 0x5ce001d86d26a325),
            [0xbfeffbff8514d010, 0xbfeff3fbab3d0034, 0xbfefebf3f02c32cf],
        ),
        (
            "periodic_1d_noise",
            5,
            (0xf190ab8e227795dc, 0x9c1bda7f8c872325, 0x355ca765aa296325),
            [0xbfeffbff5325fb32, 0xbfeff3f9e6c21af2, 0xbfefebeefbf6ac2c],
        ),
        (
            "periodic_2d_box",
            0,
            (0x338a1f3ce6a2fc05, 0x8738898cbc42a993, 0x32091b4b708e9d25),
            [0xbfcfb80a524f17e0, 0x3ff7d11a8eb9880c, 0xbfc9c4aa87d31ca1],
        ),
        (
            "periodic_2d_box",
            5,
            (0x338a1f3ce6a2fc05, 0x746599c8b5676ed2, 0x32091b4b708e9d25),
            [0xbff55a744e9298fa, 0x3fd733092bc5529d, 0xbff3e6b0eee56a88],
        ),
    ];
    for (name, seed, (x, v, m), first) in pins {
        assert_eq!(initial(name, seed), (x, v, m, first), "{name}, run seed {seed}");
    }
}
