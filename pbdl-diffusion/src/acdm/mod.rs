//! Autoregressive conditional diffusion (ACDM) for flow prediction.
pub(crate) mod entries;
