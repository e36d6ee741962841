//! Max pooling with any kernel and stride, with a backward: [`max_pool2d`] now lives in
//! [`pbdl_core::nn`] (it is an NN layer, used by pbdl-temporal too); re-exported here so
//! existing `pbdl_metrics::pool::max_pool2d` calls keep working.

pub use pbdl_core::nn::max_pool2d;
