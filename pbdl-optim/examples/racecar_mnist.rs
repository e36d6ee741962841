//! racecar's one-layer "MNIST" model on two procedurally drawn digits (a stand-in for MNIST):
//! prints the `|cos|` of the leading singular vectors of `W` with the span of the training
//! images, racecar against plain, and writes `target/pbdl/racecar_mnist.png` for the first
//! seed: row 1 the two training images (gray), row 2 the racecar model's singular vectors
//! reshaped to 28x28, row 3 the plain model's (blue-white-red, symmetric range per panel);
//! in rows 2 and 3 the two leading singular vectors, then the two most aligned with the span.
//!
//! `cargo run --release -p pbdl-optim --example racecar_mnist [seed ...]` (default seeds 0 1 2)

use pbdl_core::viz::{field_to_rgb, write_png, ColorRange, Colormap, FieldStyle, Origin, RgbImage};
use pbdl_optim::racecar::digits::SIDE;
use pbdl_optim::racecar::mnist::{mnist_alignment_experiment, MnistConfig};

const UPSCALE: u32 = 8;
const GAP: u32 = 8;

/// Copies `panel` into `canvas` with its top-left corner at `(x0, y0)`.
fn blit(canvas: &mut RgbImage, panel: &RgbImage, x0: u32, y0: u32) {
    for (x, y, p) in panel.enumerate_pixels() {
        canvas.put_pixel(x0 + x, y0 + y, *p);
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let seeds: Vec<u64> = std::env::args().skip(1).map(|a| a.parse()).collect::<Result<_, _>>()?;
    let seeds = if seeds.is_empty() { vec![0, 1, 2] } else { seeds };
    println!("| seed | racecar cos | plain cos | racecar CE | plain CE | racecar rec | plain rec | s/run |");
    println!("|---:|---|---|---:|---:|---:|---:|---:|");
    let mut first = None;
    for &seed in &seeds {
        let cfg = MnistConfig { seed, ..Default::default() };
        let e = mnist_alignment_experiment(&cfg)?;
        let f = |c: &[f64]| c.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>().join(", ");
        println!(
            "| {seed} | {} | {} | {:.3e} | {:.3e} | {:.3e} | {:.3e} | {:.3} / {:.3} |",
            f(&e.racecar.cos),
            f(&e.plain.cos),
            e.racecar.task_loss,
            e.plain.task_loss,
            e.racecar.reconstruction,
            e.plain.reconstruction,
            e.racecar.seconds,
            e.plain.seconds
        );
        let sv = |s: &[f64]| s.iter().take(4).map(|v| format!("{v:.3}")).collect::<Vec<_>>().join(", ");
        println!(
            "|   | singular values racecar {} | plain {} | | | | | |",
            sv(&e.racecar.singular_values),
            sv(&e.plain.singular_values)
        );
        let best = |r: &pbdl_optim::racecar::mnist::MnistRun| {
            r.best_aligned(2).iter().map(|(i, c)| format!("#{} {c:.3}", i + 1)).collect::<Vec<_>>().join(", ")
        };
        println!("|   | most span-aligned: racecar {} | plain {} | | | | | |", best(&e.racecar), best(&e.plain));
        first.get_or_insert(e);
    }
    let e = first.expect("at least one seed");
    let images = e.images.to_vec2::<f64>()?;
    let gray = FieldStyle {
        colormap: Colormap::Gray,
        range: ColorRange::Fixed(0.0, 255.0),
        upscale: Some(UPSCALE),
        origin: Origin::Upper,
        ..Default::default()
    };
    let signed = FieldStyle { upscale: Some(UPSCALE), origin: Origin::Upper, ..FieldStyle::diverging() };
    // Per model: the two leading singular vectors, then the two most aligned with the span.
    let pick = |vectors: &[Vec<f64>], run: &pbdl_optim::racecar::mnist::MnistRun| -> Vec<Vec<f64>> {
        let lead = (0..2).map(|i| vectors[i].clone());
        lead.chain(run.best_aligned(2).into_iter().map(|(i, _)| vectors[i].clone())).collect()
    };
    let rows: Vec<(Vec<Vec<f64>>, &FieldStyle)> = vec![
        (images, &gray),
        (pick(&e.racecar_vectors, &e.racecar), &signed),
        (pick(&e.plain_vectors, &e.plain), &signed),
    ];
    let cols = rows.iter().map(|r| r.0.len()).max().unwrap_or(1) as u32;
    let cell = SIDE as u32 * UPSCALE;
    let mut canvas =
        RgbImage::new(cols * cell + (cols + 1) * GAP, rows.len() as u32 * cell + (rows.len() as u32 + 1) * GAP);
    canvas.iter_mut().for_each(|v| *v = 255); // white background
    for (r, (panels, style)) in rows.iter().enumerate() {
        for (c, data) in panels.iter().enumerate() {
            let panel = field_to_rgb(data, SIDE, SIDE, style)?;
            blit(&mut canvas, &panel, GAP + c as u32 * (cell + GAP), GAP + r as u32 * (cell + GAP));
        }
    }
    let path = std::path::Path::new("target/pbdl/racecar_mnist.png");
    std::fs::create_dir_all(path.parent().expect("has a parent"))?;
    write_png(path, &canvas)?;
    println!(
        "wrote {} (seed {}; rows: training images | racecar | plain; columns: singular vectors 1, 2, then the two most span-aligned)",
        path.display(),
        seeds[0]
    );
    Ok(())
}
