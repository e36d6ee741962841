//! SFBC test case I, small: the symmetry claims and momentum conservation of the antisymmetric
//! last layer, on a few small periodic 1D SPH simulations (the full-size table is the
//! `case1d` example; numbers in the README).

use pbdl_pconv::periodic_case::{train_and_evaluate, CaseConfig, CaseKind, Dataset, Task, TrainConfig};
use pbdl_pconv::Basis;

fn data() -> Dataset {
    Dataset::generate(&CaseConfig::small(CaseKind::Compressible1d)).unwrap()
}

#[test]
fn even_basis_cannot_learn_the_odd_density_gradient() {
    let data = data();
    let train = TrainConfig { steps: 400, ..TrainConfig::for_task(Task::DensityGradient) };
    let even = train_and_evaluate(&data, Task::DensityGradient, Basis::FourierEven, &train, 0).unwrap();
    let odd = train_and_evaluate(&data, Task::DensityGradient, Basis::FourierOdd, &train, 0).unwrap();
    // An even filter summed against the constant feature gives an even response: no better
    // than predicting the mean of an odd target.
    assert!(even.test_rel_mse >= 0.9, "even basis on the odd target: {}", even.test_rel_mse);
    assert!(odd.test_rel_mse <= 0.3, "odd basis on the odd target: {}", odd.test_rel_mse);
}

#[test]
fn antisymmetric_last_layer_conserves_momentum_in_rollouts() {
    let data = data();
    let train = TrainConfig { steps: 150, ..TrainConfig::for_task(Task::Update) };
    let anti = train_and_evaluate(
        &data,
        Task::Update,
        Basis::Fourier,
        &TrainConfig { antisymmetric: true, ..train.clone() },
        0,
    )
    .unwrap();
    let plain = train_and_evaluate(&data, Task::Update, Basis::Fourier, &train, 0).unwrap();
    let (da, dp) = (anti.momentum_drift.unwrap(), plain.momentum_drift.unwrap());
    assert!(da <= 1e-5, "antisymmetric drift {da:e}");
    assert!(dp > 1e-3, "plain drift {dp:e} (the check must be able to fail)");
    assert!(anti.rollout_error.unwrap().is_finite() && plain.rollout_error.unwrap().is_finite());
}

#[test]
fn bad_configuration_is_a_typed_error() {
    let cfg = CaseConfig { frames: 1, ..CaseConfig::small(CaseKind::Compressible1d) };
    let e = Dataset::generate(&cfg).unwrap_err();
    assert!(e.to_string().contains("frames"), "{e}");
    let cfg = CaseConfig { test_seeds: vec![], ..CaseConfig::small(CaseKind::Compressible1d) };
    assert!(Dataset::generate(&cfg).is_err());
}

#[test]
fn test_case_2_antisymmetric_rollout_conserves_both_momentum_components() {
    let data = Dataset::generate(&CaseConfig::small(CaseKind::WeaklyCompressible2d)).unwrap();
    assert_eq!(data.dim(), 2);
    let train = TrainConfig { steps: 40, ..TrainConfig::for_task(Task::Update) };
    let anti = train_and_evaluate(
        &data,
        Task::Update,
        Basis::Fourier,
        &TrainConfig { antisymmetric: true, ..train.clone() },
        0,
    )
    .unwrap();
    let plain = train_and_evaluate(&data, Task::Update, Basis::Fourier, &train, 0).unwrap();
    let (da, dp) = (anti.momentum_drift.unwrap(), plain.momentum_drift.unwrap());
    assert!(da <= 1e-5, "antisymmetric drift {da:e}");
    assert!(dp > 1e-4, "plain drift {dp:e} (the check must be able to fail)");
}

#[test]
fn unrolled_training_runs_through_positions() {
    let data = data();
    let train = TrainConfig { steps: 30, rollout_steps: 3, ..TrainConfig::for_task(Task::Update) };
    let r = train_and_evaluate(&data, Task::Update, Basis::Linear, &train, 0).unwrap();
    assert!(r.train_loss.is_finite() && r.rollout_error.unwrap().is_finite());
    let too_long = TrainConfig { rollout_steps: 12, ..train };
    let e = train_and_evaluate(&data, Task::Update, Basis::Linear, &too_long, 0).unwrap_err();
    assert!(e.to_string().contains("rollout_steps"), "{e}");
}
