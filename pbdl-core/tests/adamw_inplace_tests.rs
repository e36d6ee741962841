//! AdamW (`pbdl_core::train`, in-place kernels on the CPU) against candle-nn's own `AdamW` and
//! against pbdl's composed update (`with_composed`): bit-identical variables after several
//! updates, for Adam and AdamW, `f32` and `f64`, with exact-zero gradients and `-0.0` entries.
//! (`adamw_inplace`'s unit tests check that the in-place kernels themselves run and agree.)

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, ParamsAdamW};
use pbdl_core::nn::with_composed;
use pbdl_core::seed;
use pbdl_core::train::{AdamWConfig, OptimizerConfig};

/// Variable values (with `-0.0` entries) and a fixed gradient (with exact zeros) per variable.
fn problem(dtype: DType) -> Vec<(Tensor, Tensor)> {
    let dev = Device::Cpu;
    [(vec![7usize, 5], 1u64), (vec![7], 2), (vec![2, 3, 4], 3)]
        .into_iter()
        .map(|(shape, s)| {
            let n: usize = shape.iter().product();
            let mut v = seed::randn(n, 0.0, 0.5, DType::F64, &dev, s).unwrap().to_vec1::<f64>().unwrap();
            let mut g = seed::randn(n, 0.0, 1.0, DType::F64, &dev, 10 + s).unwrap().to_vec1::<f64>().unwrap();
            for i in (0..n).step_by(3) {
                g[i] = 0.0;
            }
            for i in (1..n).step_by(4) {
                v[i] = -0.0;
            }
            let t = |d: Vec<f64>| Tensor::from_vec(d, shape.as_slice(), &dev).unwrap().to_dtype(dtype).unwrap();
            (t(v), t(g))
        })
        .collect()
}

/// Six updates of `opt` on the loss `sum(v * g)` (whose gradient is exactly `g`); the final
/// variables as bits.
fn run<O: Optimizer>(dtype: DType, build: impl FnOnce(Vec<Var>) -> O) -> Vec<Vec<u64>> {
    let p = problem(dtype);
    let vars: Vec<Var> = p.iter().map(|(v, _)| Var::from_tensor(v).unwrap()).collect();
    let mut opt = build(vars.clone());
    for _ in 0..6 {
        let loss = vars
            .iter()
            .zip(&p)
            .map(|(v, (_, g))| (v.as_tensor() * g).unwrap().sum_all().unwrap())
            .reduce(|a, b| (a + b).unwrap())
            .unwrap();
        opt.backward_step(&loss).unwrap();
    }
    vars.iter()
        .map(|v| {
            let t = v.as_tensor().flatten_all().unwrap().to_dtype(DType::F64).unwrap();
            t.to_vec1::<f64>().unwrap().into_iter().map(f64::to_bits).collect()
        })
        .collect()
}

#[test]
fn in_place_update_is_bit_identical_to_candle_nn_and_to_the_composed_one() {
    for dtype in [DType::F32, DType::F64] {
        for (lr, weight_decay) in [(1e-2, 0.0), (3e-3, 0.1)] {
            let config = OptimizerConfig::AdamW(AdamWConfig { lr, weight_decay, ..Default::default() });
            let ours = run(dtype, |vars| config.build(vars).unwrap());
            let composed = with_composed(|| run(dtype, |vars| config.build(vars).unwrap()));
            let params = ParamsAdamW { lr, weight_decay, ..Default::default() };
            let candle = run(dtype, |vars| candle_nn::AdamW::new(vars, params).unwrap());
            let start = problem(dtype);
            for (i, ((a, b), c)) in ours.iter().zip(&composed).zip(&candle).enumerate() {
                assert_eq!(a, c, "{dtype:?} lr {lr} wd {weight_decay}: variable {i} differs from candle-nn");
                assert_eq!(a, b, "{dtype:?} lr {lr} wd {weight_decay}: variable {i} differs from the composed update");
                // The update moved the variable.
                let before: Vec<u64> = start[i]
                    .0
                    .flatten_all()
                    .unwrap()
                    .to_dtype(DType::F64)
                    .unwrap()
                    .to_vec1::<f64>()
                    .unwrap()
                    .into_iter()
                    .map(f64::to_bits)
                    .collect();
                assert_ne!(a, &before);
            }
        }
    }
}
