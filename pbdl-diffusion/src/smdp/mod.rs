//! Score matching through differentiable physics (SMDP).
