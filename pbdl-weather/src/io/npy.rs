//! `.npy` files (NumPy format versions 1-3): float32 or float64, C or Fortran order.
//!
//! A field is `[time, lat, lon]` (a single `[lat, lon]` map counts as one time); its latitudes
//! come separately (a 1-D `.npy` of degrees), longitudes are taken as `0, 360/n, ...`.

use crate::error::{Error, Result};
use crate::field::{Field, Values};
use crate::grid::{check_latitudes, LatLonGrid};
use crate::io::Selection;
use std::io::Write;
use std::path::Path;

/// A float array read from `.npy`: its shape and values in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// The shape.
    pub shape: Vec<usize>,
    /// The values, row-major.
    pub values: Values,
}

fn npy_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Npy { file: path.to_path_buf(), reason: reason.into() }
}

/// Reads a float32/float64 `.npy` array.
pub fn read_array(path: &Path) -> Result<NpyArray> {
    let bytes = std::fs::read(path).map_err(|source| Error::Io { file: path.to_path_buf(), source })?;
    parse_array(&bytes).map_err(|reason| npy_err(path, reason))
}

/// Parses the bytes of a `.npy` file.
pub fn parse_array(bytes: &[u8]) -> std::result::Result<NpyArray, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("missing the \\x93NUMPY magic".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(format!("unsupported format version {v}")),
    };
    let header = bytes.get(start..start + header_len).ok_or("truncated header")?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text")?;
    let descr = dict_value(header, "descr").ok_or("header without 'descr'")?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let fortran = dict_value(header, "fortran_order").ok_or("header without 'fortran_order'")?.starts_with("True");
    let shape_text = dict_value(header, "shape").ok_or("header without 'shape'")?;
    let shape: Vec<usize> = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|_| format!("bad shape entry '{s}'")))
        .collect::<std::result::Result<_, _>>()?;
    let n: usize = shape.iter().product();
    let data = &bytes[start + header_len..];
    let values = match descr {
        "<f4" | "|f4" => {
            let v = decode(data, n, f32::from_le_bytes)?;
            Values::F32(if fortran { to_c_order(&v, &shape) } else { v })
        }
        "<f8" | "|f8" => {
            let v = decode(data, n, f64::from_le_bytes)?;
            Values::F64(if fortran { to_c_order(&v, &shape) } else { v })
        }
        ">f4" => {
            Values::F32(decode(data, n, f32::from_be_bytes).map(|v| if fortran { to_c_order(&v, &shape) } else { v })?)
        }
        ">f8" => {
            Values::F64(decode(data, n, f64::from_be_bytes).map(|v| if fortran { to_c_order(&v, &shape) } else { v })?)
        }
        other => return Err(format!("dtype '{other}' is not float32 or float64")),
    };
    Ok(NpyArray { shape, values })
}

/// The text after `'key':` up to the next top-level comma of a Python dict literal.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pos = header.find(&format!("'{key}'")).or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = header[pos + key.len() + 2..].trim_start().strip_prefix(':')?.trim_start();
    let mut depth = 0;
    for (i, c) in rest.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => {
                depth -= 1;
                if depth == 0 {
                    return Some(&rest[..=i]);
                }
            }
            ',' | '}' if depth == 0 => return Some(rest[..i].trim()),
            _ => {}
        }
    }
    None
}

fn decode<T, const N: usize>(data: &[u8], n: usize, from: fn([u8; N]) -> T) -> std::result::Result<Vec<T>, String> {
    if data.len() < n * N {
        return Err(format!("{} data bytes for {n} values of {N} bytes", data.len()));
    }
    Ok(data[..n * N].chunks_exact(N).map(|c| from(c.try_into().unwrap())).collect())
}

/// Fortran (column-major) values to row-major.
fn to_c_order<T: Copy>(v: &[T], shape: &[usize]) -> Vec<T> {
    let nd = shape.len();
    let mut out = Vec::with_capacity(v.len());
    let mut idx = vec![0usize; nd];
    for _ in 0..v.len() {
        // Column-major offset of the current row-major index.
        let (mut off, mut stride) = (0, 1);
        for d in 0..nd {
            off += idx[d] * stride;
            stride *= shape[d];
        }
        out.push(v[off]);
        for d in (0..nd).rev() {
            idx[d] += 1;
            if idx[d] < shape[d] {
                break;
            }
            idx[d] = 0;
        }
    }
    out
}

/// Reads a `[time, lat, lon]` (or `[lat, lon]`) field; `sel.lat` must hold its latitudes.
pub fn read_field(path: &Path, sel: &Selection) -> Result<Field> {
    let arr = read_array(path)?;
    let lat = sel.lat.clone().ok_or_else(|| {
        Error::InvalidArgument(format!("{}: a .npy field needs its latitudes (--lat LAT.npy, degrees)", path.display()))
    })?;
    let (n_lat, n_lon) = match arr.shape.as_slice() {
        [_, y, x] | [y, x] => (*y, *x),
        s => return Err(npy_err(path, format!("shape {s:?}; expected [time, lat, lon]"))),
    };
    if n_lat != lat.len() {
        return Err(npy_err(path, format!("{n_lat} latitudes in the array but {} in --lat", lat.len())));
    }
    check_latitudes(&lat).map_err(|e| npy_err(path, e.to_string()))?;
    let lon = (0..n_lon).map(|j| j as f64 * 360.0 / n_lon as f64).collect();
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let mut field = Field::new(sel.var.clone().unwrap_or(name), None, LatLonGrid { lat, lon }, arr.values)?;
    field.source = path.to_path_buf();
    Ok(field)
}

/// Reads a 1-D coordinate array (latitudes) as f64.
pub fn read_coordinate(path: &Path) -> Result<Vec<f64>> {
    let arr = read_array(path)?;
    if arr.shape.len() != 1 {
        return Err(npy_err(path, format!("shape {:?}; a coordinate is 1-D", arr.shape)));
    }
    Ok(arr.values.to_f64())
}

/// Writes values of the given shape as `.npy` (C order, little endian), atomically.
pub fn write_array(path: &Path, shape: &[usize], values: &Values) -> Result<()> {
    let (descr, width) = match values {
        Values::F32(_) => ("<f4", 4),
        Values::F64(_) => ("<f8", 8),
    };
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Pad so that the data starts at a multiple of 64 bytes; the header ends with a newline.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + values.len() * width);
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    match values {
        Values::F32(v) => v.iter().for_each(|x| bytes.extend_from_slice(&x.to_le_bytes())),
        Values::F64(v) => v.iter().for_each(|x| bytes.extend_from_slice(&x.to_le_bytes())),
    }
    pbdl_core::io::write_atomic(path, |w| w.write_all(&bytes))
        .map_err(|e| Error::Io { file: path.to_path_buf(), source: std::io::Error::other(e.to_string()) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_fortran_order() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let v = Values::F64((0..6).map(|x| x as f64).collect());
        write_array(&p, &[2, 3], &v).unwrap();
        let a = read_array(&p).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.values, v);
        // column-major [[0,1,2],[3,4,5]] is stored 0,3,1,4,2,5
        assert_eq!(to_c_order(&[0, 3, 1, 4, 2, 5], &[2, 3]), vec![0, 1, 2, 3, 4, 5]);
        assert!(parse_array(b"not an npy file").is_err());
    }
}
