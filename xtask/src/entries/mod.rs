//! Tour, bench and stress entries, one module per library crate. Each module has
//! `pub fn tasks() -> CrateTasks`; [`crate::registry::all`] lists them in tour order.
//! [`stability`] holds the time-step sweeps (`dt_limit`) that three simulator crates share.

pub mod core;
pub mod diffusion;
pub mod grid;
pub mod latent;
pub mod metrics;
pub mod nets;
pub mod optim;
pub mod particles;
pub mod particles3d;
pub mod pconv;
pub mod smoke3d;
pub mod sol;
pub mod spectral;
pub mod stability;
pub mod temporal;
pub mod weather;
