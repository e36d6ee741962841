//! Kernel normalisation, symmetry, support and gradients against finite differences.

use pbdl_particles::{Kernel, KernelKind};
use std::f64::consts::PI;

/// ∫ W dV by the midpoint rule in radius: 1D 2∫W dr, 2D 2π∫W r dr, 3D 4π∫W r² dr.
fn integral(k: &Kernel<f64>) -> f64 {
    let n = 200_000;
    let rmax = k.support();
    let dr = rmax / n as f64;
    let mut s = 0.0;
    for i in 0..n {
        let r = (i as f64 + 0.5) * dr;
        let shell = match k.dim() {
            1 => 2.0,
            2 => 2.0 * PI * r,
            _ => 4.0 * PI * r * r,
        };
        s += k.w(r) * shell * dr;
    }
    s
}

#[test]
fn kernels_integrate_to_one() {
    for kind in KernelKind::ALL {
        for dim in 1..=3 {
            for h in [0.1, 1.7] {
                let k = Kernel::new(kind, dim, h).unwrap();
                let i = integral(&k);
                assert!((i - 1.0).abs() < 1e-8, "{kind:?} in {dim}D, h = {h}: integral {i}");
            }
        }
    }
}

#[test]
fn compact_support_positive_and_monotone() {
    for kind in KernelKind::ALL {
        for dim in 1..=3 {
            let k = Kernel::new(kind, dim, 0.5).unwrap();
            assert_eq!(k.w(k.support()), 0.0);
            assert_eq!(k.w(k.support() * 1.01), 0.0);
            assert_eq!(k.dw_dr(k.support() * 1.5), 0.0);
            let mut prev = f64::INFINITY;
            for i in 0..100 {
                let r = k.support() * i as f64 / 100.0;
                let w = k.w(r);
                assert!(w > 0.0 && w <= prev, "{kind:?} {dim}D: W({r}) = {w}");
                assert!(k.dw_dr(r) <= 0.0);
                prev = w;
            }
        }
    }
}

#[test]
fn gradients_match_finite_differences_and_are_antisymmetric() {
    for kind in KernelKind::ALL {
        for dim in 1..=3 {
            let k = Kernel::new(kind, dim, 0.3).unwrap();
            let eps = 1e-6;
            let mut max_err = 0.0f64;
            for i in 1..60 {
                let r = k.support() * i as f64 / 60.0;
                let fd = (k.w(r + eps) - k.w(r - eps)) / (2.0 * eps);
                max_err = max_err.max((fd - k.dw_dr(r)).abs() / k.w(0.0) * k.h());
            }
            assert!(max_err < 1e-7, "{kind:?} {dim}D: dW/dr off by {max_err:.2e} (relative)");
            // Vector gradient in 3D/2D vs FD of W(|d|), and ∇W(d) = -∇W(-d).
            let d = [0.11, -0.07, 0.05];
            let g = k.grad(d);
            let gm = k.grad(d.map(|x: f64| -x));
            let w_of = |x: [f64; 3]| k.w((x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt());
            for a in 0..3 {
                let (mut p, mut m) = (d, d);
                p[a] += eps;
                m[a] -= eps;
                let fd = (w_of(p) - w_of(m)) / (2.0 * eps);
                assert!((fd - g[a]).abs() < 1e-6 * k.w(0.0) / k.h(), "{kind:?} {dim}D grad[{a}]: {} vs {fd}", g[a]);
                assert_eq!(g[a], -gm[a]);
            }
            assert_eq!(k.grad([0.0, 0.0]), [0.0, 0.0]);
        }
    }
}

#[test]
fn f32_matches_f64_and_bad_h_is_an_error() {
    let k64 = Kernel::<f64>::new(KernelKind::WendlandC2, 2, 0.2).unwrap();
    let k32 = Kernel::<f32>::new(KernelKind::WendlandC2, 2, 0.2).unwrap();
    for i in 0..40 {
        let r = 0.01 * i as f64;
        assert!((k64.w(r) - k32.w(r as f32) as f64).abs() < 1e-5 * k64.w(0.0));
    }
    assert!(Kernel::<f64>::new(KernelKind::CubicSpline, 2, 0.0).is_err());
    assert!(Kernel::<f64>::new(KernelKind::CubicSpline, 2, f64::NAN).is_err());
    assert!(Kernel::<f64>::new(KernelKind::CubicSpline, 4, 0.1).is_err());
}
