//! [`BasisNetwork`]: SFBC's network of continuous convolutions, each with a dense branch on the
//! same input (`h' = relu(conv(h) + dense(h))`), the output scaled down (`1/128` in SFBC and
//! CConv); optionally with an antisymmetric last layer (DMCF), whose outputs sum to zero.
//!
//! ```
//! use std::sync::Arc;
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::VarMap;
//! use pbdl_pconv::{net::{BasisNetwork, NetworkConfig}, Basis, FilterSpec, PairGraph};
//! use pbdl_particles::Domain;
//!
//! let x: Vec<[f64; 1]> = (0..32).map(|i| [i as f64 / 32.0 + 0.001 * (i % 3) as f64]).collect();
//! let r = 4.0 / 32.0;
//! let graph = Arc::new(PairGraph::build_self(&Domain::periodic([0.0], [1.0]), r, &x)?);
//! let cfg = NetworkConfig {
//!     antisymmetric_last: true,
//!     ..NetworkConfig::new(FilterSpec::sfbc(1, Basis::Fourier, 6, r), 2, vec![8, 1])
//! };
//! let varmap = VarMap::new();
//! let net = BasisNetwork::new(&varmap, cfg, 0)?;
//! let dev = Device::Cpu;
//! let pos = Tensor::from_vec(x.iter().map(|p| p[0] as f32).collect::<Vec<_>>(), (32, 1), &dev)?;
//! let f = pbdl_core::seed::randn((32, 2), 0.0, 1.0, DType::F32, &dev, 1)?;
//! let y = net.forward(&graph, &f, &graph.offsets(&pos, &pos)?)?;
//! // Antisymmetric last layer: the outputs sum to zero (f32 round-off).
//! assert!(y.sum_all()?.to_scalar::<f32>()?.abs() < 1e-5 * y.abs()?.sum_all()?.to_scalar::<f32>()?);
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::filter::FilterSpec;
use crate::graph::PairGraph;
use crate::layer::{insert, ContinuousConv};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Shape of a [`BasisNetwork`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkConfig {
    /// The filter of every layer (its `antisymmetric` flag is ignored; see `antisymmetric_last`).
    pub filter: FilterSpec,
    /// Feature channels per particle at the input.
    pub input_channels: usize,
    /// Output channels of each layer; the last is the network's output.
    pub widths: Vec<usize>,
    /// A dense (per-particle linear) branch beside each convolution.
    pub dense_branch: bool,
    /// The last convolution antisymmetric, without bias or dense branch (DMCF): `Σ_i out_i = 0`.
    pub antisymmetric_last: bool,
    /// Factor on the output (SFBC and CConv: 1/128).
    pub output_scale: f64,
}

impl NetworkConfig {
    /// Defaults: dense branches, no antisymmetry, output scale 1.
    pub fn new(filter: FilterSpec, input_channels: usize, widths: Vec<usize>) -> Self {
        NetworkConfig {
            filter,
            input_channels,
            widths,
            dense_branch: true,
            antisymmetric_last: false,
            output_scale: 1.0,
        }
    }

    fn validate(&self) -> Result<()> {
        self.filter.validate()?;
        if self.widths.is_empty() || self.widths.contains(&0) || self.input_channels == 0 {
            return Err(Error::Config {
                field: "widths",
                reason: format!(
                    "{:?} with {} inputs; give at least one layer, no zero widths",
                    self.widths, self.input_channels
                ),
            });
        }
        if !self.output_scale.is_finite() {
            return Err(Error::Config { field: "output_scale", reason: format!("{}", self.output_scale) });
        }
        Ok(())
    }
}

/// A dense per-particle layer `x W + b`.
#[derive(Clone, Debug)]
struct Dense {
    weight: Tensor,
    bias: Tensor,
}

/// Continuous convolutions with dense branches and ReLU between layers.
#[derive(Clone, Debug)]
pub struct BasisNetwork {
    cfg: NetworkConfig,
    convs: Vec<ContinuousConv>,
    dense: Vec<Option<Dense>>,
}

impl BasisNetwork {
    /// Creates the variables in `varmap` (f32) from `seed`.
    pub fn new(varmap: &VarMap, cfg: NetworkConfig, seed: u64) -> Result<Self> {
        Self::new_as(varmap, cfg, seed, DType::F32)
    }

    /// [`BasisNetwork::new`] in the given float dtype.
    pub fn new_as(varmap: &VarMap, cfg: NetworkConfig, seed: u64, dtype: DType) -> Result<Self> {
        cfg.validate()?;
        let mut convs = Vec::new();
        let mut dense = Vec::new();
        let mut c_in = cfg.input_channels;
        let last = cfg.widths.len() - 1;
        for (l, &c_out) in cfg.widths.iter().enumerate() {
            let anti = cfg.antisymmetric_last && l == last;
            let spec = FilterSpec { antisymmetric: anti, ..cfg.filter };
            let layer_seed = pbdl_core::noise::stream_seed(seed, 2 * l as u64);
            convs.push(ContinuousConv::new_as(
                varmap,
                &format!("conv{l}"),
                spec,
                c_in,
                c_out,
                !anti,
                layer_seed,
                dtype,
            )?);
            dense.push(if cfg.dense_branch && !anti {
                let bound = 1.0 / (c_in as f64).sqrt();
                let s = pbdl_core::noise::stream_seed(seed, 2 * l as u64 + 1);
                let w = pbdl_core::seed::rand_uniform((c_in, c_out), -bound, bound, dtype, &Device::Cpu, s)?;
                Some(Dense {
                    weight: insert(varmap, &format!("dense{l}.weight"), w)?,
                    bias: insert(varmap, &format!("dense{l}.bias"), Tensor::zeros(c_out, dtype, &Device::Cpu)?)?,
                })
            } else {
                None
            });
            c_in = c_out;
        }
        Ok(BasisNetwork { cfg, convs, dense })
    }

    /// The configuration.
    pub fn config(&self) -> &NetworkConfig {
        &self.cfg
    }

    /// The convolution layers, first to last.
    pub fn convolutions(&self) -> &[ContinuousConv] {
        &self.convs
    }

    /// `features [n, input_channels]` -> `[n, widths.last()]` on a self graph.
    pub fn forward(&self, graph: &Arc<PairGraph>, features: &Tensor, offsets: &Tensor) -> Result<Tensor> {
        let mut h = features.clone();
        let last = self.convs.len() - 1;
        for (l, (conv, dense)) in self.convs.iter().zip(&self.dense).enumerate() {
            let mut y = conv.forward(graph, &h, offsets)?;
            if let Some(d) = dense {
                y = (y + h.matmul(&d.weight)?.broadcast_add(&d.bias)?)?;
            }
            h = if l < last { y.relu()? } else { y };
        }
        Ok(if self.cfg.output_scale == 1.0 { h } else { (h * self.cfg.output_scale)? })
    }
}
