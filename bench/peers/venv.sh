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
