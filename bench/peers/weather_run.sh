#!/usr/bin/env bash
# Peer of `cargo xtask bench weather`: WeatherBench's official score.py (xarray) and xarray's
# NetCDF reading on a year of hourly 32x64 fields (weather_score_speed.py). Needs a clone of
# https://github.com/pangeo-data/WeatherBench (its src/score.py is not part of pbdl):
#   bench/peers/weather_run.sh /path/to/WeatherBench [--reps N]
# Makes the venv target/pbdl/weather-peers-venv (xarray, netCDF4, h5netcdf from PyPI); writes
# target/pbdl/bench/weather_peers.json, which `cargo xtask bench weather` merges, and the year
# files target/pbdl/weather-bench/truth_year_{nc4,nc3}.nc that the pbdl entry reads too.
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
threads="${PBDL_THREADS:-2}"
wb="${1:-}"
[ -n "$wb" ] && [ -f "$wb/src/score.py" ] || { echo "usage: $0 /path/to/WeatherBench [--reps N]" >&2; exit 2; }
shift
. "$root/bench/peers/venv.sh"
peer_venv "$root/target/pbdl/weather-peers-venv"
"$vpy" -c 'import xarray, netCDF4' 2>/dev/null || "$vpy" -m pip install --quiet xarray netCDF4 h5netcdf numpy pandas \
  || skip "pip install xarray netCDF4 failed (no network?)"
cd "$root" && peer_run_pinned "$root/bench/peers/weather_score_speed.py" --score-py "$wb/src/score.py" --root "$root" "$@"
