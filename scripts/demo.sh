#!/usr/bin/env bash
# Set up (if needed) and run the main job on the embedded defaults: the default body walking,
# written to out/walk.usda with an MP4 preview and a contact sheet.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/wrinkles body --motion walk --camera front --out out/walk.usda --preview out/walk.mp4 --sheet out/walk.png "$@"
