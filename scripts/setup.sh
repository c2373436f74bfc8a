#!/usr/bin/env bash
# Set up wrinkles in ./.venv on a fresh machine (Linux/macOS, Python >= 3.10).
#
# torch: on a machine without an NVIDIA GPU this installs the CPU wheel torch==2.13.0 FIRST, so
# nothing later can pull gigabytes of CUDA packages. On a GPU machine it installs nothing of
# torch unless asked: install your CUDA build beforehand, e.g.
#     .venv/bin/pip install torch --index-url https://download.pytorch.org/whl/cu128
# or set WRINKLES_TORCH_SPEC (e.g. "torch==2.13.0") to have this script install it.
# Re-running is cheap: it does nothing when pyproject.toml has not changed.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
py=${PYTHON:-python3}
venv=${WRINKLES_VENV:-$root/.venv}
stamp="$venv/.wrinkles-setup"
want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -c1-16)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$venv/bin/python" -c "import sim, warp, pxr" 2>/dev/null; then
  exit 0
fi
echo "setting up $venv ..." >&2
[ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
pip=("$venv/bin/python" -m pip --disable-pip-version-check -q)
"${pip[@]}" install --upgrade pip >/dev/null
if ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
  if [ -n "${WRINKLES_TORCH_SPEC:-}" ]; then
    "${pip[@]}" install "$WRINKLES_TORCH_SPEC"
  elif command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
    echo "NVIDIA GPU found and no torch installed: installing the default (CUDA) torch wheel;" \
         "set WRINKLES_TORCH_SPEC to choose another build." >&2
    "${pip[@]}" install torch
  else
    "${pip[@]}" install "torch==2.13.0"   # CPU wheel: never pull CUDA packages onto a CPU machine
  fi
fi
"${pip[@]}" install -e ".[dev]"
# the reference SMPL implementation, for the parity test only (its deps are torch + numpy)
"${pip[@]}" install --no-deps "smplx>=0.1.28"
echo "$want" > "$stamp"
echo "ready: $venv/bin/wrinkles" >&2
