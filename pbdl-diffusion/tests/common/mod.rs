//! Helpers shared by the integration tests (`mod common;` in each test file that uses them):
//! seeded networks and inputs, and the SMDP toy training configurations. (The finite-difference
//! check of a whole network moved to pbdl-nets' tests with the U-Net tests.)

#![allow(dead_code)]

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::seed;
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::sde::ToySde;
use pbdl_diffusion::smdp::toy::{train_toy, TimeSampling, ToyLoss, ToyTrainConfig};
use pbdl_diffusion::unet::seeded_init;

/// The device of the tests.
pub const CPU: Device = Device::Cpu;

/// A standard normal tensor of `shape` drawn from seed `s`.
pub fn randn(shape: &[usize], dtype: DType, s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, dtype, &CPU, s).unwrap()
}

/// A network built by `new` (a `pbdl_diffusion` or `pbdl_nets` constructor) on the variables of
/// a fresh [`VarMap`] (`dtype`, CPU), initialised with [`seeded_init`] from `seed`.
pub fn build_seeded<N, E: std::fmt::Debug>(
    dtype: DType,
    seed: u64,
    new: impl FnOnce(VarBuilder) -> Result<N, E>,
) -> (VarMap, N) {
    let varmap = VarMap::new();
    let net = new(VarBuilder::from_varmap(&varmap, dtype, &CPU)).unwrap();
    seeded_init(&varmap, seed).unwrap();
    (varmap, net)
}

/// Makes every strided 1-step stage of `cfg` one-directional (the official configs train the
/// strided loss in both time directions).
pub fn one_directional_strides(cfg: &mut ToyTrainConfig) {
    for st in &mut cfg.stages {
        if let ToyLoss::Strided { stride, .. } = st.loss {
            st.loss = ToyLoss::Strided { stride, bidirectional: false };
        }
    }
}

/// The official regularised quadratic config (`smdp_reg_mlp_paper`: regularised 1-step loss,
/// stride 5 at lr 1e-3 then stride 1 at lr 1e-4, 250k + 250k updates) on data at the sampler
/// step 0.02 (no simulator sub-steps), one-directional, with log-uniform training times.
pub fn quadratic_reg_config() -> ToyTrainConfig {
    let mut cfg = ToyTrainConfig {
        log_every: 50_000,
        sim_substeps: 1,
        time_sampling: TimeSampling::LogUniform,
        ..ToyTrainConfig::official(250_000, 250_000)
    };
    one_directional_strides(&mut cfg);
    cfg
}

/// Trains `net` on `sde` with `cfg` and prints `"{what} in ... s; losses ..."`.
pub fn train_logged(sde: &ToySde, net: &mut ScoreMlp, cfg: &ToyTrainConfig, what: &str) {
    let rep = train_toy(sde, net, cfg).unwrap();
    println!("{what} in {:.1} s; losses {:?}", rep.seconds, rep.losses);
}

/// Two synthetic wake cases (Re 100 and 200) of 8 snapshots `m + s sin(2 pi k / 8 + 0.3 p)` on
/// an 8 x 8 window, for short `uncertainty::train` runs.
pub fn synthetic_wake_cases() -> Vec<pbdl_diffusion::uncertainty::WakeCase> {
    let (h, w, n) = (8, 8, 8);
    [100.0, 200.0]
        .iter()
        .map(|&re| {
            let mut v = vec![0f32; n * 2 * h * w];
            for k in 0..n {
                for c in 0..2 {
                    for p in 0..h * w {
                        let s = (2.0 * std::f32::consts::PI * k as f32 / n as f32 + p as f32 * 0.3).sin();
                        let amp = [0.1 * re as f32 / 100.0, 0.2][c];
                        v[(k * 2 + c) * h * w + p] = [1.0, 0.0][c] + amp * (1.0 + p as f32 / 64.0) * s;
                    }
                }
            }
            pbdl_diffusion::uncertainty::WakeCase { re, snapshots: Tensor::from_vec(v, (n, 2, h, w), &CPU).unwrap() }
        })
        .collect()
}
