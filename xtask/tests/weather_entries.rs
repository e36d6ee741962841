//! `cargo xtask weather score` end to end (the binary on files written by pbdl-weather) and the
//! registration of pbdl-weather's entries.

use pbdl_weather::field::Values;
use pbdl_weather::io::netcdf::{write, Flavour};
use pbdl_weather::score::{score, Metric};
use pbdl_weather::{Field, Forecast, LatLonGrid};
use std::process::Command;

fn field(seed: u32, times: std::ops::Range<i64>) -> Field {
    let n = (times.end - times.start) as usize;
    let values =
        (0..n * 32 * 64).map(|k| 5.0e4 + ((k as u32).wrapping_mul(2654435761) ^ seed) as f64 % 977.0).collect();
    Field::new(
        "z",
        Some(times.map(|h| 1_483_228_800 + 3600 * h).collect()),
        LatLonGrid::weatherbench(32),
        Values::F64(values),
    )
    .unwrap()
}

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn weather_score_prints_the_library_scores_as_json_on_the_last_line() {
    let dir = tempfile::tempdir().unwrap();
    let (truth, fc) = (field(1, 0..30), field(2, 5..25));
    let (tp, fp) = (dir.path().join("truth.nc"), dir.path().join("fc.nc"));
    write(&tp, &Forecast::Direct(truth.clone()), Flavour::Nc4).unwrap();
    write(&fp, &Forecast::Direct(fc.clone()), Flavour::Classic).unwrap();
    for metric in Metric::ALL {
        let (ok, stdout, stderr) = run(&[
            "weather",
            "score",
            "--forecast",
            fp.to_str().unwrap(),
            "--truth",
            tp.to_str().unwrap(),
            "--var",
            "z",
            "--metric",
            metric.name(),
        ]);
        assert!(ok, "{stderr}");
        let json: serde_json::Value = serde_json::from_str(stdout.trim().lines().last().unwrap()).unwrap();
        let got = json[metric.name()].as_f64().unwrap();
        let expected = score(metric, &fc, &truth).unwrap();
        assert!((got - expected).abs() <= 1e-12 * expected.abs(), "{metric:?}: {got} vs {expected}");
    }
    // A missing variable: non-zero exit, the message names the file and what is there.
    let (ok, _, stderr) =
        run(&["weather", "score", "--forecast", fp.to_str().unwrap(), "--truth", tp.to_str().unwrap(), "--var", "t"]);
    assert!(!ok);
    assert!(stderr.contains("truth.nc") && stderr.contains("'t' not found") && stderr.contains("\"z\""), "{stderr}");
}

#[test]
fn weather_entries_are_registered() {
    let tasks = xtask::entries::weather::tasks();
    assert_eq!(tasks.crate_name, "weather");
    assert_eq!(tasks.tour.iter().map(|e| e.name).collect::<Vec<_>>(), ["standin_forecast"]);
    assert_eq!(tasks.bench.iter().map(|e| e.name).collect::<Vec<_>>(), ["score_year"]);
    assert_eq!(tasks.stress.iter().map(|e| e.name).collect::<Vec<_>>(), ["standin_years", "dt_limit", "acceptance"]);
}

/// The tour entry end to end in quick mode (about 25 s in the test profile; the tour runs it in
/// release with 4x the training).
#[test]
fn weather_tour_entry_runs_and_writes_its_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let ctx = xtask::registry::TaskContext { out_dir: dir.path().into(), quick: true, threads: 2 };
    let tasks = xtask::entries::weather::tasks();
    let outcome = (tasks.tour[0].run)(&ctx).unwrap();
    eprintln!("{}", outcome.markdown);
    let row = &outcome.rows[0];
    assert!(row.error.is_some_and(f64::is_finite), "{row:?}");
    for f in &outcome.files {
        assert!(dir.path().join(f).is_file(), "{f:?} missing");
    }
}
