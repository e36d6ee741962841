"""Peer timings for `cargo xtask bench weather`: WeatherBench's official score.py (xarray) on a
year of hourly 32x64 float32 fields, and xarray reading that year from NetCDF-4 and classic
files. Writes the files to target/pbdl/weather-bench/ (pbdl's entry reads the same files) and
the rows to target/pbdl/bench/weather_peers.json (shared bench schema, peer = true).

Usage: python bench/peers/weather_score_speed.py --score-py PATH/TO/WeatherBench/src/score.py [--reps 7]
"""
import argparse, importlib.util, json, os, statistics, time
import numpy as np
import xarray as xr

from provenance import stamp, versions_of  # bench/peers/provenance.py, beside this script


def year_of_fields(seed, n_time=8760):
    rng = np.random.default_rng(seed)
    lat = -90 + 5.625 / 2 + 5.625 * np.arange(32)
    lon = 5.625 * np.arange(64)
    t = np.datetime64("2017-01-01") + np.arange(n_time) * np.timedelta64(1, "h")
    z = (54000 + 2000 * np.cos(np.deg2rad(lat))[None, :, None] + 300 * rng.standard_normal((n_time, 32, 64))).astype(np.float32)
    return xr.DataArray(z, dims=("time", "lat", "lon"), coords={"time": t, "lat": lat, "lon": lon}, name="z")


def median_time(f, reps):
    f()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--score-py", required=True)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--root", default=".")
    args = ap.parse_args()
    spec = importlib.util.spec_from_file_location("wb_score", args.score_py)
    sc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sc)
    threads = int(os.environ.get("PBDL_THREADS", "2"))
    data_dir = os.path.join(args.root, "target/pbdl/weather-bench")
    os.makedirs(data_dir, exist_ok=True)
    truth = year_of_fields(0)
    fc = year_of_fields(1)
    rows = []
    size = "8760x32x64_f32"
    for metric, func in [("rmse", sc.compute_weighted_rmse), ("mae", sc.compute_weighted_mae), ("acc", sc.compute_weighted_acc)]:
        s = median_time(lambda: float(func(fc, truth)), args.reps)
        rows.append(dict(case=f"score_year_{metric}", method="weatherbench_score_py", size=size, seconds=s, unit="call",
                         error=None, error_kind="", peer=True, threads=threads))
        print(f"score.py {metric}: {s * 1e3:.1f} ms")
    for flavour, fmt in [("nc4", "NETCDF4"), ("nc3", "NETCDF3_64BIT")]:
        path = os.path.join(data_dir, f"truth_year_{flavour}.nc")
        truth.to_dataset().to_netcdf(path, format=fmt)
        mb = os.path.getsize(path) / 1e6
        s = median_time(lambda: xr.open_dataset(path)["z"].load(), args.reps)
        rows.append(dict(case=f"read_year_{flavour}", method="xarray_netcdf4", size=f"{size}_{mb:.0f}MB", seconds=s, unit="file",
                         error=None, error_kind="", peer=True, threads=threads))
        print(f"xarray read {flavour}: {s * 1e3:.1f} ms ({mb / s:.0f} MB/s)")
    out = os.path.join(args.root, "target/pbdl/bench/weather_peers.json")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    meta = versions_of(xr, np)
    with open(out + ".tmp", "w") as f:
        json.dump({"rows": stamp(rows, __file__, meta)}, f, indent=1)
    os.replace(out + ".tmp", out)
    print(f"wrote {out} ({meta})")


if __name__ == "__main__":
    main()
