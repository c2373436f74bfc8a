#!/usr/bin/env bash
# Make room in .gpu1 for the project tree (session 39). Every device call carries the tracked tree
# (~38 MB) beside its carried folders, 64 MiB in all; gpu-warp-pack's .gpu1 (~28.5 MB) left
# ~0.2 MB, and the tree grows with every session's results. This moves all but the first 20 MB
# of .gpu1's warp.so.xz.00 into the stashed part with the CPU backend (.gpu4, ~27 MB after),
# as warp.so.xz.005: install.sh joins /tmp/stash/warp.so.xz.* in name order, and .005 sorts
# between .00 and .01. Run once after `WITH_CLANG=1 ../shared/tools/gpu-warp-pack 1.19.0`, then
# stash .gpu2, .gpu3 and .gpu4 as before (docs/BENCHMARKS.md, "GPU machine").
set -euo pipefail
root=$(git rev-parse --show-toplevel)
first="$root/.gpu1/warp.so.xz.00"
keep=20000000
[ -f "$first" ] || { echo "no $first: run gpu-warp-pack first" >&2; exit 2; }
[ -d "$root/.gpu4" ] || { echo "no .gpu4: pack with WITH_CLANG=1" >&2; exit 2; }
size=$(stat -c %s "$first")
if [ "$size" -le "$keep" ]; then echo ".gpu1 already split ($size bytes)"; exit 0; fi
tail -c +$((keep + 1)) "$first" > "$root/.gpu4/warp.so.xz.005"
truncate -s "$keep" "$first"
cat "$first" "$root/.gpu4/warp.so.xz.005" "$root"/.gpu2/warp.so.xz.01 "$root"/.gpu3/warp.so.xz.02 | xz -t
du -sh "$root"/.gpu1 "$root"/.gpu4
