#!/usr/bin/env bash
# Set up (if needed) and run the main job on the embedded defaults: a t-shirt animated with
# learned wrinkles (shipped models in pretrained/) on the default body walking, written to
# out/tshirt_walk.usda with an MP4 preview and a contact sheet. CPU is fine (~1-2 min).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/wrinkles animate --garment tshirt --motion walk --duration 2 --steps 20 --camera front \
    --out out/tshirt_walk.usda --preview out/tshirt_walk.mp4 --sheet out/tshirt_walk.png "$@"
