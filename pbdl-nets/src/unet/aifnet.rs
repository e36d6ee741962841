//! The U-Net of the airfoil uncertainty paper ("AifNet", Liu and Thuerey, "Uncertainty-aware
//! surrogate models for airfoil flow simulations with denoising diffusion probabilistic
//! models"), as configured by its published network configs.
//!
//! Widths `c_i = dim_basic * dim_multipliers[i]`; level `l = 1..L` maps `c_{l-1} -> c_l`.
//!
//! * `initial_layer`: 1x1 conv `in -> c_0` (the caller concatenates the condition channels).
//! * Down level `l` (depth 2): block `c_{l-1} -> c_l`, then block `c_l -> c_l` followed by
//!   self-attention (if `l` is an attention layer) and a space-to-depth downsampling
//!   (2x2 pixels to channels, 1x1 conv `4 c_l -> c_l`). Every block's output, times
//!   `skip_scale` (0.707), is kept as a skip.
//! * Bottleneck: block + self-attention, block.
//! * Up level `l = L..1`: each block first concatenates the latest skip. Block one upsamples
//!   (nearest 2x, 3x3 conv), applies self-attention (attention layers) and maps
//!   `2 c_l -> c_l`; block two maps `2 c_l -> c_{l-1}`.
//! * Head: block `c_0 -> out`, then a 1x1 conv.
//!
//! A block is the depthwise-separable residual block `h = x + MLP(t_enc)`,
//! `y = conv3x3(GN(GELU(dwconv7x7(h)))) + res(x)`, where the MLP is
//! Linear(time_dim -> c) -> GELU -> Linear(c -> c) of the block's own, `t_enc` the sinusoidal
//! encoding of the step (dimension 8), GN a GroupNorm with 16 channels per group (at least
//! one group), and `res` a 1x1 conv when the widths differ. Self-attention is full multi-head
//! attention with `heads` heads of width `block output / heads`, bias-free 1x1 projections,
//! a residual and a GroupNorm after it. GELU is the exact (erf) one.

use crate::attention::full_attention;
use crate::embedding::sinusoidal_embedding;
use crate::layers::{conv2d_layer, Linear};
use crate::resample::{space_to_depth, upsample_nearest2};
use crate::{Error, Result};
use candle_core::{Module, Tensor};
use candle_nn::VarBuilder;
use pbdl_core::conv::{conv2d, Conv2d, Conv2dParams};
use pbdl_core::nn::activation::gelu_erf;
use pbdl_core::nn::{GroupNorm, GroupNormConfig};
use serde::{Deserialize, Serialize};

/// Configuration of an [`AifNet`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AifNetConfig {
    /// Input channels: the noisy target followed by the condition (airfoil: 3 + 3).
    pub in_channels: usize,
    /// Output channels (the predicted noise of the target: 3).
    pub out_channels: usize,
    /// Base width.
    pub dim_basic: usize,
    /// Width multipliers `[m_0, .., m_L]`: `L` down/up levels.
    pub dim_multipliers: Vec<usize>,
    /// Levels (1-based) with self-attention.
    pub attention_layers: Vec<usize>,
    /// Attention heads.
    pub heads: usize,
    /// Blocks per level (the paper: 2).
    pub depth_each_layer: usize,
    /// Dimension of the sinusoidal step encoding (8).
    pub time_dim: usize,
    /// Factor on the skip connections (0.707).
    pub skip_scale: f64,
}

impl AifNetConfig {
    fn airfoil(dim_basic: usize, dim_multipliers: Vec<usize>, attention_layers: Vec<usize>) -> Self {
        Self {
            in_channels: 6,
            out_channels: 3,
            dim_basic,
            dim_multipliers,
            attention_layers,
            heads: 4,
            depth_each_layer: 2,
            time_dim: 8,
            skip_scale: 0.707,
        }
    }

    /// The 32x32 single-parameter network: `16 * [1, 2, 4, 4]`, attention at levels 2 and 3.
    pub fn airfoil_32() -> Self {
        Self::airfoil(16, vec![1, 2, 4, 4], vec![2, 3])
    }

    /// The 64x64 network: `16 * [1, 2, 4, 4, 8]`, attention at levels 3 and 4.
    pub fn airfoil_64() -> Self {
        Self::airfoil(16, vec![1, 2, 4, 4, 8], vec![3, 4])
    }

    /// The 128x128 network: `32 * [1, 2, 4, 4, 8, 8]`, attention at levels 3 and 4.
    pub fn airfoil_128() -> Self {
        Self::airfoil(32, vec![1, 2, 4, 4, 8, 8], vec![3, 4])
    }

    /// The factor by which height and width must be divisible (`2^L`).
    pub fn size_multiple(&self) -> usize {
        1 << self.dim_multipliers.len().saturating_sub(1)
    }

    fn widths(&self) -> Vec<usize> {
        self.dim_multipliers.iter().map(|m| self.dim_basic * m).collect()
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.dim_multipliers.len() < 2 || self.dim_multipliers.contains(&0) || self.dim_basic == 0 {
            return bad(
                "dim_multipliers",
                format!("{} * {:?}", self.dim_basic, self.dim_multipliers),
                "use a positive base width and at least two positive multipliers, e.g. 16 * [1, 2, 4, 4]",
            );
        }
        if self.in_channels == 0 || self.out_channels == 0 {
            return bad(
                "channels",
                format!("{} -> {}", self.in_channels, self.out_channels),
                "use at least one input and one output channel",
            );
        }
        if self.time_dim < 4 || self.time_dim % 2 != 0 {
            return bad("time_dim", self.time_dim.to_string(), "use an even dimension of at least 4 (paper: 8)");
        }
        if self.depth_each_layer == 0 {
            return bad("depth_each_layer", "0".into(), "use at least one block per level (paper: 2)");
        }
        for &c in &self.widths() {
            if c % self.heads.max(1) != 0 || self.heads == 0 {
                return bad(
                    "heads",
                    self.heads.to_string(),
                    "use a head count that divides every level width (paper: 4)",
                );
            }
            if c % group_count(c) != 0 || (2 * c) % group_count(2 * c) != 0 {
                return bad(
                    "dim_basic",
                    self.dim_basic.to_string(),
                    "widths need c / 16 groups dividing c (use multiples of 16, or widths below 32)",
                );
            }
        }
        Ok(())
    }
}

/// GroupNorm groups of the airfoil network: 16 channels each, at least one group.
fn group_count(channels: usize) -> usize {
    (channels / 16).max(1)
}

/// The depthwise-separable residual block with its own step MLP.
#[derive(Clone, Debug)]
struct DscBlock {
    time1: Linear,
    time2: Linear,
    dw: Conv2d,
    norm: GroupNorm,
    conv: Conv2d,
    res: Option<Conv2d>,
}

impl DscBlock {
    fn new(c_in: usize, c_out: usize, time_dim: usize, vb: VarBuilder) -> Result<Self> {
        let p = Conv2dParams::default();
        Ok(Self {
            time1: Linear::new(time_dim, c_in, vb.pp("timeEmb.linear1"))?,
            time2: Linear::new(c_in, c_in, vb.pp("timeEmb.linear2"))?,
            dw: conv2d_layer(vb.pp("mainblock.0"), c_in, c_in, 7, p.padding(3).groups(c_in), true)?,
            norm: GroupNorm::new(group_count(c_in), c_in, GroupNormConfig::default(), vb.pp("mainblock.2.norm"))?,
            conv: conv2d_layer(vb.pp("mainblock.3"), c_in, c_out, 3, p.padding(1), true)?,
            res: (c_in != c_out).then(|| conv2d_layer(vb.pp("residual_conv"), c_in, c_out, 1, p, true)).transpose()?,
        })
    }

    fn forward(&self, x: &Tensor, t_enc: &Tensor) -> Result<Tensor> {
        let bias = self.time2.forward(&gelu_erf(&self.time1.forward(t_enc)?)?)?;
        let h = x.broadcast_add(&bias.unsqueeze(2)?.unsqueeze(3)?)?;
        let h = self.conv.forward(&self.norm.apply(&gelu_erf(&self.dw.forward(&h)?)?)?)?;
        let res = match &self.res {
            Some(c) => c.forward(x)?,
            None => x.clone(),
        };
        Ok((h + res)?)
    }
}

/// `GN(x + W_o attention(W_q x, W_k x, W_v x))`: post-norm self-attention with a residual.
#[derive(Clone, Debug)]
struct SelfAttention {
    heads: usize,
    dim_head: usize,
    w_q: Tensor,
    w_k: Tensor,
    w_v: Tensor,
    w_o: Conv2d,
    norm: GroupNorm,
}

impl SelfAttention {
    fn new(c: usize, heads: usize, dim_head: usize, vb: VarBuilder) -> Result<Self> {
        let hidden = heads * dim_head;
        let p = Conv2dParams::default();
        let proj = |name: &str| -> Result<Tensor> {
            Ok(conv2d_layer(vb.pp("att").pp(name), c, hidden, 1, p, false)?.weight().clone())
        };
        Ok(Self {
            heads,
            dim_head,
            w_q: proj("w_q")?,
            w_k: proj("w_k")?,
            w_v: proj("w_v")?,
            w_o: conv2d_layer(vb.pp("att.w_o"), hidden, c, 1, p, false)?,
            norm: GroupNorm::new(group_count(c), c, GroupNormConfig::default(), vb.pp("normal.norm"))?,
        })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        // One projection for q, k and v: the three weights stacked.
        let w = Tensor::cat(&[&self.w_q, &self.w_k, &self.w_v], 0)?;
        let qkv = conv2d(x, &w, None, &Conv2dParams::default())?;
        let att = self.w_o.forward(&full_attention(&qkv, self.heads, self.dim_head)?)?;
        Ok(self.norm.apply(&(att + x)?)?)
    }
}

/// One element of a block sequence.
#[derive(Clone, Debug)]
enum Layer {
    Dsc(DscBlock),
    Attention(SelfAttention),
    /// Space-to-depth, then a 1x1 conv `4c -> c`.
    Down(Conv2d),
    /// Nearest 2x, then a 3x3 conv `c -> c`.
    Up(Conv2d),
}

/// A block: the layers of one `AifBlock`, whose output is (scaled) a skip on the way down.
#[derive(Clone, Debug)]
struct Block(Vec<Layer>);

impl Block {
    /// A down-path block: conv block, optional attention, optional downsampling.
    fn down(
        c_in: usize,
        c_out: usize,
        attn: bool,
        size_change: bool,
        cfg: &AifNetConfig,
        vb: VarBuilder,
    ) -> Result<Self> {
        let vb = vb.pp("net");
        let mut layers = vec![Layer::Dsc(DscBlock::new(c_in, c_out, cfg.time_dim, vb.pp("0"))?)];
        if attn {
            let vbi = vb.pp(layers.len().to_string());
            layers.push(Layer::Attention(SelfAttention::new(c_out, cfg.heads, c_out / cfg.heads, vbi)?));
        }
        if size_change {
            let vbi = vb.pp(layers.len().to_string()).pp("1");
            layers.push(Layer::Down(conv2d_layer(vbi, 4 * c_out, c_out, 1, Conv2dParams::default(), true)?));
        }
        Ok(Self(layers))
    }

    /// An up-path block: optional upsampling, optional attention (heads of width
    /// `c_out / heads`), conv block.
    fn up(
        c_in: usize,
        c_out: usize,
        attn: bool,
        size_change: bool,
        cfg: &AifNetConfig,
        vb: VarBuilder,
    ) -> Result<Self> {
        let vb = vb.pp("net");
        let mut layers = Vec::new();
        if size_change {
            let vbi = vb.pp("0").pp("1");
            layers.push(Layer::Up(conv2d_layer(vbi, c_in, c_in, 3, Conv2dParams::default().padding(1), true)?));
        }
        if attn {
            let vbi = vb.pp(layers.len().to_string());
            layers.push(Layer::Attention(SelfAttention::new(c_in, cfg.heads, c_out / cfg.heads, vbi)?));
        }
        let vbi = vb.pp(layers.len().to_string());
        layers.push(Layer::Dsc(DscBlock::new(c_in, c_out, cfg.time_dim, vbi)?));
        Ok(Self(layers))
    }

    fn forward(&self, x: &Tensor, t_enc: &Tensor) -> Result<Tensor> {
        let mut h = x.clone();
        for layer in &self.0 {
            h = match layer {
                Layer::Dsc(b) => b.forward(&h, t_enc)?,
                Layer::Attention(a) => a.forward(&h)?,
                Layer::Down(conv) => conv.forward(&space_to_depth(&h)?)?,
                Layer::Up(conv) => conv.forward(&upsample_nearest2(&h)?)?,
            };
        }
        Ok(h)
    }
}

/// The airfoil-paper U-Net (see the module docs). Variable names follow the official PyTorch
/// module tree (`down_nets.0.0.net.0.mainblock.0.weight`, ...).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::unet::{AifNet, AifNetConfig};
///
/// let varmap = VarMap::new();
/// let net = AifNet::new(AifNetConfig::airfoil_32(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
/// let x = Tensor::zeros((2, 6, 32, 32), DType::F32, &Device::Cpu)?; // x_t and the condition
/// let t = Tensor::new(&[1f32, 200.0], &Device::Cpu)?;
/// assert_eq!(net.forward(&x, &t)?.dims(), &[2, 3, 32, 32]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct AifNet {
    config: AifNetConfig,
    initial: Conv2d,
    downs: Vec<Block>,
    bottleneck: Vec<Block>,
    ups: Vec<Block>,
    final_block: Block,
    final_conv: Conv2d,
}

impl AifNet {
    /// Builds the network, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a config outside its valid range.
    pub fn new(config: AifNetConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let c = config.widths();
        let levels = c.len() - 1;
        let depth = config.depth_each_layer;
        let p = Conv2dParams::default();
        let initial = conv2d_layer(vb.pp("initial_layer"), config.in_channels, c[0], 1, p, true)?;
        let mut downs = Vec::new();
        for l in 1..=levels {
            let attn = config.attention_layers.contains(&l);
            let vb = vb.pp(format!("down_nets.{}", l - 1));
            let (a, b) = (c[l - 1], c[l]);
            if depth == 1 {
                downs.push(Block::down(a, b, attn, true, &config, vb.pp("0"))?);
                continue;
            }
            downs.push(Block::down(a, b, false, false, &config, vb.pp("0"))?);
            for j in 1..depth - 1 {
                downs.push(Block::down(b, b, false, false, &config, vb.pp(j.to_string()))?);
            }
            downs.push(Block::down(b, b, attn, true, &config, vb.pp((depth - 1).to_string()))?);
        }
        let mid = c[levels];
        let bottleneck = vec![
            Block::down(mid, mid, true, false, &config, vb.pp("bottle_neck.0"))?,
            Block::up(mid, mid, false, false, &config, vb.pp("bottle_neck.1"))?,
        ];
        let mut ups = Vec::new();
        for (i, l) in (1..=levels).rev().enumerate() {
            let attn = config.attention_layers.contains(&l);
            let vb = vb.pp(format!("up_nets.{i}"));
            let (a, b2) = (c[l - 1], 2 * c[l]);
            if depth == 1 {
                ups.push(Block::up(b2, a, attn, true, &config, vb.pp("0"))?);
                continue;
            }
            ups.push(Block::up(b2, b2 / 2, attn, true, &config, vb.pp("0"))?);
            for j in 1..depth - 1 {
                ups.push(Block::up(b2, b2 / 2, false, false, &config, vb.pp(j.to_string()))?);
            }
            ups.push(Block::up(b2, a, false, false, &config, vb.pp((depth - 1).to_string()))?);
        }
        let out = config.out_channels;
        let final_block = Block::up(c[0], out, false, false, &config, vb.pp("final_layer.0"))?;
        let final_conv = conv2d_layer(vb.pp("final_layer.1"), out, out, 1, p, true)?;
        Ok(Self { config, initial, downs, bottleneck, ups, final_block, final_conv })
    }

    /// The configuration.
    pub fn config(&self) -> &AifNetConfig {
        &self.config
    }

    /// The network on `x` `[batch, in_channels, y, x]` (the noisy target followed by the
    /// condition; y and x multiples of [`AifNetConfig::size_multiple`]) at steps `t` `[batch]`;
    /// returns `[batch, out_channels, y, x]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong input shape or size or a `t` of the wrong length.
    pub fn forward(&self, x: &Tensor, t: &Tensor) -> Result<Tensor> {
        let cfg = &self.config;
        let m = cfg.size_multiple();
        let d = x.dims();
        if d.len() != 4 || d[1] != cfg.in_channels || d[2] == 0 || d[3] == 0 || d[2] % m != 0 || d[3] % m != 0 {
            return Err(Error::shape(
                format!("AifNet input (height and width must be positive multiples of {m})"),
                format!("[batch, {}, y, x]", cfg.in_channels),
                d,
            ));
        }
        if t.dims() != [d[0]] {
            return Err(Error::shape("AifNet diffusion step t", [d[0]], t.dims()));
        }
        let t_enc = sinusoidal_embedding(t, cfg.time_dim, x.dtype())?;
        let mut h = self.initial.forward(x)?;
        let mut skips = Vec::with_capacity(self.downs.len());
        for block in &self.downs {
            h = block.forward(&h, &t_enc)?;
            skips.push((&h * cfg.skip_scale)?);
        }
        for block in &self.bottleneck {
            h = block.forward(&h, &t_enc)?;
        }
        for block in &self.ups {
            let skip = skips.pop().expect("one skip per down block, as many up blocks");
            h = block.forward(&Tensor::cat(&[&h, &skip], 1)?, &t_enc)?;
        }
        let h = self.final_block.forward(&h, &t_enc)?;
        Ok(self.final_conv.forward(&h)?)
    }
}
