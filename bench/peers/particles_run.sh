#!/usr/bin/env bash
# Peer benchmarks for `cargo xtask bench particles`: SciPy cKDTree and Open3D fixed-radius
# neighbour search on pbdl's 100k-point sets, PySPH's dam_break_2d example at dx = 0.05.
#
# Creates a Python venv from PyPI in target/pbdl/particles-peers-venv (once), runs
# particles_peers.py and writes target/pbdl/bench/particles_peers.json in the shared bench schema;
# `cargo xtask bench particles` merges it. numpy and scipy are required; open3d and pysph are
# optional (a failed install or import skips their rows with a message). PySPH has no wheels: pip
# builds it from source (Cython, a C compiler; ~10-15 minutes on 2 cores), and its example
# compiles its kernels on the first run. Open3D needs libusb-1.0 (Debian/Ubuntu:
# `sudo apt-get install libusb-1.0-0`); this script only prints that command.
# Without Python 3.10+ or network access to PyPI the peers are skipped with a message (exit 0).
#
# Usage: bench/peers/particles_run.sh [--quick] [--only neighbors|pysph]
#        (PBDL_THREADS=2 by default, as in pbdl's own rows)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/particles-peers-venv"
out="$root/target/pbdl/bench/particles_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
if ! "$vpy" -c 'import numpy, scipy' 2>/dev/null; then
  echo "peers: installing numpy and scipy from PyPI" >&2
  "$vpy" -m pip install --quiet --upgrade pip || skip "pip unavailable"
  "$vpy" -m pip install --quiet numpy scipy || skip "pip install numpy scipy failed (no network or no wheels)"
fi
# Optional peers: try to install once; a marker file stops retrying a failed install every run
# (delete it to retry).
optional() { # module, pip spec, what the install needs
  local mod="$1" spec="$2" marker="$venv/.no-$1"
  if "$vpy" -c "import $mod" 2>/dev/null || [ -e "$marker" ]; then return; fi
  if ! "$vpy" -m pip show "$mod" >/dev/null 2>&1; then
    echo "peers: installing $spec from PyPI ($3)" >&2
    if ! "$vpy" -m pip install --quiet "$spec"; then
      echo "peers: $spec did not install; its rows will be skipped (rm $marker to retry)" >&2
      touch "$marker"
    fi
  fi
}
optional open3d "open3d" "wheel, ~400 MB"
optional pysph "pysph==1.0b2" "source build with Cython and a C compiler, ~10-15 minutes"
if "$vpy" -m pip show open3d >/dev/null 2>&1 && ! "$vpy" -c 'import open3d' 2>/dev/null; then
  if "$vpy" -c 'import open3d' 2>&1 | grep -q libusb; then
    echo "peers: open3d needs libusb-1.0: run \`sudo apt-get install libusb-1.0-0\` (Debian/Ubuntu) to measure it" >&2
  fi
fi

mkdir -p "$(dirname "$out")"
# Pin every backend to the same thread count as pbdl's rows.
export OMP_NUM_THREADS="$threads" OPENBLAS_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads"
export PBDL_THREADS="$threads"
pin=()
command -v taskset >/dev/null && pin=(taskset -c "0-$((threads - 1))")
"${pin[@]}" "$vpy" "$root/bench/peers/particles_peers.py" --out "$out" "$@" \
  || skip "particles_peers.py failed (see above)"
