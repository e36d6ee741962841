//! Diffusion surrogate for the mean and spread of an unsteady flow (the airfoil-paper method on our own cylinder wake).
pub(crate) mod entries;
