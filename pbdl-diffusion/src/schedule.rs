//! Noise schedules. TODO(core helper).
