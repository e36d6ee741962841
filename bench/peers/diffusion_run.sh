#!/usr/bin/env bash
# PyTorch CPU peer of `cargo xtask bench diffusion` (entry acdm_unet): the same ACDM U-Net
# training and sampling step (acdm_unet_torch.py) on the same threads.
#
# Creates a Python venv in target/pbdl/diffusion-peers-venv (once) and installs torch from
# PyPI. The PyPI wheel is the CUDA build (about 5 GB with its nvidia-* dependencies; it runs on
# the CPU without a GPU); with access to download.pytorch.org set
# PBDL_TORCH_INDEX=https://download.pytorch.org/whl/cpu for the small CPU wheel instead.
# Writes target/pbdl/bench/diffusion_peers.json in the shared bench schema;
# `cargo xtask bench diffusion` merges it. Without Python 3.10+ or network access the peer is
# skipped with a message (exit 0).
#
# Usage: bench/peers/diffusion_run.sh [--full] [--reps N]   (PBDL_THREADS=2 by default)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/diffusion-peers-venv"
out="$root/target/pbdl/bench/diffusion_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
peer_torch
mkdir -p "$(dirname "$out")"
peer_run_pinned "$root/bench/peers/acdm_unet_torch.py" --out "$out" "$@" \
  || skip "acdm_unet_torch.py failed (see above)"
