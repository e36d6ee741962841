//! Temporal metrics for frame sequences (videos, simulation rollouts): a dense optical flow and
//! the scores of TecoGAN (Chu et al., "Learning temporal coherence via self-supervision for
//! GAN-based video generation", ToG 2020) next to the per-frame ones.
//!
//! | item | what it is |
//! |---|---|
//! | [`optical_flow`], [`optical_flow_tensor`], [`Flow`], [`FlowOptions`] | dense optical flow between two grey frames: coarse-to-fine Horn–Schunck with bicubic warping ([`flow`] documents the method and the sign convention `frame0(y, x) ≈ frame1(y + v, x + u)`) |
//! | [`tof`], [`tof_pairs`] | TecoGAN's tOF: mean `|OF(truth pair) - OF(output pair)|_2` over (centre-cropped, [`Crop`]) pixels and consecutive pairs |
//! | [`tlsim`], [`tlsim_pairs`] | tLSiM: TecoGAN's tLP, `100 |d(truth_(t-1), truth_t) - d(output_(t-1), output_t)|`, with LSiM as `d` in place of LPIPS, because LPIPS' backbone weights are not available offline; LSiM is a learned metric for simulation fields |
//! | [`psnr`], [`ssim`], [`lsim_mean`] (and `*_frames`) | per-frame PSNR, SSIM (Wang et al. 2004, window 11, sigma 1.5) and LSiM to the truth, averaged over frames |
//! | [`TemporalScores`] | all five at once, with Markdown table rows |
//!
//! Sequences are tensors `[t, channel, y, x]` (`f32`/`f64`), output and truth of one shape; the
//! flow-based scores take 1 (grey) or 3 (RGB, converted to luma) channels. Bad input is a typed
//! [`crate::Error`] naming the argument.
//!
//! tOF and tLSiM measure whether an output *changes* between frames as the truth does: a
//! sequence that is right on every frame scores 0, and so does one that is wrong by the same
//! static amount on every frame; a flickering sequence does not. Because the flow estimator is
//! not OpenCV's Farnebäck and the distance is LSiM instead of LPIPS, the values compare methods
//! with each other, not with the numbers published for Vid4.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_metrics::temporal::{optical_flow, tof, FlowOptions, TofOptions};
//!
//! // Two frames of a smooth pattern; in the second it has moved by (0.5, -0.25) pixels.
//! let (ny, nx) = (48, 48);
//! let pattern = |x: f64, y: f64| ((x / 5.0).sin() * (y / 7.0).cos() + (0.1 * (x + y)).sin()) as f32;
//! let frame = |sx: f64, sy: f64| -> Vec<f32> {
//!     (0..ny * nx).map(|i| pattern((i % nx) as f64 - sx, (i / nx) as f64 - sy)).collect()
//! };
//! let (f0, f1) = (frame(0.0, 0.0), frame(0.5, -0.25));
//! let flow = optical_flow(&f0, &f1, ny, nx, &FlowOptions::default())?;
//! let (u, v) = flow.at(24, 24); // x (column) and y (row) components
//! assert!((u - 0.5).abs() < 0.05 && (v + 0.25).abs() < 0.05);
//!
//! // tOF of a 3-frame sequence against itself is 0.
//! let seq: Vec<f32> = [frame(0.0, 0.0), frame(0.5, 0.0), frame(1.0, 0.0)].concat();
//! let seq = Tensor::from_vec(seq, (3, 1, ny, nx), &Device::Cpu)?;
//! assert_eq!(tof(&seq, &seq, &TofOptions::default())?, 0.0);
//! # Ok::<(), pbdl_metrics::Error>(())
//! ```

pub mod flow;
mod scores;

pub use flow::{optical_flow, optical_flow_tensor, Flow, FlowOptions, MIN_FLOW_SIDE, PYRAMID_SIGMA};
pub use scores::{
    lsim_frames, lsim_mean, psnr, psnr_frames, ssim, ssim_frames, tlsim, tlsim_pairs, tof, tof_pairs, Crop,
    TemporalOptions, TemporalScores, TofOptions,
};
