//! Seeded periodic Perlin gradient noise (1D and 2D) for the noise scenes: a SplitMix64 hash
//! of `(seed, octave, lattice index)` gives each lattice point its gradient; the lattice wraps
//! with period `cells`, so the field is periodic on the domain.

/// SplitMix64 hash of `(seed, octave, lattice index)` to `[-1, 1)`.
fn hash(seed: u64, octave: u64, i: u64, j: u64) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(octave.wrapping_mul(0xBF58_476D_1CE4_E5B9))
        .wrapping_add(i.wrapping_mul(0x94D0_49BB_1331_11EB))
        .wrapping_add(j.wrapping_mul(0x2545_F491_4F6C_DD1D));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Periodic 1D Perlin gradient noise at `u` in lattice units (period `cells`).
pub(super) fn perlin1(seed: u64, octave: u64, u: f64, cells: usize) -> f64 {
    let i0 = u.floor();
    let t = u - i0;
    let c = cells as i64;
    let k0 = (i0 as i64).rem_euclid(c) as u64;
    let k1 = ((i0 as i64) + 1).rem_euclid(c) as u64;
    let (g0, g1) = (hash(seed, octave, k0, 0), hash(seed, octave, k1, 0));
    let (a, b) = (g0 * t, g1 * (t - 1.0));
    a + fade(t) * (b - a)
}

/// Periodic 2D Perlin gradient noise at `u` in lattice units (period `cells` per side).
pub(super) fn perlin2(seed: u64, octave: u64, u: [f64; 2], cells: usize) -> f64 {
    let c = cells as i64;
    let i0 = [u[0].floor(), u[1].floor()];
    let t = [u[0] - i0[0], u[1] - i0[1]];
    let corner = |di: i64, dj: i64| {
        let i = ((i0[0] as i64) + di).rem_euclid(c) as u64;
        let j = ((i0[1] as i64) + dj).rem_euclid(c) as u64;
        let ang = std::f64::consts::PI * hash(seed, octave, i, j);
        let (gx, gy) = (ang.cos(), ang.sin());
        gx * (t[0] - di as f64) + gy * (t[1] - dj as f64)
    };
    let (sx, sy) = (fade(t[0]), fade(t[1]));
    let a = corner(0, 0) + sx * (corner(1, 0) - corner(0, 0));
    let b = corner(0, 1) + sx * (corner(1, 1) - corner(0, 1));
    a + sy * (b - a)
}
