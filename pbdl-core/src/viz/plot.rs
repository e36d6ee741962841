//! Line plots (training curves, errors over time) and time-versus-error Pareto plots, drawn
//! with plotters into a PNG, using the bundled font (see [`super::font`]).
//!
//! ```
//! use pbdl_core::viz::{line_plot, pareto_plot, ParetoPoint, PlotStyle, Series};
//! # fn main() -> pbdl_core::Result<()> {
//! let dir = tempfile::tempdir().unwrap();
//! let loss: Vec<f64> = (1..=100).map(|i| 1.0 / i as f64).collect();
//! let style = PlotStyle { title: "training".into(), x_label: "step".into(), y_label: "loss".into(), log_y: true, ..Default::default() };
//! line_plot(dir.path().join("loss.png"), &[Series::from_y("train", &loss)], &style)?;
//!
//! let points = [
//!     ParetoPoint::new("solver", 2.0, 1e-4),
//!     ParetoPoint::new("network", 0.01, 3e-2),
//! ];
//! pareto_plot(dir.path().join("pareto.png"), &points, &PlotStyle::pareto())?;
//! # Ok(())
//! # }
//! ```

use super::font::{register_fonts, GlyphBackend, FONT_FAMILY};
use super::write_png;
use crate::error::{Error, Result};
use image::RgbImage;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// One named curve of a line plot.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// x values.
    pub x: Vec<f64>,
    /// y values, as many as `x`.
    pub y: Vec<f64>,
}

impl Series {
    /// A series from x and y values.
    pub fn new(name: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Self {
        Series { name: name.into(), x, y }
    }

    /// A series with x = 0, 1, 2, ... (e.g. a loss per step).
    pub fn from_y<T: Copy + Into<f64>>(name: impl Into<String>, y: &[T]) -> Self {
        Series {
            name: name.into(),
            x: (0..y.len()).map(|i| i as f64).collect(),
            y: y.iter().map(|&v| v.into()).collect(),
        }
    }
}

/// One measured method of a Pareto plot: run time against error.
#[derive(Clone, Debug, PartialEq)]
pub struct ParetoPoint {
    /// The method; points of one method share a colour and a legend entry, and are joined in
    /// order of time (e.g. a resolution sweep).
    pub method: String,
    /// Run time (any unit, > 0 on a log axis).
    pub time: f64,
    /// Error (> 0 on a log axis).
    pub error: f64,
    /// Text written next to the point, e.g. `"64²"`. `None`: the method name if the method has
    /// only this one point, else nothing.
    pub label: Option<String>,
}

impl ParetoPoint {
    /// A point without its own label.
    pub fn new(method: impl Into<String>, time: f64, error: f64) -> Self {
        ParetoPoint { method: method.into(), time, error, label: None }
    }

    /// The same point with a label.
    pub fn with_label(mut self, label: impl Into<String>) -> Self {
        self.label = Some(label.into());
        self
    }
}

/// Where the legend goes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Legend {
    /// The inner corner with the fewest data points near it (default).
    #[default]
    Best,
    /// Upper right corner.
    UpperRight,
    /// Upper left corner.
    UpperLeft,
    /// Lower left corner.
    LowerLeft,
    /// Lower right corner.
    LowerRight,
    /// No legend.
    Hidden,
}

/// Titles, axes and size of a plot.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotStyle {
    /// Caption above the plot; empty for none.
    pub title: String,
    /// x axis description.
    pub x_label: String,
    /// y axis description.
    pub y_label: String,
    /// Logarithmic x axis (values must be > 0).
    pub log_x: bool,
    /// Logarithmic y axis (values must be > 0).
    pub log_y: bool,
    /// Image width in pixels (at least 200). Default: 800.
    pub width: u32,
    /// Image height in pixels (at least 150). Default: 500.
    pub height: u32,
    /// Legend placement. Default: [`Legend::Best`].
    pub legend: Legend,
}

impl Default for PlotStyle {
    fn default() -> Self {
        PlotStyle {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            log_x: false,
            log_y: false,
            width: 800,
            height: 500,
            legend: Legend::Best,
        }
    }
}

impl PlotStyle {
    /// Log-log axes labelled `time [s]` and `error`, titled `accuracy vs. cost`.
    pub fn pareto() -> Self {
        PlotStyle {
            title: "accuracy vs. cost".into(),
            x_label: "time [s]".into(),
            y_label: "error".into(),
            log_x: true,
            log_y: true,
            ..Default::default()
        }
    }
}

/// Draws `series` as lines (with a legend) into an RGB image.
///
/// Errors ([`Error::InvalidArgument`] unless noted): no series, an empty series, `x` and `y` of
/// different lengths, a non-finite value ([`Error::NonFinite`]), a value <= 0 on a log axis, a
/// too small image.
pub fn line_plot_rgb(series: &[Series], style: &PlotStyle) -> Result<RgbImage> {
    const OP: &str = "line_plot";
    if series.is_empty() {
        return Err(Error::invalid(OP, "series", "no series to plot"));
    }
    for s in series {
        if s.x.is_empty() || s.x.len() != s.y.len() {
            let why = format!(
                "series `{}` has {} x and {} y values; need as many of each, at least one",
                s.name,
                s.x.len(),
                s.y.len()
            );
            return Err(Error::invalid(OP, "series", why));
        }
        check_values(OP, &format!("series `{}` x", s.name), &s.x, style.log_x)?;
        check_values(OP, &format!("series `{}` y", s.name), &s.y, style.log_y)?;
    }
    let xs: Vec<f64> = series.iter().flat_map(|s| s.x.iter().copied()).collect();
    let ys: Vec<f64> = series.iter().flat_map(|s| s.y.iter().copied()).collect();
    render_chart(OP, style, &xs, &ys, &LineBody { series })
}

/// [`line_plot_rgb`] written to a PNG file (atomically).
pub fn line_plot(path: impl AsRef<Path>, series: &[Series], style: &PlotStyle) -> Result<()> {
    write_png(path, &line_plot_rgb(series, style)?)
}

/// Draws run time against error, one colour per method, each point labelled (see
/// [`ParetoPoint::label`]), with the Pareto front (the points no other point beats in both time
/// and error) as a grey line. Use [`PlotStyle::pareto`] for log-log axes.
///
/// Errors as for [`line_plot_rgb`].
pub fn pareto_plot_rgb(points: &[ParetoPoint], style: &PlotStyle) -> Result<RgbImage> {
    const OP: &str = "pareto_plot";
    if points.is_empty() {
        return Err(Error::invalid(OP, "points", "no points to plot"));
    }
    let xs: Vec<f64> = points.iter().map(|p| p.time).collect();
    let ys: Vec<f64> = points.iter().map(|p| p.error).collect();
    check_values(OP, "time", &xs, style.log_x)?;
    check_values(OP, "error", &ys, style.log_y)?;
    render_chart(OP, style, &xs, &ys, &ParetoBody { points })
}

/// [`pareto_plot_rgb`] written to a PNG file (atomically).
pub fn pareto_plot(path: impl AsRef<Path>, points: &[ParetoPoint], style: &PlotStyle) -> Result<()> {
    write_png(path, &pareto_plot_rgb(points, style)?)
}

/// Matplotlib's "tab10" colours: distinct, and readable on white.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

type Backend<'b> = GlyphBackend<BitMapBackend<'b>>;
type Chart<'a, 'b, X, Y> = ChartContext<'a, Backend<'b>, Cartesian2d<X, Y>>;
type DrawResult = std::result::Result<(), String>;

/// What goes inside the axes; generic over linear and log coordinates.
trait Body {
    fn draw<'a, 'b: 'a, X, Y>(&self, chart: &mut Chart<'a, 'b, X, Y>, font: f64) -> DrawResult
    where
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
        Y: Ranged<ValueType = f64> + ValueFormatter<f64>;

    /// Every drawn point, for the legend placement.
    fn points(&self) -> Vec<(f64, f64)>;
}

struct LineBody<'s> {
    series: &'s [Series],
}

impl Body for LineBody<'_> {
    fn draw<'a, 'b: 'a, X, Y>(&self, chart: &mut Chart<'a, 'b, X, Y>, _font: f64) -> DrawResult
    where
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
        Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        for (i, s) in self.series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let points: Vec<(f64, f64)> = s.x.iter().copied().zip(s.y.iter().copied()).collect();
            let style = color.stroke_width(2);
            let drawn = if points.len() == 1 {
                // A single point has no line: show it as a dot.
                chart
                    .draw_series(std::iter::once(Circle::new(points[0], 4, color.filled())))
                    .map_err(|e| e.to_string())?
            } else {
                chart.draw_series(LineSeries::new(points, style)).map_err(|e| e.to_string())?
            };
            drawn.label(s.name.clone()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], style));
        }
        Ok(())
    }

    fn points(&self) -> Vec<(f64, f64)> {
        self.series.iter().flat_map(|s| s.x.iter().copied().zip(s.y.iter().copied())).collect()
    }
}

struct ParetoBody<'p> {
    points: &'p [ParetoPoint],
}

impl Body for ParetoBody<'_> {
    fn draw<'a, 'b: 'a, X, Y>(&self, chart: &mut Chart<'a, 'b, X, Y>, font: f64) -> DrawResult
    where
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
        Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        let err = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
        // Pareto front: scanning by time, every point more accurate than all faster ones.
        let mut sorted: Vec<&ParetoPoint> = self.points.iter().collect();
        sorted.sort_by(|a, b| a.time.total_cmp(&b.time).then(a.error.total_cmp(&b.error)));
        let mut front = Vec::new();
        for p in sorted {
            if front.last().is_none_or(|&(_, e): &(f64, f64)| p.error < e) {
                front.push((p.time, p.error));
            }
        }
        let grey = RGBColor(150, 150, 150);
        if front.len() > 1 {
            chart
                .draw_series(LineSeries::new(front, grey.stroke_width(3)))
                .map_err(err)?
                .label("Pareto front")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], grey.stroke_width(3)));
        }

        let mut methods: Vec<&str> = Vec::new();
        for p in self.points {
            if !methods.contains(&p.method.as_str()) {
                methods.push(&p.method);
            }
        }
        let label_font = (FONT_FAMILY, font * 0.85).into_font().color(&BLACK);
        for (i, method) in methods.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let mut pts: Vec<&ParetoPoint> = self.points.iter().filter(|p| p.method == *method).collect();
            pts.sort_by(|a, b| a.time.total_cmp(&b.time));
            if pts.len() > 1 {
                let line: Vec<(f64, f64)> = pts.iter().map(|p| (p.time, p.error)).collect();
                chart.draw_series(LineSeries::new(line, color.stroke_width(1))).map_err(err)?;
            }
            let single = pts.len() == 1;
            let coords = pts.iter().map(|p| (p.time, p.error));
            // Shapes as well as colours, so that methods differ in grey print too.
            let anno = match i % 3 {
                0 => chart.draw_series(coords.map(|c| Circle::new(c, 5, color.filled()))),
                1 => chart.draw_series(coords.map(|c| TriangleMarker::new(c, 6, color.filled()))),
                _ => chart.draw_series(coords.map(|c| Cross::new(c, 5, color.stroke_width(2)))),
            }
            .map_err(err)?;
            anno.label(method.to_string()).legend(move |(x, y)| {
                // One element type for all shapes (the legend needs one): unused shapes are
                // transparent.
                let none = TRANSPARENT.filled();
                let (c, t, x_) = match i % 3 {
                    0 => (color.filled(), none, none),
                    1 => (none, color.filled(), none),
                    _ => (none, none, color.stroke_width(2)),
                };
                EmptyElement::at((x + 12, y))
                    + Circle::new((0, 0), 5, c)
                    + TriangleMarker::new((0, 0), 6, t)
                    + Cross::new((0, 0), 5, x_)
            });
            let labels = pts.iter().filter_map(|p| {
                let text = p.label.clone().or_else(|| single.then(|| p.method.clone()))?;
                Some(
                    EmptyElement::at((p.time, p.error))
                        + Text::new(text, (7, -(font * 0.9) as i32), label_font.clone()),
                )
            });
            chart.draw_series(labels).map_err(err)?;
        }
        Ok(())
    }

    fn points(&self) -> Vec<(f64, f64)> {
        self.points.iter().map(|p| (p.time, p.error)).collect()
    }
}

fn check_values(op: &'static str, what: &str, values: &[f64], log: bool) -> Result<()> {
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Error::NonFinite { what: format!("{op}: {what}"), index, value, len: values.len() });
    }
    if log {
        if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| **v <= 0.0) {
            return Err(Error::invalid(op, "style", format!("{what}[{i}] = {v} cannot be shown on a log axis")));
        }
    }
    Ok(())
}

/// The axis range: the data's extent plus a margin (5% of the span, or of the decades on a
/// log axis), and a sensible window around a single value.
fn axis_range(values: &[f64], log: bool) -> (f64, f64) {
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if log {
        let (a, b) = (lo.log10(), hi.log10());
        let pad = if b > a { 0.05 * (b - a) } else { 0.5 };
        (10f64.powf(a - pad), 10f64.powf(b + pad))
    } else {
        let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 * lo.abs().max(1.0) };
        (lo - pad, hi + pad)
    }
}

/// Labelled and grid-only ticks of a log axis over `[lo, hi]`: powers of ten if at least two
/// fit (every n-th for long ranges), else 1-2-5 or 1..9 steps, else plain linear steps.
fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let inside = |v: &f64| *v >= lo && *v <= hi;
    let (k0, k1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let seq = |mults: &[f64]| -> Vec<f64> {
        (k0..=k1).flat_map(|k| mults.iter().map(move |m| m * 10f64.powi(k))).filter(inside).collect()
    };
    let decades = seq(&[1.0]);
    let all = seq(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    let light = if decades.len() <= 12 { all.clone() } else { decades.clone() };
    let bold = if decades.len() >= 2 {
        let step = decades.len().div_ceil(8);
        decades.into_iter().step_by(step).collect()
    } else {
        let one_two_five = seq(&[1.0, 2.0, 5.0]);
        if one_two_five.len() >= 3 {
            one_two_five
        } else if all.len() >= 3 {
            all
        } else {
            // Less than a factor of ~1.5: linear steps of 1, 2 or 5 times a power of ten.
            let raw = (hi - lo) / 5.0;
            let mag = 10f64.powf(raw.log10().floor());
            let step = [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
            let first = (lo / step).ceil() as i64;
            (first..).map(|i| i as f64 * step).take_while(|v| *v <= hi).collect()
        }
    };
    (bold, light)
}

/// Short tick labels: `0.25`, `1500`, `1e-5`, `2.5e6`.
fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    if (1e-3..1e5).contains(&a) {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        return if s == "-0" { "0".into() } else { s.to_string() };
    }
    let s = format!("{v:.3e}");
    let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
    let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
    format!("{mantissa}e{exp}")
}

fn render_chart<B: Body>(op: &'static str, style: &PlotStyle, xs: &[f64], ys: &[f64], body: &B) -> Result<RgbImage> {
    if style.width < 200 || style.height < 150 || style.width > 16384 || style.height > 16384 {
        return Err(Error::invalid(
            op,
            "style",
            format!("size {}x{}: use 200..=16384 x 150..=16384", style.width, style.height),
        ));
    }
    register_fonts()?;
    let (x0, x1) = axis_range(xs, style.log_x);
    let (y0, y1) = axis_range(ys, style.log_y);
    let legend = match style.legend {
        Legend::Best => Some(best_corner(&body.points(), (x0, x1, style.log_x), (y0, y1, style.log_y))),
        Legend::UpperRight => Some(SeriesLabelPosition::UpperRight),
        Legend::UpperLeft => Some(SeriesLabelPosition::UpperLeft),
        Legend::LowerLeft => Some(SeriesLabelPosition::LowerLeft),
        Legend::LowerRight => Some(SeriesLabelPosition::LowerRight),
        Legend::Hidden => None,
    };
    let (w, h) = (style.width, style.height);
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let root = GlyphBackend(BitMapBackend::with_buffer(&mut buf, (w, h))).into_drawing_area();
        // plotters' own log ticks are only powers of ten, so a range within one decade would
        // get no labels at all: ticks are chosen here.
        let log = |lo: f64, hi: f64| {
            let (bold, light) = log_ticks(lo, hi);
            (lo..hi).log_scale().with_key_points(bold).with_light_points(light)
        };
        let result = match (style.log_x, style.log_y) {
            (false, false) => draw_chart(&root, x0..x1, y0..y1, style, legend, body),
            (false, true) => draw_chart(&root, x0..x1, log(y0, y1), style, legend, body),
            (true, false) => draw_chart(&root, log(x0, x1), y0..y1, style, legend, body),
            (true, true) => draw_chart(&root, log(x0, x1), log(y0, y1), style, legend, body),
        };
        result
            .and_then(|()| root.present().map_err(|e| e.to_string()))
            .map_err(|reason| Error::invalid(op, "style", format!("plotting failed: {reason}")))?;
    }
    Ok(RgbImage::from_raw(w, h, buf).expect("buffer has w * h * 3 bytes"))
}

fn draw_chart<XS, YS, B>(
    root: &DrawingArea<Backend<'_>, Shift>,
    x: XS,
    y: YS,
    style: &PlotStyle,
    legend: Option<SeriesLabelPosition>,
    body: &B,
) -> DrawResult
where
    XS: AsRangedCoord<Value = f64>,
    YS: AsRangedCoord<Value = f64>,
    XS::CoordDescType: ValueFormatter<f64>,
    YS::CoordDescType: ValueFormatter<f64>,
    B: Body,
{
    let err = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
    // Text scales with the image, so that small and large plots both read well.
    let font = (style.height.min(style.width) as f64 / 30.0).clamp(11.0, 28.0);
    root.fill(&WHITE).map_err(err)?;
    let mut builder = ChartBuilder::on(root);
    builder
        .margin_top((font * 0.8) as i32)
        .margin_right((font * 1.5) as i32)
        .margin_left((font * 0.5) as i32)
        .margin_bottom((font * 0.5) as i32)
        .x_label_area_size((font * 3.2) as i32)
        .y_label_area_size((font * 5.0) as i32);
    if !style.title.is_empty() {
        builder.caption(&style.title, (FONT_FAMILY, font * 1.4));
    }
    let mut chart = builder.build_cartesian_2d(x, y).map_err(err)?;
    // Ticks are stepped in floating point, so "0" can arrive as -5.6e-17: snap values that are
    // negligible against the axis span.
    let (xr, yr) = (chart.x_range(), chart.y_range());
    // Log axes never contain 0: nothing to snap there.
    let x_span = if style.log_x { 0.0 } else { (xr.end - xr.start).abs() };
    let y_span = if style.log_y { 0.0 } else { (yr.end - yr.start).abs() };
    let x_formatter = |v: &f64| tick_label(if v.abs() < 1e-9 * x_span { 0.0 } else { *v });
    let y_formatter = |v: &f64| tick_label(if v.abs() < 1e-9 * y_span { 0.0 } else { *v });
    chart
        .configure_mesh()
        .x_desc(&style.x_label)
        .y_desc(&style.y_label)
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&x_formatter)
        .y_label_formatter(&y_formatter)
        .label_style((FONT_FAMILY, font * 0.85))
        .axis_desc_style((FONT_FAMILY, font))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(244, 244, 244))
        .axis_style(RGBColor(80, 80, 80))
        .draw()
        .map_err(err)?;
    body.draw(&mut chart, font)?;
    if let Some(position) = legend {
        chart
            .configure_series_labels()
            .position(position)
            .margin((font * 0.6) as i32)
            .label_font((FONT_FAMILY, font * 0.85))
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(180, 180, 180))
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

/// The corner whose quarter of the plot holds the fewest points (in axis coordinates).
fn best_corner(points: &[(f64, f64)], x: (f64, f64, bool), y: (f64, f64, bool)) -> SeriesLabelPosition {
    let unit = |v: f64, (lo, hi, log): (f64, f64, bool)| {
        if log {
            (v.log10() - lo.log10()) / (hi.log10() - lo.log10())
        } else {
            (v - lo) / (hi - lo)
        }
    };
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let count = |right: bool, top: bool| {
        points
            .iter()
            .filter(|&&(px, py)| {
                let (u, v) = (unit(px, x), unit(py, y));
                (if right { u > 0.55 } else { u < 0.45 }) && (if top { v > 0.55 } else { v < 0.45 })
            })
            .count()
    };
    // Ties go to the first corner listed, upper right.
    corners.iter().min_by_key(|(_, r, t)| count(*r, *t)).map(|c| c.0.clone()).unwrap_or(SeriesLabelPosition::UpperRight)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(1500.0), "1500");
        assert_eq!(tick_label(1e-5), "1e-5");
        assert_eq!(tick_label(2.5e6), "2.5e6");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(-2.0), "-2");
    }

    #[test]
    fn log_ticks_label_every_range() {
        let decades = |v: &[f64]| v.iter().map(|x| x.log10().round() as i32).collect::<Vec<_>>();
        assert_eq!(decades(&log_ticks(0.9e-3, 1.1).0), [-3, -2, -1, 0]);
        // 20 decades: every third one labelled.
        assert_eq!(log_ticks(1e-10, 1e10).0.len(), 7);
        // Within one decade: 1-2-5 or 1..9 steps.
        let t = log_ticks(0.15, 0.95).0;
        assert_eq!(t.len(), 8, "{t:?}");
        assert!(log_ticks(0.22, 0.5).0.len() >= 3);
        // Very narrow: linear steps.
        let t = log_ticks(0.25, 0.3).0;
        assert!(t.len() >= 3 && t.iter().all(|v| (0.25..=0.3).contains(v)), "{t:?}");
    }
}
