//! Helpers shared by the convolution test files (`mod common;`); each file uses only some.
#![allow(dead_code)]

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::ConvParams;
use pbdl_core::seed;

pub use pbdl_core::tolerance::{F32_AGREEMENT as F32_TOL, F64_AGREEMENT as F64_TOL, GRAD_CHECK_F64 as GRAD_TOL};

/// Standard-normal samples of `shape`, seeded.
pub fn randn(shape: &[usize], dtype: DType, seed: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, dtype, &Device::Cpu, seed).unwrap()
}

/// max |t| over all elements, in f64.
pub fn max_abs(t: &Tensor) -> f64 {
    t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
}

/// max |a - b| / max |b|.
pub fn rel_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.dims(), b.dims(), "shapes differ");
    max_abs(&(a - b).unwrap()) / max_abs(b).max(1e-30)
}

/// Output and gradients (input, weight, bias) under the loss `sum(y * r)`, `r` seeded.
pub fn value_and_grads<const N: usize>(
    f: fn(&Tensor, &Tensor, Option<&Tensor>, &ConvParams<N>) -> pbdl_core::Result<Tensor>,
    x: &Tensor,
    w: &Tensor,
    b: &Tensor,
    p: &ConvParams<N>,
) -> [Tensor; 4] {
    let (xv, wv, bv) = (Var::from_tensor(x).unwrap(), Var::from_tensor(w).unwrap(), Var::from_tensor(b).unwrap());
    let y = f(xv.as_tensor(), wv.as_tensor(), Some(bv.as_tensor()), p).unwrap();
    let r = randn(y.dims(), y.dtype(), 99);
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let get = |v: &Var| grads.get(v.as_tensor()).expect("missing gradient").clone();
    [y, get(&xv), get(&wv), get(&bv)]
}
