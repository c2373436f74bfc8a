#!/usr/bin/env bash
# Set up (if needed) and run the main job on the embedded defaults: a t-shirt animated with
# learned wrinkles (shipped models in pretrained/) on the default body walking, written to
# out/tshirt_walk.usdc with an MP4 preview and a contact sheet. CPU is fine (~1.5 min on 2 cores).
# 10 DDIM steps: on the shipped t-shirt's test split they give the wrinkles of 20 and 50 (Ev 0.647
# against 0.662 and 0.741 mm, docs/WRINKLES.md) at a fifth of 50 steps' time.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/wrinkles animate --garment tshirt --motion walk --duration 2 --steps 10 --camera front \
    --out out/tshirt_walk.usdc --preview out/tshirt_walk.mp4 --sheet out/tshirt_walk.png "$@"
