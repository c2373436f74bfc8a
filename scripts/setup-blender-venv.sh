#!/usr/bin/env bash
# Create .venv-blender: Blender 4.5 as a Python module (PyPI `bpy`), used only by
# tests/test_blender_import.py to check that our USD stages import into Blender.
#
# bpy 4.5 needs CPython 3.11 exactly and numpy<2. The wheel is large (~350 MB).
#
# Usage: scripts/setup-blender-venv.sh [python3.11]
#   WRINKLES_BLENDER_VENV=/path  overrides the venv location (default: <repo>/.venv-blender).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${WRINKLES_BLENDER_VENV:-$here/.venv-blender}"
py="${1:-python3.11}"

if ! command -v "$py" >/dev/null 2>&1; then
    echo "setup-blender-venv: '$py' not found; bpy 4.5 needs Python 3.11" >&2
    exit 2
fi
ver="$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if [[ "$ver" != "3.11" ]]; then
    echo "setup-blender-venv: '$py' is Python $ver; bpy 4.5 needs Python 3.11" >&2
    exit 2
fi

if [[ ! -x "$venv/bin/python" ]]; then
    "$py" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --upgrade pip
"$venv/bin/python" -m pip install "bpy==4.5.*" "numpy<2"
"$venv/bin/python" -c 'import bpy; print("bpy", bpy.app.version_string, "ready in '"$venv"'")'
