//! # pbdl-core
//!
//! The shared foundation of the pbdl crates: everything a differentiable simulator or a
//! physics-based learning method needs besides its own physics.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | sequence datasets: [`data::SequenceSource`] (in memory or streamed from `.npz` shards), seeded splits, random training windows, generate-once caching |
//! | [`error`] | the crate's [`Error`] enum and shape/dtype/finiteness checks |
//! | [`real`] | the [`Real`] float trait (`f32`, `f64`) that kernels are generic over |
//! | [`noise`] | seeded noise: independent streams of one seed ([`noise::stream_seed`]), smooth periodic power-law fields ([`noise::power_law_noise`]), periodic Perlin gradient noise ([`noise::perlin_1d`], [`noise::perlin_2d`]) |
//! | [`op`] | a toolkit for differentiable candle custom ops (forward + backward in one place) |
//! | [`grad_check`] | [`check_grad`] (central finite differences) and gradient-presence checks |
//! | [`seed`] | seeded random tensors: same seed, same numbers |
//! | [`conv`] | fast differentiable conv1d/2d/3d (im2col + gemm): stride, dilation, groups, zero or circular padding; layers |
//! | [`nn`] | layer/group/RMS norm, softmax and activations that train (candle's fused ones have no backward) |
//! | [`tolerance`] | named test tolerances with their reasons ([`tolerance::GRAD_CHECK_F64`], f32/f64 agreement) |
//! | [`train`] | optimisers (Adam/AdamW/SGD+momentum) from serde configs, lr schedules, gradient clipping, CSV/JSON scalar logs, progress bar, divergence guard |
//! | [`sample`] | differentiable bilinear/trilinear sampling at points and warping (clamped or periodic), resize (nearest, bilinear, bicubic) |
//! | [`fft`] | differentiable real FFTs over the last 2 or 3 axes as numpy/PyTorch ([`fft::rfft2`], [`fft::irfft2`], [`fft::rfft3`], [`fft::irfft3`]; `(re, im)` as a trailing axis), [`fft::power_spectrum_2d`] |
//! | [`shard`] | sharded data generation: `--shard i/n` item ranges, manifests with SHA-256, [`shard::open_shards`] checks and reads a directory of shards |
//! | [`stepper`] | the simulator seams: [`stepper::Stepper`] (state in, state out, operators listed, differentiable where it is) and [`stepper::Evolve`] (in place, adaptive step, `run_until`) |
//! | [`testing`] | for tests that need `../shared` data or published weights: a visible skip that fails in CI ([`testing::skip_or_fail`]) |
//! | [`threads`] | the one thread policy: [`threads::init`] sets rayon's pool, candle's and gemm's thread count once (`PBDL_THREADS`), [`threads::parallel`] says whether an op is big enough to split (`PBDL_SERIAL_BELOW`) |
//! | `ndarray_interop` (feature `ndarray`) | candle tensors to and from `ndarray` arrays: buffers moved, views without copies |
//! | [`malloc`] | [`malloc::keep_freed_memory`]: glibc keeps freed tensor buffers instead of returning them to the OS (called by [`threads::init`]; `PBDL_TUNE_MALLOC=0` to skip) |
//! | [`matmul`] | [`matmul::matmul`]: the one bounds-checked strided matrix product (gemm, runtime CPU dispatch) behind every hand-written kernel |
//! | [`io`] | atomic writes, checkpoints (safetensors + JSON sidecar, resume from the latest), `.npy`/`.npz` with typed errors |
//! | [`vmath`] | branch-free `exp`, `expm1`, `tanh`, `sigmoid` that vectorise, slice maps with runtime AVX2 dispatch (libm's scalar calls dominated the fused LSTM) |
//! | `viz` (feature `viz`) | colormaps (viridis, blue-white-red), field and quiver PNGs (y up), rollout GIFs, line and Pareto plots with a bundled font |
//!
//! Conventions: tensors are candle `Tensor`s laid out `[batch, channel, (z,) y, x]` with x
//! fastest; `f32` by default, `f64` where an accuracy test needs it.
#![warn(missing_docs)]

pub mod conv;
pub mod data;
pub mod error;
pub mod fft;
pub mod grad_check;
pub mod io;
pub mod malloc;
pub mod matmul;
#[cfg(feature = "ndarray")]
pub mod ndarray_interop;
pub mod nn;
pub mod noise;
pub mod op;
pub mod real;
pub mod sample;
pub mod seed;
pub mod shard;
pub mod stepper;
pub mod testing;
pub mod threads;
pub mod tolerance;
pub mod train;
#[cfg(feature = "viz")]
pub mod viz;
pub mod vmath;

pub use error::{Error, Result};
pub use grad_check::{assert_all_have_grads, assert_varmap_has_grads, check_grad, GradCheckOptions, GradCheckReport};
pub use real::Real;
