#!/bin/bash
# Run benchmark command lines on a GPU machine one after another, each with a time limit and a
# log (docs/BENCHMARKS.md, "How to run"), from the repository root:
#     CMDS_FILE=cmds.txt bash benchmarks/gpu_batch.sh
# Each non-empty line of CMDS_FILE not starting with '#' runs under `timeout ${TMO:-500}` with its
# output in /tmp/gpu_batch/cmd_N.log; the last ${TAIL:-6} lines of each are printed. Where the
# machine has no Warp, .gpu1/install.sh (../shared/tools/gpu-warp-pack) installs it into
# /tmp/site first. Where OUT is set, the result files the lines wrote (benchmarks/results/*.json)
# go to $OUT/results, and with every log to $OUT/all.tgz.
set -u
if [ -f .gpu1/install.sh ]; then
  bash .gpu1/install.sh > /tmp/install.log 2>&1 || { tail -20 /tmp/install.log; exit 1; }
  export PYTHONPATH=/tmp/site:$PWD
fi
logs=/tmp/gpu_batch
mkdir -p "$logs"
touch "$logs/.start"
n=0
while IFS= read -r line; do
  [ -z "$line" ] && continue
  case "$line" in \#*) continue;; esac
  n=$((n + 1))
  echo "=== [$n] $line  ($(date +%T))"
  timeout "${TMO:-500}" bash -c "$line" < /dev/null > "$logs/cmd_$n.log" 2>&1
  echo "rc=$? ($(date +%T))"
  tail -n "${TAIL:-6}" "$logs/cmd_$n.log"
done < "${CMDS_FILE:?set CMDS_FILE to a file of command lines}"
if [ -n "${OUT:-}" ]; then
  mkdir -p "$OUT/results"
  find benchmarks/results -name '*.json' -newer "$logs/.start" -exec cp {} "$OUT/results/" \;
  tar czf "$OUT/all.tgz" -C /tmp gpu_batch -C "$OUT" results
fi
