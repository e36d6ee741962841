//! # pbdl-pconv
//!
//! Learned particle convolutions on neighbour lists, trained on pbdl-particles' SPH data:
//! continuous convolutions (CConv, Ummenhofer et al. 2020), separable basis convolutions
//! (SFBC, Winchenbach & Thuerey 2024) and momentum-conserving antisymmetric convolutions
//! (DMCF, Prantl et al. 2022), in 1D, 2D and 3D, as one candle custom op with a hand-written
//! backward pass for features, filter weights and positions.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`basis`] | 1D bases on `[-1, 1]`: linear hats (CConv), Fourier (full, SFBC's, even, odd), Chebyshev, Gaussian RBF |
//! | [`mapping`] | offset-to-filter coordinate maps: Cartesian and CConv's volume-preserving ball-to-cube, with Jacobians |
//! | [`window`] | radial windows: none, poly6 (CConv), peak (DMCF) |
//! | [`filter`] | [`FilterSpec`] (basis, terms, map, window, radius, antisymmetric) and the per-pair basis values with gradients |
//! | [`graph`] | [`PairGraph`]: receiver-sorted pairs within the radius (cell list, periodic images) and differentiable offsets |
//! | [`op`] | [`continuous_conv`]: the convolution as a custom op (block gather + GEMM), backward for features, weights, offsets |
//! | [`layer`] | [`ContinuousConv`]: a layer with its weights in a `VarMap` (seeded init) and an optional bias |
//! | [`net`] | [`net::BasisNetwork`]: SFBC's network (convolution + dense branch per layer, ReLU, output scale), optional antisymmetric last layer |
//! | [`liquid`] | CConv's liquid network (Ummenhofer et al. 2020) in 2D at CPU size: dam-break data from our WCSPH, two-step training, long rollouts against SPH with stability checks and a GIF |
//! | [`periodic_case`] | SFBC's test cases I (periodic 1D compressible SPH) and II (periodic 2D weakly compressible SPH) at CPU size: data from pbdl-particles, density / density-gradient / update tasks, training (resumable), test errors, rollouts, momentum drift |
//! | [`error`] | [`Error`], [`Result`] |
//!
//! ```
//! use std::sync::Arc;
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::VarMap;
//! use pbdl_pconv::{Basis, ContinuousConv, FilterSpec, PairGraph};
//! use pbdl_particles::Domain;
//!
//! // 64 particles on a periodic line, a Fourier filter over 4 particle spacings.
//! let x: Vec<[f64; 1]> = (0..64).map(|i| [i as f64 / 64.0]).collect();
//! let radius = 4.0 / 64.0;
//! let graph = Arc::new(PairGraph::build_self(&Domain::periodic([0.0], [1.0]), radius, &x)?);
//! let varmap = VarMap::new();
//! let conv = ContinuousConv::new(&varmap, "conv0", FilterSpec::sfbc(1, Basis::Fourier, 6, radius), 1, 8, true, 0)?;
//! let dev = Device::Cpu;
//! let pos = Tensor::from_vec(x.iter().map(|p| p[0] as f32).collect::<Vec<_>>(), (64, 1), &dev)?;
//! let ones = Tensor::ones((64, 1), DType::F32, &dev)?;
//! let out = conv.forward(&graph, &ones, &graph.offsets(&pos, &pos)?)?;
//! assert_eq!(out.dims(), &[64, 8]);
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```
#![warn(missing_docs)]

pub mod basis;
pub mod error;
pub mod filter;
pub mod graph;
pub mod layer;
pub mod liquid;
pub mod mapping;
pub mod net;
pub mod op;
pub mod periodic_case;
pub mod window;

pub use basis::Basis;
pub use error::{Error, Result};
pub use filter::FilterSpec;
pub use graph::PairGraph;
pub use layer::ContinuousConv;
pub use mapping::CoordinateMap;
pub use op::continuous_conv;
pub use window::Window;
