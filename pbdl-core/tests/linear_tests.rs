//! `pbdl_core::nn::linear`: finite-difference gradients in `f64` (with and without bias, rank-3
//! input), and the fused op against the composed candle ops in `f32`.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::nn::{linear, with_composed};
use pbdl_core::{check_grad, seed, GradCheckOptions};

fn inputs(dtype: DType) -> (Tensor, Tensor, Tensor) {
    let dev = Device::Cpu;
    (
        seed::randn((3, 4, 5), 0.0, 1.0, dtype, &dev, 1).unwrap(),
        seed::randn((6, 5), 0.0, 0.5, dtype, &dev, 2).unwrap(),
        seed::randn(6, 0.0, 0.5, dtype, &dev, 3).unwrap(),
    )
}

#[test]
fn gradients_match_finite_differences() {
    let (x, w, b) = inputs(DType::F64);
    let opts = GradCheckOptions::default();
    let r = check_grad(|v| Ok(linear(&v[0], &v[1], Some(&v[2]))?), &[x.clone(), w.clone(), b], &opts).unwrap();
    println!("with bias: max rel {:.2e}", r.max_rel_error);
    assert!(r.max_rel_error < 1e-8, "{r:?}");
    let r = check_grad(|v| Ok(linear(&v[0], &v[1], None)?), &[x, w], &opts).unwrap();
    println!("without bias: max rel {:.2e}", r.max_rel_error);
    assert!(r.max_rel_error < 1e-8, "{r:?}");
}

#[test]
fn fused_equals_composed_in_f32() {
    let (x, w, b) = inputs(DType::F32);
    let (xv, wv, bv) = (Var::from_tensor(&x).unwrap(), Var::from_tensor(&w).unwrap(), Var::from_tensor(&b).unwrap());
    let target = seed::randn((3, 4, 6), 0.0, 1.0, DType::F32, &Device::Cpu, 4).unwrap();
    let run = || {
        let y = linear(xv.as_tensor(), wv.as_tensor(), Some(bv.as_tensor())).unwrap();
        let g = (&y - &target).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap();
        let grad = |v: &Var| g.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        (y.flatten_all().unwrap().to_vec1::<f32>().unwrap(), grad(&xv), grad(&wv), grad(&bv))
    };
    let fused = run();
    let composed = with_composed(run);
    let max_diff =
        |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(p, q)| (p - q).abs() / q.abs().max(1.0)).fold(0.0f32, f32::max);
    for (name, a, b) in [
        ("y", &fused.0, &composed.0),
        ("dx", &fused.1, &composed.1),
        ("dw", &fused.2, &composed.2),
        ("db", &fused.3, &composed.3),
    ] {
        let d = max_diff(a, b);
        println!("{name}: {d:.2e}");
        assert!(d < 1e-5, "{name}: fused and composed differ by {d}");
    }
}

#[test]
fn shape_errors_name_the_layout() {
    let (x, _, b) = inputs(DType::F32);
    let bad_w = Tensor::zeros((6, 4), DType::F32, &Device::Cpu).unwrap();
    let err = linear(&x, &bad_w, Some(&b)).unwrap_err().to_string();
    assert!(err.contains("[outputs, inputs]"), "{err}");
    let w = Tensor::zeros((6, 5), DType::F32, &Device::Cpu).unwrap();
    let bad_b = Tensor::zeros(5, DType::F32, &Device::Cpu).unwrap();
    let err = linear(&x, &w, Some(&bad_b)).unwrap_err().to_string();
    assert!(err.contains("bias"), "{err}");
}

#[test]
fn constant_input_rank_one_and_zero_outputs() {
    // x without gradient (data): only dW and db are formed; they equal the composed ones.
    let (x, w, b) = inputs(DType::F64);
    let (wv, bv) = (Var::from_tensor(&w).unwrap(), Var::from_tensor(&b).unwrap());
    let grads_of = |composed: bool| {
        let run = || {
            let y = linear(&x, wv.as_tensor(), Some(bv.as_tensor())).unwrap();
            let g = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
            let get = |v: &Var| g.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            (get(&wv), get(&bv))
        };
        if composed {
            with_composed(run)
        } else {
            run()
        }
    };
    let (fused, composed) = (grads_of(false), grads_of(true));
    for (a, c) in fused.0.iter().chain(&fused.1).zip(composed.0.iter().chain(&composed.1)) {
        assert!((a - c).abs() <= 1e-12 * c.abs().max(1.0), "{a} vs {c}");
    }
    // A single vector is one row, on both paths.
    let v = Tensor::new(&[1.0f64, -2.0, 0.5, 3.0, 0.0], &Device::Cpu).unwrap();
    let y1 = linear(&v, &w, Some(&b)).unwrap().to_vec1::<f64>().unwrap();
    let y2 = with_composed(|| linear(&v, &w, Some(&b))).unwrap().to_vec1::<f64>().unwrap();
    assert_eq!(y1.len(), 6);
    for (p, q) in y1.iter().zip(&y2) {
        assert!((p - q).abs() < 1e-12, "{p} vs {q}");
    }
    // No outputs: an empty result, not a panic.
    let w0 = Tensor::zeros((0, 5), DType::F64, &Device::Cpu).unwrap();
    let b0 = Tensor::zeros(0, DType::F64, &Device::Cpu).unwrap();
    assert_eq!(linear(&x, &w0, Some(&b0)).unwrap().dims(), &[3, 4, 0]);
}
