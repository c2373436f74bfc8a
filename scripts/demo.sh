#!/usr/bin/env bash
# Set up (if needed) and run the main job on the embedded defaults: a straight skirt animated with
# learned wrinkles (shipped models in pretrained/) on the default body raising its arms, written to
# out/skirt_arm_raise.usda with an MP4 preview and a contact sheet. CPU is fine (~1-2 min).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/wrinkles animate --garment skirt --motion arm_raise --duration 2 --steps 20 --camera front \
    --out out/skirt_arm_raise.usda --preview out/skirt_arm_raise.mp4 --sheet out/skirt_arm_raise.png "$@"
