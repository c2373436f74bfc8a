#!/usr/bin/env bash
# How GSNet's figures (docs/GSNET.md) and shipped weights are made: generate the multi-garment
# dataset (pipelines/configs/gsnet.toml: six designs in training, two held out), train GSNet, its
# ablations (no temporal input, no physical regression, no learned joint edges, 4 joint edges a
# vertex), the skinned_mlp baseline and linear blend skinning (lbs) on the same data, export
# release weights (WORKDIR/release), evaluate every row on test_id and test_ood (all sequences),
# write GSNet's Tables 1-3 and time GSNet (all and 4 joint edges a vertex) against the simulator.
# Needs a CUDA GPU (two are used when present). Time-boxed and resumable as
# scripts/train_pretrained.sh: generation and training stop at their budgets; run it again to go
# on. Exits 1 when a training, the export or an evaluation failed.
#   bash scripts/train_gsnet.sh WORKDIR [GEN_SECONDS] [TRAIN_SECONDS]
# STAGES picks stages (default "generate train export evaluate bench"); ABLATION_STEPS the
# ablations' and the baseline's steps (default 3000); MAXSEQ limits the sequences evaluated per
# split (default: all). DEVICE=cpu and DATA_CONFIG=sample make a small CPU run of it; EXTRA_SET
# holds --set overrides of every training (train.* and optim.* keys: the skinned_mlp baseline has
# other model.* keys).
set -u
W=$(realpath -m "${1:?work directory}"); GEN=${2:-420}; TRAIN=${3:-600}
cd "$(dirname "$0")/.."  # configs and `-m pipelines.cli` are the repository's
for n in "$GEN" "$TRAIN"; do
  [[ "$n" =~ ^[0-9]+$ ]] || { echo "GEN_SECONDS and TRAIN_SECONDS must be whole seconds, got '$n'" >&2; exit 2; }
done
source scripts/stages.sh "generate train export evaluate bench" "generate train export evaluate bench"
PY=${PYTHON:-python3}
CLI="$PY -m pipelines.cli"
D="$W/data/gsnet"
CFG=pipelines/configs/train/gsnet.toml
DEVICE=${DEVICE:-cuda}; DATA_CONFIG=${DATA_CONFIG:-pipelines/configs/gsnet.toml}
UNSEEN=flared_skirt,long_sleeve
mkdir -p "$W/logs" "$W/runs" "$W/eval" "$W/release"; rm -f "$W/.failed"
GPUS=$($PY -c "import torch; print(max(1, torch.cuda.device_count()))") || { echo "$PY cannot import torch" >&2; exit 2; }
gpu() { [ "$DEVICE" = cpu ] && echo cpu || echo "cuda:$(( $1 % GPUS ))"; }  # the k-th job's device

if stage generate; then
  log "generate (budget ${GEN}s)"
  resume=""; [ -d "$D/parts" ] && resume="--resume"
  timeout -s INT "$GEN" $CLI dataset generate --config "$DATA_CONFIG" --out "$D" \
    --batch ${BATCH:-32} --device "$DEVICE" -q $resume >>"$W/logs/gen.log" 2>&1
  $CLI dataset combine "$D" 2>&1 | tail -2 | tee -a "$W/logs/pipeline.log"
  $CLI dataset info "$D" 2>&1 | head -24 | tee -a "$W/logs/pipeline.log"
fi

if stage train; then
  log "train (budget ${TRAIN}s, $GPUS GPU(s))"
  AB=${ABLATION_STEPS:-3000}
  train() {  # name method device [overrides...]; 4 CPU threads each, seven at once
    local name=$1 method=$2 dev=$3; shift 3
    local resume=""; [ -f "$W/runs/$name/checkpoints/last.pt" ] && resume="--resume"
    local cfg=$CFG; [ "$method" = gsnet ] || cfg=pipelines/configs/train/gsnet_baseline.toml
    OMP_NUM_THREADS=4 timeout -s INT "$TRAIN" $CLI train "$method" --data "$D" --out "$W/runs/$name" --config "$cfg" \
      --device "$dev" -q ${EXTRA_SET:-} "$@" $resume >"$W/logs/train-$name.log" 2>&1
  }
  pids=()
  train gsnet gsnet "$(gpu 0)" & pids+=($!)
  train gsnet_notemp gsnet "$(gpu 1)" --set model.temporal=false --set train.steps=$AB & pids+=($!)
  train gsnet_noreg gsnet "$(gpu 1)" --set model.regression=false --set train.steps=$AB & pids+=($!)
  train gsnet_noedges gsnet "$(gpu 0)" --set model.learned_edges=false --set train.steps=$AB & pids+=($!)
  train skinned_mlp skinned_mlp "$(gpu 1)" --set train.steps=$AB & pids+=($!)
  train gsnet_top4 gsnet "$(gpu 0)" --set model.joint_topk=4 --set train.steps=$AB & pids+=($!)
  # lbs: the body's skinning weights carried to the garment, nothing learned (one step at lr 1e-12
  # writes the untrained network, whose zero-initialised heads leave the skinning as it is), then
  # GSNet's projection out of the body, so its collision column compares with GSNet's
  train lbs gsnet "$(gpu 1)" --set model.learned_edges=false --set model.regression=false \
    --set train.steps=1 --set optim.lr=1e-12 & pids+=($!)
  for p in "${pids[@]}"; do  # 124: stopped at the budget (timeout's SIGINT), resumable; else failed
    wait "$p"; rc=$?; [ $rc -eq 0 ] || [ $rc -eq 124 ] || { log "a training failed ($rc)"; touch "$W/.failed"; }
  done
  for f in "$W"/logs/train-*.log; do log "$(basename $f): $(tail -1 $f)"; done
fi

if stage export; then
  log "export"
  $PY -m learn.train.export "$W/runs/gsnet/checkpoints/last.pt" "$W/release/gsnet.pt" \
    && log "exported: $(du -h "$W/release/gsnet.pt" | cut -f1)" || { log "export failed"; touch "$W/.failed"; }
fi

if stage evaluate; then
  log "evaluate"
  # fourteen evaluations at once, 2 CPU threads each: with torch's default (every core each) the
  # CPU metrics oversubscribe the host, and 12 evaluations on an H200 x2 host (32 cores) did not
  # finish 23 sequences in 356 s
  ev() {  # row split model device
    local row=$1 split=$2 model=$3 dev=$4
    OMP_NUM_THREADS=2 $CLI evaluate --model "$model" --data "$D" --split "$split" --out "$W/eval/$row-$split" --no-images \
      --image-resolution 0 ${MAXSEQ:+--max-sequences $MAXSEQ} --device "$dev" >"$W/logs/eval-$row-$split.log" 2>&1 \
      || { log "evaluate $row $split failed"; touch "$W/.failed"; }
  }
  k=0
  for row in gsnet gsnet_notemp gsnet_noreg gsnet_noedges gsnet_top4 skinned_mlp lbs; do
    m="$W/runs/$row/checkpoints/last.pt"; [ "$row" = gsnet ] && [ -f "$W/release/gsnet.pt" ] && m="$W/release/gsnet.pt"
    for split in test_id test_ood; do ev $row $split "$m" "$(gpu $k)" & k=$((k + 1)); done
  done
  wait
  $PY -m benchmarks.gsnet_tables "$W/eval" --out "$W/tables.md" --json "$W/tables.json" --unseen $UNSEEN \
    | tee -a "$W/logs/pipeline.log"
fi

if stage bench; then
  log "bench"
  m="$W/release/gsnet.pt"; [ -f "$m" ] || m="$W/runs/gsnet/checkpoints/last.pt"
  $PY -m benchmarks.bench_gsnet --device "$DEVICE" --vertices ${BENCH_VERTICES:-5000,20000} --seconds 2 --model "$m" \
    --joint-topk 0,4 \
    --results "$W/bench" >"$W/logs/bench.log" 2>&1 || log "bench failed (see $W/logs/bench.log)"
fi

log "done"
[ -f "$W/.failed" ] && { log "some stages failed (see $W/logs/)"; exit 1; }
exit 0
