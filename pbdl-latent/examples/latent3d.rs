//! Latent-space physics in 3D at CPU size: simulate buoyant plumes with pbdl-grid's `Smoke3d`
//! (pressure of every step kept through its pressure split), train the 3D pressure autoencoder
//! and print its held-out aggregate relative L2 reconstruction error and timings (solver step,
//! encode, decode).
//!
//! `cargo run --release -p pbdl-latent --example latent3d [res=16|32] [train=6] [test=2]
//! [frames=48] [steps=600] [batch=8] [lr=1e-3] [widths=16,32,64] [latent=8] [seed=0] [dir=PATH]`

use candle_core::{DType, Device, Tensor};
use pbdl_latent::autoencoder3d::{
    autoencoder3d_error, train_autoencoder3d, Autoencoder3dConfig, Autoencoder3dTrainConfig,
};
use pbdl_latent::data3d::{generate3d, PlumeData3d};
use pbdl_latent::train::PhaseSettings;
use std::path::PathBuf;
use std::time::Instant;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).and_then(|v| v.parse().ok())).unwrap_or(default)
}

fn list(name: &str, default: &str) -> Vec<usize> {
    arg(name, default.to_string()).split(',').filter_map(|s| s.parse().ok()).collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let res: usize = arg("res", 32);
    let seed: u64 = arg("seed", 0);
    let data_cfg = PlumeData3d {
        resolution: res,
        train_scenes: arg("train", 6),
        test_scenes: arg("test", 2),
        frames: arg("frames", 48),
        seed,
        ..PlumeData3d::default()
    };
    let t = Instant::now();
    let data = generate3d(&data_cfg)?;
    println!(
        "data: {} + {} scenes of {} frames at {res}^3 in {:.1} s; solver step {:.1} ms (split step, f32, scenes in parallel)",
        data.train.len(),
        data.test.len(),
        data_cfg.frames,
        t.elapsed().as_secs_f64(),
        data.solver_ms_per_step()
    );
    let cfg = Autoencoder3dTrainConfig {
        autoencoder: Autoencoder3dConfig {
            resolution: res,
            widths: list("widths", "16,32,64"),
            latent_channels: arg("latent", 8),
            ..Autoencoder3dConfig::default()
        },
        training: PhaseSettings { steps: arg("steps", 600), batch: arg("batch", 8), lr: arg("lr", 1e-3) },
        seed,
    };
    let dir: Option<PathBuf> = std::env::args().find_map(|a| a.strip_prefix("dir=").map(PathBuf::from));
    let t = Instant::now();
    let model = train_autoencoder3d(&data, &cfg, dir.as_deref())?;
    let train_s = t.elapsed().as_secs_f64();
    let code = model.autoencoder.code_size();
    println!(
        "trained {} updates of {} frames in {train_s:.1} s ({:.0} ms/update); code {code} entries ({:.0}x compression)",
        cfg.training.steps,
        cfg.training.batch,
        1e3 * train_s / cfg.training.steps as f64,
        (res * res * res) as f64 / code as f64
    );
    let t = Instant::now();
    let test = autoencoder3d_error(&model, &data.test)?;
    let eval_s = t.elapsed().as_secs_f64();
    let train = autoencoder3d_error(&model, &data.train)?;
    println!(
        "autoencoder held-out aggregate rel L2: {test:.4} (train {train:.4}); bar <= 0.05: {}",
        if test <= 0.05 { "met" } else { "MISSED" }
    );
    // Encode / decode timings of one frame (batch 1), after a warm-up call.
    let p = data.test[0].pressure.narrow(0, data.test[0].frames() - 1, 1)?;
    let z = model.encode_pressure(&p)?;
    model.decode_pressure(&z)?;
    let reps = 5;
    let t = Instant::now();
    for _ in 0..reps {
        model.encode_pressure(&p)?;
    }
    let enc = 1e3 * t.elapsed().as_secs_f64() / reps as f64;
    let t = Instant::now();
    for _ in 0..reps {
        model.decode_pressure(&z)?;
    }
    let dec = 1e3 * t.elapsed().as_secs_f64() / reps as f64;
    // One solver step alone (not in parallel with other scenes).
    let scene = data_cfg.scene(data.test[0].param);
    let smoke = scene.smoke()?;
    let n = res;
    let v = data.test[0].velocity.narrow(0, data.test[0].frames() - 1, 1)?;
    let rho = data.test[0].density.narrow(0, data.test[0].frames() - 1, 1)?;
    let state = pbdl_grid::grid3d::Smoke3dState {
        velocity: pbdl_grid::grid3d::MacField3d::new(v, *smoke.grid())?,
        density: rho,
    };
    let t = Instant::now();
    let mut s = state.clone();
    for _ in 0..reps {
        s = smoke.step(&s, None)?;
    }
    let step = 1e3 * t.elapsed().as_secs_f64() / reps as f64;
    let t = Instant::now();
    for _ in 0..reps {
        smoke.step_unprojected(&state, None)?;
    }
    let unprojected = 1e3 * t.elapsed().as_secs_f64() / reps as f64;
    let zero = Tensor::zeros((1, 1, n, n, n), DType::F32, &Device::Cpu)?;
    let before = smoke.step_unprojected(&state, None)?;
    let t = Instant::now();
    for _ in 0..reps {
        smoke.correct_with_pressure(&before.velocity, &zero)?;
    }
    let correct = 1e3 * t.elapsed().as_secs_f64() / reps as f64;
    println!(
        "timings (ms, batch 1, alone): solver step {step:.1} (of it before the projection {unprojected:.1}); \
         encode {enc:.1}, decode {dec:.1}, correction with a given pressure {correct:.1}; held-out scoring {eval_s:.1} s"
    );
    Ok(())
}
