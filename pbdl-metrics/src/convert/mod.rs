//! Conversion of the official LSiM / VolSiM checkpoints (legacy PyTorch `.pth` pickles) into the
//! safetensors layout that [`crate::weights`] reads; the library side of
//! `cargo xtask weights convert IN.pth OUT.safetensors`.
//!
//! The official files are `torch.save`d dicts with the keys `stateDict` (the network's
//! `OrderedDict`), `normAcc` and `normM2` (lists of the per-layer mean and M2 maps), `normCount`
//! (a list of counts) and, for VolSiM, `hyperparams` (a dict). They become
//!
//! | safetensors | from |
//! |---|---|
//! | `model.<key>` | `stateDict[key]` |
//! | `norm.mean.<i>`, `norm.m2.<i>` | `normAcc[i]`, `normM2[i]` |
//! | metadata `normCount` | `normCount` as a JSON list |
//! | metadata `hyperparams` | `hyperparams` as JSON; for LSiM, whose file has none, the constructor defaults of the official `DistanceModel` used with it: `{"baseType": "lsim", "featureDistance": "L2", "normMode": "normDist"}` |
//!
//! Values are copied bit for bit (same dtype, row-major); JSON is written as Python's
//! `json.dumps` writes it (`", "` and `": "` separators, floats as `repr`), so the metadata
//! strings equal those of the reference conversion.
//!
//! The pickle reader ([`pickle`]) and the legacy container ([`legacy`]) are general enough for
//! other legacy checkpoints; [`convert_checkpoint`] is specific to the metric files.

pub mod legacy;
pub mod pickle;

pub use legacy::{LegacyCheckpoint, RawTensor, StorageDtype};
pub use pickle::Value;

use crate::{Error, Result};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// The `hyperparams` metadata written for LSiM checkpoints, which store none: the defaults of
/// the official `DistanceModel(baseType="lsim")` that loads them.
pub const LSIM_DEFAULT_HYPERPARAMS: &str = r#"{"baseType": "lsim", "featureDistance": "L2", "normMode": "normDist"}"#;

/// A converted checkpoint: named tensors and string metadata.
#[derive(Clone, Debug)]
pub struct Converted {
    /// `(name, tensor)` in the order they appear in the checkpoint.
    pub tensors: Vec<(String, RawTensor)>,
    /// Metadata (`normCount`, `hyperparams`).
    pub metadata: HashMap<String, String>,
}

impl Converted {
    /// The tensor `name`, if present.
    pub fn tensor(&self, name: &str) -> Option<&RawTensor> {
        self.tensors.iter().find(|(n, _)| n == name).map(|(_, t)| t)
    }

    /// Writes the tensors and metadata as a safetensors file (atomically: a failed write leaves
    /// no partial file).
    pub fn write_safetensors(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let bad = |reason: String| Error::Weights { path: path.to_path_buf(), reason };
        let views = self
            .tensors
            .iter()
            .map(|(n, t)| {
                safetensors::tensor::TensorView::new(t.dtype.safetensors(), t.shape.clone(), &t.data)
                    .map(|v| (n.clone(), v))
                    .map_err(|e| bad(format!("tensor `{n}`: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        let bytes = safetensors::serialize(views, Some(self.metadata.clone()))
            .map_err(|e| bad(format!("cannot serialise ({e})")))?;
        pbdl_core::io::write_atomic(path, |w| std::io::Write::write_all(w, &bytes))?;
        Ok(())
    }
}

/// Reads an official LSiM / VolSiM `.pth` file and converts it (see the module docs).
///
/// Errors: [`Error::Io`] if unreadable; [`Error::Pickle`] / [`Error::UnsupportedOpcode`] if it is
/// not a legacy checkpoint this reader understands; [`Error::Weights`] naming the key if the
/// saved dict lacks `stateDict`, `normAcc`, `normM2` or `normCount` or holds something else there.
pub fn convert_file(path: impl AsRef<Path>) -> Result<Converted> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    convert_checkpoint(&bytes, path)
}

/// [`convert_file`] on bytes already in memory; `path` only names the file in errors.
pub fn convert_checkpoint(bytes: &[u8], path: &Path) -> Result<Converted> {
    let ckpt = LegacyCheckpoint::parse(bytes)?;
    let bad = |reason: String| Error::Weights { path: path.to_path_buf(), reason };
    let root = &ckpt.object;
    let Value::Dict(_) = root else {
        return Err(bad(format!("the saved object is a {}, expected the metric's dict", root.kind())));
    };
    let key_list = || match root {
        Value::Dict(items) => items.iter().map(|(k, _)| format!("{k:?}")).collect::<Vec<_>>().join(", "),
        _ => String::new(),
    };
    let need =
        |k: &str| root.get(k).ok_or_else(|| bad(format!("the checkpoint has no `{k}` (its keys: {})", key_list())));
    let mut tensors = Vec::new();
    let Value::Dict(state) = need("stateDict")? else {
        return Err(bad("`stateDict` is not a dict".into()));
    };
    for (k, v) in state {
        let name = k.as_str().ok_or_else(|| bad(format!("a `stateDict` key is a {}", k.kind())))?;
        if !LegacyCheckpoint::is_tensor(v) {
            return Err(bad(format!("`stateDict[{name}]` is a {}, expected a tensor", v.kind())));
        }
        tensors.push((format!("model.{name}"), ckpt.tensor(v)?));
    }
    let mut layers = None;
    for (key, prefix) in [("normAcc", "norm.mean"), ("normM2", "norm.m2")] {
        let list = need(key)?.as_seq().ok_or_else(|| bad(format!("`{key}` is not a list")))?;
        if layers.is_some_and(|n| n != list.len()) {
            return Err(bad(format!("`normAcc` and `normM2` differ in length ({:?} vs {})", layers, list.len())));
        }
        layers = Some(list.len());
        for (i, v) in list.iter().enumerate() {
            if !LegacyCheckpoint::is_tensor(v) {
                return Err(bad(format!("`{key}[{i}]` is a {}, expected a tensor", v.kind())));
            }
            tensors.push((format!("{prefix}.{i}"), ckpt.tensor(v)?));
        }
    }
    let mut metadata = HashMap::new();
    let counts = need("normCount")?;
    if counts.as_seq().is_none_or(|c| Some(c.len()) != layers) {
        return Err(bad(format!("`normCount` is not a list of {} counts", layers.unwrap_or(0))));
    }
    metadata.insert("normCount".into(), python_json(counts).map_err(bad)?);
    match root.get("hyperparams") {
        Some(h) => {
            metadata.insert("hyperparams".into(), python_json(h).map_err(bad)?);
        }
        None if tensors.iter().any(|(n, _)| n == "model.lin0.1.weight") => {
            metadata.insert("hyperparams".into(), LSIM_DEFAULT_HYPERPARAMS.into());
        }
        None => {}
    }
    Ok(Converted { tensors, metadata })
}

/// A value as Python's `json.dumps` (default arguments) writes it: `", "` / `": "` separators,
/// non-ASCII characters escaped, floats as `repr`, tuples as lists.
///
/// Errors: a message naming the value kind JSON cannot hold (tensors, globals, ...).
pub fn python_json(v: &Value) -> std::result::Result<String, String> {
    let mut s = String::new();
    write_json(v, &mut s)?;
    Ok(s)
}

fn write_json(v: &Value, s: &mut String) -> std::result::Result<(), String> {
    match v {
        Value::None => s.push_str("null"),
        Value::Bool(b) => s.push_str(if *b { "true" } else { "false" }),
        Value::Int(i) => write!(s, "{i}").expect("write to String"),
        Value::Float(f) => s.push_str(&python_float_repr(*f)),
        Value::Str(t) => write_json_str(t, s),
        Value::Tuple(items) | Value::List(items) => {
            s.push('[');
            for (i, x) in items.iter().enumerate() {
                if i > 0 {
                    s.push_str(", ");
                }
                write_json(x, s)?;
            }
            s.push(']');
        }
        Value::Dict(items) => {
            s.push('{');
            for (i, (k, x)) in items.iter().enumerate() {
                if i > 0 {
                    s.push_str(", ");
                }
                // json.dumps turns int, float, bool and None keys into strings.
                match k {
                    Value::Str(t) => write_json_str(t, s),
                    Value::Int(_) | Value::Float(_) | Value::Bool(_) | Value::None => {
                        let mut inner = String::new();
                        write_json(k, &mut inner)?;
                        write_json_str(&inner, s);
                    }
                    other => return Err(format!("a dict key of kind {} cannot be JSON", other.kind())),
                }
                s.push_str(": ");
                write_json(x, s)?;
            }
            s.push('}');
        }
        other => return Err(format!("a {} cannot be written as JSON metadata", other.kind())),
    }
    Ok(())
}

fn write_json_str(t: &str, s: &mut String) {
    s.push('"');
    for c in t.chars() {
        match c {
            '"' => s.push_str("\\\""),
            '\\' => s.push_str("\\\\"),
            '\n' => s.push_str("\\n"),
            '\r' => s.push_str("\\r"),
            '\t' => s.push_str("\\t"),
            '\u{8}' => s.push_str("\\b"),
            '\u{c}' => s.push_str("\\f"),
            c if (c as u32) < 0x20 || (c as u32) > 0x7e => {
                let mut buf = [0u16; 2];
                for u in c.encode_utf16(&mut buf) {
                    write!(s, "\\u{u:04x}").expect("write to String");
                }
            }
            c => s.push(c),
        }
    }
    s.push('"');
}

/// Python's `repr(float)`: the shortest digits that round-trip, positional for decimal
/// exponents -4 ..= 15 (always with a fractional part), otherwise `d.ddde±XX`.
pub fn python_float_repr(f: f64) -> String {
    if f.is_nan() {
        return "NaN".into();
    }
    if f.is_infinite() {
        return if f > 0.0 { "Infinity".into() } else { "-Infinity".into() };
    }
    if f == 0.0 {
        return if f.is_sign_negative() { "-0.0".into() } else { "0.0".into() };
    }
    // Rust's `{:e}` gives the shortest round-trip digits: "-1.2345e-5".
    let e = format!("{f:e}");
    let (mant, exp) = e.split_once('e').expect("`{:e}` has an exponent");
    let exp: i32 = exp.parse().expect("integer exponent");
    let (sign, mant) = mant.strip_prefix('-').map_or(("", mant), |m| ("-", m));
    let digits: String = mant.chars().filter(|c| *c != '.').collect();
    if (-4..16).contains(&exp) {
        let point = exp + 1; // digits before the decimal point
        let body = if point <= 0 {
            format!("0.{}{}", "0".repeat((-point) as usize), digits)
        } else if point as usize >= digits.len() {
            format!("{}{}.0", digits, "0".repeat(point as usize - digits.len()))
        } else {
            format!("{}.{}", &digits[..point as usize], &digits[point as usize..])
        };
        format!("{sign}{body}")
    } else {
        let m = if digits.len() > 1 { format!("{}.{}", &digits[..1], &digits[1..]) } else { digits };
        format!("{sign}{m}e{}{:02}", if exp < 0 { '-' } else { '+' }, exp.abs())
    }
}
