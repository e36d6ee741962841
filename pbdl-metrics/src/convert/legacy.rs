//! The legacy (pre-1.6, non-zip) PyTorch checkpoint format: a sequence of pickles, then raw
//! storage bytes.
//!
//! Layout (what `torch.save` wrote before the zip container of PyTorch 1.6):
//! 1. pickle: the magic number `0x1950a86a20f9469cfc6c`;
//! 2. pickle: the protocol version (1001);
//! 3. pickle: system info (`little_endian`, type sizes);
//! 4. pickle: the saved object; each storage appears as the persistent id
//!    `('storage', torch.<Type>Storage, key, location, size, view_metadata)` and each tensor as
//!    `torch._utils._rebuild_tensor_v2(storage, offset, size, stride, requires_grad, hooks)`;
//! 5. pickle: the list of storage keys;
//! 6. per key, in that order: the element count (8 bytes, little-endian) and the elements
//!    (little-endian).

use super::pickle::{self, Value};
use crate::{Error, Result};
use std::collections::HashMap;

/// The magic number that starts a legacy PyTorch checkpoint.
pub const LEGACY_MAGIC: i128 = 0x1950a86a20f9469cfc6c;

/// The element type of a PyTorch storage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StorageDtype {
    /// `HalfStorage`.
    F16,
    /// `BFloat16Storage`.
    BF16,
    /// `FloatStorage`.
    F32,
    /// `DoubleStorage`.
    F64,
    /// `ByteStorage`.
    U8,
    /// `CharStorage`.
    I8,
    /// `ShortStorage`.
    I16,
    /// `IntStorage`.
    I32,
    /// `LongStorage`.
    I64,
    /// `BoolStorage`.
    Bool,
}

impl StorageDtype {
    /// From a storage class name such as `FloatStorage`.
    pub fn from_class(name: &str) -> Option<Self> {
        Some(match name {
            "HalfStorage" => Self::F16,
            "BFloat16Storage" => Self::BF16,
            "FloatStorage" => Self::F32,
            "DoubleStorage" => Self::F64,
            "ByteStorage" => Self::U8,
            "CharStorage" => Self::I8,
            "ShortStorage" => Self::I16,
            "IntStorage" => Self::I32,
            "LongStorage" => Self::I64,
            "BoolStorage" => Self::Bool,
            _ => return None,
        })
    }

    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 | Self::Bool => 1,
            Self::F16 | Self::BF16 | Self::I16 => 2,
            Self::F32 | Self::I32 => 4,
            Self::F64 | Self::I64 => 8,
        }
    }

    /// The safetensors dtype.
    pub fn safetensors(self) -> safetensors::Dtype {
        use safetensors::Dtype as D;
        match self {
            Self::F16 => D::F16,
            Self::BF16 => D::BF16,
            Self::F32 => D::F32,
            Self::F64 => D::F64,
            Self::U8 => D::U8,
            Self::I8 => D::I8,
            Self::I16 => D::I16,
            Self::I32 => D::I32,
            Self::I64 => D::I64,
            Self::Bool => D::BOOL,
        }
    }
}

/// A tensor taken out of a checkpoint: contiguous little-endian bytes in row-major order.
#[derive(Clone, Debug, PartialEq)]
pub struct RawTensor {
    /// Element type.
    pub dtype: StorageDtype,
    /// Shape (empty for a scalar).
    pub shape: Vec<usize>,
    /// `shape.iter().product() * dtype.size()` bytes.
    pub data: Vec<u8>,
}

/// The reference to a storage in a persistent id.
struct StorageRef {
    dtype: StorageDtype,
    key: String,
    /// Element offset of a view into the root storage (`view_metadata`), else 0.
    view_offset: usize,
    /// Elements visible through the reference.
    len: usize,
}

/// A legacy checkpoint read into memory: the saved object and its storages.
pub struct LegacyCheckpoint {
    /// The saved object (for a module checkpoint usually a dict); tensors in it are
    /// `_rebuild_tensor_v2` calls, read with [`LegacyCheckpoint::tensor`].
    pub object: Value,
    storages: HashMap<String, (StorageDtype, Vec<u8>)>,
}

fn perr(offset: usize, reason: impl Into<String>) -> Error {
    Error::Pickle { offset, reason: reason.into() }
}

fn usize_of(v: &Value, what: &str) -> Result<usize> {
    v.as_int()
        .and_then(|i| usize::try_from(i).ok())
        .ok_or_else(|| perr(0, format!("{what}: expected a non-negative integer, got a {}", v.kind())))
}

/// Reads a storage reference from a persistent id.
fn storage_ref(pid: &Value) -> Result<StorageRef> {
    let bad = |why: &str| perr(0, format!("a persistent id that is not a legacy storage reference: {why}"));
    let t = pid.as_seq().ok_or_else(|| bad("not a tuple"))?;
    if t.len() != 6 || t[0].as_str() != Some("storage") {
        return Err(bad("expected ('storage', type, key, location, size, view)"));
    }
    let dtype = match &t[1] {
        Value::Global { module, name } if module == "torch" => {
            StorageDtype::from_class(name).ok_or_else(|| bad(&format!("unsupported storage type torch.{name}")))?
        }
        other => return Err(bad(&format!("storage type is a {}", other.kind()))),
    };
    let key = t[2].as_str().ok_or_else(|| bad("key is not a string"))?.to_string();
    let size = usize_of(&t[4], "storage size")?;
    let (view_offset, len) = match &t[5] {
        Value::None => (0, size),
        Value::Tuple(v) if v.len() == 3 => (usize_of(&v[1], "view offset")?, usize_of(&v[2], "view size")?),
        other => return Err(bad(&format!("view metadata is a {}", other.kind()))),
    };
    Ok(StorageRef { dtype, key, view_offset, len })
}

/// Every storage reference in a value, for the element sizes of the raw data.
fn collect_storages(v: &Value, out: &mut HashMap<String, StorageDtype>) -> Result<()> {
    match v {
        Value::PersistentId(pid) => {
            let r = storage_ref(pid)?;
            if let Some(&d) = out.get(&r.key) {
                if d != r.dtype {
                    return Err(perr(0, format!("storage {} is referenced as {d:?} and as {:?}", r.key, r.dtype)));
                }
            }
            out.insert(r.key, r.dtype);
        }
        Value::Tuple(items) | Value::List(items) => {
            for i in items {
                collect_storages(i, out)?;
            }
        }
        Value::Dict(items) => {
            for (k, i) in items {
                collect_storages(k, out)?;
                collect_storages(i, out)?;
            }
        }
        Value::Reduce { callable, args } => {
            collect_storages(callable, out)?;
            collect_storages(args, out)?;
        }
        Value::Build { object, state } => {
            collect_storages(object, out)?;
            collect_storages(state, out)?;
        }
        _ => {}
    }
    Ok(())
}

impl LegacyCheckpoint {
    /// Parses a whole legacy checkpoint file.
    ///
    /// Errors: [`Error::Pickle`] for a file that is not a legacy checkpoint (a zip-format file of
    /// PyTorch >= 1.6 is named as such), truncated storage data or a malformed pickle;
    /// [`Error::UnsupportedOpcode`] naming an opcode the reader does not implement.
    pub fn parse(bytes: &[u8]) -> Result<Self> {
        if bytes.starts_with(b"PK\x03\x04") {
            return Err(perr(
                0,
                "this is a zip-format checkpoint (PyTorch >= 1.6); this reader takes the legacy format \
                 (re-save with `torch.save(obj, path, _use_new_zipfile_serialization=False)`)",
            ));
        }
        if bytes.first() != Some(&0x80) {
            return Err(perr(
                0,
                "the file does not start with a pickle protocol header (0x80); not a legacy PyTorch .pth file",
            ));
        }
        let mut pos = 0;
        let magic = pickle::load(bytes, &mut pos)?;
        if magic.as_int() != Some(LEGACY_MAGIC) {
            return Err(perr(0, "no legacy PyTorch magic number at the start; not a legacy .pth file"));
        }
        let at = pos;
        let version = pickle::load(bytes, &mut pos)?;
        if version.as_int() != Some(1001) {
            return Err(perr(at, format!("protocol version {version:?}, expected 1001")));
        }
        let at = pos;
        let sys = pickle::load(bytes, &mut pos)?;
        if sys.get("little_endian") == Some(&Value::Bool(false)) {
            return Err(perr(at, "the checkpoint was written on a big-endian machine; not supported"));
        }
        let object = pickle::load(bytes, &mut pos)?;
        let mut dtypes = HashMap::new();
        collect_storages(&object, &mut dtypes)?;
        let at = pos;
        let keys = pickle::load(bytes, &mut pos)?;
        let keys = keys.as_seq().ok_or_else(|| perr(at, "the storage key list is not a list"))?;
        let mut storages = HashMap::new();
        for k in keys {
            let key = k.as_str().ok_or_else(|| perr(at, "a storage key that is not a string"))?;
            let dtype = *dtypes.get(key).ok_or_else(|| {
                perr(at, format!("storage {key} is listed but never referenced (element size unknown)"))
            })?;
            if bytes.len() - pos < 8 {
                return Err(perr(pos, format!("the file ends before the data of storage {key}")));
            }
            let n = u64::from_le_bytes(bytes[pos..pos + 8].try_into().expect("8 bytes")) as usize;
            pos += 8;
            let len = n
                .checked_mul(dtype.size())
                .filter(|&l| l <= bytes.len() - pos)
                .ok_or_else(|| perr(pos, format!("storage {key} claims {n} elements, more than the file holds")))?;
            storages.insert(key.to_string(), (dtype, bytes[pos..pos + len].to_vec()));
            pos += len;
        }
        Ok(Self { object, storages })
    }

    /// The tensor that `v` rebuilds: a call of `torch._utils._rebuild_tensor_v2` (or the older
    /// `_rebuild_tensor`) with a storage, an element offset, a size and a stride. Elements are
    /// gathered through the stride, so views and non-contiguous tensors come out row-major.
    ///
    /// Errors: [`Error::Pickle`] if `v` is something else or indexes outside its storage.
    pub fn tensor(&self, v: &Value) -> Result<RawTensor> {
        let bad = |why: String| perr(0, format!("not a tensor: {why}"));
        let Value::Reduce { callable, args } = v else {
            return Err(bad(format!("a {}", v.kind())));
        };
        match callable.as_ref() {
            Value::Global { module, name }
                if module == "torch._utils" && (name == "_rebuild_tensor_v2" || name == "_rebuild_tensor") => {}
            other => return Err(bad(format!("a call of {other:?}"))),
        }
        let a = args.as_seq().ok_or_else(|| bad("arguments are not a tuple".into()))?;
        if a.len() < 4 {
            return Err(bad(format!("{} arguments, expected at least 4", a.len())));
        }
        let Value::PersistentId(pid) = &a[0] else {
            return Err(bad(format!("the storage argument is a {}", a[0].kind())));
        };
        let r = storage_ref(pid)?;
        let offset = usize_of(&a[1], "storage offset")?;
        let ints = |v: &Value, what: &str| -> Result<Vec<usize>> {
            v.as_seq()
                .ok_or_else(|| bad(format!("{what} is a {}", v.kind())))?
                .iter()
                .map(|x| usize_of(x, what))
                .collect()
        };
        let shape = ints(&a[2], "size")?;
        let stride = ints(&a[3], "stride")?;
        if shape.len() != stride.len() {
            return Err(bad(format!("size {shape:?} and stride {stride:?} differ in rank")));
        }
        let (dtype, data) =
            self.storages.get(&r.key).ok_or_else(|| bad(format!("storage {} has no data in the file", r.key)))?;
        let es = dtype.size();
        let numel: usize = shape.iter().product();
        // The last element read must lie inside the referenced part of the storage.
        if numel > 0 {
            let last: usize = offset + shape.iter().zip(&stride).map(|(n, s)| (n - 1) * s).sum::<usize>();
            if last >= r.len || (r.view_offset + last + 1) * es > data.len() {
                return Err(bad(format!(
                    "size {shape:?}, stride {stride:?}, offset {offset} reach past storage {} of {} elements",
                    r.key, r.len
                )));
            }
        }
        let mut out = Vec::with_capacity(numel * es);
        let mut idx = vec![0usize; shape.len()];
        for _ in 0..numel {
            let e = r.view_offset + offset + idx.iter().zip(&stride).map(|(i, s)| i * s).sum::<usize>();
            out.extend_from_slice(&data[e * es..(e + 1) * es]);
            // Row-major increment of the multi-index.
            for d in (0..idx.len()).rev() {
                idx[d] += 1;
                if idx[d] < shape[d] {
                    break;
                }
                idx[d] = 0;
            }
        }
        Ok(RawTensor { dtype: *dtype, shape, data: out })
    }

    /// Whether `v` is a tensor (a `_rebuild_tensor` call).
    pub fn is_tensor(v: &Value) -> bool {
        matches!(v, Value::Reduce { callable, .. } if matches!(callable.as_ref(),
            Value::Global { module, name } if module == "torch._utils" && name.starts_with("_rebuild_tensor")))
    }
}
