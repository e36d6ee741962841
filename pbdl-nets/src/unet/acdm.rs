//! The U-Net of ACDM (Kohl, Chen and Thuerey, "Benchmarking autoregressive conditional
//! diffusion models for turbulent flow simulation"): the annotated-diffusion U-Net with
//! ConvNeXt blocks, linear attention on every level, full attention in the middle and a
//! sinusoidal step embedding.
//!
//! Structure for `dim_mults = (1, 1, 1)` (ACDM's choice), widths `dims = [init, dim, dim, dim]`
//! with `init = dim / 3 * 2`:
//!
//! * `init_conv` 7x7 `in -> init`; `time_mlp`: sinusoid(dim) -> Linear(4 dim) -> GELU -> Linear(4 dim).
//! * Down level `i`: ConvNeXt(`dims[i] -> dims[i+1]`), ConvNeXt, residual linear attention, the
//!   output is kept as a skip, then a 4x4 stride-2 conv (all levels but the last).
//! * Middle: ConvNeXt, residual full attention, ConvNeXt.
//! * Up level `j` (one fewer than down levels): concatenate the skip of down level
//!   `L - 1 - j`, ConvNeXt(`2 dims -> dims`), ConvNeXt, residual linear attention, 4x4
//!   stride-2 transposed conv. The skip of the top level is computed but never used, a quirk
//!   of the official network that this one reproduces (so parameter counts and outputs match).
//! * Head: ConvNeXt(`dim -> dim`) without step input, then a 1x1 conv to `out_channels`.
//!
//! A ConvNeXt block is `h = dwconv7x7(x) [+ Linear(GELU(t_emb))] ; h = conv3x3(GELU(conv3x3(GN(h))))`
//! with one-group GroupNorms before each 3x3 conv, plus a residual (1x1 conv if the widths
//! differ). GELU is the exact (erf) one, GroupNorm eps 1e-5, as PyTorch's defaults.
//! Variable names follow the official PyTorch module tree (`downs.0.0.ds_conv.weight`, ...).

use crate::attention::{AttentionKind, ResidualAttention};
use crate::embedding::sinusoidal_embedding;
use crate::layers::{conv2d_layer, ConvTranspose2d, Linear};
use crate::{Error, Result};
use candle_core::{Module, Tensor};
use candle_nn::VarBuilder;
use pbdl_core::conv::{Conv2d, Conv2dParams};
use pbdl_core::nn::activation::gelu_erf;
use pbdl_core::nn::{GroupNorm, GroupNormConfig};
use serde::{Deserialize, Serialize};

/// Configuration of an [`AcdmUnet`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AcdmUnetConfig {
    /// Base width; ACDM uses the data width (128 for 128x64 fields). Also the width of the
    /// step embedding's sinusoid (the MLP maps it to `4 dim`).
    pub dim: usize,
    /// Width multiplier of each level (`dim * m`); the number of levels is its length.
    /// ACDM: `[1, 1, 1]`.
    pub dim_mults: Vec<usize>,
    /// Channels of the network input (ACDM: conditioning frames and target, e.g. 3 x 4 = 12).
    pub in_channels: usize,
    /// Channels of the output.
    pub out_channels: usize,
    /// Whether the blocks get the diffusion-step embedding (ACDM: yes; the U-Net baseline: no).
    pub with_time_embedding: bool,
    /// Width of the 7x7 input conv; `None` is `dim / 3 * 2` (84 at dim 128).
    pub init_dim: Option<usize>,
    /// Width multiplier inside a ConvNeXt block (ACDM: 1).
    pub convnext_mult: usize,
    /// Attention heads (4).
    pub attn_heads: usize,
    /// Width of one attention head (32).
    pub attn_dim_head: usize,
}

impl AcdmUnetConfig {
    /// ACDM's diffusion U-Net: `dim`, three levels of width `dim`, step embedding,
    /// `channels` in and out (noisy conditioning predicts the noise of every channel).
    pub fn acdm(dim: usize, channels: usize) -> Self {
        Self {
            dim,
            dim_mults: vec![1, 1, 1],
            in_channels: channels,
            out_channels: channels,
            with_time_embedding: true,
            init_dim: None,
            convnext_mult: 1,
            attn_heads: 4,
            attn_dim_head: 32,
        }
    }

    /// The deterministic U-Net baseline: the same network without step embedding.
    pub fn unet_baseline(dim: usize, in_channels: usize, out_channels: usize) -> Self {
        Self { in_channels, out_channels, with_time_embedding: false, ..Self::acdm(dim, in_channels) }
    }

    /// Full-size ACDM on the transonic cylinder flow (Tra): 128 wide, 3 frames x 5 fields.
    /// 6,994,035 parameters.
    pub fn transonic() -> Self {
        Self::acdm(128, 15)
    }

    /// Full-size ACDM on the incompressible cylinder flow (Inc): 128 wide, 3 frames x 4
    /// fields. 6,981,300 parameters.
    pub fn incompressible() -> Self {
        Self::acdm(128, 12)
    }

    /// Width of the input conv.
    pub fn init_width(&self) -> usize {
        self.init_dim.unwrap_or(self.dim / 3 * 2)
    }

    /// The factor by which height and width must be divisible (`2^(levels - 1)`).
    pub fn size_multiple(&self) -> usize {
        1 << self.dim_mults.len().saturating_sub(1)
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.dim < 4 || (self.with_time_embedding && self.dim % 2 != 0) {
            return bad("dim", self.dim.to_string(), "use an even width of at least 4 (ACDM: 128)");
        }
        if self.dim_mults.is_empty() || self.dim_mults.contains(&0) {
            return bad(
                "dim_mults",
                format!("{:?}", self.dim_mults),
                "use one positive multiplier per level, e.g. [1, 1, 1]",
            );
        }
        if self.in_channels == 0 || self.out_channels == 0 {
            return bad(
                "channels",
                format!("{} -> {}", self.in_channels, self.out_channels),
                "use at least one input and one output channel",
            );
        }
        if self.init_width() == 0 {
            return bad("init_dim", self.init_width().to_string(), "use a positive width (default dim / 3 * 2)");
        }
        if self.convnext_mult == 0 {
            return bad("convnext_mult", "0".into(), "use a positive multiplier (ACDM: 1)");
        }
        Ok(())
    }
}

/// A ConvNeXt block (see the module docs), optionally with a step-embedding input.
#[derive(Clone, Debug)]
pub struct ConvNextBlock {
    time: Option<Linear>,
    ds_conv: Conv2d,
    norm1: GroupNorm,
    conv1: Conv2d,
    norm2: GroupNorm,
    conv2: Conv2d,
    res_conv: Option<Conv2d>,
}

impl ConvNextBlock {
    /// A block `dim_in -> dim_out` with inner width `dim_out * mult`; `time_dim` is the width
    /// of the step embedding it receives, if any.
    pub fn new(dim_in: usize, dim_out: usize, time_dim: Option<usize>, mult: usize, vb: VarBuilder) -> Result<Self> {
        let gn = GroupNormConfig::default();
        let p = Conv2dParams::default();
        let inner = dim_out * mult;
        let time = time_dim.map(|td| Linear::new(td, dim_in, vb.pp("mlp.1"))).transpose()?;
        Ok(Self {
            time,
            ds_conv: conv2d_layer(vb.pp("ds_conv"), dim_in, dim_in, 7, p.padding(3).groups(dim_in), true)?,
            norm1: GroupNorm::new(1, dim_in, gn, vb.pp("net.0"))?,
            conv1: conv2d_layer(vb.pp("net.1"), dim_in, inner, 3, p.padding(1), true)?,
            norm2: GroupNorm::new(1, inner, gn, vb.pp("net.3"))?,
            conv2: conv2d_layer(vb.pp("net.4"), inner, dim_out, 3, p.padding(1), true)?,
            res_conv: (dim_in != dim_out)
                .then(|| conv2d_layer(vb.pp("res_conv"), dim_in, dim_out, 1, p, true))
                .transpose()?,
        })
    }

    /// The block applied to `x` `[batch, dim_in, y, x]` with the step embedding `t_emb`
    /// `[batch, time_dim]` (ignored by a block built without `time_dim`).
    pub fn forward(&self, x: &Tensor, t_emb: Option<&Tensor>) -> Result<Tensor> {
        let mut h = self.ds_conv.forward(x)?;
        if let (Some(mlp), Some(t)) = (&self.time, t_emb) {
            let bias = mlp.forward(&gelu_erf(t)?)?;
            h = h.broadcast_add(&bias.unsqueeze(2)?.unsqueeze(3)?)?;
        }
        let h = self.conv1.forward(&self.norm1.apply(&h)?)?;
        let h = self.conv2.forward(&self.norm2.apply(&gelu_erf(&h)?)?)?;
        let res = match &self.res_conv {
            Some(c) => c.forward(x)?,
            None => x.clone(),
        };
        Ok((h + res)?)
    }
}

/// The sinusoid -> Linear -> GELU -> Linear step embedding.
#[derive(Clone, Debug)]
struct TimeMlp {
    dim: usize,
    lin1: Linear,
    lin2: Linear,
}

impl TimeMlp {
    fn forward(&self, t: &Tensor, x: &Tensor) -> Result<Tensor> {
        let e = sinusoidal_embedding(t, self.dim, x.dtype())?;
        self.lin2.forward(&gelu_erf(&self.lin1.forward(&e)?)?)
    }
}

/// One down level: two blocks, residual linear attention, optional stride-2 conv.
#[derive(Clone, Debug)]
struct Down {
    block1: ConvNextBlock,
    block2: ConvNextBlock,
    attn: ResidualAttention,
    down: Option<Conv2d>,
}

/// One up level: two blocks on the concatenated skip, residual linear attention, transposed conv.
#[derive(Clone, Debug)]
struct Up {
    block1: ConvNextBlock,
    block2: ConvNextBlock,
    attn: ResidualAttention,
    up: ConvTranspose2d,
}

/// The ACDM U-Net (see the module docs). Build it with [`AcdmUnet::new`] from a
/// `VarBuilder` over a `VarMap` to train it and save it with `pbdl_core::io::save_varmap`.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::unet::{AcdmUnet, AcdmUnetConfig};
/// use pbdl_nets::count_parameters;
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let net = AcdmUnet::new(AcdmUnetConfig::acdm(8, 3), vb)?;
/// let x = Tensor::zeros((2, 3, 16, 8), DType::F32, &Device::Cpu)?;
/// let t = Tensor::new(&[0f32, 19.0], &Device::Cpu)?;
/// assert_eq!(net.forward(&x, Some(&t))?.dims(), &[2, 3, 16, 8]);
/// assert!(count_parameters(&varmap) > 0);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct AcdmUnet {
    config: AcdmUnetConfig,
    init_conv: Conv2d,
    time_mlp: Option<TimeMlp>,
    downs: Vec<Down>,
    mid_block1: ConvNextBlock,
    mid_attn: ResidualAttention,
    mid_block2: ConvNextBlock,
    ups: Vec<Up>,
    final_block: ConvNextBlock,
    final_conv: Conv2d,
}

impl AcdmUnet {
    /// Builds the network, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a config outside its valid range.
    pub fn new(config: AcdmUnetConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let p = Conv2dParams::default();
        let (dim, mult, heads, dh) = (config.dim, config.convnext_mult, config.attn_heads, config.attn_dim_head);
        let init = config.init_width();
        let init_conv = conv2d_layer(vb.pp("init_conv"), config.in_channels, init, 7, p.padding(3), true)?;
        let time_dim = config.with_time_embedding.then_some(4 * dim);
        let time_mlp = match time_dim {
            Some(td) => Some(TimeMlp {
                dim,
                lin1: Linear::new(dim, td, vb.pp("time_mlp.1"))?,
                lin2: Linear::new(td, td, vb.pp("time_mlp.3"))?,
            }),
            None => None,
        };
        let mut dims = vec![init];
        dims.extend(config.dim_mults.iter().map(|m| dim * m));
        let levels = config.dim_mults.len();
        let mut downs = Vec::with_capacity(levels);
        for i in 0..levels {
            let (a, b) = (dims[i], dims[i + 1]);
            let vb = vb.pp(format!("downs.{i}"));
            downs.push(Down {
                block1: ConvNextBlock::new(a, b, time_dim, mult, vb.pp("0"))?,
                block2: ConvNextBlock::new(b, b, time_dim, mult, vb.pp("1"))?,
                attn: ResidualAttention::new(AttentionKind::Linear, b, heads, dh, vb.pp("2"))?,
                down: (i + 1 < levels)
                    .then(|| conv2d_layer(vb.pp("3"), b, b, 4, p.stride(2).padding(1), true))
                    .transpose()?,
            });
        }
        let mid = dims[levels];
        let mid_block1 = ConvNextBlock::new(mid, mid, time_dim, mult, vb.pp("mid_block1"))?;
        let mid_attn = ResidualAttention::new(AttentionKind::Full, mid, heads, dh, vb.pp("mid_attn"))?;
        let mid_block2 = ConvNextBlock::new(mid, mid, time_dim, mult, vb.pp("mid_block2"))?;
        // Up levels pair with down levels L-1 .. 1; level 0's skip is never consumed.
        let mut ups = Vec::with_capacity(levels - 1);
        for (j, lvl) in (1..levels).rev().enumerate() {
            let (a, b) = (dims[lvl], dims[lvl + 1]);
            let vb = vb.pp(format!("ups.{j}"));
            ups.push(Up {
                block1: ConvNextBlock::new(2 * b, a, time_dim, mult, vb.pp("0"))?,
                block2: ConvNextBlock::new(a, a, time_dim, mult, vb.pp("1"))?,
                attn: ResidualAttention::new(AttentionKind::Linear, a, heads, dh, vb.pp("2"))?,
                up: ConvTranspose2d::new(vb.pp("3"), a, a, 4, 2, 1)?,
            });
        }
        // The head takes `dim` channels: the up path ends at width dims[1] = dim * dim_mults[0].
        let last = if levels > 1 { dims[1] } else { dims[levels] };
        if last != dim {
            return Err(Error::InvalidConfig {
                name: "dim_mults",
                value: format!("{:?}", config.dim_mults),
                hint: "the head expects width dim after the up path: make the first multiplier 1",
            });
        }
        let final_block = ConvNextBlock::new(dim, dim, None, mult, vb.pp("final_conv.0"))?;
        let final_conv = conv2d_layer(vb.pp("final_conv.1"), dim, config.out_channels, 1, p, true)?;
        Ok(Self { config, init_conv, time_mlp, downs, mid_block1, mid_attn, mid_block2, ups, final_block, final_conv })
    }

    /// The configuration.
    pub fn config(&self) -> &AcdmUnetConfig {
        &self.config
    }

    /// The network applied to `x` `[batch, in_channels, y, x]` (y and x multiples of
    /// [`AcdmUnetConfig::size_multiple`]) at diffusion steps `t` `[batch]`; returns
    /// `[batch, out_channels, y, x]`. A network without step embedding ignores `t` (pass `None`).
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong input shape or size, a `t` of the wrong length, or
    /// no `t` for a network with step embedding.
    pub fn forward(&self, x: &Tensor, t: Option<&Tensor>) -> Result<Tensor> {
        self.check_input(x, t)?;
        let t_emb = match (&self.time_mlp, t) {
            (Some(mlp), Some(t)) => Some(mlp.forward(t, x)?),
            _ => None,
        };
        let t_emb = t_emb.as_ref();
        let mut h = self.init_conv.forward(x)?;
        let mut skips = Vec::with_capacity(self.downs.len());
        for level in &self.downs {
            h = level.block1.forward(&h, t_emb)?;
            h = level.block2.forward(&h, t_emb)?;
            h = level.attn.forward(&h)?;
            skips.push(h.clone());
            if let Some(down) = &level.down {
                h = down.forward(&h)?;
            }
        }
        h = self.mid_block1.forward(&h, t_emb)?;
        h = self.mid_attn.forward(&h)?;
        h = self.mid_block2.forward(&h, t_emb)?;
        for level in &self.ups {
            // `skips` still holds level 0's output at the end: the unused top-level skip.
            let skip = skips.pop().expect("one skip per down level, more down than up levels");
            h = Tensor::cat(&[&h, &skip], 1)?;
            h = level.block1.forward(&h, t_emb)?;
            h = level.block2.forward(&h, t_emb)?;
            h = level.attn.forward(&h)?;
            h = level.up.forward(&h)?;
        }
        let h = self.final_block.forward(&h, None)?;
        Ok(self.final_conv.forward(&h)?)
    }

    fn check_input(&self, x: &Tensor, t: Option<&Tensor>) -> Result<()> {
        let c = &self.config;
        let m = c.size_multiple();
        let dims = x.dims();
        let ok = dims.len() == 4 && dims[1] == c.in_channels && dims[2] % m == 0 && dims[3] % m == 0 && dims[2] > 0;
        if !ok || dims[3] == 0 {
            return Err(Error::shape(
                format!("AcdmUnet input (height and width must be positive multiples of {m})"),
                format!("[batch, {}, y, x]", c.in_channels),
                dims,
            ));
        }
        match (&self.time_mlp, t) {
            (Some(_), None) => {
                Err(Error::shape("AcdmUnet diffusion step t (this network embeds the step)", [dims[0]], "none"))
            }
            (Some(_), Some(t)) if t.dims() != [dims[0]] => {
                Err(Error::shape("AcdmUnet diffusion step t", [dims[0]], t.dims()))
            }
            _ => Ok(()),
        }
    }
}
