//! Short seeded training runs of the reusable networks: each learns a small task with Adam and
//! its loss falls by a clear factor. They show that every parameter path trains (gradients
//! flow through the convs, norms, padding, up- and downsampling and heads), not accuracy.

use candle_core::{DType, Tensor};
use pbdl_core::nn::Activation;
use pbdl_nets::discriminator::{bce_with_logits, Discriminator, DiscriminatorConfig};
use pbdl_nets::encoder_decoder::{Autoencoder, EncoderDecoderConfig, Upsampling};
use pbdl_nets::mlp::{Mlp, MlpConfig};
use pbdl_nets::resnet::{BlockOrder, ResNet, ResNetConfig};
use pbdl_nets::Padding;

mod common;
use common::{build_seeded, first_last_mean, randn, train, CPU};

/// `[n, 1, h, w]` fields `sin(2 pi (k_y y / h + k_x x / w) + phase)` with per-sample wave
/// numbers (1 or 2) and phases from `seed`.
fn smooth_fields(n: usize, h: usize, w: usize, seed: u64) -> Tensor {
    let r: Vec<f32> = pbdl_core::seed::rand_uniform(&[n, 3], 0.0, 1.0, DType::F32, &CPU, seed)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    let mut v = Vec::with_capacity(n * h * w);
    for s in 0..n {
        let (ky, kx, phase) =
            (1.0 + (r[3 * s] * 2.0).floor(), 1.0 + (r[3 * s + 1] * 2.0).floor(), r[3 * s + 2] * std::f32::consts::TAU);
        for y in 0..h {
            for x in 0..w {
                let arg = std::f32::consts::TAU * (ky * y as f32 / h as f32 + kx * x as f32 / w as f32) + phase;
                v.push(arg.sin());
            }
        }
    }
    Tensor::from_vec(v, (n, 1, h, w), &CPU).unwrap()
}

fn mse(a: &Tensor, b: &Tensor) -> pbdl_nets::Result<Tensor> {
    Ok((a - b)?.sqr()?.mean_all()?)
}

fn report(name: &str, losses: &[f64], factor: f64) {
    let (first, last) = first_last_mean(losses, 5);
    println!("{name}: loss {first:.4e} -> {last:.4e} ({:.1}x) in {} steps", first / last, losses.len());
    assert!(losses.iter().all(|l| l.is_finite()), "{name}: non-finite loss");
    assert!(last * factor < first, "{name}: loss fell only {first:.3e} -> {last:.3e}, wanted {factor}x");
}

#[test]
fn mlp_fits_a_smooth_function() {
    let (varmap, mlp) =
        build_seeded(DType::F32, 1, |vb| Mlp::new(MlpConfig::uniform(2, 32, 2, 1, Activation::Tanh), vb));
    let x = pbdl_core::seed::rand_uniform(&[64, 2], -1.0, 1.0, DType::F32, &CPU, 2).unwrap();
    let target = ((x.narrow(1, 0, 1).unwrap() * 2.0).unwrap().sin().unwrap() * x.narrow(1, 1, 1).unwrap()).unwrap();
    let losses = train(&varmap, 1e-2, 200, |_| mse(&mlp.forward(&x)?, &target));
    report("MLP", &losses, 10.0);
}

/// The map to learn: the mean of each cell's two x neighbours, periodic in x and zero beyond
/// the y border (which it does not reach), so a periodic-x ResNet can represent it.
#[test]
fn resnet_learns_a_periodic_stencil() {
    for order in [BlockOrder::PostActivation, BlockOrder::PreActivation] {
        let cfg = ResNetConfig {
            order,
            norm_groups: Some(1),
            padding: Padding::PeriodicX,
            activation: Activation::Gelu,
            ..ResNetConfig::new(1, 1, 8, 2)
        };
        let (varmap, net) = build_seeded(DType::F32, 3, |vb| ResNet::new(cfg, vb));
        let x = randn(&[8, 1, 8, 16], DType::F32, 4);
        let left = Tensor::cat(&[&x.narrow(3, 15, 1).unwrap(), &x.narrow(3, 0, 15).unwrap()], 3).unwrap();
        let right = Tensor::cat(&[&x.narrow(3, 1, 15).unwrap(), &x.narrow(3, 0, 1).unwrap()], 3).unwrap();
        let target = ((left + right).unwrap() * 0.5).unwrap();
        let losses = train(&varmap, 3e-3, 150, |_| mse(&net.forward(&x)?, &target));
        report(&format!("ResNet {order:?}"), &losses, 5.0);
    }
}

#[test]
fn autoencoder_reconstructs_smooth_fields() {
    for upsampling in [Upsampling::Transposed, Upsampling::Nearest] {
        let cfg =
            EncoderDecoderConfig { upsampling, norm_groups: Some(2), ..EncoderDecoderConfig::new(1, vec![8, 16], 4) };
        let (varmap, ae) = build_seeded(DType::F32, 5, |vb| Autoencoder::new(cfg, vb));
        let x = smooth_fields(8, 16, 16, 6);
        let losses = train(&varmap, 3e-3, 150, |_| mse(&ae.forward(&x)?, &x));
        report(&format!("autoencoder {upsampling:?}"), &losses, 4.0);
    }
}

/// Real samples are smooth waves, fakes are white noise: the discriminator's BCE falls from
/// about ln 2.
#[test]
fn discriminator_separates_smooth_fields_from_noise() {
    let cfg = DiscriminatorConfig { norm_groups: Some(2), ..DiscriminatorConfig::new(1, vec![4, 8, 8]) };
    let (varmap, d) = build_seeded(DType::F32, 7, |vb| Discriminator::new(cfg, vb));
    let real = smooth_fields(8, 16, 16, 8);
    let losses = train(&varmap, 3e-3, 100, |step| {
        let fake = randn(&[8, 1, 16, 16], DType::F32, 100 + step as u64);
        let l_real = bce_with_logits(&d.forward(&real)?.logits, 1.0)?;
        let l_fake = bce_with_logits(&d.forward(&fake)?.logits, 0.0)?;
        Ok((l_real + l_fake)?)
    });
    report("discriminator", &losses, 4.0);
}
