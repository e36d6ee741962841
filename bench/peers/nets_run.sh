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
peer_torch
mkdir -p "$(dirname "$out")"
peer_run_pinned "$root/bench/peers/nets_torch.py" --out "$out" "$@" \
  || skip "nets_torch.py failed (see above)"
