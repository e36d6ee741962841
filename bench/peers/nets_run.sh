#!/usr/bin/env bash
# PyTorch CPU peer of `cargo xtask bench nets` (entry training_steps): the WeatherBench ResNet
# training step, a TecoGAN generator forward+backward and an LSTM forward+backward
# (nets_torch.py) on the same threads. Shares the venv of diffusion_run.sh
# (target/pbdl/diffusion-peers-venv; torch from PyPI, or PBDL_TORCH_INDEX for the CPU wheel).
# Writes target/pbdl/bench/nets_peers.json; `cargo xtask bench nets` merges it. Without Python
# 3.10+ or network access the peer is skipped with a message (exit 0).
#
# Usage: bench/peers/nets_run.sh [--reps N] [--only CASE]   (PBDL_THREADS=2 by default)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/diffusion-peers-venv"
out="$root/target/pbdl/bench/nets_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
if ! "$vpy" -c 'import torch' 2>/dev/null; then
  echo "peers: installing torch (CPU use) from ${PBDL_TORCH_INDEX:-PyPI}" >&2
  index=()
  [ -n "${PBDL_TORCH_INDEX:-}" ] && index=(--index-url "$PBDL_TORCH_INDEX")
  "$vpy" -m pip install --quiet "${index[@]}" torch numpy \
    || skip "pip install torch failed (no network or no wheel for this platform)"
fi

mkdir -p "$(dirname "$out")"
export OMP_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads" PBDL_THREADS="$threads"
pin=()
command -v taskset >/dev/null && pin=(taskset -c "0-$((threads - 1))")
"${pin[@]}" "$vpy" "$root/bench/peers/nets_torch.py" --out "$out" "$@" \
  || skip "nets_torch.py failed (see above)"
