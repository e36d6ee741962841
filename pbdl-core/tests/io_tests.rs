//! Tests of `pbdl_core::io`: atomic writes, checkpoints, `.npy` / `.npz`.

use candle_core::{DType, Device, Tensor};
use candle_nn::{Init, VarMap};
use pbdl_core::io::{
    checkpoint_files, latest_checkpoint, list_checkpoints, load_checkpoint, load_varmap, read_checkpoint_info,
    read_npy, read_npz, read_npz_array, save_checkpoint, save_varmap, write_atomic, write_npy, write_npz,
    CheckpointMeta,
};
use pbdl_core::seed::randn;
use pbdl_core::Error;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

fn dir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// Names of all files in `dir`, sorted.
fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

/// Raw little-endian bytes of a tensor, to compare bit for bit (NaN payloads, -0.0).
fn bits(t: &Tensor) -> Vec<u8> {
    let mut b = Vec::new();
    t.write_bytes(&mut b).unwrap();
    b
}

fn model(init: f64) -> VarMap {
    let vm = VarMap::new();
    vm.get((4, 3), "enc.weight", Init::Const(init), DType::F32, &Device::Cpu).unwrap();
    vm.get(4, "enc.bias", Init::Const(init), DType::F32, &Device::Cpu).unwrap();
    vm.get((2, 2), "head.scale", Init::Const(init), DType::F64, &Device::Cpu).unwrap();
    vm
}

fn randomize(vm: &VarMap) {
    for (i, (_, var)) in vm.data().lock().unwrap().iter().enumerate() {
        var.set(&randn(var.dims(), 0.0, 1.0, var.dtype(), &Device::Cpu, 10 + i as u64).unwrap()).unwrap();
    }
}

fn meta(step: u64) -> CheckpointMeta {
    CheckpointMeta { step, seed: Some(42), config: serde_json::json!({"lr": 0.001, "layers": [32, 32], "name": "mlp"}) }
}

// ---------------------------------------------------------------- atomic writes

#[test]
fn write_atomic_error_halfway_keeps_old_file_and_leaves_no_temp() {
    let d = dir();
    let path = d.path().join("state.bin");
    write_atomic(&path, |w| w.write_all(b"old content")).unwrap();
    let err = write_atomic(&path, |w| {
        w.write_all(&[7u8; 100_000])?; // more than the buffer, so bytes did reach the temp file
        Err(std::io::Error::other("simulated crash"))
    })
    .unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("simulated crash"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), b"old content");
    assert_eq!(files_in(d.path()), vec!["state.bin"]);
}

#[test]
fn write_atomic_panic_halfway_keeps_old_file_and_leaves_no_temp() {
    let d = dir();
    let path = d.path().join("state.bin");
    write_atomic(&path, |w| w.write_all(b"old content")).unwrap();
    let result = std::panic::catch_unwind(|| {
        write_atomic(&path, |w| {
            w.write_all(&[1u8; 100_000]).unwrap();
            panic!("simulated crash in the writer");
        })
    });
    assert!(result.is_err());
    assert_eq!(std::fs::read(&path).unwrap(), b"old content");
    assert_eq!(files_in(d.path()), vec!["state.bin"]);
}

#[test]
fn write_atomic_creates_and_replaces() {
    let d = dir();
    let path = d.path().join("a.txt");
    write_atomic(&path, |w| w.write_all(b"one")).unwrap();
    write_atomic(&path, |w| w.write_all(b"two, longer")).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"two, longer");
    let missing_dir = d.path().join("no/such/dir/a.txt");
    assert!(matches!(write_atomic(&missing_dir, |w| w.write_all(b"x")), Err(Error::Io { .. })));
}

// ---------------------------------------------------------------- checkpoints

#[test]
fn checkpoint_round_trip_is_bit_exact_with_sidecar_fields() {
    let d = dir();
    let vm = model(0.0);
    randomize(&vm);
    let path = d.path().join("run/step-00000100");
    let info = save_varmap(&path, &vm, &meta(100)).unwrap();
    assert_eq!(files_in(&d.path().join("run")), vec!["step-00000100.json", "step-00000100.safetensors"]);

    // Values: bit-exact, dtype kept.
    let (loaded, info2) = load_checkpoint(&path, &Device::Cpu).unwrap();
    assert_eq!(info, info2);
    assert_eq!(loaded.len(), 3);
    for (name, var) in vm.data().lock().unwrap().iter() {
        let t = &loaded[name];
        assert_eq!(t.dtype(), var.dtype(), "{name}");
        assert_eq!(t.dims(), var.dims(), "{name}");
        assert_eq!(bits(t), bits(var.as_tensor()), "{name}");
    }

    // Sidecar: every field, also as raw JSON as Python would read it.
    let raw: serde_json::Value = serde_json::from_slice(&std::fs::read(checkpoint_files(&path).1).unwrap()).unwrap();
    assert_eq!(raw["format"], "pbdl-checkpoint");
    assert_eq!(raw["step"], 100);
    assert_eq!(raw["seed"], 42);
    assert_eq!(raw["config"], meta(100).config);
    assert_eq!(raw["crate_version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(raw["weights_file"], "step-00000100.safetensors");
    let created = raw["created_utc"].as_str().unwrap();
    assert!(created.len() == 20 && created.ends_with('Z') && created.as_bytes()[10] == b'T', "{created}");
    assert!(raw["created_unix_s"].as_u64().unwrap() > 1_600_000_000);
    let names: Vec<&str> = info.tensors.iter().map(|t| t.name.as_str()).collect();
    assert_eq!(names, ["enc.bias", "enc.weight", "head.scale"]);
    assert_eq!(info.tensors[1].shape, [4, 3]);
    assert_eq!(info.tensors[2].dtype, "f64");
    assert_eq!(
        info.weights_bytes,
        std::fs::metadata(checkpoint_files(&path).0).unwrap().len(),
        "recorded size of the weights file"
    );

    // Either file name works as the checkpoint's path.
    assert_eq!(read_checkpoint_info(path.with_extension("safetensors")).unwrap().step, 100);
}

#[test]
fn checkpoint_loads_into_varmap_and_from_hashmap() {
    let d = dir();
    let vm = model(0.0);
    randomize(&vm);
    save_varmap(d.path().join("ck"), &vm, &meta(5)).unwrap();
    let fresh = model(1.0);
    let info = load_varmap(d.path().join("ck.safetensors"), &fresh).unwrap();
    assert_eq!(info.step, 5);
    let (a, b) = (vm.data().lock().unwrap(), fresh.data().lock().unwrap());
    for (name, var) in a.iter() {
        assert_eq!(bits(var.as_tensor()), bits(b[name].as_tensor()), "{name}");
    }

    // Plain maps of tensors, u8 included.
    let mut map = HashMap::new();
    map.insert("mask".to_string(), Tensor::new(&[0u8, 1, 255], &Device::Cpu).unwrap());
    map.insert("x".to_string(), Tensor::new(&[[1.5f32, -0.0], [f32::INFINITY, 1e-40]], &Device::Cpu).unwrap());
    save_checkpoint(d.path().join("map"), &map, &CheckpointMeta::default()).unwrap();
    let (back, info) = load_checkpoint(d.path().join("map"), &Device::Cpu).unwrap();
    assert_eq!(info.config, serde_json::Value::Null);
    assert_eq!(info.seed, None);
    for (name, t) in &map {
        assert_eq!(bits(&back[name]), bits(t), "{name}");
    }
}

#[test]
fn loading_a_wrong_shape_names_the_tensor_and_both_shapes() {
    let d = dir();
    save_varmap(d.path().join("ck"), &model(0.5), &meta(1)).unwrap();
    let other = VarMap::new();
    other.get((4, 5), "enc.weight", Init::Const(9.0), DType::F32, &Device::Cpu).unwrap();
    other.get(4, "enc.bias", Init::Const(9.0), DType::F32, &Device::Cpu).unwrap();
    let err = load_varmap(d.path().join("ck"), &other).unwrap_err();
    match &err {
        Error::TensorShape { name, stored, expected, .. } => {
            assert_eq!(name, "enc.weight");
            assert_eq!(stored, &[4, 3]);
            assert_eq!(expected, &[4, 5]);
        }
        other => panic!("expected TensorShape, got {other:?}"),
    }
    let msg = err.to_string();
    assert!(msg.contains("enc.weight") && msg.contains("[4, 3]") && msg.contains("[4, 5]"), "{msg}");
    // Nothing was set, not even the tensor whose shape matched.
    let bias = other.data().lock().unwrap()["enc.bias"].as_tensor().to_vec1::<f32>().unwrap();
    assert_eq!(bias, [9.0; 4]);
}

#[test]
fn loading_reports_all_missing_tensor_names() {
    let d = dir();
    let small = VarMap::new();
    small.get(3, "a", Init::Const(1.0), DType::F32, &Device::Cpu).unwrap();
    save_varmap(d.path().join("ck"), &small, &meta(1)).unwrap();
    let err = load_varmap(d.path().join("ck"), &model(0.0)).unwrap_err();
    match &err {
        Error::MissingTensors { missing, available, .. } => {
            assert_eq!(missing, &["enc.bias", "enc.weight", "head.scale"]);
            assert_eq!(available, &["a"]);
        }
        other => panic!("expected MissingTensors, got {other:?}"),
    }
}

#[test]
fn missing_and_malformed_checkpoints_give_typed_errors() {
    let d = dir();
    // Missing file.
    match load_checkpoint(d.path().join("nope"), &Device::Cpu) {
        Err(Error::Io { source, .. }) => assert_eq!(source.kind(), std::io::ErrorKind::NotFound),
        other => panic!("expected Io NotFound, got {other:?}"),
    }
    // A sidecar that is not JSON.
    std::fs::write(d.path().join("bad.json"), b"not json at all").unwrap();
    assert!(matches!(read_checkpoint_info(d.path().join("bad")), Err(Error::Format { .. })));
    // JSON, but not a pbdl sidecar.
    std::fs::write(d.path().join("cfg.json"), br#"{"lr": 0.1}"#).unwrap();
    assert!(matches!(read_checkpoint_info(d.path().join("cfg")), Err(Error::Format { .. })));
    // A valid sidecar whose weights file is garbage.
    save_varmap(d.path().join("ck"), &model(0.0), &meta(1)).unwrap();
    std::fs::write(d.path().join("ck.safetensors"), b"\x05\x00\x00\x00\x00\x00\x00\x00garbage").unwrap();
    let err = load_checkpoint(d.path().join("ck"), &Device::Cpu).unwrap_err();
    assert!(matches!(err, Error::Format { .. }), "{err:?}");
    assert!(err.to_string().contains("safetensors"), "{err}");
}

#[test]
fn weights_from_an_interrupted_overwrite_do_not_load_under_the_old_sidecar() {
    let d = dir();
    let path = d.path().join("ck");
    save_varmap(&path, &model(1.0), &meta(1)).unwrap();
    let old_sidecar = std::fs::read(checkpoint_files(&path).1).unwrap();
    // Second save under the same name "dies" after its weights: put the old sidecar back.
    save_varmap(&path, &model(2.0), &meta(2)).unwrap();
    std::fs::write(checkpoint_files(&path).1, old_sidecar).unwrap();
    let err = load_checkpoint(&path, &Device::Cpu).unwrap_err();
    assert!(matches!(err, Error::Format { .. }) && err.to_string().contains("do not belong"), "{err}");
}

#[test]
fn latest_checkpoint_picks_the_largest_complete_step() {
    let d = dir();
    assert_eq!(latest_checkpoint(d.path().join("not-yet-created")).unwrap(), None);
    assert_eq!(latest_checkpoint(d.path()).unwrap(), None);
    let vm = model(0.0);
    for step in [10, 300, 20] {
        save_varmap(d.path().join(format!("step-{step:08}")), &vm, &meta(step)).unwrap();
    }
    // Leftovers of crashes and unrelated files are ignored: weights without a sidecar (died
    // before the sidecar), a temporary file of a killed writer, another JSON file.
    save_varmap(d.path().join("step-00000999"), &vm, &meta(999)).unwrap();
    std::fs::remove_file(d.path().join("step-00000999.json")).unwrap();
    std::fs::write(d.path().join(".step-00001000.json.123.0.tmp"), b"{\"format\": \"pbdl-ch").unwrap();
    std::fs::write(d.path().join("config.json"), br#"{"lr": 0.1}"#).unwrap();

    let latest = latest_checkpoint(d.path()).unwrap().unwrap();
    assert_eq!(latest, d.path().join("step-00000300.safetensors"));
    let steps: Vec<u64> = list_checkpoints(d.path()).unwrap().iter().map(|(_, i)| i.step).collect();
    assert_eq!(steps, [10, 20, 300]);
    assert_eq!(load_varmap(&latest, &model(5.0)).unwrap().step, 300);
}

// ---------------------------------------------------------------- npy / npz

#[test]
fn npy_round_trips_f32_f64_u8_bit_exact() {
    let d = dir();
    let f32s = Tensor::new(&[[0.0f32, -0.0, 1.5], [f32::NAN, f32::INFINITY, 1e-42]], &Device::Cpu).unwrap();
    let f64s = randn((2, 3, 4, 5), 0.0, 1.0, DType::F64, &Device::Cpu, 3).unwrap();
    let u8s = Tensor::new(&[0u8, 1, 127, 128, 255], &Device::Cpu).unwrap();
    let scalar = Tensor::new(2.5f32, &Device::Cpu).unwrap();
    for (name, t) in [("f32", &f32s), ("f64", &f64s), ("u8", &u8s), ("scalar", &scalar)] {
        let path = d.path().join(format!("{name}.npy"));
        write_npy(&path, t).unwrap();
        let back = read_npy(&path).unwrap();
        assert_eq!(back.dtype(), t.dtype(), "{name}");
        assert_eq!(back.dims(), t.dims(), "{name}");
        assert_eq!(bits(&back), bits(t), "{name}");
    }
    // The exact bytes NumPy 1.x/2.x writes for np.save(f, np.arange(3, dtype="<f4")).
    let path = d.path().join("arange.npy");
    write_npy(&path, &Tensor::new(&[0.0f32, 1.0, 2.0], &Device::Cpu).unwrap()).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = b"{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }";
    assert_eq!(&bytes[..10], b"\x93NUMPY\x01\x00\x76\x00");
    assert_eq!(&bytes[10..10 + header.len()], header);
    assert_eq!(bytes.len(), 128 + 12);
    assert_eq!(bytes[127], b'\n');
}

#[test]
fn npy_writes_non_contiguous_tensors_in_logical_order() {
    let d = dir();
    let t = Tensor::new(&[[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]], &Device::Cpu).unwrap().t().unwrap();
    write_npy(d.path().join("t.npy"), &t).unwrap();
    let back = read_npy(d.path().join("t.npy")).unwrap();
    assert_eq!(back.to_vec2::<f32>().unwrap(), [[1.0, 4.0], [2.0, 5.0], [3.0, 6.0]]);
}

#[test]
fn npz_round_trips_named_arrays_in_order() {
    let d = dir();
    let path = d.path().join("traj.npz");
    // A trajectory [T, C, Y, X] plus metadata arrays of other dtypes.
    let density = randn((5, 1, 6, 7), 1.0, 0.1, DType::F32, &Device::Cpu, 1).unwrap();
    let velocity = randn((5, 2, 6, 7), 0.0, 1.0, DType::F64, &Device::Cpu, 2).unwrap();
    let mask = Tensor::new(&[[1u8, 0], [0, 1]], &Device::Cpu).unwrap();
    write_npz(&path, &[("velocity", &velocity), ("density", &density), ("obstacle_mask", &mask)]).unwrap();
    let arrays = read_npz(&path).unwrap();
    let names: Vec<&str> = arrays.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["velocity", "density", "obstacle_mask"]);
    for ((_, back), orig) in arrays.iter().zip([&velocity, &density, &mask]) {
        assert_eq!(back.dtype(), orig.dtype());
        assert_eq!(back.dims(), orig.dims());
        assert_eq!(bits(back), bits(orig));
    }
    assert_eq!(bits(&read_npz_array(&path, "density").unwrap()), bits(&density));
    match read_npz_array(&path, "pressure") {
        Err(Error::MissingTensors { missing, available, .. }) => {
            assert_eq!(missing, ["pressure"]);
            assert_eq!(available, ["velocity", "density", "obstacle_mask"]);
        }
        other => panic!("expected MissingTensors, got {other:?}"),
    }
    // Duplicate names are refused before anything is written.
    let dup = write_npz(d.path().join("dup.npz"), &[("a", &mask), ("a", &mask)]);
    assert!(matches!(dup, Err(Error::InvalidArgument { .. })));
    assert!(!d.path().join("dup.npz").exists());
}

/// Builds a `.npy` file by hand, as NumPy would write it with the given header.
fn hand_npy(header: &str, data: &[u8]) -> Vec<u8> {
    let mut h = header.to_string();
    while (10 + h.len() + 1) % 64 != 0 {
        h.push(' ');
    }
    h.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((h.len() as u16).to_le_bytes());
    out.extend(h.as_bytes());
    out.extend(data);
    out
}

fn format_reason(result: pbdl_core::Result<Tensor>) -> String {
    match result {
        Err(Error::Format { reason, .. }) => reason,
        other => panic!("expected a Format error, got {other:?}"),
    }
}

#[test]
fn malformed_or_unsupported_npy_files_give_format_errors() {
    let d = dir();
    let p = |n: &str| d.path().join(n);

    std::fs::write(p("text.npy"), b"this is a text file, not an array").unwrap();
    assert!(format_reason(read_npy(p("text.npy"))).contains("not a .npy file"));

    let fortran = hand_npy("{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }", &[0u8; 24]);
    std::fs::write(p("fortran.npy"), fortran).unwrap();
    assert!(format_reason(read_npy(p("fortran.npy"))).contains("Fortran"));

    // Fortran order of a 1-d array is the same layout as C order: accepted.
    let f1 = hand_npy("{'descr': '<f4', 'fortran_order': True, 'shape': (2,), }", &[0, 0, 128, 63, 0, 0, 0, 64]);
    std::fs::write(p("fortran1d.npy"), f1).unwrap();
    assert_eq!(read_npy(p("fortran1d.npy")).unwrap().to_vec1::<f32>().unwrap(), [1.0, 2.0]);

    let big = hand_npy("{'descr': '>f8', 'fortran_order': False, 'shape': (1,), }", &[0u8; 8]);
    std::fs::write(p("big.npy"), big).unwrap();
    assert!(format_reason(read_npy(p("big.npy"))).contains("big-endian"));

    let complex = hand_npy("{'descr': '<c8', 'fortran_order': False, 'shape': (1,), }", &[0u8; 8]);
    std::fs::write(p("complex.npy"), complex).unwrap();
    assert!(format_reason(read_npy(p("complex.npy"))).contains("'<c8' is not supported"));

    let truncated = hand_npy("{'descr': '<f4', 'fortran_order': False, 'shape': (10,), }", &[0u8; 12]);
    std::fs::write(p("short.npy"), truncated).unwrap();
    assert!(format_reason(read_npy(p("short.npy"))).contains("truncated"));

    match read_npy(p("missing.npy")) {
        Err(Error::Io { source, .. }) => assert_eq!(source.kind(), std::io::ErrorKind::NotFound),
        other => panic!("expected Io NotFound, got {other:?}"),
    }
}

#[test]
fn malformed_or_compressed_npz_files_give_format_errors() {
    let d = dir();
    std::fs::write(d.path().join("x.npz"), b"\x93NUMPY not a zip").unwrap();
    assert!(matches!(read_npz(d.path().join("x.npz")), Err(Error::Format { .. })));

    // A stored archive patched to claim deflate compression, as np.savez_compressed writes.
    let path = d.path().join("c.npz");
    write_npz(&path, &[("a", Tensor::new(&[1.0f32, 2.0], &Device::Cpu).unwrap())]).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    for (sig, offset) in [(b"PK\x03\x04", 8), (b"PK\x01\x02", 10)] {
        let at = bytes.windows(4).position(|w| w == sig).unwrap();
        bytes[at + offset] = 8;
    }
    std::fs::write(&path, bytes).unwrap();
    let reason = match read_npz(&path) {
        Err(Error::Format { reason, .. }) => reason,
        other => panic!("expected Format, got {other:?}"),
    };
    assert!(reason.contains("np.savez_compressed") && reason.contains("`a`"), "{reason}");
}

#[test]
fn writing_unsupported_dtypes_is_a_dtype_error() {
    let d = dir();
    let t = Tensor::new(&[1.0f32, 2.0], &Device::Cpu).unwrap().to_dtype(DType::BF16).unwrap();
    assert!(matches!(write_npy(d.path().join("b.npy"), &t), Err(Error::DType { got: DType::BF16, .. })));
    assert!(matches!(write_npz(d.path().join("b.npz"), &[("b", &t)]), Err(Error::DType { .. })));
    assert!(files_in(d.path()).is_empty());
}

// Regressions from `cargo xtask stress fuzz` (targets npy / npz).

/// A `.npy` whose header shape multiplies past `usize` (crafted; was an unchecked product).
#[test]
fn npy_with_an_overflowing_shape_is_a_format_error() {
    let d = dir();
    let path = d.path().join("huge.npy");
    let header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296, 16), }\n";
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    std::fs::write(&path, &bytes).unwrap();
    match read_npy(&path) {
        Err(Error::Format { reason, .. }) => assert!(reason.contains("more bytes than memory"), "{reason}"),
        other => panic!("expected a format error, got {other:?}"),
    }
    // Elements fit but bytes do not (n * 8 overflows).
    let header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4611686018427387904,), }\n";
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    std::fs::write(&path, &bytes).unwrap();
    assert!(matches!(read_npy(&path), Err(Error::Format { .. })));
}

/// A `.npz` member whose zip header declares more bytes than the archive holds is refused before
/// anything is allocated for it (was `Vec::with_capacity(declared size)`).
#[test]
fn npz_member_declaring_more_than_the_file_is_a_format_error() {
    let d = dir();
    let path = d.path().join("a.npz");
    let t = Tensor::new(&[1f32, 2.0, 3.0], &Device::Cpu).unwrap();
    write_npz(&path, &[("a", &t)]).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    // The uncompressed size sits at offset 22 of a local header ("PK\x03\x04") and at offset 24
    // of a central directory entry ("PK\x01\x02").
    let declared = 0x7fff_fff0u32.to_le_bytes();
    let mut patched = 0;
    for i in 0..bytes.len() - 4 {
        let at = match &bytes[i..i + 4] {
            b"PK\x03\x04" => i + 22,
            b"PK\x01\x02" => i + 24,
            _ => continue,
        };
        bytes[at..at + 4].copy_from_slice(&declared);
        patched += 1;
    }
    assert_eq!(patched, 2);
    std::fs::write(&path, &bytes).unwrap();
    for result in [read_npz(&path).map(|_| ()), read_npz_array(&path, "a").map(|_| ())] {
        match result {
            Err(Error::Format { reason, .. }) => assert!(reason.contains("declares 2147483632 bytes"), "{reason}"),
            other => panic!("expected a format error, got {other:?}"),
        }
    }
}
