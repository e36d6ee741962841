#!/usr/bin/env bash
# Peer benchmarks for `cargo xtask bench grid`: PhiFlow 3.4 (NumPy and JAX backends) and JAX-CFD
# 0.2.1 (finite-volume RK4 and spectral) on the Taylor-Green vortex and the lid-driven cavity.
#
# Creates a Python venv from PyPI in target/pbdl/peers-venv (once), runs grid_peers.py and writes
# target/pbdl/bench/grid_peers.json in the shared bench schema; `cargo xtask bench grid` merges it.
# Without Python 3.10+ or network access to PyPI the peers are skipped with a message (exit 0).
#
# Usage: bench/peers/run.sh [--quick]      (PBDL_THREADS=2 by default, as in pbdl's own rows)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/peers-venv"
out="$root/target/pbdl/bench/grid_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
if ! "$vpy" -c 'import phi, jax_cfd, jax' 2>/dev/null; then
  echo "peers: installing phiflow 3.4, jax-cfd 0.2.1, jax (CPU) from PyPI" >&2
  "$vpy" -m pip install --quiet --upgrade pip || skip "pip unavailable"
  "$vpy" -m pip install --quiet "phiflow==3.4.*" "jax-cfd==0.2.1" "jax[cpu]" numpy \
    || skip "pip install failed (no network or no wheels for this platform)"
fi

mkdir -p "$(dirname "$out")"
# Pin every backend to the same thread count as pbdl's rows.
export OMP_NUM_THREADS="$threads" OPENBLAS_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads"
export XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=$threads ${XLA_FLAGS:-}"
export JAX_PLATFORMS=cpu PBDL_THREADS="$threads"
pin=()
command -v taskset >/dev/null && pin=(taskset -c "0-$((threads - 1))")
"${pin[@]}" "$vpy" "$root/bench/peers/grid_peers.py" --out "$out" "$@" \
  || skip "grid_peers.py failed (see above)"
