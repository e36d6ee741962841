//! TecoGAN (Chu, Xie, Mayer, Leal-Taixé, Thuerey 2020) on single-channel densities: the motion
//! network F, the frame-recurrent generator, the spatio-temporal discriminator's triplet input,
//! the ping-pong loss, a non-adversarial trainer for F and G, and the adversarial trainer
//! against the spatio-temporal discriminator.
//!
//! | item | what it is |
//! |---|---|
//! | [`MotionNet`] | F: two low-resolution frames in, the low-resolution flow that warps the first onto the second (encoder/decoder, leaky ReLU 0.2, `tanh * max_flow`) |
//! | [`RecurrentGenerator`] | G: the low-resolution frame and the space-to-depth of the warped previous output in, a `factor`-times finer frame out (residual on bicubic) |
//! | [`TecoGan`] | F and G together: [`TecoGan::run_batch`] / [`TecoGan::run_sequence`] keep the graph for training, [`Rollout`] generates arbitrarily long sequences frame by frame |
//! | [`pingpong_sequence`], [`pingpong_loss`], [`split_pingpong`], [`drift`] | the ping-pong extension `0..T-1, T-2..0` and `mean |g_t - g'_t|` over the frames seen twice |
//! | [`triplet_input`], [`triplet_flows`], [`spatio_temporal_discriminator`] | D_s,t's 9-channel input (HR triplet, the triplet warped to its middle frame with stop-gradient flows and a 75% centre crop, the bilinearly upsampled LR triplet) and a matching [`pbdl_nets::discriminator::DiscriminatorConfig`] |
//! | [`TecoTrainConfig`], [`train_tecogan`] | L2 content + LR warp loss for F + optional ping-pong term (weight 0.5 as TecoGAN), Adam, seeded |
//! | [`TecoGanTrainConfig`], [`train_tecogan_gan`], [`tecogan_gan_players`] | adversarial fine-tuning against D_s,t on generated vs real triplets: content, ping-pong, `-log D(fake)` and D-feature losses, F's warp loss, the D/G balance; run directory, checkpoints, exact resume |
//!
//! **Flow convention.** A flow `[B, 2, y, x]` (x component first, in cells of the grid it lives
//! on) warps the previous frame onto the current one with
//! [`backward_warp`](crate::warp::backward_warp): `out(x) = prev(x - flow(x))`. F's output is in
//! low-resolution cells; [`upsample_motion`](crate::warp::upsample_motion) turns it into a
//! high-resolution flow.
//!
//! **Deviations from TecoGAN** (for single-channel fluid data on a CPU): one input channel
//! instead of RGB (so G's input is `1 + factor^2` channels and D_s,t's is 9); F is narrower
//! (`base_width` 16 and 2 levels by default instead of 32 and 3) and its flow is bounded by
//! `max_flow` = 4 LR cells instead of 24; G has 32 channels and 4 residual blocks instead of 64
//! and 16 (10 in FRVSR). The upsampling is TecoGAN's: 3x3 transposed convs, stride 2, ReLU.
//! [`train_tecogan`] is non-adversarial (no VGG or D terms); [`train_tecogan_gan`] adds D_s,t's
//! adversarial and feature terms but no VGG term.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_temporal::tecogan::{drift, pingpong_sequence, split_pingpong, TecoGan, TecoGanConfig};
//!
//! let varmap = VarMap::new();
//! let model = TecoGan::new(TecoGanConfig::default(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
//! pbdl_nets::seeded_init(&varmap, 0)?;
//! // Three 16^2 frames, extended to the ping-pong order 0, 1, 2, 1, 0 and upscaled to 64^2.
//! let lr = Tensor::zeros((3, 1, 16, 16), DType::F32, &Device::Cpu)?;
//! let pp = pingpong_sequence(&lr)?;
//! let hr = model.run_sequence(&pp)?;
//! assert_eq!(hr.dims(), [5, 1, 64, 64]);
//! let (forward, backward) = split_pingpong(&hr)?;
//! assert!(drift(&forward, &backward)?.is_finite());
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

mod adversarial;
mod motion;
mod pingpong;
mod recurrent;
mod train;
mod triplet;

pub use adversarial::{tecogan_gan_players, train_tecogan_gan, TecoGanPlayers, TecoGanTrainConfig, TecoGanTrainReport};
pub use motion::{MotionNet, MotionNetConfig};
pub use pingpong::{drift, drift_tensor, pingpong_loss, pingpong_sequence, reverse_time, split_pingpong};
pub use recurrent::{RecurrentGenerator, RecurrentGeneratorConfig, Rollout, SequenceOutput, TecoGan, TecoGanConfig};
pub use train::{train_tecogan, TecoTrainConfig, TecoTrainReport};
pub use triplet::{spatio_temporal_discriminator, triplet_flows, triplet_input, CROP_FRACTION, TRIPLET_CHANNELS};
