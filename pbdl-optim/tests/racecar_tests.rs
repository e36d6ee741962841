//! racecar: the reverse-pass loss against its closed form, and the SVD alignment analysis.

use candle_core::{Device, Tensor};
use pbdl_optim::racecar::{alignment_experiment, span_alignment, AlignmentConfig, RacecarMlp};

/// One linear layer: `d'_0 = (d_1 - b) W^T = x W W^T`, loss `1/2 ||x W W^T - x||^2 / batch`.
#[test]
fn single_layer_reconstruction_is_x_w_wt() {
    let net = RacecarMlp::new(&[5, 3], 1).unwrap();
    let x = Tensor::new(&[[0.1f64, -0.4, 0.3, 0.9, -1.0], [0.5, 0.2, -0.7, 0.0, 0.3]], &Device::Cpu).unwrap();
    let acts = net.forward(&x).unwrap();
    let ours = net.reconstruction_loss(&acts).unwrap().to_scalar::<f64>().unwrap();
    let w = net.weight(0).to_vec2::<f64>().unwrap();
    let xv = x.to_vec2::<f64>().unwrap();
    let mut expect = 0.0;
    for row in &xv {
        let h: Vec<f64> = (0..3).map(|o| (0..5).map(|i| row[i] * w[i][o]).sum()).collect();
        for i in 0..5 {
            let r: f64 = (0..3).map(|o| h[o] * w[i][o]).sum::<f64>() - row[i];
            expect += 0.5 * r * r / 2.0;
        }
    }
    assert!((ours - expect).abs() < 1e-12 * expect.max(1.0), "{ours} vs {expect}");
}

/// A vector inside the data span has `|cos| = 1`, one orthogonal to it `0`.
#[test]
fn span_alignment_of_known_vectors() {
    let data = Tensor::new(&[[1.0f64, 0.0, 0.0], [1.0, 1.0, 0.0]], &Device::Cpu).unwrap();
    // W = [in 3, out 2]: left singular vectors e_2 (sigma 2) and e_0 (sigma 1).
    let w = Tensor::new(&[[1.0f64, 0.0], [0.0, 0.0], [0.0, 2.0]], &Device::Cpu).unwrap();
    let a = span_alignment(&w, &data, 2).unwrap();
    assert!(a[0].abs() < 1e-12 && (a[1] - 1.0).abs() < 1e-12, "{a:?}");
}

/// The racecar-trained first layer's four leading singular vectors lie in the span of the
/// training inputs (|cos| > 0.9); the plain network's do not. (Inputs span 6 dimensions; the
/// 5th and 6th vectors are not always aligned after 4000 steps, see the README.)
#[test]
fn racecar_aligns_leading_singular_vectors_with_the_data() {
    let r = alignment_experiment(&AlignmentConfig::default()).unwrap();
    assert!(r.racecar[..4].iter().all(|c| *c > 0.9), "racecar {:?}", r.racecar);
    assert!(r.plain[..4].iter().all(|c| *c < 0.9), "plain {:?}", r.plain);
}
