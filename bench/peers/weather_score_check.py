"""Checks `cargo xtask weather score` against WeatherBench's official src/score.py.

Usage (the official scorer is not part of pbdl; clone https://github.com/pangeo-data/WeatherBench):
    python bench/peers/weather_score_check.py --score-py PATH/TO/WeatherBench/src/score.py \
        [--xtask target/release/xtask] [--out target/pbdl/weather-check]

Writes random WeatherBench-like files (32x64 grid, hourly, float32; NetCDF-4 and classic;
a direct forecast, a forecast by lead time with NaN where no truth exists, .npy copies),
scores them with score.py (xarray) and with pbdl, and prints one row per case with the
relative difference. Exits non-zero if any difference exceeds 1e-6 (float32 inputs: score.py
subtracts in float32, pbdl in float64).
"""
import argparse, importlib.util, json, os, subprocess, sys, time
import numpy as np
import xarray as xr


def load_score_module(path):
    spec = importlib.util.spec_from_file_location("wb_score", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def make_truth(rng, n_time, start="2017-01-01"):
    lat = -90 + 5.625 / 2 + 5.625 * np.arange(32)
    lon = 5.625 * np.arange(64)
    time_ = np.datetime64(start) + np.arange(n_time) * np.timedelta64(1, "h")
    base = 54000 + 2000 * np.cos(np.deg2rad(lat))[None, :, None]
    wave = 300 * np.sin(np.deg2rad(lon)[None, None, :] * 3 + np.arange(n_time)[:, None, None] * 0.05)
    z = (base + wave + 100 * rng.standard_normal((n_time, 32, 64))).astype(np.float32)
    return xr.DataArray(z, dims=("time", "lat", "lon"), coords={"time": time_, "lat": lat, "lon": lon}, name="z")


def run_pbdl(xtask, fc, truth, metric, extra=()):
    cmd = [xtask, "weather", "score", "--forecast", fc, "--truth", truth, "--metric", metric, *extra]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--score-py", required=True)
    ap.add_argument("--xtask", default="target/release/xtask")
    ap.add_argument("--out", default="target/pbdl/weather-check")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    sc = load_score_module(args.score_py)
    os.makedirs(args.out, exist_ok=True)
    funcs = {"rmse": sc.compute_weighted_rmse, "mae": sc.compute_weighted_mae, "acc": sc.compute_weighted_acc}
    worst = 0.0
    print(f"xarray {xr.__version__}, numpy {np.__version__}, {time.strftime('%Y-%m-%d')}")
    print("| seed | case | metric | score.py | pbdl | rel. diff |")
    print("|---|---|---|---|---|---|")
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        truth = make_truth(rng, 240)
        # direct forecast on a subset of times (inner join), float32
        fc = (truth.isel(time=slice(24, 200)) + 50 * rng.standard_normal((176, 32, 64)) + 20).astype(np.float32)
        # iterative forecast: lead_time (hours) x init time, NaN past the truth
        leads = np.array([1, 3, 6, 12, 24])
        inits = truth.time.values[::6]
        vals = np.full((len(leads), len(inits), 32, 64), np.nan, dtype=np.float32)
        for k, l in enumerate(leads):
            for i, t0 in enumerate(inits):
                tv = t0 + np.timedelta64(int(l), "h")
                if tv in truth.time.values:
                    vals[k, i] = truth.sel(time=tv).values + (10 + 5 * l) * rng.standard_normal((32, 64))
        it = xr.DataArray(vals, dims=("lead_time", "time", "lat", "lon"),
                          coords={"lead_time": leads, "time": inits, "lat": truth.lat, "lon": truth.lon}, name="z")
        paths = {}
        flavours = [("nc4", "NETCDF4", False), ("nc4z", "NETCDF4", True), ("nc3", "NETCDF3_64BIT", False)]
        for flavour, fmt, zlib in flavours:
            for name, da in [("truth", truth), ("fc", fc), ("iter", it)]:
                p = os.path.join(args.out, f"{name}_{seed}_{flavour}.nc")
                enc = {"z": {"zlib": True, "complevel": 4, "shuffle": True}} if zlib else None
                da.to_dataset().to_netcdf(p, format=fmt, encoding=enc)
                paths[(name, flavour)] = p
        # the truth as WeatherBench's multi-level files store it: [time, level, lat, lon]
        lev = xr.concat([truth + 1000.0, truth], dim=xr.DataArray([300, 500], dims="level", name="level"))
        lev = lev.transpose("time", "level", "lat", "lon")
        lev_path = os.path.join(args.out, f"truth_{seed}_levels.nc")
        lev.to_dataset(name="z").to_netcdf(lev_path, format="NETCDF4")
        np.save(os.path.join(args.out, f"lat.npy"), truth.lat.values)
        fc_same = fc.sel(time=fc.time)  # positional .npy case needs equal times
        truth_same = truth.sel(time=fc.time)
        np.save(os.path.join(args.out, f"fc_{seed}.npy"), fc_same.values)
        np.save(os.path.join(args.out, f"truth_{seed}.npy"), truth_same.values)
        cases = []
        for metric in ["rmse", "acc"]:
            ref = float(funcs[metric](fc, lev.sel(level=500).drop_vars("level")))
            got = run_pbdl(args.xtask, paths[("fc", "nc4")], lev_path, metric, ["--var", "z"])[metric]
            cases.append(("truth with levels (500 picked)", metric, ref, got))
        for flavour in ["nc4", "nc4z", "nc3"]:
            for metric in ["rmse", "mae", "acc"]:
                ref = float(funcs[metric](fc, truth))
                got = run_pbdl(args.xtask, paths[("fc", flavour)], paths[("truth", flavour)], metric)[metric]
                cases.append((f"direct {flavour}", metric, ref, got))
            ref = float(sc.compute_weighted_rmse(fc, truth, mean_dims=["lat", "lon"]).mean("time"))
            got = run_pbdl(args.xtask, paths[("fc", flavour)], paths[("truth", flavour)], "rmse_mean_per_time")["rmse_mean_per_time"]
            cases.append((f"direct {flavour}", "rmse_mean_per_time", ref, got))
            for metric in ["rmse", "mae", "acc"]:
                ref = sc.evaluate_iterative_forecast(it, truth, funcs[metric]).values
                got = run_pbdl(args.xtask, paths[("iter", flavour)], paths[("truth", flavour)], metric)
                assert got["lead_time"] == [int(l) for l in leads], got
                for l, r, g in zip(leads, ref, got[metric]):
                    cases.append((f"lead {l} h {flavour}", metric, float(r), g))
        for metric in ["rmse", "acc"]:
            ref = float(funcs[metric](fc_same, truth_same))
            got = run_pbdl(args.xtask, os.path.join(args.out, f"fc_{seed}.npy"), os.path.join(args.out, f"truth_{seed}.npy"),
                           metric, ["--lat", os.path.join(args.out, "lat.npy")])[metric]
            cases.append(("npy", metric, ref, got))
        for case, metric, ref, got in cases:
            rel = abs(got - ref) / max(abs(ref), 1e-30)
            worst = max(worst, rel)
            print(f"| {seed} | {case} | {metric} | {ref:.10g} | {got:.10g} | {rel:.1e} |")
    print(f"worst relative difference: {worst:.2e} (bar 1e-6)")
    sys.exit(0 if worst <= 1e-6 else 1)


if __name__ == "__main__":
    main()
