//! The in-place AdamW kernels against candle-nn's tensor expression (run inside
//! `with_composed`): bit-identical variables and moments after several updates, for Adam and
//! AdamW, `f32` and `f64`, with gradients that hit exact zeros and come from a strided view.

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::Optimizer;
use pbdl_core::nn::{linear, with_composed};
use pbdl_core::seed;
use pbdl_core::train::{AdamConfig, AdamWConfig, OptimizerConfig};

/// Variables, then the update: 6 steps on a loss whose gradient has exact zeros (relu) and
/// whose weight gradient is a view into a packed buffer (`linear`'s backward).
fn train(dtype: DType, config: OptimizerConfig) -> Vec<Vec<u64>> {
    let dev = Device::Cpu;
    let w = Var::from_tensor(&seed::randn((7, 5), 0.0, 0.5, dtype, &dev, 1).unwrap()).unwrap();
    let b = Var::from_tensor(&seed::randn(7, 0.0, 0.5, dtype, &dev, 2).unwrap()).unwrap();
    let u = Var::from_tensor(&seed::randn((2, 3, 4), 0.0, 0.5, dtype, &dev, 3).unwrap()).unwrap();
    let x = seed::randn((9, 5), 0.0, 1.0, dtype, &dev, 4).unwrap();
    let mut opt = config.build(vec![w.clone(), b.clone(), u.clone()]).unwrap();
    for _ in 0..6 {
        let y = linear(&x, w.as_tensor(), Some(b.as_tensor())).unwrap().relu().unwrap();
        let loss = (y.sqr().unwrap().mean_all().unwrap() + u.as_tensor().sqr().unwrap().sum_all().unwrap()).unwrap();
        opt.backward_step(&loss).unwrap();
    }
    let bits = |t: &Tensor| -> Vec<u64> {
        let t = t.flatten_all().unwrap().to_dtype(DType::F64).unwrap();
        t.to_vec1::<f64>().unwrap().into_iter().map(f64::to_bits).collect()
    };
    let mut out: Vec<Vec<u64>> = [&w, &b, &u].iter().map(|v| bits(v.as_tensor())).collect();
    for (_, _, t) in opt.state().unwrap().slots {
        out.push(bits(&t));
    }
    out
}

#[test]
fn in_place_update_is_bit_identical_to_the_composed_one() {
    let configs = [
        OptimizerConfig::Adam(AdamConfig { lr: 1e-2, ..Default::default() }),
        OptimizerConfig::AdamW(AdamWConfig { lr: 3e-3, weight_decay: 0.1, ..Default::default() }),
    ];
    for dtype in [DType::F32, DType::F64] {
        for config in configs {
            let fused = train(dtype, config);
            let composed = with_composed(|| train(dtype, config));
            assert_eq!(fused.len(), 9, "3 variables + 6 moment slots");
            for (i, (a, b)) in fused.iter().zip(&composed).enumerate() {
                assert_eq!(a, b, "{dtype:?} {config:?}: tensor {i} differs");
            }
            // The run moved the variables (the comparison is not between two untouched copies).
            assert_ne!(
                fused[0],
                with_composed(|| train(dtype, OptimizerConfig::Adam(AdamConfig { lr: 0.0, ..Default::default() })))[0]
            );
        }
    }
}
