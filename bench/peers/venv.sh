# Shared by the peer scripts (sourced, not run): skip with a message instead of failing, and make
# a Python 3.10+ venv once. After `peer_venv DIR`, "$vpy" is the venv's python.
skip() { echo "peers: skipped: $*" >&2; exit 0; }

peer_venv() {
  local venv="$1" py
  py="$(command -v python3 || true)"
  [ -n "$py" ] || skip "python3 not found"
  "$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else 1)' || skip "python >= 3.10 needed ($("$py" --version))"
  if [ ! -x "$venv/bin/python" ]; then
    echo "peers: creating $venv" >&2
    "$py" -m venv "$venv" || skip "python3 -m venv failed (install python3-venv)"
  fi
  vpy="$venv/bin/python"
}

# After `peer_venv`: installs torch (and numpy) into the venv unless it imports already. PyPI's
# wheel is the CUDA build (about 5 GB; runs on the CPU); PBDL_TORCH_INDEX (e.g.
# https://download.pytorch.org/whl/cpu) picks another index.
peer_torch() {
  if ! "$vpy" -c 'import torch' 2>/dev/null; then
    echo "peers: installing torch (CPU use) from ${PBDL_TORCH_INDEX:-PyPI}" >&2
    local index=()
    [ -n "${PBDL_TORCH_INDEX:-}" ] && index=(--index-url "$PBDL_TORCH_INDEX")
    "$vpy" -m pip install --quiet "${index[@]}" torch numpy \
      || skip "pip install torch failed (no network or no wheel for this platform)"
  fi
}

# Runs the python script "$@" with the venv's python on the first $threads cores (taskset where
# present), with OpenMP/MKL/PBDL thread counts set to $threads.
peer_run_pinned() {
  export OMP_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads" PBDL_THREADS="$threads"
  local pin=()
  command -v taskset >/dev/null && pin=(taskset -c "0-$((threads - 1))")
  "${pin[@]}" "$vpy" "$@"
}
