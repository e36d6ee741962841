//! The LSiM base network, its feature normalisation and the weighted feature distance.

use crate::learned::{layer_distance, stats};
use crate::pool::max_pool2d;
use crate::weights::WeightFile;
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_core::conv::{conv2d, Conv2dParams};

/// One feature layer of the base network: optional max-pool (kernel 4, stride 2), a convolution
/// and a ReLU, whose output is a feature map.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LayerSpec {
    /// State-dict prefix of the convolution, e.g. `model.basenet.slice2.1`.
    pub name: &'static str,
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
    pub stride: usize,
    pub padding: usize,
    pub pool_before: bool,
    /// Feature map side at 224x224 input, the size of the stored normalisation maps.
    pub size_224: usize,
}

/// The five feature layers of `LSiM_Base` (626,304 parameters).
pub(crate) const LAYERS: [LayerSpec; 5] = [
    LayerSpec {
        name: "model.basenet.slice1.0",
        c_in: 3,
        c_out: 32,
        kernel: 12,
        stride: 4,
        padding: 2,
        pool_before: false,
        size_224: 55,
    },
    LayerSpec {
        name: "model.basenet.slice2.1",
        c_in: 32,
        c_out: 96,
        kernel: 5,
        stride: 1,
        padding: 2,
        pool_before: true,
        size_224: 26,
    },
    LayerSpec {
        name: "model.basenet.slice3.1",
        c_in: 96,
        c_out: 192,
        kernel: 3,
        stride: 1,
        padding: 1,
        pool_before: true,
        size_224: 12,
    },
    LayerSpec {
        name: "model.basenet.slice4.0",
        c_in: 192,
        c_out: 128,
        kernel: 3,
        stride: 1,
        padding: 1,
        pool_before: false,
        size_224: 12,
    },
    LayerSpec {
        name: "model.basenet.slice5.0",
        c_in: 128,
        c_out: 128,
        kernel: 3,
        stride: 1,
        padding: 1,
        pool_before: false,
        size_224: 12,
    },
];

/// Pooling of the layers with `pool_before`.
pub(crate) const POOL: (usize, usize) = (4, 2);

/// Side length of a feature map of layer `l` for an input side `n` (`None` if it vanishes).
pub(crate) fn feature_side(n: usize, upto: usize) -> Option<usize> {
    let mut s = n;
    for spec in &LAYERS[..=upto] {
        if spec.pool_before {
            s = s.checked_sub(POOL.0)? / POOL.1 + 1;
        }
        s = (s + 2 * spec.padding).checked_sub(spec.kernel)? / spec.stride + 1;
    }
    Some(s)
}

/// Weights and normalisation statistics, in one dtype.
#[derive(Clone)]
pub(crate) struct Network {
    /// `(weight, bias)` per layer.
    pub convs: Vec<(Tensor, Tensor)>,
    /// Learned feature weights per layer, `[1, C, 1, 1]`, clamped to `>= 0`.
    pub lin: Vec<Tensor>,
    /// Stored per-pixel feature mean per layer, `[1, 1, h, w]` at 224 input.
    pub mean: Vec<Tensor>,
    /// Stored Welford M2 map per layer, `[1, 1, h, w]`.
    pub m2: Vec<Tensor>,
    /// Sample count of the statistics per layer.
    pub count: Vec<f64>,
}

impl Network {
    pub fn from_file(w: &WeightFile) -> Result<Self> {
        let mut convs = Vec::new();
        let mut lin = Vec::new();
        let mut mean = Vec::new();
        let mut m2 = Vec::new();
        for (i, s) in LAYERS.iter().enumerate() {
            let weight = w.get(&format!("{}.weight", s.name), &[s.c_out, s.c_in, s.kernel, s.kernel])?;
            let bias = w.get(&format!("{}.bias", s.name), &[s.c_out])?;
            convs.push((weight, bias));
            // The official model clamps the weights to >= 0 before every forward pass.
            lin.push(w.get(&format!("model.lin{i}.1.weight"), &[1, s.c_out, 1, 1])?.clamp(0f32, f32::INFINITY)?);
            let n = s.size_224;
            mean.push(w.get(&format!("norm.mean.{i}"), &[n, n])?.reshape((1, 1, n, n))?);
            m2.push(w.get(&format!("norm.m2.{i}"), &[n, n])?.reshape((1, 1, n, n))?);
        }
        let count = w.norm_counts(LAYERS.len())?;
        if let Some(i) =
            m2.iter().position(|t| t.min_all().and_then(|m| m.to_scalar::<f32>()).map(|m| m < 0.0).unwrap_or(true))
        {
            return Err(Error::Weights {
                path: w.path().to_path_buf(),
                reason: format!("`norm.m2.{i}` has negative entries; an M2 (sum of squared deviations) map is >= 0"),
            });
        }
        Ok(Self { convs, lin, mean, m2, count })
    }

    pub fn to_dtype(&self, dtype: DType) -> Result<Self> {
        let conv = |v: &[Tensor]| -> Result<Vec<Tensor>> {
            Ok(v.iter().map(|t| t.to_dtype(dtype)).collect::<candle_core::Result<_>>()?)
        };
        Ok(Self {
            convs: self
                .convs
                .iter()
                .map(|(w, b)| Ok((w.to_dtype(dtype)?, b.to_dtype(dtype)?)))
                .collect::<Result<_>>()?,
            lin: conv(&self.lin)?,
            mean: conv(&self.mean)?,
            m2: conv(&self.m2)?,
            count: self.count.clone(),
        })
    }

    pub fn dtype(&self) -> DType {
        self.convs[0].0.dtype()
    }

    /// The five ReLU feature maps of `x` `[n, 3, h, w]`.
    pub fn features(&self, x: &Tensor) -> Result<Vec<Tensor>> {
        let mut h = x.clone();
        let mut out = Vec::with_capacity(LAYERS.len());
        for (spec, (w, b)) in LAYERS.iter().zip(&self.convs) {
            if spec.pool_before {
                h = max_pool2d(&h, POOL.0, POOL.1)?;
            }
            let p = Conv2dParams::default().stride(spec.stride).padding(spec.padding);
            h = conv2d(&h, w, Some(b), &p)?.relu()?;
            out.push(h.clone());
        }
        Ok(out)
    }

    /// `sqrt( sum_l mean_(h,w) sum_c w_(l,c) (n_l(b) - n_l(a))^2 )` per batch entry; `[n]`.
    pub fn feature_distance(&self, fa: &[Tensor], fb: &[Tensor]) -> Result<Tensor> {
        let mut total: Option<Tensor> = None;
        for (l, (a, b)) in fa.iter().zip(fb).enumerate() {
            let (mean, std) = stats(&self.mean[l], &self.m2[l], self.count[l], &a.dims()[2..])?;
            let layer = layer_distance(a, b, &mean, &std, &self.lin[l])?;
            total = Some(match total {
                None => layer,
                Some(t) => (t + layer)?,
            });
        }
        Ok(total.expect("five layers").sqrt()?)
    }
}
