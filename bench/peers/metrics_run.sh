#!/usr/bin/env bash
# The official LSiM / VolSiM code (PyTorch CPU) as the peer of `cargo xtask bench metrics`
# (entry lsim), on the same threads (metrics_official.py says what is timed).
#
# The official repositories are not part of pbdl; clone them first:
#   git clone https://github.com/tum-pbs/LSIM && git clone https://github.com/tum-pbs/VOLSIM
# Uses the venv target/pbdl/diffusion-peers-venv (torch, created once as for diffusion_run.sh)
# and adds scipy to it. Writes target/pbdl/bench/metrics_peers.json; `cargo xtask bench metrics`
# merges it with the date and versions of the run. Without Python 3.10+, network access or the
# checkouts the peer is skipped with a message (exit 0).
#
# Usage: bench/peers/metrics_run.sh --lsim PATH/LSIM [--volsim PATH/VOLSIM] [--reps N]
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/diffusion-peers-venv"
out="$root/target/pbdl/bench/metrics_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
peer_torch
"$vpy" -c 'import scipy' 2>/dev/null || "$vpy" -m pip install --quiet scipy || skip "pip install scipy failed"
mkdir -p "$(dirname "$out")"
peer_run_pinned "$root/bench/peers/metrics_official.py" --out "$out" "$@" \
  || skip "metrics_official.py failed (see above)"
