//! Tests of the airfoil-paper U-Net (AifNet): output shapes of the three published
//! configurations, the PyTorch variable layout, finite-difference gradients through a tiny
//! network in f64, and typed errors. The official repository prints no parameter count, so
//! the counts are reported, not asserted.

use candle_core::{DType, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_nets::unet::{AifNet, AifNetConfig};
use pbdl_nets::{count_parameters, Error};
use std::time::Instant;

mod common;
use common::{randn, CPU};

fn build(config: AifNetConfig, dtype: DType, s: u64) -> (VarMap, AifNet) {
    common::build_seeded(dtype, s, |vb| AifNet::new(config, vb))
}

fn check_shape(name: &str, config: AifNetConfig, n: usize) {
    let (varmap, net) = build(config, DType::F32, 1);
    let x = randn(&[1, 6, n, n], DType::F32, 2);
    let t = Tensor::new(&[200f32], &CPU).unwrap();
    let start = Instant::now();
    let y = net.forward(&x, &t).unwrap();
    println!("AifNet {name}: {} parameters, forward {:.3} s", count_parameters(&varmap), start.elapsed().as_secs_f64());
    assert_eq!(y.dims(), &[1, 3, n, n]);
    let v: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
    assert!(v.iter().all(|x| x.is_finite()));
    // (That `NoisePredictor::predict` is this forward pass is tested in pbdl-diffusion.)
}

#[test]
fn published_configurations_give_the_output_shape() {
    check_shape("32x32 16*[1,2,4,4]", AifNetConfig::airfoil_32(), 32);
    check_shape("64x64 16*[1,2,4,4,8]", AifNetConfig::airfoil_64(), 64);
}

#[test]
#[ignore = "the 128x128 network (19.8M parameters): ~1-5 s of forward pass"]
fn published_128_configuration_gives_the_output_shape() {
    check_shape("128x128 32*[1,2,4,4,8,8]", AifNetConfig::airfoil_128(), 128);
}

/// The module tree of the official network (names and shapes of `state_dict` entries), so
/// its checkpoints map one to one.
#[test]
fn variables_follow_the_official_module_tree() {
    let (varmap, _) = build(AifNetConfig::airfoil_32(), DType::F32, 3);
    let data = varmap.data().lock().unwrap();
    let expect: [(&str, &[usize]); 10] = [
        ("initial_layer.weight", &[16, 6, 1, 1]),
        ("down_nets.0.0.net.0.timeEmb.linear1.weight", &[16, 8]),
        ("down_nets.0.0.net.0.mainblock.0.weight", &[16, 1, 7, 7]),
        ("down_nets.0.0.net.0.residual_conv.weight", &[32, 16, 1, 1]),
        ("down_nets.0.1.net.1.1.weight", &[32, 128, 1, 1]), // space-to-depth conv, level 1 (no attention)
        ("down_nets.1.1.net.1.att.w_q.weight", &[64, 64, 1, 1]), // attention at level 2
        ("down_nets.1.1.net.1.normal.norm.weight", &[64]),
        ("bottle_neck.0.net.1.att.w_o.weight", &[64, 64, 1, 1]),
        ("up_nets.0.0.net.0.1.weight", &[128, 128, 3, 3]), // upsampling conv
        ("up_nets.0.0.net.1.att.w_q.weight", &[64, 128, 1, 1]), // heads of width 64 / 4
    ];
    for (name, shape) in expect {
        let v = data.get(name).unwrap_or_else(|| panic!("missing {name}"));
        assert_eq!(v.dims(), shape, "{name}");
    }
    assert_eq!(data["up_nets.2.1.net.0.mainblock.3.weight"].dims(), &[16, 64, 3, 3]);
    assert_eq!(data["final_layer.1.weight"].dims(), &[3, 3, 1, 1]);
    assert!(!data.contains_key("down_nets.0.1.net.1.att.w_q.weight"), "no attention at level 1");
}

/// Central finite differences through a tiny AifNet (4 * [1, 2, 2], attention at level 2,
/// 8x8, f64) with respect to the input and parameters of each layer type.
#[test]
fn gradients_match_finite_differences_through_a_tiny_network() {
    let config = AifNetConfig {
        dim_basic: 4,
        dim_multipliers: vec![1, 2, 2],
        attention_layers: vec![2],
        ..AifNetConfig::airfoil_32()
    };
    let (varmap, _) = build(config.clone(), DType::F64, 4);
    let probed = [
        "initial_layer.weight",
        "down_nets.0.0.net.0.timeEmb.linear1.weight",
        "down_nets.0.1.net.0.mainblock.0.weight",
        "down_nets.0.1.net.1.1.weight",
        "down_nets.1.1.net.1.att.w_k.weight",
        "down_nets.1.1.net.1.normal.norm.weight",
        "up_nets.0.0.net.0.1.weight",
        "up_nets.1.1.net.0.mainblock.3.weight",
        "final_layer.1.bias",
    ];
    let x = randn(&[2, 6, 8, 8], DType::F64, 5);
    let t = Tensor::new(&[1f64, 150.0], &CPU).unwrap();
    let report = common::check_network_grad("AifNet", &varmap, &probed, x, |vb, x| {
        AifNet::new(config.clone(), vb)?.forward(x, &t)
    });
    assert!(report.max_rel_error < 1e-6, "{report:?}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let (_, net) = build(AifNetConfig::airfoil_32(), DType::F32, 6);
    let t = Tensor::new(&[1f32], &CPU).unwrap();
    let wrong_channels = randn(&[1, 3, 32, 32], DType::F32, 7);
    assert!(matches!(net.forward(&wrong_channels, &t), Err(Error::ShapeMismatch { .. })));
    let wrong_size = randn(&[1, 6, 36, 32], DType::F32, 7);
    assert!(matches!(net.forward(&wrong_size, &t), Err(Error::ShapeMismatch { .. })));
    let x = randn(&[2, 6, 32, 32], DType::F32, 7);
    assert!(matches!(net.forward(&x, &t), Err(Error::ShapeMismatch { .. })));
    let vb = VarBuilder::zeros(DType::F32, &CPU);
    let bad = AifNetConfig { heads: 3, ..AifNetConfig::airfoil_32() };
    assert!(matches!(AifNet::new(bad, vb.clone()), Err(Error::InvalidConfig { .. })));
    let bad = AifNetConfig { dim_multipliers: vec![1], ..AifNetConfig::airfoil_32() };
    assert!(matches!(AifNet::new(bad, vb), Err(Error::InvalidConfig { .. })));
}
