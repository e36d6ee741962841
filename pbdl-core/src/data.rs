//! Sequence datasets for training: where trajectories come from, seeded splits, random training
//! windows, and generate-once caching.
//!
//! A training set of physics-based learning is a list of trajectories `[T, C, (z,) y, x]`
//! (simulated or read from files). [`SequenceSource`] is what a training loop needs of it; it is
//! implemented for in-memory tensors (`[Tensor]`, `Vec<Tensor>`) and for [`NpzShards`], a set of
//! `.npz` files read one array at a time (a dataset larger than memory streams from disk).
//!
//! | item | what it does |
//! |---|---|
//! | [`SequenceSource`] | count, lengths and frames of the trajectories |
//! | [`NpzShards`] | trajectories stored as arrays in `.npz` shards, read on demand |
//! | [`seeded_split`] | train / validation / test indices from a seed |
//! | [`sample_windows`] | a batch `[B, L, ...]` of random windows of `L` consecutive frames |
//! | [`cached`] | read a generated dataset from its file, or generate and write it atomically |
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_core::data::{sample_windows, seeded_split, SequenceSource};
//!
//! // Three trajectories of 10, 6 and 3 frames of a 2x4x4 field.
//! let seqs: Vec<Tensor> = [10usize, 6, 3]
//!     .iter()
//!     .map(|&t| Tensor::zeros((t, 2, 4, 4), candle_core::DType::F32, &Device::Cpu))
//!     .collect::<candle_core::Result<_>>()?;
//! let split = seeded_split(seqs.len(), 1.0 / 3.0, 0.0, 7);
//! assert_eq!(split.train.len() + split.valid.len(), 3);
//! let mut rng = pbdl_core::seed::rng(0);
//! let batch = sample_windows(&seqs, 4, 8, &mut rng)?; // the 3-frame trajectory is too short
//! assert_eq!(batch.dims(), &[8, 4, 2, 4, 4]);
//! assert_eq!(seqs.frames(1)?, 6);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::Tensor;
use rand::seq::SliceRandom;
use rand::Rng;
use std::path::{Path, PathBuf};

/// A list of trajectories `[T, ...]` (frames first).
pub trait SequenceSource {
    /// Number of trajectories.
    fn len(&self) -> usize;

    /// Whether there are none.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Frames of trajectory `i`.
    fn frames(&self, i: usize) -> Result<usize>;

    /// Trajectory `i`, all frames.
    fn get(&self, i: usize) -> Result<Tensor>;

    /// Frames `t0..t0 + len` of trajectory `i`.
    fn window(&self, i: usize, t0: usize, len: usize) -> Result<Tensor> {
        Ok(self.get(i)?.narrow(0, t0, len)?)
    }
}

impl SequenceSource for [Tensor] {
    fn len(&self) -> usize {
        <[Tensor]>::len(self)
    }
    fn frames(&self, i: usize) -> Result<usize> {
        Ok(self[i].dim(0)?)
    }
    fn get(&self, i: usize) -> Result<Tensor> {
        Ok(self[i].clone())
    }
    fn window(&self, i: usize, t0: usize, len: usize) -> Result<Tensor> {
        Ok(self[i].narrow(0, t0, len)?)
    }
}

impl SequenceSource for Vec<Tensor> {
    fn len(&self) -> usize {
        self.as_slice().len()
    }
    fn frames(&self, i: usize) -> Result<usize> {
        SequenceSource::frames(self.as_slice(), i)
    }
    fn get(&self, i: usize) -> Result<Tensor> {
        SequenceSource::get(self.as_slice(), i)
    }
    fn window(&self, i: usize, t0: usize, len: usize) -> Result<Tensor> {
        SequenceSource::window(self.as_slice(), i, t0, len)
    }
}

/// Trajectories stored as arrays of `.npz` files (each array one trajectory `[T, ...]`), read
/// from disk when asked for: only the array in use is in memory.
#[derive(Clone, Debug)]
pub struct NpzShards {
    /// `(file, array name, frames)` of every trajectory, in file then storage order.
    entries: Vec<(PathBuf, String, usize)>,
}

impl NpzShards {
    /// Indexes the arrays of `files` whose names start with `prefix` (e.g. `"frames_"`; `""`
    /// for all). Opening reads each array once, one at a time, to record its frame count.
    pub fn open(files: &[PathBuf], prefix: &str) -> Result<Self> {
        let mut entries = Vec::new();
        for file in files {
            for (name, t) in crate::io::read_npz(file)? {
                if name.starts_with(prefix) {
                    if t.rank() == 0 {
                        return Err(Error::Format {
                            path: file.clone(),
                            reason: format!("array `{name}` is a scalar; trajectories are [T, ...] with frames first"),
                        });
                    }
                    entries.push((file.clone(), name, t.dim(0)?));
                }
            }
        }
        Ok(Self { entries })
    }

    /// The `.npz` files of a directory (sorted by name), indexed as [`NpzShards::open`] does.
    pub fn open_dir(dir: impl AsRef<Path>, prefix: &str) -> Result<Self> {
        let dir = dir.as_ref();
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| Error::io(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "npz"))
            .collect();
        files.sort();
        Self::open(&files, prefix)
    }
}

impl SequenceSource for NpzShards {
    fn len(&self) -> usize {
        self.entries.len()
    }
    fn frames(&self, i: usize) -> Result<usize> {
        Ok(self.entries[i].2)
    }
    fn get(&self, i: usize) -> Result<Tensor> {
        let (file, name, _) = &self.entries[i];
        crate::io::read_npz_array(file, name)
    }
}

/// Indices of a seeded split.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Split {
    /// Training indices, ascending.
    pub train: Vec<usize>,
    /// Validation indices, ascending.
    pub valid: Vec<usize>,
    /// Test indices, ascending.
    pub test: Vec<usize>,
}

/// Splits `0..n` at random (from `seed`) into train, validation (`round(valid * n)` items) and
/// test (`round(test * n)` items); the same seed gives the same split.
pub fn seeded_split(n: usize, valid: f64, test: f64, seed: u64) -> Split {
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(&mut crate::seed::rng(seed));
    let nv = ((valid.clamp(0.0, 1.0) * n as f64).round() as usize).min(n);
    let nt = ((test.clamp(0.0, 1.0) * n as f64).round() as usize).min(n - nv);
    let sorted = |v: &[usize]| {
        let mut v = v.to_vec();
        v.sort_unstable();
        v
    };
    Split { valid: sorted(&order[..nv]), test: sorted(&order[nv..nv + nt]), train: sorted(&order[nv + nt..]) }
}

/// `batch` windows of `len` consecutive frames, stacked `[batch, len, ...]`: for each, a
/// trajectory uniformly among those with at least `len` frames, then a uniform start. Draws
/// exactly two random integers per window from `rng`, in that order.
pub fn sample_windows<S: SequenceSource + ?Sized>(
    src: &S,
    len: usize,
    batch: usize,
    rng: &mut impl Rng,
) -> Result<Tensor> {
    let mut usable = Vec::new();
    for i in 0..src.len() {
        if src.frames(i)? >= len {
            usable.push(i);
        }
    }
    if usable.is_empty() {
        return Err(Error::InvalidArgument {
            op: "sample_windows",
            arg: "len",
            reason: format!(
                "none of the {} sequences has {len} frames; give longer sequences or shorter windows",
                src.len()
            ),
        });
    }
    let mut w = Vec::with_capacity(batch);
    for _ in 0..batch {
        let i = usable[rng.random_range(0..usable.len())];
        let t0 = rng.random_range(0..=src.frames(i)? - len);
        w.push(src.window(i, t0, len)?);
    }
    Ok(Tensor::stack(&w, 0)?)
}

/// Reads a generated dataset from `path` when `load` can read it, otherwise calls `make` and
/// writes its result with `save` (which should write atomically, as [`crate::io::write_npz`]
/// does). A file that cannot be read (older format, interrupted run) is regenerated, not an
/// error. Creates the parent directory.
pub fn cached<T, E: From<Error>>(
    path: impl AsRef<Path>,
    load: impl FnOnce(&Path) -> std::result::Result<T, E>,
    make: impl FnOnce() -> std::result::Result<T, E>,
    save: impl FnOnce(&Path, &T) -> std::result::Result<(), E>,
) -> std::result::Result<T, E> {
    let path = path.as_ref();
    if path.exists() {
        if let Ok(v) = load(path) {
            return Ok(v);
        }
    }
    let v = make()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    save(path, &v)?;
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    fn ramp(t: usize, offset: f32) -> Tensor {
        (Tensor::arange(0f32, t as f32, &Device::Cpu).unwrap() + offset as f64).unwrap().reshape((t, 1)).unwrap()
    }

    #[test]
    fn splits_are_seeded_disjoint_and_complete() {
        let a = seeded_split(20, 0.2, 0.1, 3);
        assert_eq!((a.train.len(), a.valid.len(), a.test.len()), (14, 4, 2));
        let mut all: Vec<usize> = a.train.iter().chain(&a.valid).chain(&a.test).copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..20).collect::<Vec<_>>());
        assert_eq!(a, seeded_split(20, 0.2, 0.1, 3));
        assert_ne!(a, seeded_split(20, 0.2, 0.1, 4));
    }

    #[test]
    fn windows_are_consecutive_frames_of_long_enough_sequences() {
        let seqs = vec![ramp(10, 0.0), ramp(2, 100.0), ramp(5, 1000.0)];
        let mut rng = crate::seed::rng(1);
        let w = sample_windows(&seqs, 3, 64, &mut rng).unwrap();
        assert_eq!(w.dims(), &[64, 3, 1]);
        let v: Vec<Vec<f32>> = w.squeeze(2).unwrap().to_vec2().unwrap();
        for row in &v {
            assert!(row[1] == row[0] + 1.0 && row[2] == row[1] + 1.0, "{row:?}");
            assert!(row[0] < 100.0 || row[0] >= 1000.0, "the 2-frame sequence is never used: {row:?}");
        }
        assert!(v.iter().any(|r| r[0] >= 1000.0) && v.iter().any(|r| r[0] < 100.0));
        let e = sample_windows(&seqs, 11, 1, &mut rng).unwrap_err().to_string();
        assert!(e.contains("shorter windows"), "{e}");
    }

    #[test]
    fn npz_shards_stream_the_same_windows_as_memory_and_cached_regenerates_broken_files() {
        let dir = std::env::temp_dir().join(format!("pbdl_data_test_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let seqs = vec![ramp(6, 0.0), ramp(4, 50.0), ramp(8, 500.0)];
        crate::io::write_npz(dir.join("a.npz"), &[("frames_0", &seqs[0]), ("frames_1", &seqs[1])]).unwrap();
        crate::io::write_npz(dir.join("b.npz"), &[("frames_0", &seqs[2]), ("meta", &ramp(1, 0.0))]).unwrap();
        let shards = NpzShards::open_dir(&dir, "frames_").unwrap();
        assert_eq!(shards.len(), 3);
        assert_eq!((shards.frames(0).unwrap(), shards.frames(2).unwrap()), (6, 8));
        let (mut r1, mut r2) = (crate::seed::rng(9), crate::seed::rng(9));
        let a = sample_windows(&seqs, 4, 16, &mut r1).unwrap().to_dtype(DType::F64).unwrap();
        let b = sample_windows(&shards, 4, 16, &mut r2).unwrap().to_dtype(DType::F64).unwrap();
        assert_eq!(
            a.flatten_all().unwrap().to_vec1::<f64>().unwrap(),
            b.flatten_all().unwrap().to_vec1::<f64>().unwrap()
        );

        let file = dir.join("cache").join("gen.npz");
        let load = |p: &Path| crate::io::read_npz_array(p, "x");
        let save = |p: &Path, t: &Tensor| crate::io::write_npz(p, &[("x", t)]);
        let made = std::cell::Cell::new(0);
        let run = || {
            cached(
                &file,
                load,
                || -> Result<Tensor> {
                    made.set(made.get() + 1);
                    Ok(ramp(3, 0.0))
                },
                save,
            )
            .unwrap()
        };
        let x = run();
        let _ = run();
        assert_eq!(made.get(), 1, "the second call reads the file");
        std::fs::write(&file, b"truncated").unwrap();
        let y = run();
        assert_eq!(made.get(), 2, "a broken file is regenerated");
        assert_eq!(x.to_vec2::<f32>().unwrap(), y.to_vec2::<f32>().unwrap());
        std::fs::remove_dir_all(&dir).ok();
    }
}
