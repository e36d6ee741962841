//! Files: atomic writes, training checkpoints, NumPy arrays.
//!
//! | file | what it gives you |
//! |---|---|
//! | [`atomic`] | [`write_atomic`]: temp file, `fsync`, rename; an interrupted write keeps the old file |
//! | [`checkpoint`] | safetensors weights + JSON sidecar, [`load_varmap`], [`latest_checkpoint`] for resume |
//! | [`npy`] | `.npy` / `.npz` read and write (f32, f64, u8, ...) with typed errors |
//!
//! Every writer here is atomic, and every reader reports a missing file as [`crate::Error::Io`]
//! and a malformed one as [`crate::Error::Format`], naming the file.

pub mod atomic;
pub mod checkpoint;
pub mod npy;

pub use atomic::{is_temp_file, write_atomic, write_atomic_path};
pub use checkpoint::{
    checkpoint_files, latest_checkpoint, list_checkpoints, load_checkpoint, load_varmap, read_checkpoint_info,
    save_checkpoint, save_varmap, CheckpointInfo, CheckpointMeta, TensorEntry, CHECKPOINT_FORMAT,
    CHECKPOINT_FORMAT_VERSION,
};
pub use npy::{read_npy, read_npz, read_npz_array, write_npy, write_npz};
