//! The U-Nets of the diffusion papers.
