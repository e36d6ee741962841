//! Conversion of legacy PyTorch checkpoints (`cargo xtask weights convert`).
//!
//! * Default: a small legacy-format file assembled here byte by byte (magic, version, sys info,
//!   object pickle with persistent storage ids, key list, raw storages) goes through the pickle
//!   reader and the converter; values, strides, views and the JSON metadata are checked against
//!   what the bytes encode, and malformed files give typed errors.
//! * With `PBDL_PTH_DIR` pointing at a directory holding the official `LSiM.pth` and
//!   `MS_3scales.pth`: their conversion must equal the reference safetensors in
//!   `../shared/weights` (or `$PBDL_WEIGHTS_DIR`) bit for bit, metadata included. `#[ignore]`d (the
//!   .pth files are not in `../shared`): run it with `-- --ignored`.

use pbdl_metrics::convert::{convert_checkpoint, convert_file, python_float_repr, LegacyCheckpoint, StorageDtype};
use pbdl_metrics::Error;
use std::path::{Path, PathBuf};

/// Builds pickle opcodes by hand (protocol 2, as `torch.save` wrote them).
#[derive(Default)]
struct Pk(Vec<u8>);

impl Pk {
    fn op(&mut self, b: u8) -> &mut Self {
        self.0.push(b);
        self
    }
    fn proto(&mut self) -> &mut Self {
        self.op(0x80).op(2)
    }
    fn stop(&mut self) -> &mut Self {
        self.op(b'.')
    }
    fn mark(&mut self) -> &mut Self {
        self.op(b'(')
    }
    fn s(&mut self, t: &str) -> &mut Self {
        self.op(b'X');
        self.0.extend_from_slice(&(t.len() as u32).to_le_bytes());
        self.0.extend_from_slice(t.as_bytes());
        self
    }
    fn int(&mut self, i: i32) -> &mut Self {
        if (0..256).contains(&i) {
            self.op(b'K').op(i as u8)
        } else if (0..65536).contains(&i) {
            self.op(b'M');
            self.0.extend_from_slice(&(i as u16).to_le_bytes());
            self
        } else {
            self.op(b'J');
            self.0.extend_from_slice(&i.to_le_bytes());
            self
        }
    }
    fn float(&mut self, f: f64) -> &mut Self {
        self.op(b'G');
        self.0.extend_from_slice(&f.to_be_bytes());
        self
    }
    fn global(&mut self, module: &str, name: &str) -> &mut Self {
        self.op(b'c');
        self.0.extend_from_slice(format!("{module}\n{name}\n").as_bytes());
        self
    }
    fn put(&mut self, id: u8) -> &mut Self {
        self.op(b'q').op(id)
    }
    fn get(&mut self, id: u8) -> &mut Self {
        self.op(b'h').op(id)
    }
    /// `_rebuild_tensor_v2((storage pid), offset, size, stride, False, OrderedDict())`; memo slot
    /// 1 holds `_rebuild_tensor_v2`, 2 `torch.FloatStorage`, 3 `collections.OrderedDict`.
    fn tensor(
        &mut self,
        key: &str,
        storage_len: i32,
        view: Option<(i32, i32)>,
        off: i32,
        size: &[i32],
        stride: &[i32],
    ) {
        self.get(1).mark().mark().s("storage").get(2).s(key).s("cpu").int(storage_len);
        match view {
            None => self.op(b'N'),
            Some((o, n)) => self.mark().s(key).int(o).int(n).op(b't'),
        };
        self.op(b't').op(b'Q').int(off);
        self.mark();
        for &n in size {
            self.int(n);
        }
        self.op(b't').mark();
        for &n in stride {
            self.int(n);
        }
        self.op(b't').op(0x89).get(3).op(b')').op(b'R').op(b't').op(b'R');
    }
}

/// Storage "s0": 12 floats 0..11; storage "s1": 3 floats 100, 101, 102.
fn tiny_checkpoint(with_hyper: bool, with_count: bool) -> Vec<u8> {
    let mut p = Pk::default();
    // 1. magic 0x1950a86a20f9469cfc6c as LONG1 (10 bytes, little-endian)
    p.proto().op(0x8a).op(10);
    p.0.extend_from_slice(&[0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19]);
    p.stop();
    // 2. protocol version 1001
    p.proto().int(1001).stop();
    // 3. sys info
    p.proto().op(b'}').mark().s("protocol_version").int(1001).s("little_endian").op(0x88).op(b'u').stop();
    // 4. the object
    p.proto().op(b'}').put(0).mark();
    p.s("stateDict").global("collections", "OrderedDict").put(3).op(b')').op(b'R').mark();
    p.global("torch._utils", "_rebuild_tensor_v2").put(1);
    p.op(b'0'); // POP: the global stays reachable through memo slot 1
    p.global("torch", "FloatStorage").put(2).op(b'0');
    // w: [2, 3] row-major from s0 at offset 0
    p.s("net.w");
    p.tensor("s0", 12, None, 0, &[2, 3], &[3, 1]);
    // wt: the transpose view of s0[6..12] as [3, 2]: stride (1, 3), offset 6
    p.s("net.wt");
    p.tensor("s0", 12, None, 6, &[3, 2], &[1, 3]);
    // b: s1 through a view (storage view offset 1, 2 elements): [101, 102]
    p.s("net.b");
    p.tensor("s1", 3, Some((1, 2)), 0, &[2], &[1]);
    p.op(b'u'); // SETITEMS into the OrderedDict
    p.op(b'}').mark().s("_metadata").op(b'}').op(b'u').op(b'b'); // BUILD: dropped
    for (key, k) in [("normAcc", "s0"), ("normM2", "s1")] {
        p.s(key).op(b']').mark();
        if k == "s0" {
            p.tensor("s0", 12, None, 3, &[2, 2], &[2, 1]); // elements 3, 4, 5, 6
        } else {
            p.tensor("s1", 3, None, 0, &[2, 2], &[0, 1]); // broadcast stride 0: 100, 101, 100, 101
        }
        p.op(b'e');
    }
    if with_count {
        p.s("normCount").op(b']').mark().int(345400).op(b'e');
    }
    if with_hyper {
        p.s("hyperparams").op(b'}').mark();
        p.s("lr").float(0.0001).s("eps").float(1e-5).s("on").op(0x88).s("name").s("fit2");
        p.s("list").op(b']').s("neg").int(-1).s("none").op(b'N');
        p.op(b'u');
    }
    p.op(b'u').stop();
    // 5. storage keys
    p.proto().op(b']').mark().s("s0").s("s1").op(b'e').stop();
    // 6. raw storages
    let mut b = p.0;
    b.extend_from_slice(&12u64.to_le_bytes());
    for i in 0..12 {
        b.extend_from_slice(&(i as f32).to_le_bytes());
    }
    b.extend_from_slice(&3u64.to_le_bytes());
    for v in [100f32, 101.0, 102.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

fn floats(t: &pbdl_metrics::convert::RawTensor) -> Vec<f32> {
    assert_eq!(t.dtype, StorageDtype::F32);
    t.data.chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}

#[test]
fn a_hand_built_legacy_checkpoint_converts_with_strides_views_and_metadata() {
    let bytes = tiny_checkpoint(true, true);
    let c = convert_checkpoint(&bytes, Path::new("tiny.pth")).unwrap();
    let names: Vec<&str> = c.tensors.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["model.net.w", "model.net.wt", "model.net.b", "norm.mean.0", "norm.m2.0"],
        "names in checkpoint order"
    );
    let w = c.tensor("model.net.w").unwrap();
    assert_eq!((w.shape.as_slice(), floats(w)), (&[2, 3][..], vec![0., 1., 2., 3., 4., 5.]));
    // Transpose of [[6, 7], [8, 9], [10, 11]]^T stored with stride (1, 3) from offset 6.
    let wt = c.tensor("model.net.wt").unwrap();
    assert_eq!((wt.shape.as_slice(), floats(wt)), (&[3, 2][..], vec![6., 9., 7., 10., 8., 11.]));
    assert_eq!(floats(c.tensor("model.net.b").unwrap()), [101., 102.]);
    assert_eq!(floats(c.tensor("norm.mean.0").unwrap()), [3., 4., 5., 6.]);
    assert_eq!(floats(c.tensor("norm.m2.0").unwrap()), [100., 101., 100., 101.]);
    assert_eq!(c.metadata["normCount"], "[345400]");
    // What Python's json.dumps writes for this dict.
    assert_eq!(
        c.metadata["hyperparams"],
        r#"{"lr": 0.0001, "eps": 1e-05, "on": true, "name": "fit2", "list": [], "neg": -1, "none": null}"#
    );

    // Round trip through a safetensors file and the weight reader.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiny.safetensors");
    c.write_safetensors(&out).unwrap();
    let w = pbdl_metrics::weights::WeightFile::read(&out).unwrap();
    let t = w.get("model.net.wt", &[3, 2]).unwrap();
    assert_eq!(t.to_vec2::<f32>().unwrap(), [[6., 9.], [7., 10.], [8., 11.]]);
    assert_eq!(w.metadata("normCount"), Some("[345400]"));
}

#[test]
fn malformed_checkpoints_are_typed_errors() {
    let p = Path::new("x.pth");
    // Missing normCount: a Weights error naming the key.
    let e = convert_checkpoint(&tiny_checkpoint(true, false), p).unwrap_err();
    assert!(matches!(&e, Error::Weights { reason, .. } if reason.contains("normCount")), "{e}");
    // Without hyperparams and without LSiM's lin layers: no hyperparams metadata.
    let c = convert_checkpoint(&tiny_checkpoint(false, true), p).unwrap();
    assert!(!c.metadata.contains_key("hyperparams"));
    // Truncated storage data.
    let full = tiny_checkpoint(true, true);
    let e = convert_checkpoint(&full[..full.len() - 5], p).unwrap_err();
    assert!(matches!(&e, Error::Pickle { reason, .. } if reason.contains("storage s1")), "{e}");
    // Cut inside the object pickle.
    let e = convert_checkpoint(&full[..200], p).unwrap_err();
    assert!(matches!(e, Error::Pickle { .. }), "{e}");
    // A protocol-4 opcode the reader does not implement (STACK_GLOBAL, 0x93) right after the header.
    let mut bad = full.clone();
    let at = bad.windows(2).position(|w| w == [b'}', b'q']).unwrap(); // the object's EMPTY_DICT
    bad[at] = 0x93;
    let e = convert_checkpoint(&bad, p).unwrap_err();
    assert!(matches!(e, Error::UnsupportedOpcode { opcode: 0x93, name: "STACK_GLOBAL", .. }), "{e}");
    assert!(e.to_string().contains("STACK_GLOBAL"), "{e}");
    // A zip-format (PyTorch >= 1.6) file and a file that is no checkpoint at all.
    let e = convert_checkpoint(b"PK\x03\x04rest", p).unwrap_err();
    assert!(e.to_string().contains("zip-format"), "{e}");
    let e = convert_checkpoint(b"import torch\n", p).unwrap_err();
    assert!(e.to_string().contains("not a legacy PyTorch .pth"), "{e}");
    let e = convert_checkpoint(&[0x80, 2, b'K', 7, b'.'], p).unwrap_err();
    assert!(e.to_string().contains("magic"), "{e}");
    // A missing file is an Io error with the path.
    let e = convert_file("/nonexistent/LSiM.pth").unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
    // Something that is not a tensor, read as one.
    let ck = LegacyCheckpoint::parse(&full).unwrap();
    let state = ck.object.get("stateDict").unwrap();
    assert!(ck.tensor(state).is_err(), "a dict is not a tensor");
}

#[test]
fn floats_are_written_as_python_repr() {
    // Values checked with python3: repr(x).
    let cases = [
        (0.0001, "0.0001"),
        (1e-05, "1e-05"),
        (1.0, "1.0"),
        (0.05, "0.05"),
        (0.7, "0.7"),
        (1e16, "1e+16"),
        (123456789012345.6, "123456789012345.6"),
        (0.1 + 0.2, "0.30000000000000004"),
        (1.5e-7, "1.5e-07"),
        (-2.5, "-2.5"),
        (1e22, "1e+22"),
        (12345.0, "12345.0"),
        (0.00012, "0.00012"),
    ];
    for (f, want) in cases {
        assert_eq!(python_float_repr(f), want, "{f:e}");
    }
}

/// Environment variable naming a directory with the official `LSiM.pth` and `MS_3scales.pth`.
const PTH_DIR_ENV: &str = "PBDL_PTH_DIR";

#[test]
#[ignore = "needs the official .pth files: PBDL_PTH_DIR=DIR cargo test -p pbdl-metrics --test weights_tests -- --ignored"]
fn official_checkpoints_convert_bit_identically_to_the_reference_files() {
    let Some(pth) = std::env::var_os(PTH_DIR_ENV).map(PathBuf::from) else {
        panic!("set {PTH_DIR_ENV} to a directory with LSiM.pth and MS_3scales.pth (see README)");
    };
    let Some(reference) = pbdl_metrics::weights::weights_dir() else {
        panic!("no reference weights (set PBDL_WEIGHTS_DIR or put them in ../shared/weights)");
    };
    for (input, want) in [("LSiM.pth", "LSiM.safetensors"), ("MS_3scales.pth", "VolSiM_MS_3scales.safetensors")] {
        let (input, want) = (pth.join(input), reference.join(want));
        assert!(want.exists(), "reference {} for {} not found", want.display(), input.display());
        let c = convert_file(&input).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.safetensors");
        c.write_safetensors(&out).unwrap();
        let (a, b) = (std::fs::read(&out).unwrap(), std::fs::read(&want).unwrap());
        let (ta, tb) =
            (safetensors::SafeTensors::deserialize(&a).unwrap(), safetensors::SafeTensors::deserialize(&b).unwrap());
        let (mut na, mut nb) = (ta.names(), tb.names());
        na.sort();
        nb.sort();
        assert_eq!(na, nb, "{}: tensor names", input.display());
        let mut bytes = 0;
        for n in &na {
            let (x, y) = (ta.tensor(n).unwrap(), tb.tensor(n).unwrap());
            assert_eq!((x.dtype(), x.shape()), (y.dtype(), y.shape()), "{n}");
            assert!(x.data() == y.data(), "{n}: data differs");
            bytes += x.data().len();
        }
        let (_, ma) = safetensors::SafeTensors::read_metadata(&a).unwrap();
        let (_, mb) = safetensors::SafeTensors::read_metadata(&b).unwrap();
        assert_eq!(ma.metadata(), mb.metadata(), "{}: metadata", input.display());
        eprintln!(
            "{}: {} tensors, {bytes} data bytes bit-identical to {}, metadata equal",
            input.display(),
            na.len(),
            want.display()
        );
    }
}

#[test]
fn the_pickle_reader_sees_filled_containers_through_the_memo_and_reads_integers() {
    use pbdl_metrics::convert::pickle::{load, Value};
    // [1, 2] memoised while empty, filled by APPENDS, fetched again: (l, l) with l = [1, 2].
    let bytes = [0x80, 2, b']', b'q', 0, b'(', b'K', 1, b'K', 2, b'e', b'h', 0, 0x86, b'.'];
    let mut pos = 0;
    let v = load(&bytes, &mut pos).unwrap();
    let l = Value::List(vec![Value::Int(1), Value::Int(2)]);
    assert_eq!(v, Value::Tuple(vec![l.clone(), l]));
    assert_eq!(pos, bytes.len());
    // LONG1 -2 (0xfe), BININT -3, BININT2 65535, BINFLOAT 0.5 (big-endian), two pickles in a row.
    let mut b = vec![0x80, 2, 0x8a, 1, 0xfe, b'.', 0x80, 2, b'(', b'J'];
    b.extend_from_slice(&(-3i32).to_le_bytes());
    b.extend_from_slice(&[b'M', 0xff, 0xff, b'G']);
    b.extend_from_slice(&0.5f64.to_be_bytes());
    b.extend_from_slice(b"t.");
    let mut pos = 0;
    assert_eq!(load(&b, &mut pos).unwrap(), Value::Int(-2));
    let t = load(&b, &mut pos).unwrap();
    assert_eq!(t, Value::Tuple(vec![Value::Int(-3), Value::Int(65535), Value::Float(0.5)]));
    // Stack misuse is an error, not a panic.
    for bad in [&b"."[..], b"(.", b"u", &[b'K', 1, b'a', b'.'], &[b'h', 9, b'.'], &[0x80]] {
        let mut pos = 0;
        assert!(matches!(load(bad, &mut pos), Err(Error::Pickle { .. })), "{bad:?}");
    }
}
