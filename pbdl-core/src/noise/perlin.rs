//! Seeded periodic Perlin gradient noise in 1D and 2D: a SplitMix64-style hash of
//! `(seed, octave, lattice index)` gives each lattice point its gradient, and lattice indices
//! wrap with period `cells`, so the field tiles the domain.

use std::f64::consts::PI;

/// Hash of `(seed, octave, lattice index i, j)` to `[-1, 1)`: the four keys mixed with odd
/// constants, then the SplitMix64 finaliser, keeping the top 53 bits.
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

/// Perlin's quintic fade `6t^5 - 15t^4 + 10t^3`: C2 across lattice points.
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// `cells` as the lattice period: at least 1, and at most `i64::MAX` (so `rem_euclid` cannot
/// overflow).
fn lattice_period(cells: usize) -> i64 {
    i64::try_from(cells.max(1)).unwrap_or(i64::MAX)
}

/// Lattice index `i0 + d` wrapped to `0..c`. Wrapping add: a huge `u` saturates the cast and
/// must not overflow (the field means nothing there, but it must not panic).
fn wrap(i0: f64, d: i64, c: i64) -> u64 {
    (i0 as i64).wrapping_add(d).rem_euclid(c) as u64
}

/// Periodic 1D Perlin gradient noise at `u`, in lattice units.
///
/// Lattice point `k` (an integer) carries a gradient `g_k` uniform in `[-1, 1)`, drawn from a
/// hash of `(seed, octave, k mod cells)`; between `k` and `k + 1` the value is the quintic-fade
/// blend of `g_k (u - k)` and `g_(k+1) (u - k - 1)`. So:
///
/// - the field is zero at every lattice point, C2 smooth, and lies in `[-0.5, 0.5]`;
/// - it has period `cells` in `u` (map a domain of length `L` with `u = x / L * cells`);
/// - `seed` picks the realisation and `octave` is a second, independent key, so the octaves of a
///   fractal sum (each usually with its own `cells`) get unrelated gradients from one seed.
///
/// `cells = 0` is treated as `1` (a lattice needs at least one cell).
///
/// ```
/// use pbdl_core::noise::perlin_1d;
///
/// let v = perlin_1d(7, 0, 2.3, 4);
/// assert!(v.abs() <= 0.5);
/// assert_eq!(perlin_1d(7, 0, 3.0, 4), 0.0); // zero on the lattice
/// assert_eq!(perlin_1d(7, 0, 1.25, 4), perlin_1d(7, 0, 5.25, 4)); // period `cells`
/// assert_ne!(perlin_1d(7, 0, 1.25, 4), perlin_1d(7, 1, 1.25, 4)); // octaves are independent
/// ```
pub fn perlin_1d(seed: u64, octave: u64, u: f64, cells: usize) -> f64 {
    let i0 = u.floor();
    let t = u - i0;
    let c = lattice_period(cells);
    let (k0, k1) = (wrap(i0, 0, c), wrap(i0, 1, c));
    let (g0, g1) = (hash(seed, octave, k0, 0), hash(seed, octave, k1, 0));
    let (a, b) = (g0 * t, g1 * (t - 1.0));
    a + fade(t) * (b - a)
}

/// Periodic 2D Perlin gradient noise at `u = [u_x, u_y]`, in lattice units.
///
/// Lattice point `(i, j)` carries a unit gradient at an angle uniform in `[-π, π)`, drawn from
/// a hash of `(seed, octave, i mod cells, j mod cells)`; inside a cell the four corner ramps
/// `g · (u - corner)` are blended with the quintic fade, first along x, then along y. So:
///
/// - the field is zero at every lattice point, C2 smooth, and lies in `[-√2/2, √2/2]` (the
///   bound is reached only at a cell centre with all four gradients pointing at it);
/// - it has period `cells` along each axis (map a square of side `L` with
///   `u = x * (cells / L)`);
/// - `seed` picks the realisation and `octave` is a second, independent key, as in
///   [`perlin_1d`]. The 2D field is not an extension of the 1D one.
///
/// `cells = 0` is treated as `1` (a lattice needs at least one cell).
///
/// ```
/// use pbdl_core::noise::perlin_2d;
///
/// let v = perlin_2d(7, 0, [0.3, 1.6], 2);
/// assert!(v.abs() <= 0.5f64.sqrt());
/// assert_eq!(perlin_2d(7, 0, [1.0, 0.0], 2), 0.0); // zero on the lattice
/// assert_eq!(perlin_2d(7, 0, [0.25, 1.5], 2), perlin_2d(7, 0, [2.25, -0.5], 2)); // period 2 per axis
/// ```
pub fn perlin_2d(seed: u64, octave: u64, u: [f64; 2], cells: usize) -> f64 {
    let c = lattice_period(cells);
    let i0 = [u[0].floor(), u[1].floor()];
    let t = [u[0] - i0[0], u[1] - i0[1]];
    let corner = |di: i64, dj: i64| {
        let (i, j) = (wrap(i0[0], di, c), wrap(i0[1], dj, c));
        let ang = PI * hash(seed, octave, i, j);
        let (gx, gy) = (ang.cos(), ang.sin());
        gx * (t[0] - di as f64) + gy * (t[1] - dj as f64)
    };
    let (sx, sy) = (fade(t[0]), fade(t[1]));
    let a = corner(0, 0) + sx * (corner(1, 0) - corner(0, 0));
    let b = corner(0, 1) + sx * (corner(1, 1) - corner(0, 1));
    a + sy * (b - a)
}

#[cfg(test)]
mod tests {
    use super::*;

    const P1: [(u64, u64, f64, usize); 10] = [
        (0, 0, 0.3, 4),
        (0, 1, 1.75, 8),
        (0, 3, 31.9, 32),
        (7, 0, -0.6, 4),
        (7, 2, 5.5, 4),
        (42, 1, 2.0, 8),
        (42, 0, 0.999_999, 3),
        (u64::MAX, 5, 123.456, 128),
        (1, 0, -13.25, 5),
        (3, 4, 0.0625, 1),
    ];
    const P2: [(u64, u64, [f64; 2], usize); 10] = [
        (0, 0, [0.3, 0.7], 2),
        (0, 1, [1.75, 3.2], 4),
        (0, 2, [7.9, 0.05], 8),
        (7, 0, [-0.6, 1.4], 2),
        (7, 2, [5.5, -2.25], 4),
        (42, 1, [2.0, 3.0], 8),
        (42, 0, [0.999_999, 0.5], 3),
        (u64::MAX, 5, [123.456, 77.7], 128),
        (1, 0, [-13.25, 9.125], 5),
        (3, 4, [0.0625, 0.9375], 1),
    ];
    // f64 bits recorded from the particle scenes' implementation before it moved here: the
    // noise scenes' initial particles depend on every bit.
    const BITS1: [u64; 10] = [
        0xbfc61fddf02dd43f,
        0x3fb20d4026319af0,
        0x3f8fae78f027529c,
        0xbfa2ba6c575444d4,
        0x3fc941788a1fa602,
        0x0000000000000000,
        0xbea20e5027e00000,
        0x3fc911a56f24f3df,
        0x3fcb9813a8004c52,
        0x3fa57801786e3dda,
    ];
    const BITS2: [u64; 10] = [
        0x3fc14ff6533ac96e,
        0xbfc6f60148e4e243,
        0x3f649419e2342450,
        0x3fd88ad5c70b6ec9,
        0xbfd7018ed40564e6,
        0x0000000000000000,
        0x3fc3b637a54d7dba,
        0x3fcb298c61f3ce48,
        0xbfa9a588d6df2a9d,
        0xbfb58198317984b0,
    ];

    #[test]
    fn perlin_values_are_pinned_bit_for_bit() {
        for ((s, o, u, c), bits) in P1.into_iter().zip(BITS1) {
            let v = perlin_1d(s, o, u, c);
            assert_eq!(v.to_bits(), bits, "perlin_1d({s}, {o}, {u}, {c}) = {v}");
        }
        for ((s, o, u, c), bits) in P2.into_iter().zip(BITS2) {
            let v = perlin_2d(s, o, u, c);
            assert_eq!(v.to_bits(), bits, "perlin_2d({s}, {o}, {u:?}, {c}) = {v}");
        }
    }

    #[test]
    fn perlin_noise_is_bounded_periodic_and_zero_on_the_lattice() {
        let (b1, b2) = (0.5, 0.5f64.sqrt() + 1e-12);
        let cells = 5;
        for k in 0..4000 {
            // Dyadic offsets (multiples of 1/64) shift by a period exactly.
            let u = -7.0 + k as f64 / 64.0;
            let v = perlin_1d(3, 1, u, cells);
            assert!(v.abs() <= b1, "perlin_1d({u}) = {v}");
            assert_eq!(v, perlin_1d(3, 1, u + cells as f64, cells));
            let w = [u, 0.5 * u + 0.25];
            let v = perlin_2d(3, 1, w, cells);
            assert!(v.abs() <= b2, "perlin_2d({w:?}) = {v}");
            assert_eq!(v, perlin_2d(3, 1, [w[0] - cells as f64, w[1] + cells as f64], cells));
        }
        for i in -6..6 {
            assert_eq!(perlin_1d(9, 0, i as f64, cells), 0.0);
            assert_eq!(perlin_2d(9, 0, [i as f64, (i * 3) as f64], cells), 0.0);
        }
    }

    #[test]
    fn perlin_noise_does_not_panic_on_degenerate_input() {
        assert!(perlin_1d(1, 0, 0.3, 0).is_finite());
        assert!(perlin_2d(1, 0, [0.3, 0.7], 0).is_finite());
        assert_eq!(perlin_1d(1, 0, 0.3, 0), perlin_1d(1, 0, 0.3, 1));
        for u in [1e300, -1e300, f64::MAX, f64::INFINITY] {
            let _ = perlin_1d(1, 0, u, 4);
            let _ = perlin_2d(1, 0, [u, u], 4);
        }
        assert!(perlin_1d(1, 0, f64::NAN, 4).is_nan());
    }
}
