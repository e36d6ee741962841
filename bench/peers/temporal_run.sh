#!/usr/bin/env bash
# PyTorch CPU peer of `cargo xtask bench temporal` (entry generation_vs_solver): the generator's
# time per frame at 16->64 and 64->256 and one training update of each objective (baseline,
# per-frame GAN, temporal GAN) at 16->64 with a batch of 4 triplets (temporal_torch.py), on the
# same threads. Shares the venv of diffusion_run.sh (target/pbdl/diffusion-peers-venv; torch from
# PyPI, or PBDL_TORCH_INDEX for the CPU wheel). Writes target/pbdl/bench/temporal_peers.json;
# `cargo xtask bench temporal` merges it. Without Python 3.10+ or network access the peer is
# skipped with a message (exit 0).
#
# Usage: bench/peers/temporal_run.sh [--reps N] [--warmup N] [--only CASE]   (PBDL_THREADS=2 by default)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/diffusion-peers-venv"
out="$root/target/pbdl/bench/temporal_peers.json"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
peer_torch
mkdir -p "$(dirname "$out")"
# OpenMP threads that spin while waiting (libgomp's default) lose their time slices when other
# processes share the cores: on this 2-core machine with a training run beside it the generator
# forward took 24-36 ms per frame spinning vs 11.5 ms passive. PASSIVE unless set (e.g. ACTIVE on
# an idle machine); the rows' stamp names the policy.
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"
peer_run_pinned "$root/bench/peers/temporal_torch.py" --out "$out" "$@" \
  || skip "temporal_torch.py failed (see above)"
