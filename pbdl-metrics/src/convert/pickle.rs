//! A small pickle reader: the opcodes of protocols 0-2 that legacy PyTorch checkpoints use, plus a
//! few cheap ones of protocols 3-4 (bytes, short strings, `MEMOIZE`, `FRAME`).
//!
//! It evaluates nothing: a global is kept as its name ([`Value::Global`]), a call as
//! [`Value::Reduce`], a persistent id as [`Value::PersistentId`]; the caller interprets them. The
//! one exception is `collections.OrderedDict()`, which becomes a [`Value::Dict`] so that the
//! following `SETITEMS` can fill it. Any other opcode is an [`Error::UnsupportedOpcode`] naming it.

use crate::{Error, Result};
use std::collections::HashMap;

/// A value of the pickle machine.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// Python `None`.
    None,
    /// `True` / `False`.
    Bool(bool),
    /// An integer (`LONG1` values up to 16 bytes).
    Int(i128),
    /// A float.
    Float(f64),
    /// A text string (also Python 2 byte strings, read as Latin-1).
    Str(String),
    /// A `bytes` object.
    Bytes(Vec<u8>),
    /// A tuple.
    Tuple(Vec<Value>),
    /// A list.
    List(Vec<Value>),
    /// A `dict` or `collections.OrderedDict`, in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A reference to `module.name` (`GLOBAL`), not resolved.
    Global {
        /// The module, e.g. `torch._utils`.
        module: String,
        /// The name in it, e.g. `_rebuild_tensor_v2`.
        name: String,
    },
    /// A call `callable(*args)` (`REDUCE`), not evaluated.
    Reduce {
        /// What is called (usually a [`Value::Global`]).
        callable: Box<Value>,
        /// The argument tuple.
        args: Box<Value>,
    },
    /// An object whose state was set with `BUILD` (other than a dict, whose state is dropped).
    Build {
        /// The object.
        object: Box<Value>,
        /// Its state.
        state: Box<Value>,
    },
    /// A persistent id (`BINPERSID`); PyTorch uses them for storages.
    PersistentId(Box<Value>),
}

impl Value {
    /// A short name of the value's kind, for error messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "bool",
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Str(_) => "str",
            Value::Bytes(_) => "bytes",
            Value::Tuple(_) => "tuple",
            Value::List(_) => "list",
            Value::Dict(_) => "dict",
            Value::Global { .. } => "global",
            Value::Reduce { .. } => "call",
            Value::Build { .. } => "object",
            Value::PersistentId(_) => "persistent id",
        }
    }

    /// The string, if this is a [`Value::Str`].
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    /// The integer, if this is a [`Value::Int`] (or a bool, as in Python).
    pub fn as_int(&self) -> Option<i128> {
        match self {
            Value::Int(i) => Some(*i),
            Value::Bool(b) => Some(*b as i128),
            _ => None,
        }
    }

    /// The items of a tuple or list.
    pub fn as_seq(&self) -> Option<&[Value]> {
        match self {
            Value::Tuple(v) | Value::List(v) => Some(v),
            _ => None,
        }
    }

    /// The entry with the string key `key`, if this is a dict.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Dict(items) => items.iter().find(|(k, _)| k.as_str() == Some(key)).map(|(_, v)| v),
            _ => None,
        }
    }
}

/// Reads one pickle from `data` starting at `*pos`, up to and including its `STOP`; `*pos` is then
/// the first byte after it (where the next pickle of a sequence starts). Error offsets count from
/// the start of `data`.
pub fn load(data: &[u8], pos: &mut usize) -> Result<Value> {
    let mut m = Machine { data, pos: *pos, stack: Vec::new(), marks: Vec::new(), memo: HashMap::new() };
    let v = m.run()?;
    *pos = m.pos;
    Ok(v)
}

/// One stack entry: the value and the memo slots that hold a copy of it (rewritten when the value
/// is changed by `SETITEMS`, `APPENDS` or `BUILD`, so that a later `BINGET` sees the filled
/// container rather than the empty one that was memoised).
struct Slot {
    value: Value,
    memo: Vec<u32>,
}

struct Machine<'a> {
    data: &'a [u8],
    pos: usize,
    stack: Vec<Slot>,
    marks: Vec<usize>,
    memo: HashMap<u32, Value>,
}

impl Machine<'_> {
    fn err(&self, offset: usize, reason: impl Into<String>) -> Error {
        Error::Pickle { offset, reason: reason.into() }
    }

    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.data.len() - self.pos < n {
            return Err(self.err(self.pos, format!("the stream ends inside an argument ({n} bytes wanted)")));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }

    fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().expect("2 bytes")))
    }

    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }

    fn line(&mut self, at: usize) -> Result<String> {
        let rest = &self.data[self.pos..];
        let n = rest.iter().position(|&b| b == b'\n').ok_or_else(|| self.err(at, "GLOBAL without a newline"))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.pos += n + 1;
        Ok(s)
    }

    fn push(&mut self, value: Value) {
        self.stack.push(Slot { value, memo: Vec::new() });
    }

    fn pop(&mut self, at: usize) -> Result<Value> {
        if self.marks.last().is_some_and(|&m| m >= self.stack.len()) {
            return Err(self.err(at, "pops across a MARK"));
        }
        self.stack.pop().map(|s| s.value).ok_or_else(|| self.err(at, "the stack is empty"))
    }

    /// The values pushed since the last MARK (which is removed).
    fn pop_mark(&mut self, at: usize) -> Result<Vec<Value>> {
        let m = self.marks.pop().ok_or_else(|| self.err(at, "no MARK to pop to"))?;
        Ok(self.stack.split_off(m).into_iter().map(|s| s.value).collect())
    }

    fn top(&mut self, at: usize) -> Result<&mut Slot> {
        if self.marks.last().is_some_and(|&m| m >= self.stack.len()) {
            return Err(self.err(at, "the object to change is hidden behind a MARK"));
        }
        let e = self.err(at, "the stack is empty");
        self.stack.last_mut().ok_or(e)
    }

    /// Copies the (changed) top of the stack into its memo slots.
    fn refresh_memo(&mut self) {
        if let Some(s) = self.stack.last() {
            for &id in &s.memo {
                self.memo.insert(id, s.value.clone());
            }
        }
    }

    fn put(&mut self, at: usize, id: u32) -> Result<()> {
        let top = self.top(at)?;
        top.memo.push(id);
        let v = top.value.clone();
        self.memo.insert(id, v);
        Ok(())
    }

    fn get(&mut self, at: usize, id: u32) -> Result<()> {
        let v = self.memo.get(&id).cloned().ok_or_else(|| self.err(at, format!("memo slot {id} was never set")))?;
        self.stack.push(Slot { value: v, memo: vec![id] });
        Ok(())
    }

    fn set_items(&mut self, at: usize, items: Vec<Value>) -> Result<()> {
        if items.len() % 2 != 0 {
            return Err(self.err(at, "SETITEMS with an odd number of keys and values"));
        }
        let top = self.top(at)?;
        let Value::Dict(d) = &mut top.value else {
            let kind = top.value.kind();
            return Err(self.err(at, format!("SETITEM(S) on a {kind}, expected a dict")));
        };
        let mut it = items.into_iter();
        while let (Some(k), Some(v)) = (it.next(), it.next()) {
            match d.iter_mut().find(|(old, _)| *old == k) {
                Some(slot) => slot.1 = v,
                None => d.push((k, v)),
            }
        }
        self.refresh_memo();
        Ok(())
    }

    fn append(&mut self, at: usize, items: Vec<Value>) -> Result<()> {
        let top = self.top(at)?;
        let Value::List(l) = &mut top.value else {
            let kind = top.value.kind();
            return Err(self.err(at, format!("APPEND(S) on a {kind}, expected a list")));
        };
        l.extend(items);
        self.refresh_memo();
        Ok(())
    }

    fn string(&mut self, at: usize, n: usize) -> Result<Value> {
        let b = self.take(n)?.to_vec();
        String::from_utf8(b).map(Value::Str).map_err(|_| self.err(at, "a text string that is not UTF-8"))
    }

    fn run(&mut self) -> Result<Value> {
        loop {
            let at = self.pos;
            let op = self.u8().map_err(|_| self.err(at, "the stream ends before STOP"))?;
            match op {
                0x80 => {
                    let proto = self.u8()?;
                    if proto > 5 {
                        return Err(self.err(at, format!("protocol {proto} is not a pickle protocol")));
                    }
                }
                0x95 => {
                    self.take(8)?; // FRAME: a length hint only
                }
                b'.' => {
                    let v = self.pop(at)?;
                    if !self.marks.is_empty() {
                        return Err(self.err(at, "STOP with an open MARK"));
                    }
                    return Ok(v);
                }
                b'(' => self.marks.push(self.stack.len()),
                b'0' => {
                    self.pop(at)?;
                }
                b'}' => self.push(Value::Dict(Vec::new())),
                b']' => self.push(Value::List(Vec::new())),
                b')' => self.push(Value::Tuple(Vec::new())),
                b't' => {
                    let v = self.pop_mark(at)?;
                    self.push(Value::Tuple(v));
                }
                b'l' => {
                    let v = self.pop_mark(at)?;
                    self.push(Value::List(v));
                }
                b'd' => {
                    let v = self.pop_mark(at)?;
                    self.push(Value::Dict(Vec::new()));
                    self.set_items(at, v)?;
                }
                0x85..=0x87 => {
                    let n = (op - 0x84) as usize;
                    let mut v = Vec::with_capacity(n);
                    for _ in 0..n {
                        v.push(self.pop(at)?);
                    }
                    v.reverse();
                    self.push(Value::Tuple(v));
                }
                b'q' => {
                    let id = self.u8()? as u32;
                    self.put(at, id)?;
                }
                b'r' => {
                    let id = self.u32()?;
                    self.put(at, id)?;
                }
                0x94 => {
                    let id = self.memo.len() as u32;
                    self.put(at, id)?;
                }
                b'h' => {
                    let id = self.u8()? as u32;
                    self.get(at, id)?;
                }
                b'j' => {
                    let id = self.u32()?;
                    self.get(at, id)?;
                }
                b'X' => {
                    let n = self.u32()? as usize;
                    let v = self.string(at, n)?;
                    self.push(v);
                }
                0x8c => {
                    let n = self.u8()? as usize;
                    let v = self.string(at, n)?;
                    self.push(v);
                }
                b'T' | b'U' => {
                    let n = if op == b'T' { self.u32()? as usize } else { self.u8()? as usize };
                    // Python 2 byte strings: Latin-1, as `encoding='latin1'` when loading.
                    let s = self.take(n)?.iter().map(|&b| b as char).collect();
                    self.push(Value::Str(s));
                }
                b'B' | b'C' => {
                    let n = if op == b'B' { self.u32()? as usize } else { self.u8()? as usize };
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b));
                }
                b'J' => {
                    let v = self.u32()? as i32;
                    self.push(Value::Int(v as i128));
                }
                b'K' => {
                    let v = self.u8()?;
                    self.push(Value::Int(v as i128));
                }
                b'M' => {
                    let v = self.u16()?;
                    self.push(Value::Int(v as i128));
                }
                0x8a | 0x8b => {
                    let n = if op == 0x8a { self.u8()? as usize } else { self.u32()? as usize };
                    if n > 16 {
                        return Err(self.err(at, format!("an integer of {n} bytes; at most 16 are supported")));
                    }
                    let b = self.take(n)?;
                    // Little-endian two's complement, sign-extended to 128 bits.
                    let fill = if b.last().is_some_and(|&x| x & 0x80 != 0) { 0xff } else { 0 };
                    let mut full = [fill; 16];
                    full[..n].copy_from_slice(b);
                    self.push(Value::Int(i128::from_le_bytes(full)));
                }
                b'N' => self.push(Value::None),
                0x88 => self.push(Value::Bool(true)),
                0x89 => self.push(Value::Bool(false)),
                b'G' => {
                    let v = f64::from_be_bytes(self.take(8)?.try_into().expect("8 bytes"));
                    self.push(Value::Float(v));
                }
                b'c' => {
                    let module = self.line(at)?;
                    let name = self.line(at)?;
                    self.push(Value::Global { module, name });
                }
                b'R' => {
                    let args = self.pop(at)?;
                    let callable = self.pop(at)?;
                    let ordered_dict = matches!(&callable, Value::Global { module, name }
                        if module == "collections" && name == "OrderedDict");
                    if ordered_dict && args == Value::Tuple(Vec::new()) {
                        self.push(Value::Dict(Vec::new()));
                    } else {
                        self.push(Value::Reduce { callable: Box::new(callable), args: Box::new(args) });
                    }
                }
                b'b' => {
                    let state = self.pop(at)?;
                    let top = self.top(at)?;
                    // A dict's state holds attributes (an OrderedDict's `_metadata`): dropped.
                    if !matches!(top.value, Value::Dict(_)) {
                        let object = std::mem::replace(&mut top.value, Value::None);
                        top.value = Value::Build { object: Box::new(object), state: Box::new(state) };
                    }
                    self.refresh_memo();
                }
                b's' => {
                    let v = self.pop(at)?;
                    let k = self.pop(at)?;
                    self.set_items(at, vec![k, v])?;
                }
                b'u' => {
                    let items = self.pop_mark(at)?;
                    self.set_items(at, items)?;
                }
                b'a' => {
                    let v = self.pop(at)?;
                    self.append(at, vec![v])?;
                }
                b'e' => {
                    let items = self.pop_mark(at)?;
                    self.append(at, items)?;
                }
                b'Q' => {
                    let pid = self.pop(at)?;
                    self.push(Value::PersistentId(Box::new(pid)));
                }
                _ => return Err(Error::UnsupportedOpcode { opcode: op, name: opcode_name(op), offset: at }),
            }
        }
    }
}

/// The name Python's `pickletools` gives an opcode byte.
pub fn opcode_name(op: u8) -> &'static str {
    match op {
        b'(' => "MARK",
        b'.' => "STOP",
        b'0' => "POP",
        b'1' => "POP_MARK",
        b'2' => "DUP",
        b'F' => "FLOAT",
        b'I' => "INT",
        b'J' => "BININT",
        b'K' => "BININT1",
        b'L' => "LONG",
        b'M' => "BININT2",
        b'N' => "NONE",
        b'P' => "PERSID",
        b'Q' => "BINPERSID",
        b'R' => "REDUCE",
        b'S' => "STRING",
        b'T' => "BINSTRING",
        b'U' => "SHORT_BINSTRING",
        b'V' => "UNICODE",
        b'X' => "BINUNICODE",
        b'a' => "APPEND",
        b'b' => "BUILD",
        b'c' => "GLOBAL",
        b'd' => "DICT",
        b'}' => "EMPTY_DICT",
        b'e' => "APPENDS",
        b'g' => "GET",
        b'h' => "BINGET",
        b'i' => "INST",
        b'j' => "LONG_BINGET",
        b'l' => "LIST",
        b']' => "EMPTY_LIST",
        b'o' => "OBJ",
        b'p' => "PUT",
        b'q' => "BINPUT",
        b'r' => "LONG_BINPUT",
        b's' => "SETITEM",
        b't' => "TUPLE",
        b')' => "EMPTY_TUPLE",
        b'u' => "SETITEMS",
        b'G' => "BINFLOAT",
        0x80 => "PROTO",
        0x81 => "NEWOBJ",
        0x82 => "EXT1",
        0x83 => "EXT2",
        0x84 => "EXT4",
        0x85 => "TUPLE1",
        0x86 => "TUPLE2",
        0x87 => "TUPLE3",
        0x88 => "NEWTRUE",
        0x89 => "NEWFALSE",
        0x8a => "LONG1",
        0x8b => "LONG4",
        b'B' => "BINBYTES",
        b'C' => "SHORT_BINBYTES",
        0x8c => "SHORT_BINUNICODE",
        0x8d => "BINUNICODE8",
        0x8e => "BINBYTES8",
        0x8f => "EMPTY_SET",
        0x90 => "ADDITEMS",
        0x91 => "FROZENSET",
        0x92 => "NEWOBJ_EX",
        0x93 => "STACK_GLOBAL",
        0x94 => "MEMOIZE",
        0x95 => "FRAME",
        0x96 => "BYTEARRAY8",
        0x97 => "NEXT_BUFFER",
        0x98 => "READONLY_BUFFER",
        _ => "unknown",
    }
}
