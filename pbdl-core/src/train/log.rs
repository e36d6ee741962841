//! Scalar logs (loss, learning rate, gradient norm, ...) as CSV, JSON lines or a JSON array.
//!
//! A [`ScalarLog`] is a table: a `step` column plus named columns that appear as they are first
//! logged (a row may leave a column empty). Bound to a file with [`ScalarLog::open`], every
//! [`ScalarLog::log`] reaches the file at once, and no write loses earlier data:
//!
//! * opening an existing log reads its rows and keeps them (resuming a run appends to it);
//! * [`ScalarLog::save`] refuses to replace a file that holds rows this log does not;
//! * a CSV or JSON-lines row is appended to the file; when the file has to be rewritten (a new
//!   CSV column, or any row of a JSON array) the new content goes to a temporary file that then
//!   replaces the old one, so a crash leaves the old or the new file, never a half-written one.
//!
//! The format follows the extension: `.csv`, `.jsonl` / `.ndjson` (one object per line) or
//! `.json` (one array, rewritten on every row: prefer the others for long runs). Values are
//! written so that they read back bit-for-bit; NaN and infinities are written as `NaN`, `inf`,
//! `-inf` (in JSON as strings), so a diverged loss is logged as such.
//!
//! ```
//! use pbdl_core::train::ScalarLog;
//!
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("train.csv");
//! let mut log = ScalarLog::open(&path)?;
//! log.log(0, &[("loss", 1.5), ("lr", 1e-3)])?;
//! log.log(1, &[("loss", 0.75), ("lr", 1e-3)])?;
//! assert_eq!(std::fs::read_to_string(&path).unwrap(), "step,loss,lr\n0,1.5,0.001\n1,0.75,0.001\n");
//!
//! let resumed = ScalarLog::open(&path)?; // earlier rows are kept
//! assert_eq!(resumed.column("loss"), vec![(0, 1.5), (1, 0.75)]);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use serde_json::Value;
use std::fmt::Write as _;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The file format of a [`ScalarLog`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFormat {
    /// Comma-separated, header `step,<columns..>`; a missing value is an empty cell.
    Csv,
    /// One JSON object per line: `{"step":0,"loss":1.5}`; a missing value is an absent key.
    JsonLines,
    /// One JSON array of such objects.
    JsonArray,
}

impl LogFormat {
    /// The format for a path's extension: `csv`, `jsonl` / `ndjson` or `json`.
    pub fn from_path(path: &Path) -> Result<Self> {
        match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
            Some("csv") => Ok(LogFormat::Csv),
            Some("jsonl" | "ndjson") => Ok(LogFormat::JsonLines),
            Some("json") => Ok(LogFormat::JsonArray),
            _ => Err(Error::Format {
                path: path.to_path_buf(),
                reason: "unknown log format; name the file *.csv, *.jsonl or *.json".into(),
            }),
        }
    }
}

/// One row of a [`ScalarLog`]: the step and one optional value per column.
#[derive(Clone, Debug, PartialEq)]
pub struct LogRow {
    /// The training step.
    pub step: u64,
    /// Values in the order of [`ScalarLog::columns`]; may be shorter (missing trailing values).
    pub values: Vec<Option<f64>>,
}

impl LogRow {
    /// The value of column `index`, if present.
    pub fn get(&self, index: usize) -> Option<f64> {
        self.values.get(index).copied().flatten()
    }
}

/// A table of scalars per step, optionally bound to a file; see the module docs.
#[derive(Clone, Debug, Default)]
pub struct ScalarLog {
    columns: Vec<String>,
    rows: Vec<LogRow>,
    file: Option<(PathBuf, LogFormat)>,
    /// Number of columns in the CSV header currently on disk.
    header_len: usize,
}

impl ScalarLog {
    /// An empty log kept in memory; write it with [`ScalarLog::save`].
    pub fn new() -> Self {
        Self::default()
    }

    /// A log bound to `path`: its rows are read if the file exists (and kept), and every later
    /// [`ScalarLog::log`] writes through to it. The format follows the extension.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let format = LogFormat::from_path(path)?;
        let mut log = if path.exists() { Self::read(path)? } else { Self::new() };
        log.header_len = log.columns.len();
        log.file = Some((path.to_path_buf(), format));
        Ok(log)
    }

    /// Opens the log of a run that resumes at step `resume_at` (its checkpoint's step), like
    /// [`ScalarLog::open`], but first cuts the file back to the rows of steps before
    /// `resume_at`: the resumed run logs the later steps again, and the file then reads as if
    /// the run had never stopped. A torn last line (the process was killed while appending
    /// it) is dropped too, and columns left without values are removed. The cut file replaces
    /// the old one atomically.
    ///
    /// ```
    /// use pbdl_core::train::ScalarLog;
    ///
    /// let dir = tempfile::tempdir().unwrap();
    /// let path = dir.path().join("loss.csv");
    /// // Steps 0..3 logged, the last row torn by a kill; the checkpoint is at step 2.
    /// std::fs::write(&path, "step,loss\n0,1.5\n1,1.25\n2,1.0\n3,0.7").unwrap();
    /// let mut log = ScalarLog::open_resumed(&path, 2)?;
    /// log.log(2, &[("loss", 1.0)])?;
    /// assert_eq!(std::fs::read_to_string(&path).unwrap(), "step,loss\n0,1.5\n1,1.25\n2,1.0\n");
    /// # Ok::<(), pbdl_core::Error>(())
    /// ```
    pub fn open_resumed(path: impl AsRef<Path>, resume_at: u64) -> Result<Self> {
        let path = path.as_ref();
        let format = LogFormat::from_path(path)?;
        if !path.exists() {
            return Self::open(path);
        }
        let bytes = fs::read(path).map_err(|e| Error::io(path, e))?;
        let text = String::from_utf8_lossy(&bytes);
        // Rows are appended one `write` each and end in a newline; a JSON array is only ever
        // replaced whole.
        let complete = match format {
            LogFormat::JsonArray => &text[..],
            _ => text.rfind('\n').map_or("", |i| &text[..=i]),
        };
        let mut log = Self::parse(path, format, complete)?;
        let rows = log.rows.len();
        log.rows.retain(|r| r.step < resume_at);
        let used: Vec<bool> = (0..log.columns.len()).map(|i| log.rows.iter().any(|r| r.get(i).is_some())).collect();
        let cut = rows != log.rows.len() || complete.len() != text.len() || used.contains(&false);
        if used.contains(&false) {
            let keep: Vec<usize> = (0..used.len()).filter(|&i| used[i]).collect();
            log.columns = keep.iter().map(|&i| log.columns[i].clone()).collect();
            for r in &mut log.rows {
                r.values = keep.iter().map(|&i| r.get(i)).collect();
            }
        }
        if cut {
            write_atomic(path, &log.render(format))?;
        }
        log.header_len = log.columns.len();
        log.file = Some((path.to_path_buf(), format));
        Ok(log)
    }

    /// Reads a log file (format by extension) into memory, not bound to the file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let format = LogFormat::from_path(path)?;
        let text = fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::parse(path, format, &text)
    }

    /// Parses the text of the log file `path` (named in errors).
    fn parse(path: &Path, format: LogFormat, text: &str) -> Result<Self> {
        let mut log = Self::new();
        match format {
            LogFormat::Csv => log.parse_csv(path, text)?,
            LogFormat::JsonLines => {
                for (i, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
                    let mut p = JsonParser::new(line);
                    let rec = p.object().and_then(|r| p.end().map(|_| r)).map_err(|e| format_err(path, i + 1, e))?;
                    log.push_record(path, i + 1, rec)?;
                }
            }
            LogFormat::JsonArray => {
                if !text.trim().is_empty() {
                    let recs = JsonParser::new(text).array().map_err(|e| Error::Format {
                        path: path.to_path_buf(),
                        reason: format!("not a JSON array of flat objects: {e}; fix or move the file"),
                    })?;
                    for (i, rec) in recs.into_iter().enumerate() {
                        log.push_record(path, i + 1, rec)?;
                    }
                }
            }
        }
        Ok(log)
    }

    /// Column names (without `step`), in order of first appearance.
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// All rows, in the order logged.
    pub fn rows(&self) -> &[LogRow] {
        &self.rows
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The file the log writes through to, if any.
    pub fn path(&self) -> Option<&Path> {
        self.file.as_ref().map(|(p, _)| p.as_path())
    }

    /// `(step, value)` of every row that has a value in column `name` (empty if no such column).
    pub fn column(&self, name: &str) -> Vec<(u64, f64)> {
        let Some(i) = self.columns.iter().position(|c| c == name) else { return Vec::new() };
        self.rows.iter().filter_map(|r| r.get(i).map(|v| (r.step, v))).collect()
    }

    /// The last value logged in column `name`.
    pub fn last(&self, name: &str) -> Option<f64> {
        let i = self.columns.iter().position(|c| c == name)?;
        self.rows.iter().rev().find_map(|r| r.get(i))
    }

    /// Adds a row `step` with the named values (new names become new columns) and, when bound
    /// to a file, writes it there before returning. Log all scalars of a step in one call.
    pub fn log(&mut self, step: u64, values: &[(&str, f64)]) -> Result<()> {
        for (k, (name, _)) in values.iter().enumerate() {
            check_name(name)?;
            if values[..k].iter().any(|(n, _)| n == name) {
                return Err(Error::invalid("ScalarLog::log", "values", format!("column `{name}` is given twice")));
            }
        }
        for (name, _) in values {
            if !self.columns.iter().any(|c| c == name) {
                self.columns.push(name.to_string());
            }
        }
        let mut row = LogRow { step, values: vec![None; self.columns.len()] };
        for (name, v) in values {
            let i = self.columns.iter().position(|c| c == name).expect("added above");
            row.values[i] = Some(*v);
        }
        self.rows.push(row);
        if let Err(e) = self.write_through() {
            // Keep memory and file in step: a row that did not reach the file is not kept.
            self.rows.pop();
            return Err(e);
        }
        Ok(())
    }

    /// Writes the whole log to `path` (format by extension), replacing the file atomically.
    ///
    /// An existing file is only replaced when its rows are the first rows of this log (saving
    /// again after more steps); otherwise this is an error, so that no earlier data is lost.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = self.render(LogFormat::from_path(path)?);
        if path.exists() {
            let old = Self::read(path)?;
            if let Some(i) = (0..old.len()).find(|&i| !self.row_extends(i, &old)) {
                return Err(Error::Format {
                    path: path.to_path_buf(),
                    reason: format!(
                        "holds a different log (row {} differs from this one); saving would lose it: \
                         pick another path, or use ScalarLog::open to append to it",
                        i + 1
                    ),
                });
            }
        }
        write_atomic(path, &text)
    }

    /// Whether row `i` of `self` has the step and every value of row `i` of `old`.
    fn row_extends(&self, i: usize, old: &ScalarLog) -> bool {
        let (Some(mine), Some(theirs)) = (self.rows.get(i), old.rows.get(i)) else { return false };
        mine.step == theirs.step
            && old.columns.iter().enumerate().all(|(c, name)| {
                let here = self.columns.iter().position(|n| n == name).and_then(|j| mine.get(j));
                match (here, theirs.get(c)) {
                    (Some(a), Some(b)) => a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                    (a, b) => a.is_none() && b.is_none(),
                }
            })
    }

    fn write_through(&mut self) -> Result<()> {
        let Some((path, format)) = self.file.clone() else { return Ok(()) };
        let row = self.rows.last().expect("called after a push");
        match format {
            LogFormat::Csv if self.header_len == self.columns.len() && self.header_len > 0 && path.exists() => {
                append(&path, &self.csv_line(row))
            }
            LogFormat::Csv => {
                // New file or new column: the header changes, so rewrite everything.
                write_atomic(&path, &self.render(LogFormat::Csv))?;
                self.header_len = self.columns.len();
                Ok(())
            }
            LogFormat::JsonLines => append(&path, &(self.json_object(row) + "\n")),
            LogFormat::JsonArray => write_atomic(&path, &self.render(LogFormat::JsonArray)),
        }
    }

    fn render(&self, format: LogFormat) -> String {
        match format {
            LogFormat::Csv => {
                let mut s = String::from("step");
                for c in &self.columns {
                    s.push(',');
                    s.push_str(c);
                }
                s.push('\n');
                for r in &self.rows {
                    s.push_str(&self.csv_line(r));
                }
                s
            }
            LogFormat::JsonLines => self.rows.iter().map(|r| self.json_object(r) + "\n").collect(),
            LogFormat::JsonArray => {
                let body: Vec<String> = self.rows.iter().map(|r| self.json_object(r)).collect();
                if body.is_empty() {
                    "[]\n".into()
                } else {
                    format!("[\n{}\n]\n", body.join(",\n"))
                }
            }
        }
    }

    fn csv_line(&self, row: &LogRow) -> String {
        let mut s = row.step.to_string();
        for i in 0..self.columns.len() {
            s.push(',');
            if let Some(v) = row.get(i) {
                s.push_str(&fmt_f64(v));
            }
        }
        s.push('\n');
        s
    }

    fn json_object(&self, row: &LogRow) -> String {
        let mut s = format!("{{\"step\":{}", row.step);
        for (i, name) in self.columns.iter().enumerate() {
            if let Some(v) = row.get(i) {
                let v = if v.is_finite() { fmt_f64(v) } else { format!("\"{}\"", fmt_f64(v)) };
                let _ = write!(s, ",{}:{v}", Value::String(name.clone()));
            }
        }
        s.push('}');
        s
    }

    fn parse_csv(&mut self, path: &Path, text: &str) -> Result<()> {
        let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else { return Ok(()) };
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        if names[0] != "step" {
            return Err(format_err(path, 1, format!("header must start with `step`, found `{}`", names[0])));
        }
        self.columns = names[1..].iter().map(|s| s.to_string()).collect();
        for (i, line) in lines {
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != names.len() {
                return Err(format_err(path, i + 1, format!("{} cells, the header has {}", cells.len(), names.len())));
            }
            let step = cells[0]
                .parse::<u64>()
                .map_err(|_| format_err(path, i + 1, format!("step `{}` is not a non-negative integer", cells[0])))?;
            let values = cells[1..]
                .iter()
                .map(|c| {
                    if c.is_empty() {
                        Ok(None)
                    } else {
                        c.parse::<f64>()
                            .map(Some)
                            .map_err(|_| format_err(path, i + 1, format!("`{c}` is not a number")))
                    }
                })
                .collect::<Result<Vec<_>>>()?;
            self.rows.push(LogRow { step, values });
        }
        Ok(())
    }

    fn push_record(&mut self, path: &Path, line: usize, rec: Vec<(String, Scalar)>) -> Result<()> {
        let mut step = None;
        let mut pairs = Vec::new();
        for (k, v) in rec {
            if k == "step" {
                let (Scalar::Number(t) | Scalar::Str(t) | Scalar::Other(t)) = &v else {
                    return Err(format_err(path, line, "step is null".into()));
                };
                step = t.parse::<u64>().ok().filter(|_| matches!(v, Scalar::Number(_)));
                if step.is_none() {
                    return Err(format_err(path, line, format!("step {t} is not a non-negative integer")));
                }
                continue;
            }
            let (text, value) = match &v {
                // Rust's parser rounds correctly, so the shortest form written reads back exactly.
                Scalar::Number(t) | Scalar::Str(t) | Scalar::Other(t) => (t, t.parse::<f64>().ok()),
                Scalar::Null => continue,
            };
            let Some(value) = value.filter(|_| !matches!(v, Scalar::Other(_))) else {
                return Err(format_err(path, line, format!("`{k}` = {text} is not a number")));
            };
            pairs.push((k, value));
        }
        let Some(step) = step else {
            return Err(format_err(path, line, "record has no `step`".into()));
        };
        for (k, _) in &pairs {
            if !self.columns.contains(k) {
                self.columns.push(k.clone());
            }
        }
        let mut values = vec![None; self.columns.len()];
        for (k, v) in pairs {
            let i = self.columns.iter().position(|c| *c == k).expect("added above");
            values[i] = Some(v);
        }
        self.rows.push(LogRow { step, values });
        Ok(())
    }
}

fn format_err(path: &Path, line: usize, reason: String) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        reason: format!("record {line}: {reason}; fix or move the file, or log to a new one"),
    }
}

fn check_name(name: &str) -> Result<()> {
    if name.is_empty() || name == "step" || name.contains([',', '"', '\n', '\r']) || name.trim() != name {
        return Err(Error::invalid(
            "ScalarLog::log",
            "values",
            format!("column name {name:?} is not allowed; use a non-empty name other than `step` without commas, quotes, newlines or surrounding spaces"),
        ));
    }
    Ok(())
}

/// Shortest text that parses back to the same `f64` (Rust's `Debug`: `0.001`, `1e-7`, `NaN`).
fn fmt_f64(v: f64) -> String {
    format!("{v:?}")
}

fn append(path: &Path, text: &str) -> Result<()> {
    let mut f = fs::OpenOptions::new().append(true).create(true).open(path).map_err(|e| Error::io(path, e))?;
    // One write call per row, so rows are not interleaved or split by our own buffering.
    f.write_all(text.as_bytes()).map_err(|e| Error::io(path, e))
}

/// Writes `text` atomically ([`crate::io::write_atomic`]: a hidden temporary file that readers
/// and [`super::remove_interrupted_writes`] recognise, then one rename).
fn write_atomic(path: &Path, text: &str) -> Result<()> {
    crate::io::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// A scalar of a flat JSON object, numbers kept as their text.
#[derive(Debug)]
enum Scalar {
    Number(String),
    Str(String),
    Null,
    Other(String),
}

/// A parser for the JSON the logs need: flat objects of scalars and arrays of them. It keeps
/// key order and number text (serde_json, without its `float_roundtrip` feature, may round the
/// last bit of a parsed `f64`).
struct JsonParser<'a> {
    s: &'a str,
    pos: usize,
}

impl<'a> JsonParser<'a> {
    fn new(s: &'a str) -> Self {
        Self { s, pos: 0 }
    }

    fn ws(&mut self) {
        let rest = &self.s[self.pos..];
        self.pos += rest.len() - rest.trim_start().len();
    }

    fn peek(&mut self) -> Option<char> {
        self.ws();
        self.s[self.pos..].chars().next()
    }

    fn expect(&mut self, c: char) -> std::result::Result<(), String> {
        match self.peek() {
            Some(got) if got == c => {
                self.pos += c.len_utf8();
                Ok(())
            }
            got => Err(format!("expected `{c}` at byte {}, found {got:?}", self.pos)),
        }
    }

    fn end(&mut self) -> std::result::Result<(), String> {
        match self.peek() {
            None => Ok(()),
            Some(c) => Err(format!("unexpected `{c}` at byte {} after the object", self.pos)),
        }
    }

    fn array(&mut self) -> std::result::Result<Vec<Vec<(String, Scalar)>>, String> {
        self.expect('[')?;
        let mut out = Vec::new();
        if self.peek() == Some(']') {
            self.pos += 1;
        } else {
            loop {
                out.push(self.object()?);
                match self.peek() {
                    Some(',') => self.pos += 1,
                    _ => {
                        self.expect(']')?;
                        break;
                    }
                }
            }
        }
        self.end()?;
        Ok(out)
    }

    fn object(&mut self) -> std::result::Result<Vec<(String, Scalar)>, String> {
        self.expect('{')?;
        let mut out = Vec::new();
        if self.peek() == Some('}') {
            self.pos += 1;
            return Ok(out);
        }
        loop {
            if self.peek() != Some('"') {
                return Err(format!("expected a quoted key at byte {}", self.pos));
            }
            let key = self.string()?;
            self.expect(':')?;
            let value = match self.peek() {
                Some('"') => Scalar::Str(self.string()?),
                Some(_) => {
                    // A bare token: number, null, true, false (nested values are not scalars).
                    let rest = &self.s[self.pos..];
                    let len = rest.find(|c: char| c == ',' || c == '}' || c.is_whitespace()).unwrap_or(rest.len());
                    let tok = &rest[..len];
                    self.pos += len;
                    match tok {
                        "null" => Scalar::Null,
                        t if t.starts_with(|c: char| c == '-' || c.is_ascii_digit()) => Scalar::Number(t.to_string()),
                        t => Scalar::Other(t.to_string()),
                    }
                }
                None => return Err("unexpected end inside an object".into()),
            };
            out.push((key, value));
            match self.peek() {
                Some(',') => self.pos += 1,
                _ => {
                    self.expect('}')?;
                    return Ok(out);
                }
            }
        }
    }

    /// A quoted string starting at `pos`, unescaped by serde_json.
    fn string(&mut self) -> std::result::Result<String, String> {
        let bytes = self.s.as_bytes();
        let start = self.pos;
        let mut i = start + 1;
        while i < bytes.len() && bytes[i] != b'"' {
            i += if bytes[i] == b'\\' { 2 } else { 1 };
        }
        if i >= bytes.len() {
            return Err(format!("unterminated string at byte {start}"));
        }
        self.pos = i + 1;
        serde_json::from_str(&self.s[start..=i]).map_err(|e| format!("bad string at byte {start}: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floats_print_in_shortest_round_trip_form() {
        for v in [0.001, 1e-7, 1.0, -2.5e300, f64::MIN_POSITIVE, 0.1 + 0.2, f64::NAN, f64::INFINITY, f64::NEG_INFINITY]
        {
            let back: f64 = fmt_f64(v).parse().unwrap();
            assert!(back.to_bits() == v.to_bits() || (v.is_nan() && back.is_nan()), "{v} -> {}", fmt_f64(v));
        }
        assert_eq!(fmt_f64(0.001), "0.001");
    }

    #[test]
    fn bad_column_names_are_rejected_with_advice() {
        let mut log = ScalarLog::new();
        for bad in ["", "step", "a,b", "q\"", " x"] {
            let e = log.log(0, &[(bad, 1.0)]).unwrap_err().to_string();
            assert!(e.contains("not allowed"), "{e}");
        }
        assert!(log.log(0, &[("a", 1.0), ("a", 2.0)]).is_err());
        assert!(log.is_empty());
    }

    #[test]
    fn json_parser_reads_foreign_spacing_escapes_and_exact_numbers() {
        let text =
            " [ {\"step\" : 1 , \"lo\\\"ss\" : 0.30000000000000004, \"x\": null},\n{\"step\":2,\"lr\":\"-inf\"} ] ";
        let recs = JsonParser::new(text).array().unwrap();
        assert_eq!(recs.len(), 2);
        assert_eq!(recs[0][1].0, "lo\"ss");
        assert!(matches!(&recs[0][1].1, Scalar::Number(t) if t.parse::<f64>().unwrap() == 0.1 + 0.2));
        assert!(matches!(recs[0][2].1, Scalar::Null));
        assert!(matches!(&recs[1][1].1, Scalar::Str(t) if t == "-inf"));
        assert!(matches!(JsonParser::new("{\"step\":1,\"a\":[1]}").object().unwrap()[1].1, Scalar::Other(_)));
        assert!(JsonParser::new("{\"step\":1").object().is_err());
        assert!(JsonParser::new("[{}] x").array().is_err());
    }

    #[test]
    fn unknown_extension_is_a_format_error() {
        assert!(matches!(ScalarLog::open("run.txt"), Err(Error::Format { .. })));
    }
}
