//! Sharded data generation: split a generator's items over machines, check the pieces, read
//! them back as one data set.
//!
//! When one machine is not enough, a generator runs as `n` independent jobs (a SLURM job array,
//! Kubernetes Jobs, GNU parallel), job `i` with `--shard i/n`. Three rules make the pieces equal
//! one run:
//! - **Items, not shards, carry the randomness.** Item `k` of a generator is a function of the
//!   generator's config and `k` alone (its seed is derived from the base seed and `k`), so the
//!   same item comes out whatever `n` is, on whichever machine.
//! - **Each item is its own file** (`item-000042.npz`), written atomically, and each shard
//!   commits a manifest (`manifest-1-of-4.json`) last, listing its items with SHA-256 hashes: a
//!   shard killed midway leaves no manifest and is simply rerun.
//! - **Reading checks everything**: [`open_shards`] refuses a directory whose manifests disagree
//!   on the generator or its config, overlap, leave items out, or whose files do not hash to
//!   what the manifests say, with an error that names the item, file or shard.
//!
//! ```
//! use pbdl_core::shard::{generate_shard, open_shards, Shard};
//!
//! let dir = std::env::temp_dir().join(format!("pbdl_shard_doc_{}", std::process::id()));
//! let config = serde_json::json!({ "seed": 7 });
//! // Two jobs, each writing its half of 5 items (here: a tiny file per item).
//! for shard in ["0/2", "1/2"] {
//!     let shard: Shard = shard.parse()?;
//!     generate_shard(&dir, "doc-example", &config, 5, shard, |k, path| {
//!         pbdl_core::io::write_atomic(path, |w| w.write_all(format!("item {k}").as_bytes()))
//!     })?;
//! }
//! let set = open_shards(&dir)?;
//! assert_eq!(set.files.len(), 5);
//! # std::fs::remove_dir_all(&dir).ok();
//! # use std::io::Write as _;
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::io::write_atomic;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::io::{Read as _, Write as _};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Job `index` of `count` (`--shard index/count`, 0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Which job, `0..count`.
    pub index: usize,
    /// How many jobs in all.
    pub count: usize,
}

impl Default for Shard {
    fn default() -> Self {
        Self::WHOLE
    }
}

impl Shard {
    /// The whole generator in one job (`0/1`).
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// Job `index` of `count`; [`Error::InvalidArgument`] unless `index < count`.
    pub fn new(index: usize, count: usize) -> Result<Self> {
        if count == 0 || index >= count {
            return Err(Error::invalid(
                "--shard",
                "i/n",
                format!("shard {index}/{count}: need n >= 1 and 0 <= i < n (0-based, e.g. 0/4 .. 3/4)"),
            ));
        }
        Ok(Self { index, count })
    }

    /// The items of `total` that this job makes: a contiguous block, sizes differing by at most
    /// one, blocks of jobs `0..count` covering `0..total` once in order.
    pub fn items(&self, total: usize) -> Range<usize> {
        (self.index * total / self.count)..((self.index + 1) * total / self.count)
    }

    /// The manifest's file name, `manifest-<i>-of-<n>.json`.
    pub fn manifest_name(&self) -> String {
        format!("manifest-{}-of-{}.json", self.index, self.count)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        let bad = || {
            Error::invalid("--shard", "i/n", format!("`{s}` is not `i/n` (0-based job index / job count, e.g. 2/8)"))
        };
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let i = i.trim().parse().map_err(|_| bad())?;
        let n = n.trim().parse().map_err(|_| bad())?;
        Self::new(i, n)
    }
}

/// One generated item as a manifest records it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ItemRecord {
    /// The item's index in `0..total_items`.
    pub index: usize,
    /// Its file, relative to the directory.
    pub file: String,
    /// SHA-256 of the file, lower-case hex.
    pub sha256: String,
    /// Its size in bytes.
    pub bytes: u64,
}

/// What one shard wrote: `manifest-<i>-of-<n>.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardManifest {
    /// The generator, e.g. `"pbdl-metrics/Adv"`.
    pub generator: String,
    /// Everything that decides the items besides their index (seed, resolution, ...).
    pub config: serde_json::Value,
    /// Items of the whole data set.
    pub total_items: usize,
    /// Which job wrote this manifest.
    pub shard: Shard,
    /// The items it wrote, in index order.
    pub items: Vec<ItemRecord>,
    /// pbdl-core's version at generation.
    pub pbdl_version: String,
}

/// The file name of item `index`: `item-000042.npz`.
pub fn item_file_name(index: usize) -> String {
    format!("item-{index:06}.npz")
}

/// SHA-256 of a file, lower-case hex.
pub fn sha256_file(path: impl AsRef<Path>) -> Result<String> {
    let path = path.as_ref();
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file.read(&mut buf).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Generates the items of `shard` into `dir`: `write_item(k, path)` writes item `k` to `path`
/// (atomically, e.g. with [`crate::io::write_npz`]); then the manifest is written, last and
/// atomically. An item whose file is already there is written again (a killed job reruns whole),
/// so `write_item` must be deterministic in `k` and `config`. Returns the manifest.
pub fn generate_shard(
    dir: impl AsRef<Path>,
    generator: &str,
    config: &serde_json::Value,
    total_items: usize,
    shard: Shard,
    mut write_item: impl FnMut(usize, &Path) -> Result<()>,
) -> Result<ShardManifest> {
    let dir = dir.as_ref();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut items = Vec::new();
    for index in shard.items(total_items) {
        let file = item_file_name(index);
        let path = dir.join(&file);
        write_item(index, &path)?;
        let bytes = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?.len();
        items.push(ItemRecord { index, file, sha256: sha256_file(&path)?, bytes });
    }
    let manifest = ShardManifest {
        generator: generator.to_string(),
        config: config.clone(),
        total_items,
        shard,
        items,
        pbdl_version: env!("CARGO_PKG_VERSION").to_string(),
    };
    let json = serde_json::to_string_pretty(&manifest)
        .map_err(|e| Error::invalid("generate_shard", "config", e.to_string()))?;
    write_atomic(dir.join(shard.manifest_name()), |w| w.write_all(json.as_bytes()))?;
    Ok(manifest)
}

/// A checked directory of shards: every item once, in index order.
#[derive(Clone, Debug)]
pub struct ShardSet {
    /// The generator all manifests name.
    pub generator: String,
    /// Its config.
    pub config: serde_json::Value,
    /// The item files, `files[k]` is item `k`.
    pub files: Vec<PathBuf>,
    /// The manifests read, by shard.
    pub manifests: Vec<ShardManifest>,
}

/// Reads and checks every `manifest-*.json` of `dir`: same generator, config and item count;
/// no item twice; every item present; every file hashing to its record. Errors name what is
/// wrong (the missing items and the shards that would have made them, the overlapping item and
/// both manifests, the file whose hash differs).
pub fn open_shards(dir: impl AsRef<Path>) -> Result<ShardSet> {
    let dir = dir.as_ref();
    let bad = |reason: String| Error::Format { path: dir.to_path_buf(), reason };
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("manifest-") && n.ends_with(".json"))
        })
        .collect();
    names.sort();
    if names.is_empty() {
        return Err(bad("no manifest-*.json: not a directory of shards (or no shard has finished)".into()));
    }
    let mut manifests = Vec::new();
    for path in &names {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let m: ShardManifest = serde_json::from_str(&text)
            .map_err(|e| Error::Format { path: path.clone(), reason: format!("not a shard manifest: {e}") })?;
        manifests.push(m);
    }
    let first = &manifests[0];
    let total = first.total_items;
    // Items are far fewer than a machine's memory; a corrupt count must not allocate wildly.
    if total > 100_000_000 {
        return Err(bad(format!("{}: {total} items is not a plausible data set", first.shard.manifest_name())));
    }
    let mut owner: Vec<Option<usize>> = vec![None; total];
    let mut files = vec![PathBuf::new(); total];
    for (m_index, m) in manifests.iter().enumerate() {
        let name = m.shard.manifest_name();
        if m.generator != first.generator || m.config != first.config || m.total_items != total {
            return Err(bad(format!(
                "{name} was written by another generator or config than {} ({} {} vs {} {}): \
                 keep one data set per directory",
                first.shard.manifest_name(),
                m.generator,
                m.config,
                first.generator,
                first.config
            )));
        }
        for item in &m.items {
            if item.index >= total {
                return Err(bad(format!("{name} lists item {} of a {total}-item data set", item.index)));
            }
            if let Some(other) = owner[item.index] {
                return Err(bad(format!(
                    "item {} is in both {} and {name}: shards overlap (were they run with different n?)",
                    item.index,
                    manifests[other].shard.manifest_name()
                )));
            }
            owner[item.index] = Some(m_index);
            // The file name comes from the manifest: it must not point outside the directory.
            if item.file.contains('/') || item.file.contains('\\') || item.file.starts_with('.') {
                return Err(bad(format!("{name}: item file `{}` is not a plain file name", item.file)));
            }
            let path = dir.join(&item.file);
            let hash = sha256_file(&path)?;
            if hash != item.sha256 {
                return Err(Error::Format {
                    path,
                    reason: format!(
                        "SHA-256 {hash} differs from {name}'s {}: the file changed or was cut short; rerun shard {}",
                        item.sha256, m.shard
                    ),
                });
            }
            files[item.index] = dir.join(&item.file);
        }
    }
    let missing: Vec<usize> = (0..total).filter(|&k| owner[k].is_none()).collect();
    if !missing.is_empty() {
        let count = first.shard.count;
        let mut jobs: Vec<String> = missing
            .iter()
            .filter_map(|&k| (0..count).find(|&i| Shard { index: i, count }.items(total).contains(&k)))
            .map(|i| format!("{i}/{count}"))
            .collect();
        jobs.dedup();
        let shown: Vec<String> = missing.iter().take(10).map(|k| k.to_string()).collect();
        return Err(bad(format!(
            "{} of {total} items missing ({}{}); run --shard {}",
            missing.len(),
            shown.join(", "),
            if missing.len() > 10 { ", ..." } else { "" },
            jobs.join(", ")
        )));
    }
    Ok(ShardSet { generator: first.generator.clone(), config: first.config.clone(), files, manifests })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_text(k: usize, path: &Path) -> Result<()> {
        write_atomic(path, |w| w.write_all(format!("item {k}").as_bytes()))
    }

    #[test]
    fn shards_partition_the_items_in_order() {
        for total in [0, 1, 5, 17, 100] {
            for count in 1..=7 {
                let mut next = 0;
                for index in 0..count {
                    let r = Shard::new(index, count).unwrap().items(total);
                    assert_eq!(r.start, next);
                    assert!(r.len() <= total / count + 1);
                    next = r.end;
                }
                assert_eq!(next, total);
            }
        }
    }

    #[test]
    fn shard_parsing_gives_typed_errors() {
        assert_eq!("2/8".parse::<Shard>().unwrap(), Shard { index: 2, count: 8 });
        for bad in ["8/8", "1/0", "a/2", "3", "-1/4", ""] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(matches!(e, Error::InvalidArgument { .. }), "{bad}: {e}");
        }
    }

    #[test]
    fn four_shards_equal_one_run_and_damage_is_named() {
        let one = tempfile::tempdir().unwrap();
        let four = tempfile::tempdir().unwrap();
        let cfg = serde_json::json!({ "seed": 3 });
        generate_shard(one.path(), "test", &cfg, 10, Shard::WHOLE, write_text).unwrap();
        // Out of order, as a scheduler may run them.
        for i in [2, 0, 3] {
            generate_shard(four.path(), "test", &cfg, 10, Shard::new(i, 4).unwrap(), write_text).unwrap();
        }
        let e = open_shards(four.path()).unwrap_err().to_string();
        assert!(e.contains("run --shard 1/4"), "{e}");
        generate_shard(four.path(), "test", &cfg, 10, Shard::new(1, 4).unwrap(), write_text).unwrap();
        let (a, b) = (open_shards(one.path()).unwrap(), open_shards(four.path()).unwrap());
        let hashes = |s: &ShardSet| s.files.iter().map(|f| sha256_file(f).unwrap()).collect::<Vec<_>>();
        assert_eq!(hashes(&a), hashes(&b));
        // A changed file, an overlapping shard and a foreign config are refused.
        std::fs::write(four.path().join(item_file_name(4)), "tampered").unwrap();
        assert!(open_shards(four.path()).unwrap_err().to_string().contains("SHA-256"));
        write_text(4, &four.path().join(item_file_name(4))).unwrap();
        generate_shard(four.path(), "test", &cfg, 10, Shard::new(0, 2).unwrap(), write_text).unwrap();
        assert!(open_shards(four.path()).unwrap_err().to_string().contains("overlap"));
        std::fs::remove_file(four.path().join("manifest-0-of-2.json")).unwrap();
        let other = serde_json::json!({ "seed": 4 });
        generate_shard(four.path(), "test", &other, 10, Shard::new(0, 2).unwrap(), write_text).unwrap();
        assert!(open_shards(four.path()).unwrap_err().to_string().contains("another generator or config"));
    }
}
