//! Validation of a convolution's shapes and parameters, and the sizes derived from them.
//!
//! Every convolution is computed as a 3D one: `N`-dimensional shapes get singleton leading
//! spatial axes, so one kernel serves conv1d, conv2d and conv3d. The tensors keep their own
//! rank (the kernels read flat buffers), so no reshape sits between the op and autograd.

use super::params::{ConvParams, PaddingMode};
use crate::{Error, Result};

/// The validated sizes of one convolution, lifted to 3D.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Geometry {
    /// Number of spatial axes the caller's tensors have (1, 2 or 3).
    pub dims: usize,
    pub batch: usize,
    pub c_in: usize,
    pub c_out: usize,
    pub groups: usize,
    /// Spatial input size `[d, h, w]`.
    pub input: [usize; 3],
    /// Kernel size `[kd, kh, kw]`.
    pub kernel: [usize; 3],
    /// Spatial output size `[od, oh, ow]`.
    pub output: [usize; 3],
    pub stride: [usize; 3],
    pub padding: [usize; 3],
    pub dilation: [usize; 3],
    /// Per axis: periodic (true) or zero padding beyond the border.
    pub circular: [bool; 3],
    /// Whether geometries the direct depthwise kernels handle use them (otherwise im2col).
    pub direct: bool,
}

fn axes_layout(n: usize) -> &'static str {
    match n {
        1 => "[batch, channel, x]",
        2 => "[batch, channel, y, x]",
        _ => "[batch, channel, z, y, x]",
    }
}

fn weight_layout(n: usize) -> &'static str {
    match n {
        1 => "[out_channels, in_channels / groups, kx]",
        2 => "[out_channels, in_channels / groups, ky, kx]",
        _ => "[out_channels, in_channels / groups, kz, ky, kx]",
    }
}

impl Geometry {
    /// Checks an `N`-dimensional convolution of an input of shape `x` with a weight of shape
    /// `w` and returns its geometry; every error says what to change.
    pub fn new<const N: usize>(op: &'static str, x: &[usize], w: &[usize], p: &ConvParams<N>) -> Result<Self> {
        if !(1..=3).contains(&N) {
            return Err(Error::invalid(op, "params", format!("{N} spatial axes given; use 1, 2 or 3")));
        }
        if x.len() != N + 2 {
            return Err(Error::Shape {
                op,
                arg: "input",
                expected: format!("rank {} {}", N + 2, axes_layout(N)),
                got: x.to_vec(),
            });
        }
        if w.len() != N + 2 {
            return Err(Error::Shape {
                op,
                arg: "weight",
                expected: format!("rank {} {}", N + 2, weight_layout(N)),
                got: w.to_vec(),
            });
        }
        if p.stride.contains(&0) {
            return Err(Error::invalid(
                op,
                "stride",
                format!("{:?} has a zero entry; use 1 for no striding", p.stride),
            ));
        }
        if p.dilation.contains(&0) {
            return Err(Error::invalid(
                op,
                "dilation",
                format!("{:?} has a zero entry; use 1 for no dilation", p.dilation),
            ));
        }
        let (batch, c_in, c_out) = (x[0], x[1], w[0]);
        let g = p.groups;
        if g == 0 || c_in % g != 0 || c_out % g != 0 {
            return Err(Error::invalid(
                op,
                "groups",
                format!(
                    "groups = {g} must be at least 1 and divide both the input channels ({c_in}) and the output channels ({c_out}, weight dim 0)"
                ),
            ));
        }
        if w[1] * g != c_in {
            return Err(Error::Shape {
                op,
                arg: "weight",
                expected: format!(
                    "{} with in_channels / groups = {c_in} / {g} = {} in dim 1",
                    weight_layout(N),
                    c_in / g
                ),
                got: w.to_vec(),
            });
        }
        if w[2..].contains(&0) {
            return Err(Error::Shape {
                op,
                arg: "weight",
                expected: format!("{} with kernel sizes of at least 1", weight_layout(N)),
                got: w.to_vec(),
            });
        }
        let mut geo = Geometry {
            dims: N,
            batch,
            c_in,
            c_out,
            groups: g,
            input: [1; 3],
            kernel: [1; 3],
            output: [1; 3],
            stride: [1; 3],
            padding: [0; 3],
            dilation: [1; 3],
            circular: [false; 3],
            direct: super::depthwise::direct_by_default(),
        };
        let p3 = p.to_3d();
        let off = 3 - N;
        geo.input[off..].copy_from_slice(&x[2..]);
        geo.kernel[off..].copy_from_slice(&w[2..]);
        geo.stride = p3.stride;
        geo.padding = p3.padding;
        geo.dilation = p3.dilation;
        geo.circular = p3.padding_mode.map(|m| m == PaddingMode::Circular);
        for a in 0..3 {
            let extent = geo.dilation[a] * (geo.kernel[a] - 1) + 1;
            let padded = geo.input[a] + 2 * geo.padding[a];
            if geo.input[a] == 0 || extent > padded {
                let axis = a - off;
                return Err(Error::invalid(
                    op,
                    "weight",
                    format!(
                        "on spatial axis {axis} the kernel extent dilation*(k-1)+1 = {extent} exceeds the padded input size {} + 2*{} = {padded}; use a smaller kernel or dilation, or more padding (input {x:?}, weight {w:?})",
                        geo.input[a], geo.padding[a]
                    ),
                ));
            }
            geo.output[a] = (padded - extent) / geo.stride[a] + 1;
        }
        Ok(geo)
    }

    /// Input channels per group.
    pub fn cin_g(&self) -> usize {
        self.c_in / self.groups
    }

    /// Output channels per group.
    pub fn cout_g(&self) -> usize {
        self.c_out / self.groups
    }

    /// Kernel taps per output channel: rows of the im2col matrix.
    pub fn k_len(&self) -> usize {
        self.cin_g() * self.kernel.iter().product::<usize>()
    }

    /// Spatial input elements per channel.
    pub fn in_len(&self) -> usize {
        self.input.iter().product()
    }

    /// Spatial output elements per channel.
    pub fn out_len(&self) -> usize {
        self.output.iter().product()
    }

    /// Whether the im2col matrix is the input itself (1x1x1 kernel, stride 1, no padding).
    pub fn pointwise(&self) -> bool {
        self.kernel == [1; 3] && self.stride == [1; 3] && self.padding == [0; 3]
    }

    /// `[a, b]` followed by the caller's spatial axes of `spatial`.
    fn shape(&self, a: usize, b: usize, spatial: &[usize; 3]) -> Vec<usize> {
        let mut s = vec![a, b];
        s.extend_from_slice(&spatial[3 - self.dims..]);
        s
    }

    /// The input shape, `[batch, c_in, spatial...]`.
    pub fn x_shape(&self) -> Vec<usize> {
        self.shape(self.batch, self.c_in, &self.input)
    }

    /// The weight shape, `[c_out, c_in / groups, kernel...]`.
    pub fn w_shape(&self) -> Vec<usize> {
        self.shape(self.c_out, self.cin_g(), &self.kernel)
    }

    /// The output shape, `[batch, c_out, spatial...]`.
    pub fn y_shape(&self) -> Vec<usize> {
        self.shape(self.batch, self.c_out, &self.output)
    }
}

/// Fails with a message naming the op if `got` differs from `expected` (an internal invariant:
/// the public functions build the geometry from the very tensors they pass).
pub(crate) fn expect_shape(
    op: &'static str,
    arg: &'static str,
    got: &[usize],
    expected: &[usize],
) -> candle_core::Result<()> {
    if got != expected {
        return Err(Error::Shape { op, arg, expected: format!("{expected:?}"), got: got.to_vec() }.into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::{Conv1dParams, Conv2dParams, Conv3dParams};

    #[test]
    fn output_size_follows_pytorch_formula() {
        let p = Conv2dParams { stride: [2, 3], padding: [1, 2], dilation: [2, 1], ..Default::default() };
        let g = Geometry::new("t", &[2, 4, 11, 10], &[6, 4, 3, 5], &p).unwrap();
        // floor((11 + 2 - 2*2 - 1) / 2) + 1 = 5, floor((10 + 4 - 4 - 1) / 3) + 1 = 4
        assert_eq!(g.output, [1, 5, 4]);
        assert_eq!(g.y_shape(), vec![2, 6, 5, 4]);
        assert_eq!(g.w_shape(), vec![6, 4, 3, 5]);
        assert_eq!(g.k_len(), 4 * 15);
    }

    #[test]
    fn lifting_1d_and_3d() {
        let g = Geometry::new("t", &[1, 2, 9], &[3, 2, 3], &Conv1dParams::default().padding(1)).unwrap();
        assert_eq!((g.input, g.kernel, g.output, g.padding), ([1, 1, 9], [1, 1, 3], [1, 1, 9], [0, 0, 1]));
        let g = Geometry::new("t", &[1, 2, 4, 5, 6], &[3, 1, 1, 1, 1], &Conv3dParams::default().groups(2));
        assert!(g.is_err(), "3 output channels are not divisible by 2 groups");
    }

    #[test]
    fn rejections_are_typed() {
        let p = Conv2dParams::default();
        assert!(matches!(Geometry::new("t", &[1, 2, 5], &[3, 2, 3, 3], &p), Err(Error::Shape { arg: "input", .. })));
        assert!(matches!(Geometry::new("t", &[1, 2, 5, 5], &[3, 2, 3], &p), Err(Error::Shape { arg: "weight", .. })));
        assert!(matches!(
            Geometry::new("t", &[1, 2, 5, 5], &[3, 3, 3, 3], &p),
            Err(Error::Shape { arg: "weight", .. })
        ));
        assert!(matches!(
            Geometry::new("t", &[1, 2, 5, 5], &[3, 2, 3, 3], &p.stride(0)),
            Err(Error::InvalidArgument { arg: "stride", .. })
        ));
        assert!(matches!(
            Geometry::new("t", &[1, 2, 5, 5], &[3, 2, 3, 3], &p.dilation(0)),
            Err(Error::InvalidArgument { arg: "dilation", .. })
        ));
        assert!(matches!(
            Geometry::new("t", &[1, 4, 5, 5], &[3, 2, 3, 3], &p.groups(2)),
            Err(Error::InvalidArgument { arg: "groups", .. })
        ));
        assert!(matches!(
            Geometry::new("t", &[1, 2, 2, 5], &[3, 2, 3, 3], &p),
            Err(Error::InvalidArgument { arg: "weight", .. })
        ));
        // Padding makes the same kernel fit.
        assert!(Geometry::new("t", &[1, 2, 2, 5], &[3, 2, 3, 3], &p.padding(1)).is_ok());
    }
}
