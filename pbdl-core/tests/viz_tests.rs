//! Tests of `pbdl_core::viz`: colormaps, field images, GIFs, plots.
//!
//! Set `PBDL_VIZ_SAMPLES=/some/dir` to keep one sample of every kind of output there (the
//! `samples_of_every_kind` test); otherwise they go to a temporary directory.

use candle_core::{DType, Device, Tensor};
use image::AnimationDecoder;
use pbdl_core::viz::{
    blue_white_red, field_to_png, field_to_rgb, line_plot, line_plot_rgb, pareto_plot, pareto_plot_rgb, rollout_to_gif,
    tensor_field_to_png, tensor_field_to_rgb, tensor_rollout_to_gif, tensor_vector_field_to_png,
    tensor_vector_field_to_rgb, vector_field_to_png, vector_field_to_rgb, viridis, ArrowStyle, ColorRange, Colormap,
    FieldStyle, GifStyle, Legend, Origin, ParetoPoint, PlotStyle, RgbImage, Series, VectorStyle, NAN_COLOR, NEUTRAL,
};
use pbdl_core::Error;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

fn close(a: [u8; 3], b: [u8; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (*x as i32 - y as i32).abs() <= 1)
}

fn px(img: &RgbImage, x: u32, y: u32) -> [u8; 3] {
    img.get_pixel(x, y).0
}

fn style(colormap: Colormap, upscale: u32, origin: Origin) -> FieldStyle {
    FieldStyle { colormap, upscale: Some(upscale), origin, ..Default::default() }
}

// ---------------------------------------------------------------- colormaps

#[test]
fn viridis_endpoints_match_matplotlib() {
    assert!(close(viridis(0.0), [0x44, 0x01, 0x54]), "{:?}", viridis(0.0));
    assert!(close(viridis(1.0), [0xfd, 0xe7, 0x25]), "{:?}", viridis(1.0));
    // Clamped outside [0, 1].
    assert_eq!(viridis(-3.0), viridis(0.0));
    assert_eq!(viridis(7.0), viridis(1.0));
    // Monotone in lightness, roughly: green rises all the way.
    let greens: Vec<u8> = (0..=10).map(|i| viridis(i as f64 / 10.0)[1]).collect();
    assert!(greens.windows(2).all(|w| w[0] < w[1]), "{greens:?}");
}

#[test]
fn diverging_map_puts_zero_at_the_neutral_colour() {
    assert_eq!(blue_white_red(0.5), NEUTRAL);
    // Auto range is symmetric about 0 whatever the data's skew.
    let (lo, hi) = ColorRange::Auto.resolve([-1.0, 0.0, 4.0], Colormap::BlueWhiteRed).unwrap();
    assert_eq!((lo, hi), (-4.0, 4.0));
    let img = field_to_rgb(&[-1.0f32, 0.0, 4.0], 1, 3, &style(Colormap::BlueWhiteRed, 1, Origin::Lower)).unwrap();
    assert_eq!(px(&img, 1, 0), NEUTRAL, "0 is neutral");
    let [r, _, b] = px(&img, 0, 0);
    assert!(b > r, "negative is blue: {:?}", px(&img, 0, 0));
    assert_eq!(px(&img, 2, 0), blue_white_red(1.0), "the largest |value| is the end colour");
    // A symmetric range given by hand behaves the same.
    let (lo, hi) = ColorRange::Symmetric(2.0).resolve([0.0f64], Colormap::BlueWhiteRed).unwrap();
    assert_eq!((lo, hi), (-2.0, 2.0));
    // Sequential maps use [min, max].
    assert_eq!(ColorRange::Auto.resolve([-1.0, 0.0, 4.0], Colormap::Viridis).unwrap(), (-1.0, 4.0));
}

#[test]
fn nan_values_are_drawn_magenta_and_ignored_by_the_auto_range() {
    let img = field_to_rgb(&[0.0f64, f64::NAN, 1.0, f64::INFINITY], 1, 4, &style(Colormap::Viridis, 1, Origin::Lower))
        .unwrap();
    assert_eq!(px(&img, 1, 0), NAN_COLOR);
    assert_eq!(px(&img, 3, 0), NAN_COLOR);
    assert_eq!(px(&img, 0, 0), viridis(0.0));
    assert_eq!(px(&img, 2, 0), viridis(1.0));
}

// ---------------------------------------------------------------- fields

#[test]
fn y_up_puts_row_zero_at_the_bottom() {
    // Row 0 (y = 0) is hot, the rest cold.
    let (h, w) = (4, 3);
    let data: Vec<f32> = (0..h * w).map(|i| if i / w == 0 { 1.0 } else { 0.0 }).collect();
    let lower = field_to_rgb(&data, h, w, &style(Colormap::Viridis, 2, Origin::Lower)).unwrap();
    assert_eq!((lower.width(), lower.height()), (6, 8));
    assert_eq!(px(&lower, 0, 7), viridis(1.0), "bottom row is y = 0");
    assert_eq!(px(&lower, 0, 0), viridis(0.0));
    let upper = field_to_rgb(&data, h, w, &style(Colormap::Viridis, 2, Origin::Upper)).unwrap();
    assert_eq!(px(&upper, 0, 0), viridis(1.0), "top row is row 0");
}

#[test]
fn field_png_decodes_to_the_upscaled_size() {
    let dir = tempfile::tempdir().unwrap();
    let data = vec![0.5f32; 64 * 64];
    let path = dir.path().join("f.png");
    field_to_png(&path, &data, 64, 64, &FieldStyle::default()).unwrap();
    let img = image::open(&path).unwrap();
    assert_eq!((img.width(), img.height()), (256, 256), "auto upscale: 64 -> 256");

    let t = Tensor::zeros((1, 1, 20, 30), DType::F64, &Device::Cpu).unwrap();
    let fixed = FieldStyle { upscale: Some(3), range: ColorRange::Fixed(-1.0, 1.0), ..Default::default() };
    tensor_field_to_png(&path, &t, &fixed).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (90, 60));
    assert!(close(px(&img, 10, 10), viridis(0.5)), "0 in [-1, 1] is mid-range");
}

#[test]
fn vector_field_draws_magnitude_and_arrows_pointing_along_the_flow() {
    // One arrow (spacing 8 on an 8x8 grid) for a flow straight "up" (+y).
    let (h, w) = (8, 8);
    let u = vec![0.0f32; h * w];
    let v = vec![1.0f32; h * w];
    let arrows = ArrowStyle { spacing: Some(8), outline: None, ..Default::default() };
    for origin in [Origin::Lower, Origin::Upper] {
        let style = VectorStyle { magnitude: style(Colormap::Viridis, 8, origin), arrows: Some(arrows.clone()) };
        let img = vector_field_to_rgb(&u, &v, h, w, &style).unwrap();
        assert_eq!((img.width(), img.height()), (64, 64));
        let white: Vec<(u32, u32)> =
            img.enumerate_pixels().filter(|(_, _, p)| p.0 == [255, 255, 255]).map(|(x, y, _)| (x, y)).collect();
        assert!(white.len() > 20, "arrow drawn: {} pixels", white.len());
        // The head (the widest row of the arrow) is at the top for y up, at the bottom otherwise.
        let (y0, y1) = (white.iter().map(|p| p.1).min().unwrap(), white.iter().map(|p| p.1).max().unwrap());
        let width = |y: u32| white.iter().filter(|p| p.1 == y).count();
        let widest =
            (y0..=y1).max_by_key(|&y| (width(y), if origin == Origin::Lower { u32::MAX - y } else { y })).unwrap();
        let near_top = widest - y0 < y1 - widest;
        assert_eq!(near_top, origin == Origin::Lower, "{origin:?}: head row {widest} in {y0}..={y1}");
    }

    // Without arrows: only the magnitude, here uniform.
    let plain = VectorStyle { arrows: None, ..Default::default() };
    let img = vector_field_to_rgb(&u, &v, h, w, &plain).unwrap();
    assert!(img.pixels().all(|p| p.0 == img.get_pixel(0, 0).0));

    // The tensor form [2, H, W] writes a PNG of the right size.
    let dir = tempfile::tempdir().unwrap();
    let t = Tensor::ones((2, 16, 32), DType::F32, &Device::Cpu).unwrap();
    let path = dir.path().join("v.png");
    tensor_vector_field_to_png(&path, &t, &VectorStyle::default()).unwrap();
    let img = image::open(&path).unwrap();
    assert_eq!((img.width(), img.height()), (32 * 16, 16 * 16), "arrows double the auto upscale");
}

// ---------------------------------------------------------------- GIFs

fn decode_gif(path: &Path) -> Vec<image::Frame> {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    image::codecs::gif::GifDecoder::new(file).unwrap().into_frames().collect_frames().unwrap()
}

#[test]
fn rollout_gif_has_every_frame_at_the_right_size_with_one_colour_range() {
    let dir = tempfile::tempdir().unwrap();
    let (h, w, t) = (10, 12, 7);
    // Constant frames 0, 1/6, ..., 1: with one range, the first is the low colour, the last the
    // high one (a per-frame range would make both mid-range).
    let frames: Vec<Vec<f64>> = (0..t).map(|i| vec![i as f64 / (t - 1) as f64; h * w]).collect();
    let path = dir.path().join("r.gif");
    let style = GifStyle {
        frame_delay_ms: 40,
        field: FieldStyle { upscale: Some(2), ..Default::default() },
        ..Default::default()
    };
    rollout_to_gif(&path, &frames, h, w, &style).unwrap();
    let decoded = decode_gif(&path);
    assert_eq!(decoded.len(), t);
    for f in &decoded {
        assert_eq!(f.buffer().dimensions(), (24, 20));
        assert_eq!(f.delay().numer_denom_ms(), (40, 1));
    }
    let first = decoded[0].buffer().get_pixel(5, 5).0;
    let last = decoded[t - 1].buffer().get_pixel(5, 5).0;
    assert!(close([first[0], first[1], first[2]], viridis(0.0)), "{first:?}");
    assert!(close([last[0], last[1], last[2]], viridis(1.0)), "{last:?}");

    // Tensor form [T, 1, H, W].
    let traj = Tensor::arange(0f32, (t * h * w) as f32, &Device::Cpu).unwrap().reshape((t, 1, h, w)).unwrap();
    tensor_rollout_to_gif(&path, &traj, &GifStyle::default()).unwrap();
    assert_eq!(decode_gif(&path).len(), t);
}

// ---------------------------------------------------------------- plots

/// Share of pixels that are not white, and whether `color` occurs.
fn ink(img: &RgbImage, color: [u8; 3]) -> (f64, usize) {
    let non_white = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let colored = img.pixels().filter(|p| close(p.0, color)).count();
    (non_white as f64 / (img.width() * img.height()) as f64, colored)
}

/// Whether the band of rows `y0..y1` contains dark (text) pixels.
fn has_text(img: &RgbImage, y0: u32, y1: u32) -> bool {
    (y0..y1).any(|y| (0..img.width()).any(|x| px(img, x, y).iter().all(|&c| c < 100)))
}

#[test]
fn line_plot_is_non_blank_at_the_asked_size() {
    let dir = tempfile::tempdir().unwrap();
    let steps: Vec<f64> = (0..200).map(|i| i as f64).collect();
    let train: Vec<f64> = steps.iter().map(|s| (-s / 40.0).exp() + 1e-3).collect();
    let style = PlotStyle {
        title: "loss".into(),
        x_label: "step".into(),
        y_label: "MSE".into(),
        log_y: true,
        width: 640,
        height: 400,
        ..Default::default()
    };
    let path = dir.path().join("loss.png");
    line_plot(&path, &[Series::new("train", steps.clone(), train)], &style).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (640, 400));
    let (share, blue) = ink(&img, [31, 119, 180]);
    assert!(share > 0.01 && share < 0.5, "non-white share {share}");
    assert!(blue > 200, "the series line is drawn: {blue} pixels");
    assert!(has_text(&img, 0, 40), "the title is rendered with the bundled font");
}

#[test]
fn pareto_plot_is_non_blank_at_the_asked_size() {
    let points = [
        ParetoPoint::new("solver", 1.0, 1e-2).with_label("32²"),
        ParetoPoint::new("solver", 8.0, 2e-4).with_label("64²"),
        ParetoPoint::new("solver", 60.0, 5e-6).with_label("128²"),
        ParetoPoint::new("U-Net", 0.02, 3e-3),
        ParetoPoint::new("FNO", 0.01, 8e-3),
    ];
    let style = PlotStyle { width: 700, height: 450, ..PlotStyle::pareto() };
    let img = pareto_plot_rgb(&points, &style).unwrap();
    assert_eq!((img.width(), img.height()), (700, 450));
    let (share, blue) = ink(&img, [31, 119, 180]);
    assert!(share > 0.01, "non-white share {share}");
    assert!(blue > 30, "markers of the first method: {blue} pixels");
}

#[test]
fn bad_input_gives_typed_errors() {
    let f = FieldStyle::default();
    // Wrong rank / shape.
    let rank1 = Tensor::zeros(5, DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(tensor_field_to_rgb(&rank1, &f), Err(Error::Shape { .. })));
    let two_channels = Tensor::zeros((2, 4, 4), DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(tensor_field_to_rgb(&two_channels, &f), Err(Error::Shape { .. })));
    let three = Tensor::zeros((3, 4, 4), DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(tensor_vector_field_to_rgb(&three, &VectorStyle::default()), Err(Error::Shape { .. })));
    let multi = Tensor::zeros((5, 2, 4, 4), DType::F32, &Device::Cpu).unwrap();
    let err = tensor_rollout_to_gif("unused.gif", &multi, &GifStyle::default()).unwrap_err();
    assert!(matches!(err, Error::Shape { .. }) && err.to_string().contains("narrow"), "{err}");
    assert!(matches!(field_to_rgb(&[1.0f32; 5], 2, 3, &f), Err(Error::Shape { .. })));
    assert!(matches!(field_to_rgb::<f32>(&[], 0, 0, &f), Err(Error::Shape { .. })));

    // Non-finite or empty ranges, a zero upscale.
    for range in [
        ColorRange::Fixed(f64::NAN, 1.0),
        ColorRange::Fixed(0.0, f64::INFINITY),
        ColorRange::Fixed(1.0, 1.0),
        ColorRange::Symmetric(0.0),
    ] {
        let s = FieldStyle { range, ..Default::default() };
        assert!(matches!(field_to_rgb(&[1.0f32; 4], 2, 2, &s), Err(Error::InvalidArgument { .. })), "{range:?}");
    }
    let s = FieldStyle { upscale: Some(0), ..Default::default() };
    assert!(matches!(field_to_rgb(&[1.0f32; 4], 2, 2, &s), Err(Error::InvalidArgument { .. })));

    // GIFs without frames.
    let none: Vec<Vec<f32>> = Vec::new();
    assert!(matches!(
        rollout_to_gif("unused.gif", &none, 2, 2, &GifStyle::default()),
        Err(Error::InvalidArgument { .. })
    ));

    // Plots: no series, an empty series, mismatched lengths, NaN, zero on a log axis, tiny size.
    let p = PlotStyle::default();
    assert!(matches!(line_plot_rgb(&[], &p), Err(Error::InvalidArgument { .. })));
    assert!(matches!(line_plot_rgb(&[Series::new("e", vec![], vec![])], &p), Err(Error::InvalidArgument { .. })));
    assert!(matches!(
        line_plot_rgb(&[Series::new("m", vec![1.0], vec![1.0, 2.0])], &p),
        Err(Error::InvalidArgument { .. })
    ));
    match line_plot_rgb(&[Series::from_y("nan", &[1.0, f64::NAN])], &p) {
        Err(Error::NonFinite { index, .. }) => assert_eq!(index, 1),
        other => panic!("expected NonFinite, got {other:?}"),
    }
    let log = PlotStyle { log_y: true, ..Default::default() };
    let err = line_plot_rgb(&[Series::from_y("zero", &[1.0, 0.0])], &log).unwrap_err();
    assert!(matches!(err, Error::InvalidArgument { .. }) && err.to_string().contains("log axis"), "{err}");
    let tiny = PlotStyle { width: 10, height: 10, ..Default::default() };
    assert!(matches!(line_plot_rgb(&[Series::from_y("a", &[1.0])], &tiny), Err(Error::InvalidArgument { .. })));
    assert!(matches!(pareto_plot_rgb(&[], &PlotStyle::pareto()), Err(Error::InvalidArgument { .. })));
    let neg = [ParetoPoint::new("a", -1.0, 0.1)];
    assert!(matches!(pareto_plot_rgb(&neg, &PlotStyle::pareto()), Err(Error::InvalidArgument { .. })));
}

#[test]
fn the_bundled_font_ships_with_its_license() {
    pbdl_core::viz::font::register_fonts().unwrap();
    assert!(pbdl_core::viz::font::DEJAVU_LICENSE.contains("Bitstream"));
    assert!(pbdl_core::viz::font::DEJAVU_SANS.len() > 100_000);
}

// ---------------------------------------------------------------- samples

fn samples_dir() -> (Option<tempfile::TempDir>, PathBuf) {
    match std::env::var_os("PBDL_VIZ_SAMPLES") {
        Some(d) => {
            std::fs::create_dir_all(&d).unwrap();
            (None, PathBuf::from(d))
        }
        None => {
            let t = tempfile::tempdir().unwrap();
            let p = t.path().to_path_buf();
            (Some(t), p)
        }
    }
}

/// Writes one sample of every kind of output (to `$PBDL_VIZ_SAMPLES` if set), to look at.
#[test]
fn samples_of_every_kind() {
    let (_keep, dir) = samples_dir();
    let (h, w) = (64, 96);
    // A Taylor-Green-like vortex field on [0, 2pi) x [0, pi), with a hot spot near (x, y) = (1, 0.5)
    // so that the orientation (y up) is visible.
    let xy = |i: usize| ((i % w) as f64 / w as f64 * 2.0 * PI, (i / w) as f64 / h as f64 * PI);
    let vort: Vec<f64> = (0..h * w)
        .map(|i| {
            let (x, y) = xy(i);
            2.0 * x.sin() * (2.0 * y).sin()
        })
        .collect();
    let hot: Vec<f32> = (0..h * w)
        .map(|i| {
            let (x, y) = xy(i);
            ((-((x - 1.0).powi(2) + (y - 0.5).powi(2)) / 0.1).exp() + 0.2 * y.sin()) as f32
        })
        .collect();
    field_to_png(dir.join("field_viridis.png"), &hot, h, w, &FieldStyle::default()).unwrap();
    field_to_png(dir.join("field_diverging.png"), &vort, h, w, &FieldStyle::diverging()).unwrap();

    let u: Vec<f64> = (0..h * w)
        .map(|i| {
            let (x, y) = xy(i);
            x.sin() * (2.0 * y).cos()
        })
        .collect();
    let v: Vec<f64> = (0..h * w)
        .map(|i| {
            let (x, y) = xy(i);
            -x.cos() * (2.0 * y).sin()
        })
        .collect();
    vector_field_to_png(dir.join("vector_quiver.png"), &u, &v, h, w, &VectorStyle::default()).unwrap();

    let frames: Vec<Vec<f64>> = (0..24)
        .map(|t| vort.iter().map(|v| v * (-(t as f64) / 12.0).exp() * (t as f64 * 0.4).cos()).collect())
        .collect();
    let gif = GifStyle { frame_delay_ms: 80, ..GifStyle::diverging() };
    rollout_to_gif(dir.join("rollout.gif"), &frames, h, w, &gif).unwrap();
    let decoded = decode_gif(&dir.join("rollout.gif"));
    assert_eq!(decoded.len(), 24);
    // Two frames as PNG, to look at (image viewers show a GIF's first frame only).
    for i in [0, 10] {
        decoded[i].buffer().save(dir.join(format!("rollout_frame{i:02}.png"))).unwrap();
    }

    let steps: Vec<f64> = (0..500).map(|i| i as f64 * 10.0).collect();
    let train: Vec<f64> =
        steps.iter().map(|s| 0.5 * (-s / 800.0).exp() + 2e-4 * (1.0 + (s / 37.0).sin() * 0.3)).collect();
    let val: Vec<f64> = steps.iter().map(|s| 0.6 * (-s / 900.0).exp() + 6e-4).collect();
    let style = PlotStyle {
        title: "training loss".into(),
        x_label: "step".into(),
        y_label: "MSE".into(),
        log_y: true,
        ..Default::default()
    };
    line_plot(
        dir.join("loss_logy.png"),
        &[Series::new("train", steps.clone(), train), Series::new("validation", steps.clone(), val)],
        &style,
    )
    .unwrap();
    let lin = PlotStyle {
        title: "kinetic energy".into(),
        x_label: "time t".into(),
        y_label: "E(t)".into(),
        legend: Legend::UpperRight,
        ..Default::default()
    };
    let ts: Vec<f64> = (0..100).map(|i| i as f64 * 0.05).collect();
    line_plot(
        dir.join("energy_linear.png"),
        &[
            Series::new("reference", ts.clone(), ts.iter().map(|t| (-0.4 * t).exp()).collect()),
            Series::new("learned", ts.clone(), ts.iter().map(|t| (-0.43 * t).exp() + 0.01 * (5.0 * t).sin()).collect()),
            Series::new("baseline", ts.clone(), ts.iter().map(|t| (-0.3 * t).exp()).collect()),
        ],
        &lin,
    )
    .unwrap();

    // A log axis spanning less than one decade still needs ticks.
    let narrow = PlotStyle {
        title: "relative error".into(),
        x_label: "step".into(),
        y_label: "error".into(),
        log_y: true,
        ..Default::default()
    };
    line_plot(
        dir.join("narrow_logy.png"),
        &[Series::from_y("rel. error", &(0..50).map(|i| 0.25 + 0.005 * i as f64).collect::<Vec<_>>())],
        &narrow,
    )
    .unwrap();

    let points = [
        ParetoPoint::new("solver", 0.8, 1.2e-2).with_label("32²"),
        ParetoPoint::new("solver", 6.5, 2.1e-4).with_label("64²"),
        ParetoPoint::new("solver", 52.0, 4.0e-6).with_label("128²"),
        ParetoPoint::new("solver + correction", 1.1, 9.0e-4).with_label("32²"),
        ParetoPoint::new("solver + correction", 8.0, 3.0e-5).with_label("64²"),
        ParetoPoint::new("U-Net", 0.02, 3.5e-3),
        ParetoPoint::new("FNO", 0.012, 8.0e-3),
    ];
    pareto_plot(dir.join("pareto.png"), &points, &PlotStyle::pareto()).unwrap();

    for name in [
        "field_viridis.png",
        "field_diverging.png",
        "vector_quiver.png",
        "loss_logy.png",
        "energy_linear.png",
        "pareto.png",
    ] {
        let img = image::open(dir.join(name)).unwrap();
        assert!(img.width() >= 256 && img.height() >= 128, "{name}");
    }
}

#[test]
fn nan_pixels_take_the_style_background_colour() {
    let data = [0.0f64, f64::NAN, 1.0, 0.5];
    let magenta = pbdl_core::viz::field_to_rgb(&data, 2, 2, &style(Colormap::Viridis, 1, Origin::Upper)).unwrap();
    assert_eq!(px(&magenta, 1, 0), pbdl_core::viz::NAN_COLOR);
    let white =
        FieldStyle { nan_color: [255, 255, 255], origin: Origin::Upper, upscale: Some(1), ..Default::default() };
    let img = pbdl_core::viz::field_to_rgb(&data, 2, 2, &white).unwrap();
    assert_eq!(px(&img, 1, 0), [255, 255, 255]);
    // Finite values keep their colormap colour.
    assert_eq!(px(&img, 0, 0), px(&magenta, 0, 0));
}
