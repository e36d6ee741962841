//! The arrays of an init file (`Simulation::set_fields`), checked and resampled to the grid.

use super::{c, max_abs};
use crate::scene::{SceneError, SceneResult};
use crate::Error;
use candle_core::{DType, Tensor};
use pbdl_core::sample::{resize2d, Resize};

/// Named arrays given to a scene, with what is needed to read them onto its grid.
pub(crate) struct FieldInput<'a> {
    /// The arrays.
    pub arrays: &'a [(String, Tensor)],
    /// The scene name (for errors).
    pub scene: &'a str,
    /// The grid size `(ny, nx)`.
    pub shape: (usize, usize),
    /// The precision of the state.
    pub dtype: DType,
}

impl FieldInput<'_> {
    /// A [`SceneError::Invalid`] naming the array.
    pub fn invalid(&self, field: &str, reason: String) -> SceneError {
        SceneError::Invalid { scene: self.scene.into(), field: format!("init file: {field}"), reason }
    }

    /// The array called `name`.
    pub fn find(&self, name: &str) -> Option<Tensor> {
        self.arrays.iter().find(|(n, _)| n == name).map(|(_, t)| t.clone())
    }

    /// The array names.
    pub fn names(&self) -> Vec<&str> {
        self.arrays.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// `t` as f64 `[1, channels, ny, nx]`: rank 1-2 (one channel), `[C, Y, X]`, or the last frame
    /// of `[T, C, Y, X]`; checked finite, resampled bilinearly when `Y, X` differ from the grid.
    pub fn to4(&self, name: &str, t: &Tensor, channels: usize) -> SceneResult<Tensor> {
        let t = c(t.to_dtype(DType::F64))?;
        let t = match t.rank() {
            1 if channels == 1 => c(t.reshape((1, 1, 1, t.dims()[0])))?,
            2 if channels == 1 => c(t.unsqueeze(0).and_then(|t| t.unsqueeze(0)))?,
            3 => c(t.unsqueeze(0))?,
            4 => {
                // A trajectory of zero frames has no last frame to start from.
                let Some(last) = t.dims()[0].checked_sub(1) else {
                    return Err(self.invalid(name, format!("the trajectory {:?} has no frames (T = 0)", t.dims())));
                };
                c(t.narrow(0, last, 1))?
            }
            _ => return Err(self.invalid(name, format!("expected [C, Y, X] or [T, C, Y, X], got {:?}", t.dims()))),
        };
        if t.dims()[1] != channels {
            return Err(self.invalid(name, format!("expected {channels} channel(s), got shape {:?}", t.dims())));
        }
        if t.elem_count() == 0 {
            return Err(
                self.invalid(name, format!("the field is empty (shape {:?}); give at least 1x1 cells", t.dims()))
            );
        }
        if !max_abs(&t)?.is_finite() {
            return Err(self.invalid(name, "contains NaN or Inf".into()));
        }
        let (h, w) = (t.dims()[2], t.dims()[3]);
        if (h, w) == self.shape {
            Ok(t)
        } else {
            Ok(resize2d(&t, self.shape, Resize::Bilinear { align_corners: false }).map_err(Error::from)?)
        }
    }

    /// The one-channel array `name` as `[1, 1, ny, nx]` in the state's precision (an error
    /// listing the arrays when there is none).
    pub fn scalar(&self, name: &str) -> SceneResult<Tensor> {
        let t = self
            .find(name)
            .ok_or_else(|| self.invalid(name, format!("the file has no array `{name}`; it has {:?}", self.names())))?;
        c(self.to4(name, &t, 1)?.to_dtype(self.dtype))
    }
}
