//! Property tests (proptest) of pbdl-nets' weight-free resampling operators, on random shapes:
//!
//! * `upsample_nearest2` and 2x2 sum pooling (`space_to_depth` then a sum over each group of
//!   four channels) are each other's transpose, and the upsampling backward is that transpose;
//! * `pixel_shuffle` / `pixel_unshuffle` are inverse permutations, hence each other's
//!   transpose, for any factor `r` and leading axes;
//! * `pad_per_axis` (zeros, periodic, replicate, reflect per axis, pads wider than the axis):
//!   the backward is the transpose, and cropping the pad gives the input back.
//!
//! Everything runs in f64; identities are exact up to round-off of the inner products (1e-12
//! relative: these ops only copy and add values, a few additions per element). The proptest
//! seed is fixed (deterministic CI) unless `PROPTEST_RNG_SEED` is set; `PROPTEST_CASES`
//! overrides the case counts.

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed;
use pbdl_core::testing::{adjoint_gap, vjp};
use pbdl_nets::pad::{pad_per_axis, PadMode};
use pbdl_nets::resample::{space_to_depth, upsample_nearest2};
use pbdl_nets::shuffle::{pixel_shuffle, pixel_unshuffle};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// `cases` random cases (or `PROPTEST_CASES`), a fixed seed (or `PROPTEST_RNG_SEED`), and no
/// regression files written into the source tree (a failure prints its minimal input).
fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_none() {
        c.cases = cases;
    }
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_0025);
    }
    c.failure_persistence = None;
    c
}

const TOL: f64 = 1e-12;

fn randn(shape: &[usize], s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

fn max_abs(a: &Tensor) -> f64 {
    a.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
}

fn pad_mode(k: usize) -> PadMode {
    [PadMode::Zeros, PadMode::Periodic, PadMode::Replicate, PadMode::Reflect][k % 4]
}

proptest! {
    #![proptest_config(config(64))]

    /// `<up(x), y> = <x, pool(y)>` with `pool` the 2x2 block sum built from `space_to_depth`,
    /// and the backward of `up` equals `pool`.
    #[test]
    fn nearest_upsampling_is_transposed_by_block_sums(
        b in 1usize..3, c in 1usize..4, h in 1usize..7, w in 1usize..7, s in any::<u64>(),
    ) {
        let x = randn(&[b, c, h, w], s);
        let y = randn(&[b, c, 2 * h, 2 * w], s ^ 1);
        let up = upsample_nearest2(&x).unwrap();
        let pool = space_to_depth(&y).unwrap().reshape((b, c, 4, h, w)).unwrap().sum(2).unwrap();
        let e = adjoint_gap(&up, &y, &x, &pool);
        prop_assert!(e < TOL, "<up x, y> vs <x, pool y>: {e:e}");
        let g = vjp(|t| upsample_nearest2(t).unwrap(), &x, &y);
        let d = max_abs(&(g - &pool).unwrap()) / max_abs(&pool);
        prop_assert!(d < TOL, "backward of upsample_nearest2 vs block sums: {d:e}");
    }

    /// `pixel_unshuffle(pixel_shuffle(x)) = x` exactly, and `<shuffle x, y> = <x, unshuffle y>`
    /// (a permutation's transpose is its inverse); the backward of each is the other.
    #[test]
    fn pixel_shuffle_and_unshuffle_are_inverse_transposes(
        lead in prop::collection::vec(1usize..3, 0..3), c in 1usize..3, r in 1usize..4,
        h in 1usize..5, w in 1usize..5, s in any::<u64>(),
    ) {
        let mut xs = lead.clone();
        xs.extend([c * r * r, h, w]);
        let mut ys = lead.clone();
        ys.extend([c, h * r, w * r]);
        let x = randn(&xs, s);
        let y = randn(&ys, s ^ 1);
        let sx = pixel_shuffle(&x, r).unwrap();
        prop_assert_eq!(sx.dims(), &ys[..]);
        let back = pixel_unshuffle(&sx, r).unwrap();
        prop_assert_eq!(max_abs(&(back - &x).unwrap()), 0.0, "unshuffle(shuffle(x)) != x");
        let uy = pixel_unshuffle(&y, r).unwrap();
        let e = adjoint_gap(&sx, &y, &x, &uy);
        prop_assert!(e < TOL, "<shuffle x, y> vs <x, unshuffle y>: {e:e}");
        let g = vjp(|t| pixel_shuffle(t, r).unwrap(), &x, &y);
        prop_assert_eq!(max_abs(&(g - &uy).unwrap()), 0.0, "backward of pixel_shuffle != unshuffle");
    }

    /// `pad_per_axis` over the last two or three axes with a random mode and pad per side (up to
    /// 2.5x the axis): the backward is the transpose (it sums the copies back onto their
    /// sources), and cropping the pad returns the input exactly.
    #[test]
    fn padding_backward_is_the_transpose(
        n in prop::array::uniform3(1usize..6), dims in 2usize..4,
        pads in prop::array::uniform3((0usize..8, 0usize..8, 0usize..4)), s in any::<u64>(),
    ) {
        let spatial = &n[3 - dims..];
        let pads: Vec<(usize, usize, PadMode)> =
            pads[3 - dims..].iter().map(|&(a, b, m)| (a, b, pad_mode(m))).collect();
        let mut xs = vec![2usize, 2];
        xs.extend(spatial);
        let x = randn(&xs, s);
        let px = pad_per_axis(&x, &pads).unwrap();
        let y = randn(px.dims(), s ^ 1);
        let g = vjp(|t| pad_per_axis(t, &pads).unwrap(), &x, &y);
        let e = adjoint_gap(&px, &y, &x, &g);
        prop_assert!(e < TOL, "pad {spatial:?} {pads:?}: {e:e}");
        let mut crop = px.clone();
        for (k, &(before, _, _)) in pads.iter().enumerate() {
            crop = crop.narrow(2 + k, before, spatial[k]).unwrap();
        }
        prop_assert_eq!(max_abs(&(crop - &x).unwrap()), 0.0, "crop(pad(x)) != x for {:?}", pads);
    }
}
