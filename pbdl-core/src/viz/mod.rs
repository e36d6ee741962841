//! Pictures of fields and runs: colormaps, field images, rollout GIFs, line and Pareto plots.
//!
//! | file | what it gives you |
//! |---|---|
//! | [`colormap`] | [`Colormap`] (viridis, blue-white-red, gray) and [`ColorRange`] (auto, fixed, symmetric) |
//! | [`field`] | scalar field `[H, W]` and vector field `[2, H, W]` (magnitude + arrows) to PNG, y up |
//! | [`gif`] | a rollout `[T, H, W]` to an animated GIF with one colour range for all frames |
//! | [`plot`] | line plots (log axes, legend) and time-vs-error Pareto plots to PNG |
//! | [`font`] | the bundled DejaVu Sans font, registered with plotters |
//!
//! Every function takes plain slices (`&[f32]` or `&[f64]` with `h, w`) and has a `tensor_*`
//! twin taking a candle `Tensor`; the `*_rgb` variants return an [`RgbImage`] for further
//! composition, the others write a file atomically ([`crate::io::write_atomic`]). Bad input
//! (wrong rank, empty series, non-finite range) is a typed [`crate::Error`].

pub mod colormap;
pub mod field;
pub mod font;
pub mod gif;
pub mod plot;

pub use colormap::{blue_white_red, viridis, ColorRange, Colormap, NAN_COLOR, NEUTRAL};
pub use field::{
    auto_upscale, field_to_png, field_to_rgb, tensor_field_to_png, tensor_field_to_rgb, tensor_vector_field_to_png,
    tensor_vector_field_to_rgb, vector_field_to_png, vector_field_to_rgb, ArrowStyle, FieldStyle, Origin, VectorStyle,
};
pub use gif::{rollout_to_gif, tensor_rollout_to_gif, GifStyle};
pub use image::RgbImage;
pub use plot::{line_plot, line_plot_rgb, pareto_plot, pareto_plot_rgb, Legend, ParetoPoint, PlotStyle, Series};

use crate::error::Result;
use candle_core::{DType, Tensor};
use std::path::Path;

/// Writes an RGB image as a PNG file, atomically.
pub fn write_png(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    use image::ImageEncoder;
    crate::io::write_atomic(path, |w| {
        image::codecs::png::PngEncoder::new(w)
            .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
            .map_err(std::io::Error::other)
    })
}

/// All values of a tensor (any dtype, any device) as `f64`, in row-major order.
pub(crate) fn tensor_values(t: &Tensor) -> Result<Vec<f64>> {
    Ok(t.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
}
