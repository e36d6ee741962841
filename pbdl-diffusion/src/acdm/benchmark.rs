//! The CPU-sized ACDM benchmark in one place: cached training and held-out data, models trained
//! (or resumed) under `target/pbdl/acdm/runs/`, and the pictures of a rollout.

use super::data::{
    default_cache_dir, test_config, train_config, CylinderConfig, CylinderDataset, Normalization, Sequence, TEST_RE,
    TRAIN_RE,
};
use super::model::{Method, Model, ModelConfig};
use super::train::{train, TrainConfig, TrainReport};
use crate::Result;
use candle_core::Tensor;
#[cfg(feature = "viz")]
use pbdl_core::viz::{rollout_to_gif, GifStyle};
use std::path::{Path, PathBuf};

/// Training and held-out data with the training statistics.
#[derive(Clone, Debug)]
pub struct Benchmark {
    /// Training sequences ([`TRAIN_RE`]).
    pub train: CylinderDataset,
    /// Held-out sequences ([`TEST_RE`]), long enough for the rollouts.
    pub test: CylinderDataset,
    /// Statistics of the training data.
    pub norm: Normalization,
    /// Normalised training sequences `[T, 4, ny, nx]`.
    pub seqs: Vec<Tensor>,
    /// Where models are trained and cached.
    pub runs: PathBuf,
}

impl Benchmark {
    /// The full benchmark (128x64 simulated, 64x32 data; 10 training Re x 400 frames, 2 held-out
    /// Re x 1002 frames), read from `dir` or simulated there (about 2 minutes on 2 cores).
    pub fn full(dir: &Path) -> Result<Self> {
        Self::with(dir, &train_config(), &TRAIN_RE, &test_config(), &TEST_RE)
    }

    /// A quick version: the tiny 64x32 generator, 3 training Re, held-out Re 950.
    pub fn quick(dir: &Path) -> Result<Self> {
        let test = CylinderConfig { frames: 260, ..CylinderConfig::tiny() };
        Self::with(dir, &CylinderConfig::tiny(), &[200.0, 500.0, 800.0], &test, &[950.0])
    }

    /// The full benchmark in [`default_cache_dir`].
    pub fn default_full() -> Result<Self> {
        Self::full(&default_cache_dir())
    }

    fn with(dir: &Path, tc: &CylinderConfig, tr: &[f64], ec: &CylinderConfig, er: &[f64]) -> Result<Self> {
        let train = CylinderDataset::cached(dir, tc, tr)?;
        let test = CylinderDataset::cached(dir, ec, er)?;
        let norm = Normalization::from_sequences(&train.sequences)?;
        let seqs = train.sequences.iter().map(|s| norm.normalize(s)).collect::<Result<Vec<_>>>()?;
        let tag = if tc == &train_config() { "full" } else { "quick" };
        Ok(Self { train, test, norm, seqs, runs: dir.join("runs").join(tag) })
    }

    /// The held-out sequence of Reynolds number `re`.
    pub fn held_out(&self, re: f64) -> Option<&Sequence> {
        self.test.get(re)
    }

    /// A model of `method` at width `dim`, trained to `steps` updates with batch `batch`:
    /// resumed from (or read from) `runs/<name>_d<dim>_b<batch>/`, trained further when its
    /// latest checkpoint is short of `steps`.
    pub fn model(
        &self,
        method: Method,
        dim: usize,
        steps: usize,
        batch: usize,
    ) -> Result<(Model, Option<TrainReport>)> {
        let model = Model::new(ModelConfig { method, dim, diffusion_steps: 20 })?;
        let dir = self.runs.join(format!("{}_d{dim}_b{batch}", method.name()));
        let cfg = TrainConfig { steps, batch, checkpoint_every: 25, ..Default::default() };
        if let Some(path) = pbdl_core::io::latest_checkpoint(&dir)? {
            let info = pbdl_core::io::read_checkpoint_info(&path)?;
            if info.step >= steps as u64 {
                pbdl_core::io::load_varmap(&path, model.varmap())?;
                return Ok((model, None));
            }
        }
        let report = train(&model, &self.seqs, &cfg, Some(&dir))?;
        Ok((model, Some(report)))
    }
}

/// Writes a GIF of one channel of several rollouts stacked vertically (first row on top), each
/// `[T, C, ny, nx]` with the same shape; the colour range is shared.
#[cfg(feature = "viz")]
pub fn stacked_gif(path: &Path, rows: &[&Tensor], channel: usize, every: usize) -> Result<()> {
    let (t, _, ny, nx) = rows[0].dims4()?;
    let mut frames = Vec::new();
    for k in (0..t).step_by(every.max(1)) {
        let mut f: Vec<f32> = Vec::with_capacity(rows.len() * ny * nx);
        // Origin::Lower draws row 0 at the bottom: push the last panel first.
        for r in rows.iter().rev() {
            f.extend(r.narrow(0, k, 1)?.narrow(1, channel, 1)?.flatten_all()?.to_vec1::<f32>()?);
        }
        frames.push(f);
    }
    rollout_to_gif(path, &frames, rows.len() * ny, nx, &GifStyle::diverging())?;
    Ok(())
}
