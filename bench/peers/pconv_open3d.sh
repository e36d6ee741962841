#!/usr/bin/env bash
# Opt-in peer for pbdl-pconv's bench (pbdl-pconv/benches/pconv.rs): Open3D's ContinuousConv
# (open3d.ml.tf on the CPU) forward and forward + backward on the same 3D cases, on
# $PBDL_THREADS (default 2) pinned cores. Open3D's ops are built against one TensorFlow release
# (open3d-cpu 0.20.0: TensorFlow 2.20, PyTorch 2.13): the venv gets tensorflow-cpu 2.20 from
# PyPI (PyPI's torch 2.13 is the CUDA build with several GB of dependencies, hence TF). Open3D
# needs libusb-1.0 (`sudo apt-get install libusb-1.0-0`); this script only prints that command.
# Open3D's op has no gradient for positions: its forward+backward rows cover features and kernel.
#
# Creates target/pbdl/pconv-peers-venv once; writes JSON lines to
# target/pbdl/bench/pconv_open3d.jsonl. Without python 3.10+ or PyPI it skips with a message.
#
# Usage: bench/peers/pconv_open3d.sh [N ...]   (default: 10000 100000)
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/pbdl/pconv-peers-venv"
out="$root/target/pbdl/bench/pconv_open3d.jsonl"
threads="${PBDL_THREADS:-2}"

. "$root/bench/peers/venv.sh"
peer_venv "$venv"
if ! "$vpy" -c 'import numpy, scipy, tensorflow, open3d.ml.tf' 2>/dev/null; then
  echo "peers: installing tensorflow-cpu 2.20, scipy and open3d-cpu 0.20.0 from PyPI (~700 MB)" >&2
  "$vpy" -m pip install --quiet "tensorflow-cpu==2.20.*" scipy "open3d-cpu==0.20.0" \
    || skip "pip install of tensorflow-cpu / open3d-cpu failed (no network or no wheels)"
fi
if ! "$vpy" -c 'import open3d.ml.tf' 2>/dev/null; then
  if "$vpy" -c 'import open3d' 2>&1 | grep -q libusb; then
    skip "open3d needs libusb-1.0: run \`sudo apt-get install libusb-1.0-0\` (Debian/Ubuntu) to measure it"
  fi
  "$vpy" -c 'import open3d.ml.tf' || skip "open3d.ml.tf does not import (see the message above)"
fi
mkdir -p "$(dirname "$out")"
peer_run_pinned "$root/bench/peers/pconv_open3d.py" "$@" | tee "$out"
