//! NetCDF and .npy files: round trips in both NetCDF flavours, per-lead forecasts, level
//! selection, and the typed errors for malformed files.

use netcdf_writer::{NcAttrValue, NcFileBuilder, NcWriteFormat, NcWriteOptions};
use pbdl_weather::field::Values;
use pbdl_weather::io::netcdf::{write, Flavour};
use pbdl_weather::io::{read_forecast, read_truth, Selection};
use pbdl_weather::score::{evaluate, score, Metric, Score};
use pbdl_weather::{Error, Field, Forecast, LatLonGrid, LeadForecast};
use std::path::Path;

const N_LAT: usize = 8;
const N_LON: usize = 16;

fn values(n_time: usize, seed: u32) -> Vec<f64> {
    (0..n_time * N_LAT * N_LON)
        .map(|k| 5000.0 + ((k as u32).wrapping_mul(2654435761).wrapping_add(seed) % 1000) as f64)
        .collect()
}

fn hours(range: std::ops::Range<i64>) -> Vec<i64> {
    range.map(|h| 1_483_228_800 + 3600 * h).collect()
}

fn field(times: Vec<i64>, seed: u32) -> Field {
    let n = times.len();
    Field::new("z", Some(times), LatLonGrid::weatherbench(N_LAT), Values::F64(values(n, seed))).unwrap()
}

fn sel(var: &str) -> Selection {
    Selection { var: Some(var.into()), ..Default::default() }
}

#[test]
fn both_netcdf_flavours_round_trip_and_score_as_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let truth = field(hours(0..48), 1);
    let fc = field(hours(6..30), 2);
    for flavour in [Flavour::Classic, Flavour::Nc4] {
        let (tp, fp) = (dir.path().join(format!("t_{flavour:?}.nc")), dir.path().join(format!("f_{flavour:?}.nc")));
        write(&tp, &Forecast::Direct(truth.clone()), flavour).unwrap();
        write(&fp, &Forecast::Direct(fc.clone()), flavour).unwrap();
        let t = read_truth(&tp, &sel("z")).unwrap();
        assert_eq!(t.values, truth.values);
        assert_eq!(t.times, truth.times);
        assert_eq!(t.grid, truth.grid);
        let Forecast::Direct(f) = read_forecast(&fp, &Selection::default()).unwrap() else { panic!("direct") };
        for m in Metric::ALL {
            assert_eq!(score(m, &f, &t).unwrap(), score(m, &fc, &truth).unwrap(), "{m:?} {flavour:?}");
        }
    }
}

#[test]
fn forecasts_by_lead_score_each_lead_at_init_plus_lead() {
    let dir = tempfile::tempdir().unwrap();
    let truth = field(hours(0..24), 3);
    let leads = vec![1.0, 6.0, 30.0];
    let inits = hours(0..12);
    // lead 1: perfect; lead 6: truth + 2; lead 30: valid times past the truth (NaN).
    let t = truth.values.to_f64();
    let plane = N_LAT * N_LON;
    let mut v = Vec::new();
    for (k, &lead) in leads.iter().enumerate() {
        for i in 0..inits.len() {
            let src = i + lead as usize;
            for p in 0..plane {
                v.push(if src < 24 { t[src * plane + p] + 2.0 * k as f64 } else { f64::NAN });
            }
        }
    }
    let fc = LeadForecast {
        name: "z".into(),
        lead_hours: leads.clone(),
        init_times: inits,
        grid: truth.grid.clone(),
        values: Values::F64(v),
        source: Default::default(),
    };
    let path = dir.path().join("iter.nc");
    write(&path, &Forecast::ByLead(fc), Flavour::Nc4).unwrap();
    let read = read_forecast(&path, &sel("z")).unwrap();
    let Score::PerLead { lead_hours, values } = evaluate(Metric::Rmse, &read, &truth).unwrap() else {
        panic!("per lead")
    };
    assert_eq!(lead_hours, leads);
    assert_eq!(values[0], 0.0);
    assert!((values[1] - 2.0).abs() < 1e-12);
    assert!(values[2].is_nan(), "no valid time of lead 30 h has a truth: {}", values[2]);
}

/// A raw file: `z` with the given dimension names/sizes, coordinates as given.
fn raw_file(path: &Path, dims: &[(&str, usize)], coords: &[(&str, Vec<f64>, &str)], fill_nan_at: Option<usize>) {
    let mut b = NcFileBuilder::new();
    let mut ids = Vec::new();
    for (name, n) in dims {
        ids.push(b.add_dimension(*name, *n as u64).unwrap());
    }
    for (name, vals, units) in coords {
        let d = ids[dims.iter().position(|(n, _)| n == name).unwrap()];
        let v = b.add_variable::<f64>(*name, &[d]).unwrap();
        if !units.is_empty() {
            b.add_variable_attribute(v, "units", NcAttrValue::Chars(units.to_string())).unwrap();
        }
        b.write_variable(v, vals).unwrap();
    }
    let n: usize = dims.iter().map(|(_, n)| n).product();
    let mut data: Vec<f32> = (0..n).map(|k| 100.0 + (k % 17) as f32).collect();
    if let Some(k) = fill_nan_at {
        data[k] = -9999.0;
    }
    let z = b.add_variable::<f32>("z", &ids).unwrap();
    b.add_variable_attribute(z, "_FillValue", NcAttrValue::Floats(vec![-9999.0])).unwrap();
    b.write_variable(z, &data).unwrap();
    let (_, bytes) = b.to_vec(NcWriteOptions { format: NcWriteFormat::Nc4 }).unwrap();
    std::fs::write(path, bytes).unwrap();
}

fn wb_coords() -> (Vec<f64>, Vec<f64>) {
    let g = LatLonGrid::weatherbench(N_LAT);
    (g.lat, g.lon)
}

#[test]
fn malformed_files_get_typed_errors_naming_file_and_variable() {
    let dir = tempfile::tempdir().unwrap();
    let (lat, lon) = wb_coords();
    let time = vec![0.0, 1.0];
    let units = "hours since 2017-01-01";

    // Longitude before latitude: refused, not transposed.
    let p = dir.path().join("lonlat.nc");
    raw_file(
        &p,
        &[("time", 2), ("lon", N_LON), ("lat", N_LAT)],
        &[("time", time.clone(), units), ("lat", lat.clone(), ""), ("lon", lon.clone(), "")],
        None,
    );
    let e = read_truth(&p, &sel("z")).unwrap_err();
    assert!(matches!(&e, Error::DimensionOrder { var, .. } if var == "z"), "{e}");
    assert!(e.to_string().contains("lonlat.nc"));

    // Descending latitudes.
    let p = dir.path().join("desc.nc");
    let desc: Vec<f64> = lat.iter().rev().copied().collect();
    raw_file(
        &p,
        &[("time", 2), ("lat", N_LAT), ("lon", N_LON)],
        &[("time", time.clone(), units), ("lat", desc, ""), ("lon", lon.clone(), "")],
        None,
    );
    let e = read_truth(&p, &sel("z")).unwrap_err();
    assert!(matches!(&e, Error::Coordinate { coord, .. } if coord == "lat"), "{e}");
    assert!(e.to_string().contains("ascending"));

    // Missing variable, listing what is there.
    let p = dir.path().join("ok.nc");
    raw_file(
        &p,
        &[("time", 2), ("lat", N_LAT), ("lon", N_LON)],
        &[("time", time.clone(), units), ("lat", lat.clone(), ""), ("lon", lon.clone(), "")],
        None,
    );
    let e = read_truth(&p, &sel("t")).unwrap_err();
    assert!(
        matches!(&e, Error::MissingVariable { var, available, .. } if var == "t" && available == &vec!["z".to_string()]),
        "{e}"
    );
    assert!(read_truth(&p, &sel("z")).is_ok());

    // A fill value in the truth: masked to NaN, then refused.
    let p = dir.path().join("fill.nc");
    raw_file(
        &p,
        &[("time", 2), ("lat", N_LAT), ("lon", N_LON)],
        &[("time", time.clone(), units), ("lat", lat.clone(), ""), ("lon", lon.clone(), "")],
        Some(5),
    );
    let e = read_truth(&p, &sel("z")).unwrap_err();
    assert!(matches!(&e, Error::NonFinite { count: 1, var, .. } if var == "z"), "{e}");
    // ... but a forecast may have missing values (they are skipped like xarray's skipna).
    assert!(read_forecast(&p, &sel("z")).is_ok());

    // Time without CF units.
    let p = dir.path().join("nounits.nc");
    raw_file(
        &p,
        &[("time", 2), ("lat", N_LAT), ("lon", N_LON)],
        &[("time", time.clone(), ""), ("lat", lat.clone(), ""), ("lon", lon.clone(), "")],
        None,
    );
    let e = read_truth(&p, &sel("z")).unwrap_err();
    assert!(matches!(&e, Error::Coordinate { coord, .. } if coord == "time"), "{e}");

    // Not NetCDF at all.
    let p = dir.path().join("junk.nc");
    std::fs::write(&p, b"hello").unwrap();
    assert!(matches!(read_truth(&p, &sel("z")), Err(Error::NetCdf { .. })));
}

#[test]
fn pressure_levels_are_selected_as_weatherbench_load_test_data_does() {
    let dir = tempfile::tempdir().unwrap();
    let (lat, lon) = wb_coords();
    let p = dir.path().join("levels.nc");
    raw_file(
        &p,
        &[("time", 3), ("level", 2), ("lat", N_LAT), ("lon", N_LON)],
        &[
            ("time", vec![0.0, 6.0, 12.0], "hours since 1979-01-01"),
            ("level", vec![500.0, 850.0], ""),
            ("lat", lat, ""),
            ("lon", lon, ""),
        ],
        None,
    );
    let plane = N_LAT * N_LON;
    let expect = |level_index: usize| -> Vec<f64> {
        (0..3)
            .flat_map(|t| (0..plane).map(move |q| 100.0 + (((t * 2 + level_index) * plane + q) % 17) as f64))
            .collect()
    };
    // z defaults to 500 hPa; --level picks another.
    let z500 = read_truth(&p, &sel("z")).unwrap();
    assert_eq!(z500.values.to_f64(), expect(0));
    let z850 = read_truth(&p, &Selection { level: Some(850.0), ..sel("z") }).unwrap();
    assert_eq!(z850.values.to_f64(), expect(1));
    let e = read_truth(&p, &Selection { level: Some(300.0), ..sel("z") }).unwrap_err();
    assert!(e.to_string().contains("level 300"), "{e}");
    let t = z500.times.unwrap();
    assert_eq!(t[1] - t[0], 6 * 3600);
    assert_eq!(pbdl_weather::time::format_time(t[0]), "1979-01-01T00:00:00");
}
