//! Tests of the ACDM U-Net: the official parameter counts at full size, output shapes,
//! finite-difference gradients through a tiny network in f64, attention, GroupNorm and the
//! step embedding against direct loops, checkpoint round trip, and typed errors.

use candle_core::{DType, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::io::{load_varmap, save_varmap, CheckpointMeta};
use pbdl_nets::attention::{Attention, AttentionKind, ResidualAttention};
use pbdl_nets::unet::{AcdmUnet, AcdmUnetConfig};
use pbdl_nets::{count_parameters, seeded_init, sinusoidal_embedding, Error};

mod common;
use common::{randn, CPU};

fn build(config: AcdmUnetConfig, dtype: DType, seed: u64) -> (VarMap, AcdmUnet) {
    common::build_seeded(dtype, seed, |vb| AcdmUnet::new(config, vb))
}

fn to_vec(t: &Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap()
}

fn max_rel_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f64, |m, v| m.max(v.abs())).max(1e-300);
    a.iter().zip(b).fold(0f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

fn var(varmap: &VarMap, name: &str) -> Tensor {
    varmap.data().lock().unwrap().get(name).unwrap_or_else(|| panic!("no variable {name}")).as_tensor().clone()
}

/// The counts printed by the official code (`acdm-demo.ipynb` for Tra) and reported for the
/// Inc model and the U-Net baseline; counted from the constructed network's variables.
#[test]
fn full_size_parameter_counts_match_the_official_networks() {
    let cases = [
        ("ACDM Tra (15 -> 15)", AcdmUnetConfig::transonic(), 6_994_035),
        ("ACDM Inc (12 -> 12)", AcdmUnetConfig::incompressible(), 6_981_300),
        ("U-Net baseline Inc (4 -> 4)", AcdmUnetConfig::unet_baseline(128, 4, 4), 5_721_912),
    ];
    for (name, config, expected) in cases {
        let varmap = VarMap::new();
        AcdmUnet::new(config, VarBuilder::from_varmap(&varmap, DType::F32, &CPU)).unwrap();
        let n = count_parameters(&varmap);
        println!("{name}: {n} parameters");
        assert_eq!(n, expected, "{name}");
    }
}

#[test]
fn output_shapes_at_128x64_and_64x32() {
    let (_, net) = build(AcdmUnetConfig::acdm(16, 12), DType::F32, 1);
    let (_, base) = build(AcdmUnetConfig::unet_baseline(16, 4, 4), DType::F32, 2);
    for (h, w) in [(128, 64), (64, 32)] {
        let x = randn(&[2, 12, h, w], DType::F32, 3);
        let t = Tensor::new(&[0f32, 19.0], &CPU).unwrap();
        let y = net.forward(&x, Some(&t)).unwrap();
        assert_eq!(y.dims(), &[2, 12, h, w]);
        assert!(to_vec(&y).iter().all(|v| v.is_finite()));
        // (That `NoisePredictor::predict` is this forward pass is tested in pbdl-diffusion.)
        let xb = randn(&[2, 4, h, w], DType::F32, 4);
        assert_eq!(base.forward(&xb, None).unwrap().dims(), &[2, 4, h, w]);
    }
}

/// The step embedding changes the output (it is wired in), the baseline ignores `t`.
#[test]
fn step_embedding_is_used_only_when_configured() {
    let (_, net) = build(AcdmUnetConfig::acdm(8, 3), DType::F64, 5);
    let x = randn(&[1, 3, 16, 8], DType::F64, 6);
    let t0 = Tensor::new(&[0f64], &CPU).unwrap();
    let t1 = Tensor::new(&[7f64], &CPU).unwrap();
    let a = to_vec(&net.forward(&x, Some(&t0)).unwrap());
    let b = to_vec(&net.forward(&x, Some(&t1)).unwrap());
    assert!(max_rel_diff(&a, &b) > 1e-3, "output does not depend on t");
    let (_, base) = build(AcdmUnetConfig::unet_baseline(8, 3, 3), DType::F64, 5);
    let a = to_vec(&base.forward(&x, Some(&t0)).unwrap());
    let b = to_vec(&base.forward(&x, Some(&t1)).unwrap());
    assert_eq!(a, b);
    assert_eq!(a, to_vec(&base.forward(&x, None).unwrap()));
}

/// Central finite differences through the whole tiny network (dim 8, 16x8, f64), with
/// respect to the input and to parameters in each kind of layer.
#[test]
fn gradients_match_finite_differences_through_a_tiny_network() {
    let config = AcdmUnetConfig::acdm(8, 3);
    let (varmap, _) = build(config.clone(), DType::F64, 7);
    let probed = [
        "init_conv.weight",              // 7x7 conv
        "downs.0.0.mlp.1.weight",        // step-embedding projection
        "downs.1.0.ds_conv.weight",      // depthwise 7x7
        "downs.1.2.fn.fn.to_qkv.weight", // linear attention
        "mid_attn.fn.fn.to_qkv.weight",  // full attention
        "ups.0.0.net.0.weight",          // GroupNorm scale
        "ups.1.3.weight",                // transposed conv
        "time_mlp.1.weight",             // time MLP
        "final_conv.1.bias",             // head
    ];
    let x = randn(&[2, 3, 16, 8], DType::F64, 8);
    let t = Tensor::new(&[3f64, 11.0], &CPU).unwrap();
    let report = common::check_network_grad("ACDM U-Net", &varmap, &probed, x, |vb, x| {
        AcdmUnet::new(config.clone(), vb)?.forward(x, Some(&t))
    });
    assert!(report.max_rel_error < 1e-6, "{report:?}");
}

/// Direct evaluation of one (linear or full) attention on `x` `[1, c, n]` with the layer's
/// weights, written from the formulas with plain loops.
fn reference_attention(
    kind: AttentionKind,
    x: &[f64],
    c: usize,
    n: usize,
    heads: usize,
    d: usize,
    wqkv: &[f64],
    wout: &[f64],
    bout: &[f64],
) -> Vec<f64> {
    let hid = heads * d;
    // qkv[o][p] = sum_c w[o][c] x[c][p]
    let mut qkv = vec![0.0; 3 * hid * n];
    for o in 0..3 * hid {
        for p in 0..n {
            qkv[o * n + p] = (0..c).map(|ci| wqkv[o * c + ci] * x[ci * n + p]).sum();
        }
    }
    let at = |part: usize, hh: usize, dd: usize, p: usize| qkv[((part * heads + hh) * d + dd) * n + p];
    let scale = 1.0 / (d as f64).sqrt();
    let mut out = vec![0.0; hid * n]; // channel hh*d + e, position p
    for hh in 0..heads {
        match kind {
            AttentionKind::Linear => {
                // q: softmax over features per position; k: softmax over positions per feature.
                let mut q = vec![0.0; d * n];
                for p in 0..n {
                    let z: f64 = (0..d).map(|dd| at(0, hh, dd, p).exp()).sum();
                    for dd in 0..d {
                        q[dd * n + p] = at(0, hh, dd, p).exp() / z * scale;
                    }
                }
                let mut k = vec![0.0; d * n];
                for dd in 0..d {
                    let z: f64 = (0..n).map(|p| at(1, hh, dd, p).exp()).sum();
                    for p in 0..n {
                        k[dd * n + p] = at(1, hh, dd, p).exp() / z;
                    }
                }
                for e in 0..d {
                    for p in 0..n {
                        let mut s = 0.0;
                        for dd in 0..d {
                            let ctx: f64 = (0..n).map(|m| k[dd * n + m] * at(2, hh, e, m)).sum();
                            s += ctx * q[dd * n + p];
                        }
                        out[(hh * d + e) * n + p] = s;
                    }
                }
            }
            AttentionKind::Full => {
                for i in 0..n {
                    let sim: Vec<f64> =
                        (0..n).map(|j| (0..d).map(|dd| at(0, hh, dd, i) * scale * at(1, hh, dd, j)).sum()).collect();
                    let z: f64 = sim.iter().map(|s| s.exp()).sum();
                    for e in 0..d {
                        out[(hh * d + e) * n + i] = (0..n).map(|j| sim[j].exp() / z * at(2, hh, e, j)).sum();
                    }
                }
            }
        }
    }
    let mut y = vec![0.0; c * n];
    for o in 0..c {
        for p in 0..n {
            y[o * n + p] = bout[o] + (0..hid).map(|h| wout[o * hid + h] * out[h * n + p]).sum::<f64>();
        }
    }
    y
}

/// One-group GroupNorm with scale and shift, from the definition (biased variance, eps 1e-5).
fn reference_group_norm_1(x: &[f64], c: usize, w: &[f64], b: &[f64]) -> Vec<f64> {
    let n = x.len() / c;
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / x.len() as f64;
    x.iter().enumerate().map(|(i, v)| (v - mean) / (var + 1e-5).sqrt() * w[i / n] + b[i / n]).collect()
}

#[test]
fn attention_and_group_norm_match_direct_loops() {
    // 6 channels, 2 heads x 5: linear attention composed from candle ops; 4 channels, 2 heads
    // x 8 (4 x 4 <= 16): the fused linear-attention layer.
    for ((c, heads, d), kind) in
        [(6, 2, 5), (4, 2, 8)].into_iter().flat_map(|s| [(s, AttentionKind::Linear), (s, AttentionKind::Full)])
    {
        let (h, w) = (4, 3);
        let n = h * w;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F64, &CPU);
        let attn = Attention::new(kind, c, heads, d, vb.clone()).unwrap();
        let res = ResidualAttention::new(kind, c, heads, d, vb.pp("res")).unwrap();
        seeded_init(&varmap, 11).unwrap();
        // Non-trivial norm parameters, so scale and shift are exercised.
        for name in ["to_out.1.weight", "to_out.1.bias", "res.fn.norm.weight", "res.fn.norm.bias"] {
            if let Some(v) = varmap.data().lock().unwrap().get(name) {
                v.set(&randn(&[c], DType::F64, 12).affine(0.5, 1.0).unwrap()).unwrap();
            }
        }
        let x = randn(&[1, c, h, w], DType::F64, 13);
        let xv = to_vec(&x);
        let wqkv = to_vec(&var(&varmap, "to_qkv.weight"));
        let out_name = if kind == AttentionKind::Linear { "to_out.0" } else { "to_out" };
        let wout = to_vec(&var(&varmap, &format!("{out_name}.weight")));
        let bout = to_vec(&var(&varmap, &format!("{out_name}.bias")));
        let mut expect = reference_attention(kind, &xv, c, n, heads, d, &wqkv, &wout, &bout);
        if kind == AttentionKind::Linear {
            let (gw, gb) = (to_vec(&var(&varmap, "to_out.1.weight")), to_vec(&var(&varmap, "to_out.1.bias")));
            expect = reference_group_norm_1(&expect, c, &gw, &gb);
        }
        let got = to_vec(&attn.forward(&x).unwrap());
        let err = max_rel_diff(&got, &expect);
        println!("{kind:?} attention ({c} channels, {heads} x {d}) vs direct loops: max rel diff {err:.2e}");
        assert!(err < 1e-12, "{kind:?}: {err:.2e}");

        // Residual pre-norm block: x + attn(GN(x)), with its own weights.
        let normed = reference_group_norm_1(
            &xv,
            c,
            &to_vec(&var(&varmap, "res.fn.norm.weight")),
            &to_vec(&var(&varmap, "res.fn.norm.bias")),
        );
        let wqkv = to_vec(&var(&varmap, "res.fn.fn.to_qkv.weight"));
        let wout = to_vec(&var(&varmap, &format!("res.fn.fn.{out_name}.weight")));
        let bout = to_vec(&var(&varmap, &format!("res.fn.fn.{out_name}.bias")));
        let mut inner = reference_attention(kind, &normed, c, n, heads, d, &wqkv, &wout, &bout);
        if kind == AttentionKind::Linear {
            let gw = to_vec(&var(&varmap, "res.fn.fn.to_out.1.weight"));
            let gb = to_vec(&var(&varmap, "res.fn.fn.to_out.1.bias"));
            inner = reference_group_norm_1(&inner, c, &gw, &gb);
        }
        let expect: Vec<f64> = inner.iter().zip(&xv).map(|(a, b)| a + b).collect();
        let err = max_rel_diff(&to_vec(&res.forward(&x).unwrap()), &expect);
        assert!(err < 1e-12, "residual {kind:?}: {err:.2e}");
    }
}

#[test]
fn sinusoidal_embedding_matches_its_formula() {
    let t = Tensor::new(&[0f64, 1.0, 19.0], &CPU).unwrap();
    let e = sinusoidal_embedding(&t, 8, DType::F64).unwrap();
    assert_eq!(e.dims(), &[3, 8]);
    let e = e.to_vec2::<f64>().unwrap();
    for (row, tv) in e.iter().zip([0.0, 1.0, 19.0f64]) {
        for i in 0..4 {
            // frequencies 1, 10^-4/3, 10^-8/3, 10^-4
            let f = 10f64.powf(-4.0 * i as f64 / 3.0);
            assert!((row[i] - (tv * f).sin()).abs() < 1e-12);
            assert!((row[i + 4] - (tv * f).cos()).abs() < 1e-12);
        }
    }
}

#[test]
fn checkpoint_round_trip_reproduces_the_output() {
    let config = AcdmUnetConfig::acdm(8, 3);
    let (varmap, net) = build(config.clone(), DType::F32, 21);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("unet");
    save_varmap(&path, &varmap, &CheckpointMeta::default()).unwrap();
    let (varmap2, net2) = build(config, DType::F32, 22);
    let x = randn(&[1, 3, 16, 8], DType::F32, 23);
    let t = Tensor::new(&[4f32], &CPU).unwrap();
    let before = to_vec(&net2.forward(&x, Some(&t)).unwrap());
    load_varmap(&path, &varmap2).unwrap();
    let after = to_vec(&net2.forward(&x, Some(&t)).unwrap());
    let reference = to_vec(&net.forward(&x, Some(&t)).unwrap());
    assert!(max_rel_diff(&before, &reference) > 1e-3, "different seeds gave the same network");
    assert_eq!(after, reference);
}

#[test]
fn seeded_init_is_reproducible_and_pytorch_scaled() {
    let (a, _) = build(AcdmUnetConfig::acdm(8, 3), DType::F32, 31);
    let (b, _) = build(AcdmUnetConfig::acdm(8, 3), DType::F32, 31);
    for name in ["init_conv.weight", "init_conv.bias", "downs.0.0.net.0.weight", "downs.0.0.net.0.bias"] {
        assert_eq!(to_vec(&var(&a, name)), to_vec(&var(&b, name)), "{name}");
    }
    // 7x7 conv from 3 channels: bound 1/sqrt(147).
    let w = to_vec(&var(&a, "init_conv.weight"));
    let bound = 1.0 / 147f64.sqrt();
    assert!(w.iter().all(|v| v.abs() <= bound) && w.iter().any(|v| v.abs() > 0.9 * bound));
    assert!(to_vec(&var(&a, "downs.0.0.net.0.weight")).iter().all(|&v| v == 1.0));
    assert!(to_vec(&var(&a, "downs.0.0.net.0.bias")).iter().all(|&v| v == 0.0));
}

#[test]
fn bad_input_is_a_typed_error() {
    let (_, net) = build(AcdmUnetConfig::acdm(8, 3), DType::F32, 41);
    let t = Tensor::new(&[1f32], &CPU).unwrap();
    let wrong_channels = randn(&[1, 4, 16, 8], DType::F32, 1);
    assert!(matches!(net.forward(&wrong_channels, Some(&t)), Err(Error::ShapeMismatch { .. })));
    let odd_size = randn(&[1, 3, 18, 8], DType::F32, 1);
    assert!(matches!(net.forward(&odd_size, Some(&t)), Err(Error::ShapeMismatch { .. })));
    let x = randn(&[1, 3, 16, 8], DType::F32, 1);
    assert!(matches!(net.forward(&x, None), Err(Error::ShapeMismatch { .. })));
    let t2 = Tensor::new(&[1f32, 2.0], &CPU).unwrap();
    assert!(matches!(net.forward(&x, Some(&t2)), Err(Error::ShapeMismatch { .. })));
    let vb = VarBuilder::zeros(DType::F32, &CPU);
    let bad = AcdmUnetConfig { dim_mults: vec![], ..AcdmUnetConfig::acdm(8, 3) };
    assert!(matches!(AcdmUnet::new(bad, vb.clone()), Err(Error::InvalidConfig { .. })));
    let bad = AcdmUnetConfig { dim_mults: vec![2, 2], ..AcdmUnetConfig::acdm(8, 3) };
    assert!(matches!(AcdmUnet::new(bad, vb), Err(Error::InvalidConfig { .. })));
}
