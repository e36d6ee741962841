//! [`ContinuousConv`]: the convolution as a trainable layer, weights `[K, C_in, C_out]` in a
//! `VarMap` (so `pbdl_core::io` checkpoints them), uniform seeded initialisation and an
//! optional bias.

use crate::error::Result;
use crate::filter::FilterSpec;
use crate::graph::PairGraph;
use crate::op::continuous_conv;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::VarMap;
use std::sync::Arc;

/// A continuous-convolution layer.
#[derive(Clone, Debug)]
pub struct ContinuousConv {
    spec: FilterSpec,
    weight: Tensor,
    bias: Option<Tensor>,
}

impl ContinuousConv {
    /// Creates the layer's variables `{name}.weight` (and `{name}.bias`) in `varmap`, in f32,
    /// drawn uniformly in `±1/sqrt(K C_in)` from `seed` (CConv draws in ±0.05; both keep the
    /// output variance independent of the filter size), the bias zero.
    pub fn new(
        varmap: &VarMap,
        name: &str,
        spec: FilterSpec,
        c_in: usize,
        c_out: usize,
        bias: bool,
        seed: u64,
    ) -> Result<Self> {
        Self::new_as(varmap, name, spec, c_in, c_out, bias, seed, DType::F32)
    }

    /// [`ContinuousConv::new`] in the given float dtype (f64 for gradient checks).
    #[allow(clippy::too_many_arguments)]
    pub fn new_as(
        varmap: &VarMap,
        name: &str,
        spec: FilterSpec,
        c_in: usize,
        c_out: usize,
        bias: bool,
        seed: u64,
        dtype: DType,
    ) -> Result<Self> {
        spec.validate()?;
        let k = spec.filter_size();
        let bound = 1.0 / ((k * c_in.max(1)) as f64).sqrt();
        let dev = Device::Cpu;
        let w = pbdl_core::seed::rand_uniform((k, c_in, c_out), -bound, bound, dtype, &dev, seed)?;
        let weight = insert(varmap, &format!("{name}.weight"), w)?;
        let bias = if bias {
            Some(insert(varmap, &format!("{name}.bias"), Tensor::zeros(c_out, dtype, &dev)?)?)
        } else {
            None
        };
        Ok(ContinuousConv { spec, weight, bias })
    }

    /// The filter.
    pub fn spec(&self) -> &FilterSpec {
        &self.spec
    }

    /// The weights `[K, C_in, C_out]`.
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    /// `conv(features) [+ bias]`, `[n_receivers, C_out]`.
    pub fn forward(&self, graph: &Arc<PairGraph>, features: &Tensor, offsets: &Tensor) -> Result<Tensor> {
        let y = continuous_conv(features, &self.weight, offsets, graph, &self.spec)?;
        Ok(match &self.bias {
            Some(b) => y.broadcast_add(b)?,
            None => y,
        })
    }
}

/// Puts `value` into `varmap` under `name` (replacing nothing: an existing variable is kept and
/// returned, as `VarBuilder::get` does) and returns the variable's tensor.
pub(crate) fn insert(varmap: &VarMap, name: &str, value: Tensor) -> Result<Tensor> {
    let mut data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    if let Some(v) = data.get(name) {
        return Ok(v.as_tensor().clone());
    }
    let var = Var::from_tensor(&value)?;
    let t = var.as_tensor().clone();
    data.insert(name.to_string(), var);
    Ok(t)
}
