//! Autoregressive rollouts: a [`FramePredictor`] maps the last `history` frames to the next one;
//! [`rollout`] unrolls it, overwriting the Reynolds-number channel with its true value after
//! every frame (as the official evaluation does) and stopping at the first non-finite frame.

use super::data::{CHANNELS, FIELDS};
use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// A model that predicts the next normalised frame from the previous ones.
pub trait FramePredictor {
    /// How many previous frames the model is conditioned on (2 for ACDM, 1 for the U-Nets).
    fn history(&self) -> usize;

    /// Predicts `[B, C, ny, nx]` from `prev`: `[B, history, C, ny, nx]`, oldest first. `seed`
    /// drives any sampling noise (same seed, same frame).
    fn predict(&self, prev: &Tensor, seed: u64) -> Result<Tensor>;

    /// A short name for tables.
    fn name(&self) -> String;
}

/// Checks that `prev` is `[B, history, 4, ny, nx]`; the error names what to change.
pub fn check_conditioning(prev: &Tensor, history: usize, ny: usize, nx: usize) -> Result<()> {
    let d = prev.dims();
    if d.len() != 5 || d[1] != history || d[2] != CHANNELS || d[3] != ny || d[4] != nx {
        return Err(Error::shape(
            format!("conditioning frames (the model needs {history} previous [vx, vy, p, Re] frames)"),
            format!("[B, {history}, {CHANNELS}, {ny}, {nx}]"),
            d,
        ));
    }
    Ok(())
}

/// The result of [`rollout`].
#[derive(Clone, Debug)]
pub struct Rollout {
    /// Predicted frames `[steps_done, B, C, ny, nx]` (normalised), not including the initial ones.
    pub frames: Tensor,
    /// The first step (1-based) whose frame was not finite; the rollout stopped there.
    pub first_non_finite: Option<usize>,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Unrolls `model` for `steps` frames from `init`: `[B, history, C, ny, nx]` (normalised).
/// After every frame the Re channel (last) is overwritten with `re_channel` (the normalised
/// value, one per batch entry). `seed` is varied per step.
pub fn rollout(
    model: &dyn FramePredictor,
    init: &Tensor,
    re_channel: &[f64],
    steps: usize,
    seed: u64,
) -> Result<Rollout> {
    let start = std::time::Instant::now();
    let h = model.history();
    let dims = init.dims().to_vec();
    if dims.len() != 5 {
        return Err(Error::shape("rollout init", format!("[B, {h}, {CHANNELS}, ny, nx]"), &dims));
    }
    check_conditioning(init, h, dims[3], dims[4])?;
    let b = dims[0];
    if re_channel.len() != b {
        return Err(Error::shape("rollout re_channel (one value per batch entry)", b, re_channel.len()));
    }
    let (ny, nx) = (dims[3], dims[4]);
    let re = Tensor::from_vec(re_channel.iter().map(|&r| r as f32).collect::<Vec<f32>>(), (b, 1, 1, 1), init.device())?
        .broadcast_as((b, 1, ny, nx))?
        .contiguous()?;
    let mut window: Vec<Tensor> =
        (0..h).map(|k| init.narrow(1, k, 1)?.squeeze(1)).collect::<candle_core::Result<_>>()?;
    let mut out = Vec::with_capacity(steps);
    let mut first_non_finite = None;
    for step in 0..steps {
        let prev = Tensor::stack(&window, 1)?;
        let next = model.predict(&prev, seed.wrapping_add(step as u64).wrapping_mul(0x9E37_79B9))?;
        if next.dims() != [b, CHANNELS, ny, nx] {
            return Err(Error::shape(format!("{} output", model.name()), [b, CHANNELS, ny, nx], next.dims()));
        }
        let next = Tensor::cat(&[next.narrow(1, 0, FIELDS)?.to_dtype(DType::F32)?, re.clone()], 1)?;
        let finite = next.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?.is_finite();
        if !finite {
            first_non_finite = Some(step + 1);
            break;
        }
        window.remove(0);
        window.push(next.clone());
        out.push(next);
    }
    let frames = if out.is_empty() {
        Tensor::zeros((0, b, CHANNELS, ny, nx), DType::F32, init.device())?
    } else {
        Tensor::stack(&out, 0)?
    };
    Ok(Rollout { frames, first_non_finite, seconds: start.elapsed().as_secs_f64() })
}
