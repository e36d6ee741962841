//! Score matching through differentiable physics (SMDP).
pub(crate) mod entries;
