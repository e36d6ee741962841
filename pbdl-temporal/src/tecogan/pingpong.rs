//! The ping-pong sequence, its loss and the drift metric.
//!
//! Sequences are `[T, C, y, x]` (time on axis 0) or `[B, T, C, y, x]` (time on axis 1).

use crate::{Error, Result};
use candle_core::Tensor;

fn time_axis(x: &Tensor, what: &str) -> Result<usize> {
    match x.rank() {
        4 => Ok(0),
        5 => Ok(1),
        _ => Err(Error::input(what, format!("{:?}: expected [frames, c, y, x] or [batch, frames, c, y, x]", x.dims()))),
    }
}

fn select_frames(x: &Tensor, axis: usize, frames: &[usize]) -> Result<Tensor> {
    let idx: Vec<u32> = frames.iter().map(|&i| i as u32).collect();
    let idx = Tensor::from_vec(idx, frames.len(), x.device())?;
    Ok(x.index_select(&idx, axis)?)
}

/// `x` with its frames in reverse order (differentiable).
pub fn reverse_time(x: &Tensor) -> Result<Tensor> {
    let axis = time_axis(x, "sequence")?;
    let t = x.dim(axis)?;
    select_frames(x, axis, &(0..t).rev().collect::<Vec<_>>())
}

/// TecoGAN's ping-pong extension: frames `0..T-1` followed by `T-2..0` (`2T - 1` frames; frame
/// `T - 1`, the turning point, appears once). `T >= 2`.
pub fn pingpong_sequence(x: &Tensor) -> Result<Tensor> {
    let axis = time_axis(x, "sequence")?;
    let t = x.dim(axis)?;
    if t < 2 {
        return Err(Error::input("sequence", format!("{t} frames: the ping-pong extension needs at least 2")));
    }
    let order: Vec<usize> = (0..t).chain((0..t - 1).rev()).collect();
    select_frames(x, axis, &order)
}

/// Splits the output of a ping-pong sequence (`2T - 1` frames) into the forward results of
/// frames `0..T-1` (exclusive of the turning point) and the backward results of the same frames,
/// aligned: both `T - 1` frames, entry `t` is frame `t`.
pub fn split_pingpong(out: &Tensor) -> Result<(Tensor, Tensor)> {
    let axis = time_axis(out, "ping-pong output")?;
    let len = out.dim(axis)?;
    if len < 3 || len % 2 == 0 {
        return Err(Error::input(
            "ping-pong output",
            format!("{len} frames: expected an odd count 2T - 1 >= 3 (see pingpong_sequence)"),
        ));
    }
    let t = len.div_ceil(2);
    let forward = out.narrow(axis, 0, t - 1)?;
    let backward = select_frames(out, axis, &(0..t - 1).map(|i| len - 1 - i).collect::<Vec<_>>())?;
    Ok((forward, backward))
}

/// The ping-pong loss `mean |g_t - g'_t|` over the frames that appear twice in a ping-pong
/// output (`2T - 1` frames, see [`pingpong_sequence`]); a scalar tensor, differentiable.
pub fn pingpong_loss(out: &Tensor) -> Result<Tensor> {
    let (f, b) = split_pingpong(out)?;
    drift_tensor(&f, &b)
}

/// `mean |a - b|` as a scalar tensor (differentiable); `a` and `b` of one shape.
pub fn drift_tensor(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    if a.dims() != b.dims() {
        return Err(Error::input("drift", format!("{:?} vs {:?}: expected one shape", a.dims(), b.dims())));
    }
    Ok((a - b)?.abs()?.mean_all()?)
}

/// The drift metric `mean |g_t - g'_t|` between a forward run and a backward run of the same
/// frames (aligned in time, e.g. by [`split_pingpong`]), as `f64`.
pub fn drift(forward: &Tensor, backward: &Tensor) -> Result<f64> {
    Ok(drift_tensor(forward, backward)?.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?)
}
