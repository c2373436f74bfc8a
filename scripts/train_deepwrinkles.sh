#!/usr/bin/env bash
# DeepWrinkles on the t-shirt, end to end (docs/DEEPWRINKLES.md): generate the data
# (pipelines/configs/tshirt_deepwrinkles.toml), train the paper-sized model with Eq. 4's temporal
# term and without it and the shipped one (RELEASE_SET: 16 filters, 200 components, 2 LSTM layers:
# 15 MB in float16) on the template's true places (SOURCE=simulation; SOURCE=registration trains
# on scans registered first, as the paper), register the first test_id sequences' scans, export
# the models and evaluate them: the paper's Table 1 inputs (registration of scans, the true places,
# subspace 500 / 200, LSTM and linear regression) and the rows of Guo et al.'s tables (test_id,
# test_ood; also the paper-sized model on the upper body's joints only, Sec. 5.3), then the
# tables (benchmarks.wrinkle_tables). With BASELINES=1 (the default) Guo et al.'s coarse
# (skeleton_cvae) and wrinkle (wrinkle_diffusion) models train on the same data beside them and
# are evaluated on the same test sequences, so the tables compare the methods on one split (rows
# base, coarse, ours: 3 sampling seeds). Needs a CUDA GPU. Time-boxed and
# resumable like scripts/train_pretrained.sh: generation and training stop at their budgets
# (SIGINT), a rerun continues; registrations are cached beside the data.
#   bash scripts/train_deepwrinkles.sh WORKDIR [GEN_SECONDS] [TRAIN_SECONDS]
# STAGES picks stages (default "generate register train export evaluate"); WORKERS registration
# processes (default 14), EVERY registers every k-th frame (default 6), MAXSEQ test sequences
# per evaluation (default 6), EXTRA_SET more --set options of the trainings, DEVICE (default cuda),
# DATA_CONFIG the generator config, LOADERS data-loader workers per training (default 4),
# TRAIN_DEVICES the devices of the three trainings (e.g. "cuda:0 cuda:1 cuda:1" on two GPUs),
# RELEASE_MODEL a release file (e.g. pretrained/t_shirt-deepwrinkles.pt) evaluated as the shipped-size
# model instead of training one (its data is made again bit for bit from the same config),
# BASELINE_DEVICE the device of Guo et al.'s two (default: the first of TRAIN_DEVICES), BASELINE_SET
# their --set options.
set -u -o pipefail
W=${1:?work directory}; GEN=${2:-400}; TRAIN=${3:-600}
source "$(dirname "$0")/stages.sh" "generate register train export evaluate" "generate register train export evaluate"
PY=${PYTHON:-python3}
CLI="$PY -m pipelines.cli"
D="$W/data/tshirt"
CFG=pipelines/configs/train/deepwrinkles.toml
DATA_CONFIG=${DATA_CONFIG:-pipelines/configs/tshirt_deepwrinkles.toml}
DEVICE=${DEVICE:-cuda}
SOURCE=${SOURCE:-simulation}
SET="--set model.workers=${WORKERS:-14} --set model.register_every=${EVERY:-6} --set model.source='$SOURCE' ${EXTRA_SET:-}"
RELEASE_SET=${RELEASE_SET:-"--set model.filters=16 --set model.components=200 --set model.layers=2"}
mkdir -p "$W/logs" "$W/runs" "$W/eval" "$W/release"

if stage generate; then
  log "generate (budget ${GEN}s)"
  resume=""; [ -d "$D/parts" ] && resume="--resume"
  timeout -s INT "$GEN" $CLI dataset generate --config "$DATA_CONFIG" --out "$D" \
    --batch ${BATCH:-32} --device $DEVICE -q $resume >>"$W/logs/gen.log" 2>&1
  $CLI dataset combine "$D" 2>&1 | tail -2 | tee -a "$W/logs/pipeline.log"
  $CLI dataset info "$D" 2>&1 | head -12 | tee -a "$W/logs/pipeline.log"
fi

if stage register; then
  log "register"
  register() {
    $PY -m learn.deepwrinkles.training "$D" --workers ${WORKERS:-14} --every ${EVERY:-6} \
      --garment t_shirt "$@" >>"$W/logs/register.log" 2>&1 || log "registration failed (see $W/logs/register.log)"
    tr '\r' '\n' < "$W/logs/register.log" | grep "registered," | tail -1 | tee -a "$W/logs/pipeline.log"
  }
  register --split train --source "$SOURCE"  # SOURCE=simulation: the true places, in seconds
  register --split test_id --max-sequences ${MAXSEQ:-6} --source registration  # the scan rows
fi

if stage train; then
  log "train (budget ${TRAIN}s)"
  train() {  # name method config device [overrides...]
    local name=$1 method=$2 cfg=$3 dev=$4; shift 4
    local resume=""; [ -f "$W/runs/$name/checkpoints/last.pt" ] && resume="--resume"
    timeout -s INT "$TRAIN" $CLI train "$method" --data "$D" --out "$W/runs/$name" --config "$cfg" \
      --device $dev -q --set train.num_workers=${LOADERS:-4} "$@" $resume >"$W/logs/train-$name.log" 2>&1
  }
  read -r dev_dw dev_notemp dev_release <<< "${TRAIN_DEVICES:-$DEVICE $DEVICE $DEVICE}"
  train dw deepwrinkles $CFG "$dev_dw" $SET &
  train dw-notemp deepwrinkles $CFG "$dev_notemp" $SET --set model.temporal_weight=0.0 &
  train dw-upper deepwrinkles $CFG "$dev_notemp" $SET --set "model.control_joints='upper'" &  # Sec. 5.3
  [ -z "${RELEASE_MODEL:-}" ] && train release deepwrinkles $CFG "$dev_release" $SET $RELEASE_SET &
  if [ "${BASELINES:-1}" = 1 ]; then  # Guo et al.'s models with their configs' settings (BASELINE_SET: more)
    bdev=${BASELINE_DEVICE:-$dev_dw}
    train coarse coarse pipelines/configs/train/coarse.toml "$bdev" ${BASELINE_SET:-} &
    train wrinkles wrinkles pipelines/configs/train/wrinkles.toml "$bdev" ${BASELINE_SET:-} &
  fi
  wait
  for f in "$W"/logs/train-*.log; do log "$(basename $f): $(tail -1 $f)"; done
fi

if stage export; then
  log "export"
  names="dw dw-notemp dw-upper"; [ -z "${RELEASE_MODEL:-}" ] && names="$names release"
  for name in $names; do
    $PY -m learn.train.export "$W/runs/$name/checkpoints/last.pt" "$W/release/t_shirt-$name.pt"
  done
  cp "${RELEASE_MODEL:-$W/release/t_shirt-release.pt}" "$W/release/t_shirt-deepwrinkles.pt"
  if [ "${BASELINES:-1}" = 1 ]; then
    for name in coarse wrinkles; do
      $PY -m learn.train.export "$W/runs/$name/checkpoints/last.pt" "$W/release/t_shirt-$name.pt"
    done
  fi
fi

if stage evaluate; then
  log "evaluate"
  rm -f "$W/.eval_failed"
  images=""; $PY -c "import pyvista" 2>/dev/null || images="--no-images"  # renders need pyvista
  ev() {  # out-name split model args...
    local name=$1 split=$2 model=$3; shift 3
    OMP_NUM_THREADS=2 $CLI evaluate --model "$model" --data "$D" --split "$split" --out "$W/eval/$name-$split" \
      --max-sequences ${MAXSEQ:-6} --device $DEVICE $images -q "$@" >"$W/logs/eval-$name-$split.log" 2>&1 \
      || { log "evaluate $name $split failed"; touch "$W/.eval_failed"; }
  }
  # folders EVAL/<garment>-<row>-<split>: python -m benchmarks.wrinkle_tables "$W/eval" makes the tables
  M="$W/release/t_shirt-dw.pt"; N="$W/release/t_shirt-dw-notemp.pt"; R="$W/release/t_shirt-deepwrinkles.pt"
  ev t_shirt-deepwrinkles test_id "$M" &
  ev t_shirt-deepwrinkles test_ood "$M" &
  scans="--predict lr_input=registration --predict source=registration"
  ev t_shirt-dw_registration test_id "$M" $scans &
  ev t_shirt-dw_truth test_id "$M" --predict lr_input=registration --predict source=simulation &
  ev t_shirt-dw_bs500 test_id "$M" --predict lr_input=subspace --predict components=500 &
  ev t_shirt-dw_bs200 test_id "$M" --predict lr_input=subspace --predict components=200 &
  ev t_shirt-dw_linear test_id "$M" --predict regressor=linear &
  ev t_shirt-dw_notemp_registration test_id "$N" $scans &
  ev t_shirt-dw_notemp test_id "$N" &
  ev t_shirt-dw_upper test_id "$W/release/t_shirt-dw-upper.pt" &
  ev t_shirt-dw_upper test_ood "$W/release/t_shirt-dw-upper.pt" &
  ev t_shirt-dw_release test_id "$R" &
  ev t_shirt-dw_release test_ood "$R" &
  if [ "${BASELINES:-1}" = 1 ]; then  # Guo et al.'s rows on the same sequences
    C="$W/release/t_shirt-coarse.pt"; G="$W/release/t_shirt-wrinkles.pt"
    ev t_shirt-base test_id base &
    ev t_shirt-base test_ood base --coarse "$C" &
    ev t_shirt-coarse test_ood "$C" &
    for s in 0 1 2; do
      ev t_shirt-ours-s$s test_id "$G" --sample-seed $s &
      ev t_shirt-ours-s$s test_ood "$G" --sample-seed $s --coarse "$C" &
    done
  fi
  wait
fi

if stage evaluate; then
  $PY -m benchmarks.wrinkle_tables "$W/eval" --out "$W/tables.md" --json "$W/tables.json" >/dev/null \
    && log "tables: $W/tables.md"
fi
log "done"
stage evaluate && [ -f "$W/.eval_failed" ] && { log "some evaluations failed (see $W/logs/eval-*.log)"; exit 1; }
exit 0
