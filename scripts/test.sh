#!/usr/bin/env bash
# Set up (if needed) and run the test suite on CPU (Warp on cpu; GPU tests skip).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
.venv/bin/ruff check sim learn pipelines usd_io tests benchmarks tools
exec .venv/bin/python -m pytest -q -rs "$@"
