//! Configuration of a convolution: stride, padding, dilation, groups and padding mode.

use serde::{Deserialize, Serialize};

/// How the input is extended beyond its border.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum PaddingMode {
    /// Values outside the input are zero (PyTorch `padding_mode="zeros"`). The default.
    #[default]
    Zeros,
    /// The input is periodic: index `-1` reads the last element (PyTorch `padding_mode="circular"`).
    /// Padding may exceed the input size; the input is then repeated as often as needed.
    Circular,
}

/// Parameters of an `N`-dimensional convolution (`N` = 1, 2 or 3), one entry per spatial axis
/// ordered like the tensor axes (`[z, y, x]` for 3D).
///
/// The defaults are PyTorch's: stride 1, padding 0, dilation 1, one group, zero padding. The
/// builder methods set every axis to the same value; assign the public fields for per-axis values.
///
/// ```
/// use pbdl_core::conv::{Conv2dParams, PaddingMode};
/// let p = Conv2dParams::default().padding(1).stride(2).circular();
/// assert_eq!(p.padding, [1, 1]);
/// assert_eq!(p.stride, [2, 2]);
/// assert_eq!(p.padding_mode, [PaddingMode::Circular; 2]);
///
/// // Periodic along x only, zero-padded along y (a global lat-lon grid):
/// let q = Conv2dParams { padding_mode: [PaddingMode::Zeros, PaddingMode::Circular], ..p };
/// assert!(q.is_circular(1) && !q.is_circular(0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(bound(
    serialize = "[usize; N]: Serialize, [PaddingMode; N]: Serialize",
    deserialize = "[usize; N]: Deserialize<'de>, [PaddingMode; N]: Deserialize<'de>"
))]
pub struct ConvParams<const N: usize> {
    /// Step between output samples, per axis; at least 1. Default 1.
    pub stride: [usize; N],
    /// Number of padded cells on each side of each axis. Default 0.
    pub padding: [usize; N],
    /// Spacing between kernel taps, per axis; at least 1. Default 1.
    pub dilation: [usize; N],
    /// Number of channel groups; must divide the input and output channels. `groups == in_channels`
    /// is a depthwise convolution. Default 1.
    pub groups: usize,
    /// What lies beyond the border, per axis. Default [`PaddingMode::Zeros`]. (Serialised as
    /// an array; configurations written before it was per axis held a single value.)
    pub padding_mode: [PaddingMode; N],
}

/// Parameters of [`conv1d`](super::conv1d).
pub type Conv1dParams = ConvParams<1>;
/// Parameters of [`conv2d`](super::conv2d).
pub type Conv2dParams = ConvParams<2>;
/// Parameters of [`conv3d`](super::conv3d).
pub type Conv3dParams = ConvParams<3>;

impl<const N: usize> Default for ConvParams<N> {
    fn default() -> Self {
        Self { stride: [1; N], padding: [0; N], dilation: [1; N], groups: 1, padding_mode: [PaddingMode::Zeros; N] }
    }
}

impl<const N: usize> ConvParams<N> {
    /// Sets the stride of every axis.
    pub fn stride(mut self, stride: usize) -> Self {
        self.stride = [stride; N];
        self
    }

    /// Sets the padding of every axis (both sides).
    pub fn padding(mut self, padding: usize) -> Self {
        self.padding = [padding; N];
        self
    }

    /// Sets the dilation of every axis.
    pub fn dilation(mut self, dilation: usize) -> Self {
        self.dilation = [dilation; N];
        self
    }

    /// Sets the number of channel groups.
    pub fn groups(mut self, groups: usize) -> Self {
        self.groups = groups;
        self
    }

    /// Sets the padding mode of every axis.
    pub fn padding_mode(mut self, mode: PaddingMode) -> Self {
        self.padding_mode = [mode; N];
        self
    }

    /// Shortcut for `padding_mode(PaddingMode::Circular)`: periodic boundaries on every axis.
    pub fn circular(self) -> Self {
        self.padding_mode(PaddingMode::Circular)
    }

    /// Whether `axis` (0 = the first spatial axis) is periodic.
    ///
    /// # Panics
    /// If `axis >= N`.
    pub fn is_circular(&self, axis: usize) -> bool {
        self.padding_mode[axis] == PaddingMode::Circular
    }

    /// Whether every axis pads with zeros.
    pub fn is_zero_padded(&self) -> bool {
        self.padding_mode.iter().all(|m| *m == PaddingMode::Zeros)
    }

    /// The same parameters as a 3D convolution with singleton leading axes (stride 1,
    /// padding 0, dilation 1 there), which is how every convolution is computed.
    pub(crate) fn to_3d(self) -> ConvParams<3> {
        let mut p = ConvParams::<3> { groups: self.groups, ..Default::default() };
        let off = 3 - N;
        p.padding_mode[off..].copy_from_slice(&self.padding_mode);
        p.stride[off..].copy_from_slice(&self.stride);
        p.padding[off..].copy_from_slice(&self.padding);
        p.dilation[off..].copy_from_slice(&self.dilation);
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lifting_to_3d_puts_singleton_axes_first() {
        let p = Conv1dParams::default().stride(2).padding(3).dilation(4).groups(5).circular().to_3d();
        assert_eq!(p.stride, [1, 1, 2]);
        assert_eq!(p.padding, [0, 0, 3]);
        assert_eq!(p.dilation, [1, 1, 4]);
        assert_eq!(p.groups, 5);
        assert_eq!(p.padding_mode, [PaddingMode::Zeros, PaddingMode::Zeros, PaddingMode::Circular]);
    }

    #[test]
    fn params_round_trip_through_json() {
        let p = Conv2dParams { stride: [1, 2], ..Default::default() }.padding(1);
        let s = serde_json::to_string(&p).unwrap();
        let q: Conv2dParams = serde_json::from_str(&s).unwrap();
        assert_eq!(p, q);
    }
}
