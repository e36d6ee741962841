//! Autoregressive conditional diffusion (ACDM) for flow prediction.
