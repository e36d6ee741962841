//! NumPy `.npy` and `.npz` files: exchange arrays with Python.
//!
//! Both are written atomically ([`write_atomic`]) and read with typed errors: a missing file is
//! [`Error::Io`]; anything that is not a valid array file, and arrays pbdl cannot represent, are
//! [`Error::Format`] with a reason that says how to convert the file in NumPy.
//!
//! | NumPy dtype | candle dtype |
//! |---|---|
//! | `float32` (`<f4`), `float64` (`<f8`), `float16` (`<f2`) | `F32`, `F64`, `F16` |
//! | `uint8` (`|u1`), `bool` (`|b1`, read only) | `U8` |
//! | `uint32` (`<u4`), `int16` (`<i2`), `int32` (`<i4`), `int64` (`<i8`) | `U32`, `I16`, `I32`, `I64` |
//!
//! Not supported, with a [`Error::Format`] on read or a [`Error::DType`] on write: Fortran-order
//! (column-major) arrays, big-endian arrays, complex, `int8`, `uint16`, `uint64`, object and
//! string arrays, `bf16` and the 8-bit float types. `.npz` members must be stored uncompressed
//! (`np.savez`, not `np.savez_compressed`). Arrays are read onto the CPU.
//!
//! A trajectory is stored as one `.npz` with one named array per quantity, each laid out
//! `[T, C, (Z,) Y, X]` (time first, x fastest), as NumPy reads it with `np.load(path)["name"]`.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_core::io::{read_npz, read_npz_array, write_npz};
//! # fn main() -> pbdl_core::Result<()> {
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("trajectory.npz");
//! // 4 time steps of a 1-channel 8x8 density and a 2-channel velocity.
//! let density = Tensor::zeros((4, 1, 8, 8), candle_core::DType::F32, &Device::Cpu)?;
//! let velocity = Tensor::ones((4, 2, 8, 8), candle_core::DType::F32, &Device::Cpu)?;
//! write_npz(&path, &[("density", &density), ("velocity", &velocity)])?;
//!
//! let arrays = read_npz(&path)?;
//! assert_eq!(arrays[0].0, "density");
//! assert_eq!(read_npz_array(&path, "velocity")?.dims(), &[4, 2, 8, 8]);
//! # Ok(())
//! # }
//! ```

use super::atomic::write_atomic;
use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor};
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";
const ZIP_MAGIC: &[u8] = b"PK";

/// Writes `t` to a `.npy` file (C order, little-endian), atomically.
///
/// Fails with [`Error::DType`] for dtypes NumPy files cannot hold here (`bf16`, 8-bit floats).
///
/// ```
/// use candle_core::{Device, Tensor};
/// # fn main() -> pbdl_core::Result<()> {
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("x.npy");
/// let x = Tensor::new(&[[1.0f64, 2.0], [3.0, 4.0]], &Device::Cpu)?;
/// pbdl_core::io::write_npy(&path, &x)?;
/// let y = pbdl_core::io::read_npy(&path)?;
/// assert_eq!(y.to_vec2::<f64>()?, x.to_vec2::<f64>()?);
/// # Ok(())
/// # }
/// ```
pub fn write_npy(path: impl AsRef<Path>, t: &Tensor) -> Result<()> {
    let descr = descr_for("write_npy", t.dtype())?;
    write_atomic(path, |w| write_npy_to(w, t, descr))
}

/// Reads a `.npy` file into a CPU tensor.
pub fn read_npy(path: impl AsRef<Path>) -> Result<Tensor> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_npy(&bytes).map_err(|reason| Error::Format { path: path.to_path_buf(), reason })
}

/// Writes named arrays to a `.npz` archive (uncompressed, like `np.savez`), atomically.
///
/// Names must be unique and non-empty; NumPy finds each array under its name. Fails with
/// [`Error::DType`] for unsupported dtypes, before anything is written.
pub fn write_npz<S: AsRef<str>, T: AsRef<Tensor>>(path: impl AsRef<Path>, arrays: &[(S, T)]) -> Result<()> {
    let mut descrs = Vec::with_capacity(arrays.len());
    let mut seen = std::collections::HashSet::new();
    for (name, t) in arrays {
        let name = name.as_ref();
        if name.is_empty() || !seen.insert(name) {
            let why =
                if name.is_empty() { "an array name is empty".to_string() } else { format!("`{name}` appears twice") };
            return Err(Error::invalid("write_npz", "arrays", why));
        }
        descrs.push(descr_for("write_npz", t.as_ref().dtype())?);
    }
    write_atomic(path, |w| {
        let mut zip = zip::ZipWriter::new(w);
        for ((name, t), descr) in arrays.iter().zip(descrs) {
            let t = t.as_ref();
            let bytes = (t.elem_count() * t.dtype().size_in_bytes()) as u64;
            // Stored, not deflated: float fields barely compress and NumPy memory-maps stored members.
            let options = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored)
                .large_file(bytes >= u32::MAX as u64 - 1024);
            zip.start_file(format!("{}.npy", name.as_ref()), options)?;
            write_npy_to(&mut zip, t, descr)?;
        }
        zip.finish()?;
        Ok(())
    })
}

/// Reads every array of a `.npz` archive, in the order they are stored, onto the CPU.
pub fn read_npz(path: impl AsRef<Path>) -> Result<Vec<(String, Tensor)>> {
    let path = path.as_ref();
    let mut archive = open_npz(path)?;
    let mut out = Vec::with_capacity(archive.len());
    for i in 0..archive.len() {
        if let Some(entry) = read_member(path, &mut archive, i)? {
            out.push(entry);
        }
    }
    Ok(out)
}

/// Reads one named array of a `.npz` archive; [`Error::MissingTensors`] lists the names the
/// archive has if `name` is not among them.
pub fn read_npz_array(path: impl AsRef<Path>, name: &str) -> Result<Tensor> {
    let path = path.as_ref();
    let mut archive = open_npz(path)?;
    let mut available = Vec::new();
    for i in 0..archive.len() {
        let member = archive.name_for_index(i).and_then(|n| n.ok()).map(|n| n.to_string()).unwrap_or_default();
        let member = member.strip_suffix(".npy").unwrap_or(&member).to_string();
        if member == name {
            if let Some((_, t)) = read_member(path, &mut archive, i)? {
                return Ok(t);
            }
        }
        available.push(member);
    }
    Err(Error::MissingTensors { path: path.to_path_buf(), missing: vec![name.to_string()], available })
}

type Archive = zip::ZipArchive<std::io::BufReader<std::fs::File>>;

fn open_npz(path: &Path) -> Result<Archive> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = [0u8; 2];
    // Checked by hand first: the zip crate's message for a non-zip file is cryptic.
    if file.read_exact(&mut head).is_err() || head != ZIP_MAGIC {
        return Err(format_err(path, "not a .npz file (no zip signature); write it with np.savez"));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| format_err(path, format!("not a valid .npz (zip) archive: {e}")))
}

/// Reads member `i`; `None` for directory entries.
fn read_member(path: &Path, archive: &mut Archive, i: usize) -> Result<Option<(String, Tensor)>> {
    let bad = |reason: String| format_err(path, reason);
    // Raw access first, so that a compressed member gets a clear message rather than the zip
    // crate's "unsupported compression".
    let raw = archive.by_index_raw(i).map_err(|e| bad(format!("member {i}: {e}")))?;
    let name = raw.name().map_err(|e| bad(format!("member {i}: {e}")))?.to_string();
    if raw.is_dir() {
        return Ok(None);
    }
    let name = name.strip_suffix(".npy").unwrap_or(&name).to_string();
    if raw.compression() != zip::CompressionMethod::Stored {
        return Err(bad(format!(
            "array `{name}` is compressed; pbdl reads uncompressed archives: save with np.savez, not np.savez_compressed"
        )));
    }
    drop(raw);
    let mut entry = archive.by_index(i).map_err(|e| bad(format!("array `{name}`: {e}")))?;
    // The declared size comes from the zip header, which a damaged or crafted file can set to
    // anything: a stored member cannot be larger than the archive, so refuse before allocating.
    let file_len = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
    let size = entry.size();
    if size > file_len {
        return Err(bad(format!(
            "array `{name}` declares {size} bytes but the archive has only {file_len}; the file is damaged"
        )));
    }
    let mut bytes = Vec::with_capacity(size as usize);
    (&mut entry).take(size).read_to_end(&mut bytes).map_err(|e| bad(format!("array `{name}`: {e}")))?;
    let t = parse_npy(&bytes).map_err(|r| bad(format!("array `{name}`: {r}")))?;
    Ok(Some((name, t)))
}

fn format_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Format { path: path.to_path_buf(), reason: reason.into() }
}

/// The NumPy type string for a candle dtype.
fn descr_for(op: &'static str, dtype: DType) -> Result<&'static str> {
    Ok(match dtype {
        DType::F16 => "<f2",
        DType::F32 => "<f4",
        DType::F64 => "<f8",
        DType::U8 => "|u1",
        DType::U32 => "<u4",
        DType::I16 => "<i2",
        DType::I32 => "<i4",
        DType::I64 => "<i8",
        got => {
            return Err(Error::DType { op, arg: "tensor", expected: "f16, f32, f64, u8, u32, i16, i32 or i64", got });
        }
    })
}

fn write_npy_to<W: Write>(w: &mut W, t: &Tensor, descr: &str) -> std::io::Result<()> {
    let shape = match t.dims() {
        [] => "()".to_string(),
        [n] => format!("({n},)"),
        dims => format!("({})", dims.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    // Version 1 has a 2-byte header length, version 2 a 4-byte one.
    let version: u8 = if header.len() + 11 < u16::MAX as usize { 1 } else { 2 };
    let prefix = MAGIC.len() + 2 + if version == 1 { 2 } else { 4 };
    // NumPy pads the header with spaces and a newline so that the data starts 64-byte aligned.
    let pad = (64 - (prefix + header.len() + 1) % 64) % 64;
    header.extend(std::iter::repeat_n(' ', pad));
    header.push('\n');
    w.write_all(MAGIC)?;
    w.write_all(&[version, 0])?;
    if version == 1 {
        w.write_all(&(header.len() as u16).to_le_bytes())?;
    } else {
        w.write_all(&(header.len() as u32).to_le_bytes())?;
    }
    w.write_all(header.as_bytes())?;
    t.write_bytes(w).map_err(std::io::Error::other)
}

/// Parses a whole `.npy` file held in memory; the error is the reason for a [`Error::Format`].
fn parse_npy(bytes: &[u8]) -> std::result::Result<Tensor, String> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("not a .npy file (the \\x93NUMPY signature is missing)".into());
    }
    let (len_bytes, start) = match bytes[6] {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => return Err(format!("unsupported .npy format version {v}")),
    };
    if bytes.len() < start {
        return Err("truncated .npy header".into());
    }
    let header_len = bytes[8..8 + len_bytes].iter().rev().fold(0usize, |acc, &b| (acc << 8) | b as usize);
    let data_start = start + header_len;
    if bytes.len() < data_start {
        return Err("truncated .npy header".into());
    }
    let header =
        std::str::from_utf8(&bytes[start..data_start]).map_err(|_| "the .npy header is not text".to_string())?;
    let (dtype, fortran, shape) = parse_header(header)?;
    // Checked: the shape comes from the file and its product can exceed usize.
    let too_big = || format!("the header's shape {shape:?} ({dtype:?}) has more bytes than memory can address");
    let n = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).ok_or_else(too_big)?;
    if fortran && shape.iter().filter(|&&d| d > 1).count() > 1 {
        return Err(
            "Fortran-order (column-major) arrays are not supported; save np.ascontiguousarray(a) instead".into()
        );
    }
    let expected = n.checked_mul(dtype.size_in_bytes()).ok_or_else(too_big)?;
    let data = &bytes[data_start..];
    if data.len() != expected {
        return Err(format!(
            "the header promises {expected} bytes of data for shape {shape:?} ({dtype:?}) but the file has {}{}",
            data.len(),
            if data.len() < expected { " (truncated file?)" } else { "" }
        ));
    }
    Tensor::from_raw_buffer(data, dtype, &shape, &Device::Cpu).map_err(|e| e.to_string())
}

/// Parses the header dict, e.g. `{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }`.
fn parse_header(header: &str) -> std::result::Result<(DType, bool, Vec<usize>), String> {
    let descr = dict_value(header, "descr").ok_or_else(|| format!("no 'descr' in the .npy header {header:?}"))?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let fortran = match dict_value(header, "fortran_order") {
        Some("True") => true,
        Some("False") | None => false,
        Some(other) => return Err(format!("unreadable 'fortran_order': {other}")),
    };
    let shape = dict_value(header, "shape").ok_or_else(|| format!("no 'shape' in the .npy header {header:?}"))?;
    let shape = shape
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| format!("unreadable 'shape': {shape}"))?;
    Ok((dtype_for(descr)?, fortran, shape))
}

/// The value text of `key` in a Python dict literal: a quoted string, a tuple or a bare word.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'")).or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = header[at + key.len() + 2..].trim_start().strip_prefix(':')?.trim_start();
    let end = match rest.chars().next()? {
        '(' => rest.find(')')? + 1,
        q @ ('\'' | '"') => rest[1..].find(q)? + 2,
        _ => rest.find([',', '}']).unwrap_or(rest.len()),
    };
    Some(rest[..end].trim())
}

fn dtype_for(descr: &str) -> std::result::Result<DType, String> {
    let (order, code) = match descr.chars().next() {
        Some(c @ ('<' | '>' | '|' | '=')) => (c, &descr[1..]),
        _ => ('=', descr),
    };
    let dtype = match code {
        "f2" | "e" => DType::F16,
        "f4" | "f" => DType::F32,
        "f8" | "d" => DType::F64,
        "u1" | "B" | "b1" | "?" => DType::U8,
        "u4" | "I" => DType::U32,
        "i2" | "h" => DType::I16,
        "i4" | "i" => DType::I32,
        "i8" | "q" => DType::I64,
        _ => {
            return Err(format!(
                "NumPy dtype '{descr}' is not supported; convert with a.astype(np.float32) (or float64, uint8, int32, int64)"
            ))
        }
    };
    if order == '>' && dtype.size_in_bytes() > 1 {
        return Err(format!(
            "big-endian arrays ('{descr}') are not supported; convert with a.astype(a.dtype.newbyteorder('<'))"
        ));
    }
    Ok(dtype)
}
