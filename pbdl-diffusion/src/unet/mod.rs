//! The U-Nets of the diffusion papers.
pub(crate) mod entries;
