//! Tests of the adversarial TecoGAN trainer: finite losses and logs, exact resume, the resume
//! guard, and that each player's update leaves the other's weights alone.

use candle_core::{DType, Tensor};
use candle_nn::VarMap;
use pbdl_temporal::data::{generate, Dataset, SmokeData};
use pbdl_temporal::tecogan::*;
use pbdl_temporal::Error;
use std::collections::BTreeMap;
use std::sync::OnceLock;

type R = Result<(), Box<dyn std::error::Error>>;
type Weights = BTreeMap<String, Vec<f32>>;

fn data() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        generate(&SmokeData {
            lr_resolution: 8,
            train_scenes: 2,
            test_scenes: 1,
            frames: 6,
            warmup: 10,
            ..SmokeData::default()
        })
        .unwrap()
    })
}

/// A tiny configuration: 8^2 -> 32^2, 3-frame windows (5 with ping-pong, one triplet each).
fn tiny(steps: u64) -> TecoGanTrainConfig {
    TecoGanTrainConfig {
        model: TecoGanConfig {
            motion: MotionNetConfig { base_width: 2, levels: 1, max_flow: 2.0 },
            generator: RecurrentGeneratorConfig { channels: 4, blocks: 1, factor: 4 },
        },
        steps,
        batch: 2,
        frames: 3,
        lr: 1e-3,
        discriminator_widths: vec![4, 4],
        feature_norms: vec![12.0, 14.0],
        ..TecoGanTrainConfig::default()
    }
}

/// name -> values of every variable.
fn values(map: &VarMap) -> Weights {
    let d = map.data().lock().unwrap();
    d.iter().map(|(n, v)| (n.clone(), v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap())).collect()
}

fn bits(t: &Tensor) -> Vec<u32> {
    t.flatten_all()
        .unwrap()
        .to_dtype(DType::F32)
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
        .iter()
        .map(|v| v.to_bits())
        .collect()
}

fn with_prefix(all: &Weights, prefix: &str) -> Weights {
    all.iter().filter(|(n, _)| n.starts_with(prefix)).map(|(n, v)| (n.clone(), v.clone())).collect()
}

#[test]
fn a_tiny_run_has_finite_losses_and_logs_every_column() -> R {
    let dir = tempfile::tempdir()?;
    let cfg = tiny(4);
    let (model, _, r) = train_tecogan_gan(&data().train, &cfg, None, Some(dir.path()))?;
    assert_eq!(r.losses.len(), 4);
    for series in
        [&r.losses, &r.d_loss, &r.d_real, &r.balance, &r.content, &r.pingpong, &r.adversarial, &r.feature, &r.warp]
    {
        assert!(series.iter().all(|v| v.is_finite()), "{series:?}");
    }
    // The balance starts at 0 < 0.4: the first D update runs.
    assert!(r.d_trained[0]);
    let csv = std::fs::read_to_string(dir.path().join("loss.csv"))?;
    let header = csv.lines().next().unwrap();
    for col in
        ["loss", "d_loss", "d_real", "d_trained", "balance", "content", "pingpong", "adversarial", "feature", "warp"]
    {
        assert!(header.split(',').any(|c| c == col), "no column {col} in {header}");
    }
    assert_eq!(csv.lines().count(), 5);
    let out = model.infer_sequence(&data().test[0].lr_density)?;
    assert_eq!(out.dims(), [6, 1, 32, 32]);
    // Bad settings are typed errors naming the field.
    for (bad, field) in [
        (TecoGanTrainConfig { feature_norms: vec![1.0], ..tiny(1) }, "feature_norms"),
        (TecoGanTrainConfig { frames: 2, pingpong_sequences: false, pingpong_weight: 0.0, ..tiny(1) }, "frames"),
        (TecoGanTrainConfig { pingpong_sequences: false, ..tiny(1) }, "pingpong_weight"),
        (TecoGanTrainConfig { adversarial_weight: -1.0, ..tiny(1) }, "adversarial_weight"),
        (
            TecoGanTrainConfig { discriminator_widths: vec![4, 4, 4, 4, 4, 4], feature_norms: vec![1.0; 6], ..tiny(1) },
            "discriminator_widths",
        ),
    ] {
        match train_tecogan_gan(&data().train, &bad, None, None) {
            Err(Error::Config { field: f, .. }) => assert_eq!(f, field),
            other => panic!("expected a config error on {field}, got {:?}", other.map(|r| r.2)),
        }
    }
    Ok(())
}

#[test]
fn stopping_and_resuming_equals_an_uninterrupted_run_bit_for_bit() -> R {
    let (a, b) = (tempfile::tempdir()?, tempfile::tempdir()?);
    let pre = train_tecogan(
        &data().train,
        &TecoTrainConfig { model: tiny(1).model, steps: 2, batch: 2, frames: 3, ..Default::default() },
    )?;
    let start = Some(&pre.1);
    let (_, _, first) = train_tecogan_gan(&data().train, &tiny(3), start, Some(a.path()))?;
    assert_eq!(first.losses.len(), 3);
    let (resumed, resumed_map, rest) = train_tecogan_gan(&data().train, &tiny(7), start, Some(a.path()))?;
    assert_eq!((rest.resumed_from, rest.losses.len()), (3, 4));
    let (whole, whole_map, all) = train_tecogan_gan(&data().train, &tiny(7), start, Some(b.path()))?;
    assert_eq!(rest.losses, all.losses[3..]);
    assert_eq!(rest.balance, all.balance[3..]);
    assert!(values(&resumed_map) == values(&whole_map), "resumed weights differ");
    let lr = &data().test[0].lr_density;
    assert_eq!(bits(&resumed.infer_sequence(lr)?), bits(&whole.infer_sequence(lr)?));
    // The logged losses of the resumed directory are the uninterrupted run's.
    assert_eq!(pbdl_core::train::logged_losses(a.path())?, pbdl_core::train::logged_losses(b.path())?);
    // The adversarial terms changed the weights relative to the start.
    assert!(values(&whole_map) != values(&pre.1), "the weights did not move");
    Ok(())
}

#[test]
fn a_run_directory_of_another_seed_or_start_is_refused() -> R {
    let dir = tempfile::tempdir()?;
    train_tecogan_gan(&data().train, &tiny(1), None, Some(dir.path()))?;
    let other = TecoGanTrainConfig { seed: 1, ..tiny(2) };
    match train_tecogan_gan(&data().train, &other, None, Some(dir.path())) {
        Err(Error::Core(pbdl_core::Error::ResumeMismatch { field, .. })) => assert_eq!(field, "seed"),
        other => panic!("expected a resume mismatch on seed, got {:?}", other.map(|r| r.2)),
    }
    let pre = tecogan_gan_players(&TecoGanTrainConfig { seed: 5, ..tiny(1) }, None)?;
    match train_tecogan_gan(&data().train, &tiny(2), Some(&pre.model_varmap), Some(dir.path())) {
        Err(Error::Core(pbdl_core::Error::ResumeMismatch { field, .. })) => assert_eq!(field, "start_digest"),
        other => panic!("expected a resume mismatch on start_digest, got {:?}", other.map(|r| r.2)),
    }
    // The same settings resume.
    let (_, _, r) = train_tecogan_gan(&data().train, &tiny(2), None, Some(dir.path()))?;
    assert_eq!((r.resumed_from, r.losses.len()), (1, 1));
    Ok(())
}

/// The weights of every player after `cfg.steps` updates (from the last checkpoint) and before.
fn before_after(cfg: &TecoGanTrainConfig) -> Result<(Weights, Weights), Box<dyn std::error::Error>> {
    let dir = tempfile::tempdir()?;
    let (_, _, r) = train_tecogan_gan(&data().train, cfg, None, Some(dir.path()))?;
    assert_eq!(r.losses.len() as u64, cfg.steps);
    let before = values(&tecogan_gan_players(cfg, None)?.varmap);
    let after = tecogan_gan_players(cfg, None)?;
    pbdl_core::train::load_train_checkpoint(dir.path().join(format!("step-{}", cfg.steps)), &after.varmap)?;
    Ok((before, values(&after.varmap)))
}

#[test]
fn the_d_update_leaves_g_and_f_alone() -> R {
    // Every G + F loss weight 0: their gradients vanish, so only the D update could move them.
    let cfg = TecoGanTrainConfig {
        content_weight: 0.0,
        pingpong_weight: 0.0,
        adversarial_weight: 0.0,
        feature_weight: 0.0,
        warp_weight: 0.0,
        balance: false,
        ..tiny(2)
    };
    let (before, after) = before_after(&cfg)?;
    assert!(with_prefix(&before, "g.") == with_prefix(&after, "g."), "the D update changed G or F");
    assert!(with_prefix(&before, "d.") != with_prefix(&after, "d."), "D must have trained");
    Ok(())
}

#[test]
fn the_g_update_leaves_d_alone() -> R {
    // A balance threshold nothing reaches: D never updates, so only the G + F update (whose
    // adversarial and feature terms depend on D's weights) could move them.
    let cfg = TecoGanTrainConfig { balance_threshold: -1e9, adversarial_weight: 1.0, feature_weight: 1.0, ..tiny(2) };
    let (before, after) = before_after(&cfg)?;
    assert!(with_prefix(&before, "d.") == with_prefix(&after, "d."), "the G update changed D");
    assert!(with_prefix(&before, "g.") != with_prefix(&after, "g."), "G must have trained");
    Ok(())
}
