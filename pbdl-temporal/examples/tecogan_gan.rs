//! TecoGAN's adversarial fine-tuning on smoke data: non-adversarial pre-training of F and G,
//! then adversarial fine-tuning against D_s,t with and without the ping-pong term, scored on
//! held-out clips.
//!
//! ```text
//! cargo run --release -p pbdl-temporal --example tecogan_gan -- [--pre-steps 200]
//!     [--gan-steps 100] [--train-scenes 8] [--test-scenes 2] [--seed 0] [--out gan.json]
//!     [--save DIR]
//! ```
//!
//! `--save DIR` writes the three models as recurrent model files (`pretrained.safetensors`,
//! `gan_pingpong.safetensors`, `gan_no_pingpong.safetensors`, each with its JSON sidecar), which
//! `cargo xtask temporal upscale --model DIR/gan_pingpong.safetensors --input LR.npz --out HR.npz`
//! applies to a low-resolution sequence.
//!
//! Protocol: smoke data 16^2 -> 64^2 (`SmokeData` defaults except the scene counts); one
//! pre-training with `train_tecogan` (defaults: L2 content + warp + ping-pong 0.5); from its
//! weights two adversarial runs of `train_tecogan_gan` (defaults: TecoGAN's weights), identical
//! (seed, D initialisation, sampled ping-pong windows) except for the ping-pong weight (0.5 vs
//! 0). On every held-out clip (all its frames): PSNR (peak 1, per frame, averaged) and tOF
//! (`pbdl_metrics::temporal::tof`, `TofOptions::default()`) of the forward run against the
//! truth, and the ping-pong drift `mean |g_t - g'_t|` of a run over the clip's ping-pong order.
//! Bicubic and the pre-trained model are reported too. The numbers are what one small CPU run
//! gives, not a tuned result.

use candle_core::{DType, Tensor};
use pbdl_core::sample::{resize2d, Resize};
use pbdl_metrics::temporal::{tof, TofOptions};
use pbdl_temporal::data::{generate, Clip, SmokeData};
use pbdl_temporal::model::{RecurrentModel, RecurrentModelInfo};
use pbdl_temporal::tecogan::{
    drift, pingpong_sequence, split_pingpong, train_tecogan, train_tecogan_gan, TecoGan, TecoGanTrainConfig,
    TecoTrainConfig,
};
use serde_json::json;
use std::time::Instant;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

struct Args {
    pre_steps: u64,
    gan_steps: u64,
    train_scenes: usize,
    test_scenes: usize,
    seed: u64,
    out: Option<String>,
    save: Option<std::path::PathBuf>,
}

fn args() -> Args {
    let mut a =
        Args { pre_steps: 200, gan_steps: 100, train_scenes: 8, test_scenes: 2, seed: 0, out: None, save: None };
    let v: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    while i < v.len() {
        let val = v.get(i + 1).cloned().unwrap_or_default();
        match v[i].as_str() {
            "--pre-steps" => a.pre_steps = val.parse().expect("--pre-steps N"),
            "--gan-steps" => a.gan_steps = val.parse().expect("--gan-steps N"),
            "--train-scenes" => a.train_scenes = val.parse().expect("--train-scenes N"),
            "--test-scenes" => a.test_scenes = val.parse().expect("--test-scenes N"),
            "--seed" => a.seed = val.parse().expect("--seed N"),
            "--out" => a.out = Some(val),
            "--save" => a.save = Some(val.into()),
            other => panic!("unknown argument {other}"),
        }
        i += 2;
    }
    a
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// PSNR (peak 1) per frame of `out` against `truth` (`[T, 1, N, N]`), averaged.
fn psnr(out: &Tensor, truth: &Tensor) -> pbdl_temporal::Result<f64> {
    let mse: Vec<f64> = (out - truth)?.sqr()?.flatten_from(1)?.mean(1)?.to_dtype(DType::F64)?.to_vec1()?;
    Ok(mean(&mse.iter().map(|m| -10.0 * m.max(1e-12).log10()).collect::<Vec<_>>()))
}

/// (PSNR, tOF) of `out` on `clip`.
fn scores(out: &Tensor, clip: &Clip) -> pbdl_temporal::Result<(f64, f64)> {
    Ok((psnr(out, &clip.hr_density)?, tof(out, &clip.hr_density, &TofOptions::default())?))
}

/// Held-out scores of a model: per clip (PSNR, tOF, drift), and their means.
fn evaluate(model: &TecoGan, clips: &[Clip]) -> pbdl_temporal::Result<serde_json::Value> {
    let mut rows = Vec::new();
    for clip in clips {
        let out = model.infer_sequence(&clip.lr_density)?;
        let (p, t) = scores(&out, clip)?;
        let (f, b) = split_pingpong(&model.infer_sequence(&pingpong_sequence(&clip.lr_density)?)?)?;
        rows.push([p, t, drift(&f, &b)?]);
    }
    let col = |i: usize| mean(&rows.iter().map(|r| r[i]).collect::<Vec<_>>());
    Ok(json!({ "psnr": col(0), "tof": col(1), "drift": col(2), "per_clip": rows }))
}

fn main() -> pbdl_temporal::Result<()> {
    let a = args();
    let data_cfg = SmokeData { train_scenes: a.train_scenes, test_scenes: a.test_scenes, ..SmokeData::default() };
    let t0 = Instant::now();
    let data = generate(&data_cfg)?;
    println!("data: {} train / {} test clips in {:.0}s", data.train.len(), data.test.len(), t0.elapsed().as_secs_f64());

    let mut bicubic = Vec::new();
    for clip in &data.test {
        let (n, m) = (clip.hr_density.dim(2)?, clip.hr_density.dim(3)?);
        let up = resize2d(&clip.lr_density, (n, m), Resize::Bicubic { align_corners: false })?;
        bicubic.push(scores(&up, clip)?);
    }
    let bicubic = json!({
        "psnr": mean(&bicubic.iter().map(|s| s.0).collect::<Vec<_>>()),
        "tof": mean(&bicubic.iter().map(|s| s.1).collect::<Vec<_>>()),
    });
    println!("bicubic: {bicubic}");

    let pre_cfg = TecoTrainConfig { steps: a.pre_steps, seed: a.seed, ..Default::default() };
    let t0 = Instant::now();
    let (pre, pre_map, pre_rep) = train_tecogan(&data.train, &pre_cfg)?;
    let pre_seconds = t0.elapsed().as_secs_f64();
    let pre_eval = evaluate(&pre, &data.test)?;
    println!("pre-trained ({} updates, {pre_seconds:.0}s): {pre_eval}", a.pre_steps);
    let save = |name: &str, objective: &str, updates: u64, varmap: &candle_nn::VarMap| -> pbdl_temporal::Result<()> {
        if let Some(dir) = &a.save {
            std::fs::create_dir_all(dir).map_err(|e| pbdl_core::Error::io(dir, e))?;
            let info = RecurrentModelInfo { tecogan: pre_cfg.model.clone(), objective: objective.into(), updates };
            let path = dir.join(format!("{name}.safetensors"));
            RecurrentModel::new(info, varmap.clone())?.save(&path)?;
            println!("saved {}", path.display());
        }
        Ok(())
    };
    save("pretrained", "content+warp+pingpong", a.pre_steps, &pre_map)?;

    let mut runs = Vec::new();
    for weight in [0.5, 0.0] {
        let cfg =
            TecoGanTrainConfig { steps: a.gan_steps, pingpong_weight: weight, seed: a.seed, ..Default::default() };
        let t0 = Instant::now();
        let (model, model_map, rep) = train_tecogan_gan(&data.train, &cfg, Some(&pre_map), None)?;
        let name = if weight > 0.0 { "gan_pingpong" } else { "gan_no_pingpong" };
        save(name, &format!("adversarial, ping-pong weight {weight}"), a.pre_steps + a.gan_steps, &model_map)?;
        let seconds = t0.elapsed().as_secs_f64();
        let eval = evaluate(&model, &data.test)?;
        let tail = |v: &[f64]| mean(&v[v.len() - (v.len() / 5).max(1)..]);
        let d_updates = rep.d_trained.iter().filter(|d| **d).count();
        println!(
            "GAN pp {weight} ({} updates, {seconds:.0}s, D updated {d_updates}x): last-20% content {:.3e} pp {:.3e} adv {:.3} d_loss {:.3} d_real {:.3} balance {:.3} | {eval}",
            a.gan_steps,
            tail(&rep.content),
            tail(&rep.pingpong),
            tail(&rep.adversarial),
            tail(&rep.d_loss),
            tail(&rep.d_real),
            rep.balance.last().copied().unwrap_or(f64::NAN),
        );
        runs.push(json!({
            "pingpong_weight": weight, "train_seconds": seconds, "d_updates": d_updates, "eval": eval,
            "content": rep.content, "pingpong": rep.pingpong, "adversarial": rep.adversarial,
            "d_loss": rep.d_loss, "d_real": rep.d_real, "balance": rep.balance,
        }));
    }
    let out = json!({
        "data": data_cfg, "pretrain": pre_cfg, "pretrain_seconds": pre_seconds,
        "pretrain_final_loss": pre_rep.losses.last(), "bicubic": bicubic, "pretrained": pre_eval,
        "gan": TecoGanTrainConfig { steps: a.gan_steps, seed: a.seed, ..Default::default() }, "runs": runs,
    });
    if let Some(path) = &a.out {
        std::fs::write(path, serde_json::to_string_pretty(&out).expect("json"))
            .map_err(|e| pbdl_core::Error::io(path, e))?;
    }
    Ok(())
}
