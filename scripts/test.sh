#!/usr/bin/env bash
# Set up (if needed) and run the test suite on CPU (Warp on cpu; GPU tests skip).
#
# The tests run in parallel worker processes (pytest-xdist), one file per worker at a time
# (`--dist loadfile`: a file's module fixtures are built once), as many workers as cores up to 4
# (WRINKLES_TEST_WORKERS overrides; 0 runs in this process). Each worker's torch and OpenMP use
# one thread, so the workers do not oversubscribe the cores.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
.venv/bin/ruff check sim learn pipelines usd_io tests benchmarks tools
cores=$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 1)
workers=${WRINKLES_TEST_WORKERS:-$(( cores < 4 ? cores : 4 ))}
if [ "$workers" -gt 1 ]; then
  export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
  exec .venv/bin/python -m pytest -q -rs -n "$workers" --dist loadfile "$@"
fi
exec .venv/bin/python -m pytest -q -rs "$@"
