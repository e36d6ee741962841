//! The ResNet forecaster on Lorenz-96 (a 1 x 40 periodic "grid", 6-hour steps): it must beat
//! linear regression at a 24-hour lead, and a run directory must resume where it stopped.

use candle_core::{DType, Device};
use candle_nn::{VarBuilder, VarMap};
use pbdl_weather::baselines::{persistence, LinearRegression};
use pbdl_weather::forecaster::{
    predict, train, Dataset, Lead, Normalizer, ResNetConfig, SampleSpec, TrainConfig, WeatherResNet,
};
use pbdl_weather::lorenz96::Lorenz96;
use pbdl_weather::score::{score_by_lead, Metric};

fn dataset(seed: u64, n: usize) -> Dataset {
    let f = Lorenz96::default().trajectory(seed, 1000, n).unwrap();
    Dataset::from_fields(&[f], vec![]).unwrap()
}

fn small_net(spec: &SampleSpec, width: usize, blocks: usize, seed: u64) -> (VarMap, WeatherResNet) {
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let cfg = ResNetConfig {
        width,
        blocks,
        first_kernel: 5,
        dropout: 0.0,
        ..ResNetConfig::cpu_size(spec.in_channels(1, 0), 1)
    };
    let net = WeatherResNet::new(cfg, vb).unwrap();
    pbdl_nets::seeded_init(&varmap, seed).unwrap();
    (varmap, net)
}

#[test]
fn resnet_beats_linear_regression_and_persistence_at_one_day() {
    let (tr, va, te) = (dataset(1, 4000), dataset(3, 400), dataset(2, 800));
    let norm = Normalizer::fit(&tr);
    let spec = SampleSpec { history: vec![0, 1, 2], lead: Lead::Fixed(4), targets: vec![0] };
    let (varmap, net) = small_net(&spec, 32, 2, 7);
    let cfg = TrainConfig {
        lr: 1e-3,
        max_epochs: 12,
        steps_per_epoch: Some(60),
        seed: 5,
        progress: false,
        ..Default::default()
    };
    let state = train(&net, &varmap, &tr, &va, &norm, &spec, &cfg).unwrap();
    for r in &state.history {
        eprintln!("epoch {} train {:.4} valid {:.4} lr {:.1e}", r.epoch, r.train_loss, r.valid_loss, r.lr);
    }
    let inits = spec.init_indices(&te);
    let fc = predict(&net, &te, &norm, &spec, &inits, 4, 64).unwrap();
    let truth = te.field(0);
    let resnet = score_by_lead(Metric::Rmse, &fc[0], &truth).unwrap()[0];
    let lr = LinearRegression::fit(&tr.field(0), 24.0, 1, 1e-10).unwrap();
    let linear = score_by_lead(Metric::Rmse, &lr.forecast(&truth, 1).unwrap(), &truth).unwrap()[0];
    let pers = score_by_lead(Metric::Rmse, &persistence(&truth, &[24.0]).unwrap(), &truth).unwrap()[0];
    eprintln!("24 h RMSE: ResNet {resnet:.4}, linear regression {linear:.4}, persistence {pers:.4}");
    assert!(resnet < linear, "ResNet {resnet} vs LR {linear}");
    assert!(linear < pers);
}

#[test]
fn training_resumes_from_its_run_directory() {
    let dir = tempfile::tempdir().unwrap();
    let (tr, va) = (dataset(1, 300), dataset(3, 100));
    let norm = Normalizer::fit(&tr);
    let spec = SampleSpec { history: vec![0], lead: Lead::Continuous { min: 1, max: 2 }, targets: vec![0] };
    let cfg = TrainConfig {
        lr: 1e-3,
        max_epochs: 2,
        steps_per_epoch: Some(3),
        batch: 8,
        seed: 1,
        dir: Some(dir.path().into()),
        progress: false,
        ..Default::default()
    };
    let (varmap, net) = small_net(&spec, 8, 1, 2);
    let first = train(&net, &varmap, &tr, &va, &norm, &spec, &cfg).unwrap();
    assert_eq!(first.history.len(), 2);
    assert!(dir.path().join("last.json").is_file() && dir.path().join("best.safetensors").is_file());
    // A fresh network over the same directory continues at epoch 2 with the stored state.
    let (varmap2, net2) = small_net(&spec, 8, 1, 99);
    let more = TrainConfig { max_epochs: 3, ..cfg };
    let second = train(&net2, &varmap2, &tr, &va, &norm, &spec, &more).unwrap();
    assert_eq!(second.history.len(), 3);
    // The stored records come back (JSON keeps f64 to the last ulp or two).
    for (a, b) in second.history.iter().zip(&first.history) {
        assert_eq!((a.epoch, a.lr), (b.epoch, b.lr));
        assert!((a.train_loss - b.train_loss).abs() < 1e-12 && (a.valid_loss - b.valid_loss).abs() < 1e-12);
    }
    assert_eq!(second.epochs_done, 3);
}
