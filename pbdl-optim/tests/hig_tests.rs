//! HIG and Gauss-Newton against independent formulas, and the mode decay on a linear model.

use faer::{Mat, MatRef, Par, Side};
use pbdl_optim::hig::{composed_jacobian, HalfInverse, HigConfig, HigTrainer};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Poisson8};
use pbdl_optim::Error;
use rand::Rng;

fn random_mat(rows: usize, cols: usize, seed: u64) -> Mat<f64> {
    let mut rng = pbdl_core::seed::rng(seed);
    Mat::from_fn(rows, cols, |_, _| rng.random_range(-1.0..1.0))
}

fn random_vec(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = pbdl_core::seed::rng(seed);
    (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
}

fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let num = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt();
    let den = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    num / den
}

fn mat_vec(m: MatRef<'_, f64>, x: &[f64]) -> Vec<f64> {
    (0..m.nrows()).map(|r| (0..m.ncols()).map(|c| m[(r, c)] * x[c]).sum()).collect()
}

fn mat_t_vec(m: MatRef<'_, f64>, x: &[f64]) -> Vec<f64> {
    (0..m.ncols()).map(|c| (0..m.nrows()).map(|r| m[(r, c)] * x[r]).sum()).collect()
}

/// HIG update against `J^T U S^{-3/2} U^T g` from the eigendecomposition of `J J^T` (an
/// independent route to the same `V S^{-1/2} U^T g`, since `V = J^T U S^{-1}`).
#[test]
fn hig_update_equals_direct_formula_via_eigen_of_jjt() {
    let (m, n) = (48, 150);
    let j = random_mat(m, n, 1);
    let g = random_vec(m, 2);
    let mut solver = HalfInverse::new(m, n, Par::Seq);
    let mut ours = vec![0.0; n];
    let info = solver.solve(&HigConfig::hig(1.0, 1e-6), j.as_ref(), &g, &mut ours).unwrap();
    assert_eq!(info.rank, m);

    let jjt = j.as_ref() * j.as_ref().transpose();
    let eig = jjt.self_adjoint_eigen(Side::Lower).unwrap();
    let (u, lam) = (eig.U(), eig.S().column_vector());
    let mut c = mat_t_vec(u, &g);
    for i in 0..m {
        c[i] *= lam[i].powf(-0.75); // s^{-3/2} with s = sqrt(lambda)
    }
    let direct = mat_t_vec(j.as_ref(), &mat_vec(u, &c));
    let err = rel_diff(&ours, &direct);
    assert!(err < 1e-10, "relative difference {err:e}");
}

/// Same with truncation on a rank-deficient Jacobian, against `V diag(s^-1/2) U^T g` built
/// explicitly from faer's high-level `thin_svd` (allocating path, independent buffers).
#[test]
fn hig_update_equals_explicit_truncated_half_inverse() {
    let (m, n, r) = (40, 90, 25);
    let j = random_mat(m, r, 3) * random_mat(r, n, 4);
    let g = random_vec(m, 5);
    let tau = 1e-8;
    let mut solver = HalfInverse::new(m, n, Par::rayon(2));
    let mut ours = vec![0.0; n];
    let info = solver.solve(&HigConfig::hig(1.0, tau), j.as_ref(), &g, &mut ours).unwrap();
    assert_eq!(info.rank, r, "rank-{r} product must keep exactly {r} singular values");

    let svd = j.as_ref().thin_svd().unwrap();
    let s = svd.S().column_vector();
    let s_max = (0..m).map(|i| s[i]).fold(0.0, f64::max);
    // The half-inverse matrix H = V diag(...) U^T, formed explicitly.
    let h = Mat::from_fn(n, m, |a, b| {
        (0..m).filter(|&i| s[i] > tau * s_max).map(|i| svd.V()[(a, i)] * s[i].powf(-0.5) * svd.U()[(b, i)]).sum::<f64>()
    });
    let direct = mat_vec(h.as_ref(), &g);
    let err = rel_diff(&ours, &direct);
    assert!(err < 1e-10, "relative difference {err:e}");
}

/// Small dense solve by Gauss-Jordan with partial pivoting (test helper).
fn solve_dense(a: &Mat<f64>, b: &[f64]) -> Vec<f64> {
    let n = a.nrows();
    let mut m: Vec<Vec<f64>> = (0..n).map(|r| (0..n).map(|c| a[(r, c)]).chain([b[r]]).collect()).collect();
    for col in 0..n {
        let piv = (col..n).max_by(|&x, &y| m[x][col].abs().total_cmp(&m[y][col].abs())).unwrap();
        m.swap(col, piv);
        for r in 0..n {
            if r != col {
                let f = m[r][col] / m[col][col];
                for c in col..=n {
                    m[r][c] -= f * m[col][c];
                }
            }
        }
    }
    (0..n).map(|r| m[r][n] / m[r][r]).collect()
}

/// Exponent 1 is the truncated pseudo-inverse: for `J = A B` (A full column rank, B full row
/// rank) `J^+ = B^T (B B^T)^-1 (A^T A)^-1 A^T`, computed without any SVD.
#[test]
fn gauss_newton_equals_truncated_pseudo_inverse() {
    let (m, n, r) = (30, 70, 12);
    let a = random_mat(m, r, 6);
    let b = random_mat(r, n, 7);
    let j = &a * &b;
    let g = random_vec(m, 8);
    let mut solver = HalfInverse::new(m, n, Par::Seq);
    let mut ours = vec![0.0; n];
    let info = solver.solve(&HigConfig::gauss_newton(1.0, 1e-9), j.as_ref(), &g, &mut ours).unwrap();
    assert_eq!(info.rank, r);
    let ata = a.as_ref().transpose() * a.as_ref();
    let bbt = b.as_ref() * b.as_ref().transpose();
    let z1 = solve_dense(&ata, &mat_t_vec(a.as_ref(), &g));
    let z2 = solve_dense(&bbt, &z1);
    let pinv_g = mat_t_vec(b.as_ref(), &z2);
    let err = rel_diff(&ours, &pinv_g);
    assert!(err < 1e-9, "relative difference {err:e}");
}

/// A network without hidden layers feeding the (linear) Poisson physics is a linear model
/// `y = A theta + c`. One HIG step must scale each kept residual mode `u_i^T r` by exactly
/// `1 - 2 eta sqrt(s_i) / b` (g = 2 r / b, see `hig::train`), and GN's by `1 - 2 eta / b`.
#[test]
fn linear_model_modes_decay_by_the_predicted_factor() {
    let physics = Poisson8;
    let data = Poisson8::dataset(3, 11);
    let b = data.len;
    for (cfg, kappa) in [(HigConfig::hig(0.05, 1e-6), 0.5), (HigConfig::gauss_newton(0.7, 1e-6), 1.0)] {
        // Input width 3 (a slice of each sample's y): build inputs of width 3 from the data.
        let inputs: Vec<f64> = (0..b).flat_map(|s| data.inputs[s * 64..s * 64 + 3].to_vec()).collect();
        let lin = Dataset { inputs, contexts: Vec::new(), targets: data.targets.clone(), len: b };
        let mut net = Mlp::new(&[3, 64], Activation::Tanh, 12).unwrap();
        let (_, y0) = composed_jacobian(&net, &physics, lin.all()).unwrap();
        let mut trainer = HigTrainer::new(cfg).unwrap();
        let info = trainer.step(&mut net, &physics, lin.all()).unwrap();
        let (_, y1) = composed_jacobian(&net, &physics, lin.all()).unwrap();
        let r0: Vec<f64> = y0.iter().zip(&lin.targets).map(|(y, t)| y - t).collect();
        let r1: Vec<f64> = y1.iter().zip(&lin.targets).map(|(y, t)| y - t).collect();
        let u = trainer.solver().u();
        let s = trainer.solver().singular_values();
        let norm0 = r0.iter().map(|x| x * x).sum::<f64>().sqrt();
        let rank = info.solve.unwrap().rank;
        assert!(rank > 100, "rank {rank}");
        let mut worst = 0.0f64;
        for i in 0..s.len() {
            let c0: f64 = (0..u.nrows()).map(|k| u[(k, i)] * r0[k]).sum();
            let c1: f64 = (0..u.nrows()).map(|k| u[(k, i)] * r1[k]).sum();
            let factor = if i < rank { 1.0 - 2.0 * cfg.eta * s[i].powf(1.0 - kappa) / b as f64 } else { 1.0 };
            worst = worst.max((c1 - factor * c0).abs() / norm0);
        }
        assert!(worst < 1e-10, "kappa {kappa}: worst mode deviation {worst:e} (relative to |r|)");
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    let j = random_mat(4, 6, 1);
    let mut out = vec![0.0; 6];
    let mut solver = HalfInverse::new(4, 6, Par::Seq);
    for tau in [0.0, -1.0, f64::NAN] {
        let e = solver.solve(&HigConfig::hig(1.0, tau), j.as_ref(), &[0.0; 4], &mut out).unwrap_err();
        assert!(matches!(e, Error::InvalidTau { .. }), "{e}");
    }
    let e = solver.solve(&HigConfig::default(), j.as_ref(), &[0.0; 3], &mut out).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    assert!(e.to_string().contains("expected 4, got 3"), "{e}");
    let mut bad = j.clone();
    bad[(2, 5)] = f64::NAN;
    let e = solver.solve(&HigConfig::default(), bad.as_ref(), &[0.0; 4], &mut out).unwrap_err();
    assert!(matches!(e, Error::NonFinite { row: 2, col: 5, .. }), "{e}");
    bad[(2, 5)] = f64::INFINITY;
    assert!(solver.solve(&HigConfig::default(), bad.as_ref(), &[0.0; 4], &mut out).is_err());
    assert!(HigTrainer::new(HigConfig { eta: -1.0, ..Default::default() }).is_err());
}

/// The eigen path (`J J^T` eigendecomposition, never forming `V`) gives the SVD path's update,
/// rank and singular values on well-conditioned and on rank-deficient Jacobians, for HIG and
/// Gauss-Newton, in the short-wide and in the tall shape.
#[test]
fn eigen_path_equals_svd_path() {
    use pbdl_optim::hig::Decomposition;
    // Rank-deficient: 40 x 120 of rank 30 (product of 40x30 and 30x120).
    let low = random_mat(40, 30, 7).as_ref() * random_mat(30, 120, 8).as_ref();
    for (j, tau) in [(random_mat(64, 300, 5), 1e-6), (random_mat(90, 40, 6), 1e-6), (low, 1e-6)] {
        let (m, n) = j.shape();
        let g = random_vec(m, 9);
        for base in [HigConfig::hig(1.0, tau), HigConfig::gauss_newton(1.0, tau)] {
            let mut svd = HalfInverse::new(m, n, Par::Seq);
            let mut eig = HalfInverse::new(m, n, Par::Seq);
            let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
            let ia = svd.solve(&base, j.as_ref(), &g, &mut a).unwrap();
            let ib = eig.solve(&base.with_decomposition(Decomposition::Eigen), j.as_ref(), &g, &mut b).unwrap();
            assert_eq!(ia.rank, ib.rank, "{m}x{n} exponent {}", base.exponent);
            assert!((ia.s_max - ib.s_max).abs() <= 1e-12 * ia.s_max);
            let err = rel_diff(&b, &a);
            assert!(err < 1e-10, "{m}x{n} exponent {}: relative difference {err:e}", base.exponent);
            let (sa, sb) = (svd.singular_values(), eig.singular_values());
            for k in 0..ia.rank {
                assert!((sa[k] - sb[k]).abs() <= 1e-10 * sa[0], "s_{k}: {} vs {}", sa[k], sb[k]);
            }
        }
    }
}
