//! CConv's liquid network on our 2D dam breaks: the acceptance pipeline (data, training,
//! 5x-horizon rollouts against SPH), a GIF learned | SPH and a PNG of its last frame.
//!
//! `cargo run --release -p pbdl-pconv --example liquid -- OUT.gif [steps=N] [batch=N] [run_dir=DIR] [test=K]`

use pbdl_pconv::liquid::{evaluate, train, LiquidConfig, LiquidDataset, LiquidTrainConfig};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn arg(name: &str) -> Option<String> {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).map(str::to_string))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let gif = std::env::args().skip(1).find(|a| !a.contains('=')).ok_or("usage: liquid OUT.gif [steps=N] ...")?;
    let mut cfg = LiquidTrainConfig::acceptance();
    if let Some(s) = arg("steps") {
        cfg.steps = s.parse()?;
    }
    if let Some(b) = arg("batch") {
        cfg.batch = b.parse()?;
    }
    let test: usize = arg("test").map_or(Ok(0), |s| s.parse())?;
    let data = LiquidDataset::generate(&LiquidConfig::default())?;
    let (tr, te) = data.particle_counts();
    println!("data: train particles {tr:?}, test {te:?}, {:.1} s of SPH", data.seconds);
    let run_dir = arg("run_dir").map(std::path::PathBuf::from);
    let trained = train(&data, &cfg, run_dir.as_deref())?;
    let (first, last) = trained.loss_ends(50);
    println!("training: {} steps in {:.0} s, loss {first:.4} -> {last:.4}", trained.losses.len(), trained.seconds);
    let report = evaluate(&data, &trained.net, test)?;
    let h = data.config.frames;
    println!(
        "rollout of {} / {} frames ({:.1} s): mean distance over the horizon {:.4} m, over 5x {:.4} m, last {:.4} m",
        report.frames,
        report.frames_requested,
        report.seconds,
        report.mean_distance_over(0..h),
        report.mean_distance_over(0..report.frames),
        report.mean_distance.last().copied().unwrap_or(f64::NAN)
    );
    let every = |v: &[f64]| v.iter().step_by(20).map(|d| format!("{d:.3}")).collect::<Vec<_>>().join(" ");
    println!("mean distance every 20th frame: {}", every(&report.mean_distance));
    println!("particles kept at their start:  {}", every(&report.frozen_distance));
    println!(
        "stable {}, escaped max {}, kinetic ratio {:.2}",
        report.stable(),
        report.escaped.iter().max().unwrap_or(&0),
        report.kinetic_ratio()
    );
    pbdl_pconv::liquid::write_gif(std::path::Path::new(&gif), &data, &report)?;
    let png = std::path::Path::new(&gif).with_extension("png");
    pbdl_pconv::liquid::write_png(&png, &data, &report, report.frames - 1)?;
    println!("wrote {gif} and {} (the last frame)", png.display());
    Ok(())
}
