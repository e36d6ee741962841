//! Branch-free elementary functions that vectorise: `exp`, `expm1`, `tanh`, `sigmoid` for
//! `f32` and `f64`, as scalar `#[inline(always)]` functions for hand-written kernels and as
//! in-place slice maps with runtime CPU dispatch.
//!
//! libm's `tanhf`/`expf` are scalar calls: in the fused LSTM they took longer than the whole
//! PyTorch step (whose Sleef kernels work 8 or 16 lanes at a time). Written as plain
//! arithmetic on a range reduction, the same functions compile to SIMD in any loop. The slice
//! maps run an AVX2 build of that loop where the CPU has AVX2 (checked once at run time; the
//! crate targets baseline x86-64, i.e. SSE2) and the portable loop otherwise. No fused
//! multiply-adds are used, so both builds give the same bits on every machine.
//!
//! Accuracy (tested against libm over a sweep, `tests/vmath_tests.rs`): within 3 ulp of the
//! type. `exp` never returns a denormal: it is 0 below `-87.3` (`f32`) / `-708` (`f64`) and
//! `+inf` above `88` (`f32`, true overflow at 88.72) / `709`; so `sigmoid` is 0 below `-88`
//! (`f32`) where libm still gives denormals (it can return a denormal just above, for `x` in
//! `(-88, -87.3]`). NaN stays NaN.
//!
//! ```
//! use pbdl_core::vmath;
//!
//! let mut v = vec![-3.0f32, -0.5, 0.0, 1e-4, 2.0];
//! vmath::tanh_in_place(&mut v);
//! assert!((v[3] - 1e-4f32.tanh()).abs() <= 1e-4 * 2.0 * f32::EPSILON);
//! assert!((vmath::sigmoid(0.3f64) - 1.0 / (1.0 + (-0.3f64).exp())).abs() < 1e-15);
//! ```

use crate::Real;

/// The per-type constants and bit operations behind the functions of this module; implemented
/// for `f32` and `f64` (every [`Real`]).
pub trait Elementary: Copy {
    /// `1.5 * 2^(mantissa bits)`: adding it rounds to an integer, kept in the low mantissa bits.
    const ROUND_MAGIC: Self;
    /// `ln 2` split so that `k * LN2_HI` is exact for every exponent `k` in range.
    const LN2_HI: Self;
    /// The rest of `ln 2`.
    const LN2_LO: Self;
    /// Inputs below give `exp = 0` (`2^k` would leave the normal range).
    const EXP_MIN: Self;
    /// Inputs above give `exp = +inf` (`2^k` would overflow).
    const EXP_MAX: Self;
    /// `1 / n!` for `n` from the highest degree down to 2: the Taylor coefficients of
    /// `(exp(r) - 1 - r) / r^2` in Horner order; truncation below half an ulp for
    /// `|r| <= ln 2 / 2`.
    const TAYLOR: &'static [f64];
    /// `2^k` from `t = y log2(e) + ROUND_MAGIC` (`k` in `t`'s low mantissa bits).
    fn pow2_from_magic(t: Self) -> Self;
}

impl Elementary for f32 {
    const ROUND_MAGIC: f32 = 12_582_912.0;
    // 0.693359375 has 9 significant bits: k * LN2_HI is exact for |k| < 2^15.
    // 0.693359375 = 355/512 exactly (as bits: the decimal literal trips clippy's precision lint).
    const LN2_HI: f32 = f32::from_bits(0x3f31_8000);
    const LN2_LO: f32 = -2.121_944_4e-4;
    const EXP_MIN: f32 = -87.3;
    const EXP_MAX: f32 = 88.0;
    // Degree 8: r^9 / 9! < 2.1e-10 at |r| = ln 2 / 2, far below 2^-24 of exp(r) - 1 ~ r.
    const TAYLOR: &'static [f64] =
        &[1.0 / 40_320.0, 1.0 / 5_040.0, 1.0 / 720.0, 1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5];
    #[inline(always)]
    fn pow2_from_magic(t: f32) -> f32 {
        // (k + 127) into the exponent field; the magic's own bits shift out.
        f32::from_bits(t.to_bits().wrapping_add(127) << 23)
    }
}

impl Elementary for f64 {
    const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
    // fdlibm's split: k * LN2_HI is exact for |k| < 2^11.
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    const EXP_MIN: f64 = -708.0;
    const EXP_MAX: f64 = 709.0;
    // Degree 14: r^15 / 15! < 1e-19 at |r| = ln 2 / 2.
    const TAYLOR: &'static [f64] = &[
        1.0 / 87_178_291_200.0,
        1.0 / 6_227_020_800.0,
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
    ];
    #[inline(always)]
    fn pow2_from_magic(t: f64) -> f64 {
        f64::from_bits(t.to_bits().wrapping_add(1023) << 52)
    }
}

/// `(2^k, exp(r) - 1)` with `y = k ln 2 + r`, `|r| <= ln 2 / 2`, after clamping `y` to the
/// type's range (NaN passes through into `r`).
#[inline(always)]
fn reduce<T: Real>(y: T) -> (T, T) {
    let y = if y < T::EXP_MIN {
        T::EXP_MIN
    } else if y > T::EXP_MAX {
        T::EXP_MAX
    } else {
        y
    };
    let t = y * T::c(std::f64::consts::LOG2_E) + T::ROUND_MAGIC;
    let k = t - T::ROUND_MAGIC;
    let r = (y - k * T::LN2_HI) - k * T::LN2_LO;
    let mut p = T::zero();
    for &c in T::TAYLOR {
        p = p * r + T::c(c);
    }
    // exp(r) - 1 = r + r^2 p(r): no cancellation for small r.
    (T::pow2_from_magic(t), r + r * r * p)
}

/// `e^y`: 0 below [`Elementary::EXP_MIN`], `+inf` above [`Elementary::EXP_MAX`].
#[inline(always)]
pub fn exp<T: Real>(y: T) -> T {
    let (s, em1) = reduce(y);
    let v = s + s * em1;
    // Selects, not branches: they vectorise as blends.
    let v = if y < T::EXP_MIN { T::zero() } else { v };
    if y > T::EXP_MAX {
        T::infinity()
    } else {
        v
    }
}

/// `e^y - 1`, accurate near 0: `-1` below [`Elementary::EXP_MIN`], `+inf` above
/// [`Elementary::EXP_MAX`].
#[inline(always)]
pub fn expm1<T: Real>(y: T) -> T {
    let (s, em1) = reduce(y);
    // 2^k (e^r - 1) + (2^k - 1): exact sum for k = 0; for |k| >= 1 at most a mild
    // cancellation (about 1.7x at k = -1), within the tested 3 ulp.
    let v = s * em1 + (s - T::one());
    if y > T::EXP_MAX {
        T::infinity()
    } else {
        v
    }
}

/// `tanh x = -expm1(-2|x|) / (2 + expm1(-2|x|))` with the sign of `x`: accurate near 0 and
/// exactly `±1` for large `|x|`.
#[inline(always)]
pub fn tanh<T: Real>(x: T) -> T {
    let e = expm1(T::c(-2.0) * x.abs());
    (-e / (T::c(2.0) + e)).copysign(x)
}

/// The logistic sigmoid `1 / (1 + e^-x)`.
#[inline(always)]
pub fn sigmoid<T: Real>(x: T) -> T {
    T::one() / (T::one() + exp(-x))
}

/// Runs `f` in a build with AVX2 enabled where the CPU has it (checked at run time), the
/// portable build otherwise. For loops over the functions above: inlined into the AVX2 build,
/// they vectorise 8 `f32` lanes wide instead of SSE2's 4. Same bits either way (no FMA).
#[inline(always)]
pub fn with_simd<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above; `avx2_build` requires nothing else.
        return unsafe { avx2_build(f) };
    }
    f()
}

/// `f()` compiled with AVX2 (the closure is inlined here).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn avx2_build<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// Applies `f` to every element of `v`, vectorised (see [`with_simd`]).
#[inline(always)]
fn map_in_place<T: Real>(v: &mut [T], f: impl Fn(T) -> T) {
    with_simd(
        #[inline(always)]
        || v.iter_mut().for_each(|x| *x = f(*x)),
    )
}

/// `v[i] = tanh(v[i])`.
pub fn tanh_in_place<T: Real>(v: &mut [T]) {
    map_in_place(v, tanh)
}

/// `v[i] = sigmoid(v[i])`.
pub fn sigmoid_in_place<T: Real>(v: &mut [T]) {
    map_in_place(v, sigmoid)
}

/// `v[i] = exp(v[i])`.
pub fn exp_in_place<T: Real>(v: &mut [T]) {
    map_in_place(v, exp)
}
