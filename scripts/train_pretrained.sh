#!/usr/bin/env bash
# How the shipped default models (pretrained/) are made: generate the t-shirt and skirt datasets,
# train the coarse (skeleton_cvae) and wrinkle (wrinkle_diffusion) models of each, plus the
# ablation variants and the LFGD-style baseline on the t-shirt, export release weights of all of
# them (WORKDIR/release; the ablation rows under release/ablation), and evaluate the release files
# (Tables 1/2 of docs/WRINKLES.md). Needs a CUDA GPU. Time-boxed: generation and training stop at
# their budget (SIGINT; the sequences made so far are combined into a manifest, training
# checkpoints) and everything is resumable (run it again to continue).
#   bash scripts/train_pretrained.sh WORKDIR [GEN_SECONDS] [TRAIN_SECONDS]
# STAGES picks stages (default "generate train export evaluate"). On a machine that has only the
# release files (WORKDIR/release, e.g. a second GPU lease), "testdata evaluate" makes the two test
# splits again (dataset generate --splits: a sequence's split comes from the config) and evaluates;
# run it at the commit that made the weights' data (the shipped weights: ccbf097; later garment
# templates have other vertices).
set -u
W=${1:?work directory}; GEN=${2:-420}; TRAIN=${3:-600}
source "$(dirname "$0")/stages.sh" "generate train export evaluate" "generate testdata train export evaluate"
PY=${PYTHON:-python3}
CLI="$PY -m pipelines.cli"
mkdir -p "$W/logs" "$W/runs" "$W/eval" "$W/release/ablation"

generate() {  # budget [extra dataset-generate args...]
  local budget=$1; shift
  for g in tshirt skirt; do
    resume=""; [ -d "$W/data/$g/parts" ] && resume="--resume"
    timeout -s INT "$budget" $CLI dataset generate --config pipelines/configs/$g.toml --out "$W/data/$g" \
      --batch ${BATCH:-16} --device cuda -q $resume "$@" >>"$W/logs/gen-$g.log" 2>&1 &
  done
  wait
  for g in tshirt skirt; do  # a generation stopped at its budget leaves its parts, not the manifest
    $CLI dataset combine "$W/data/$g" 2>&1 | tail -2 | tee -a "$W/logs/pipeline.log"
  done
  for g in tshirt skirt; do $CLI dataset info "$W/data/$g" 2>&1 | head -20 | tee -a "$W/logs/pipeline.log"; done
}

if stage generate; then
  log "generate (budget ${GEN}s)"
  generate "$GEN"
fi
if stage testdata; then
  log "test data (budget ${GEN}s)"
  generate "$GEN" --splits test_id,test_ood
fi

if stage train; then
  log "train (budget ${TRAIN}s)"
  WCFG=pipelines/configs/train/wrinkles.toml; CCFG=pipelines/configs/train/coarse.toml
  train() {  # name method data config [overrides...]
    local name=$1 method=$2 data=$3 cfg=$4; shift 4
    local resume=""; [ -f "$W/runs/$name/checkpoints/last.pt" ] && resume="--resume"
    timeout -s INT "$TRAIN" $CLI train "$method" --data "$W/data/$data" --out "$W/runs/$name" --config "$cfg" \
      --device cuda -q --set train.num_workers=3 "$@" $resume >"$W/logs/train-$name.log" 2>&1
  }
  train tshirt-coarse coarse tshirt $CCFG &
  train skirt-coarse coarse skirt $CCFG &
  train tshirt-wrinkles wrinkles tshirt $WCFG &
  train skirt-wrinkles wrinkles skirt $WCFG &
  AB=${ABLATION_STEPS:-1500}  # the ablation rows train shorter, leaving the GPU to the shipped models
  train tshirt-tensor wrinkles tshirt $WCFG --set model.conditioning=strain_tensor --set train.steps=$AB &
  train tshirt-normal wrinkles tshirt $WCFG --set model.conditioning=normal --set train.steps=$AB &
  train tshirt-lfgd displacement_regressor tshirt pipelines/configs/train/lfgd.toml --set train.steps=$AB &
  wait
  for f in "$W"/logs/train-*.log; do log "$(basename $f): $(tail -1 $f)"; done
fi

if stage export; then
  log "export"
  for g in tshirt skirt; do
    cat=$([ $g = tshirt ] && echo t_shirt || echo straight_skirt)
    $PY -m learn.train.export "$W/runs/$g-coarse/checkpoints/last.pt" "$W/release/$cat-coarse.pt"
    $PY -m learn.train.export "$W/runs/$g-wrinkles/checkpoints/last.pt" "$W/release/$cat-wrinkles.pt"
  done
  for v in tensor normal lfgd; do
    $PY -m learn.train.export "$W/runs/tshirt-$v/checkpoints/last.pt" "$W/release/ablation/t_shirt-$v.pt"
  done
  log "exported"
fi

if stage evaluate; then
  log "evaluate"
  rm -f "$W/.eval_failed"
  MAXSEQ=${MAXSEQ:-6}
  ev() {  # out-name split args...   (the data is the part of the name before the first '-')
    local name=$1 split=$2; shift 2
    $CLI evaluate --data "$W/data/${name%%-*}" --split "$split" --out "$W/eval/$name-$split" --no-images -q \
      --max-sequences "$MAXSEQ" "$@" >"$W/logs/eval-$name-$split.log" 2>&1 || { log "evaluate $name $split failed"; touch "$W/.eval_failed"; }
  }
  R="$W/release"
  for g in tshirt skirt; do
    cat=$([ $g = tshirt ] && echo t_shirt || echo straight_skirt)
    C="$R/$cat-coarse.pt"; M="$R/$cat-wrinkles.pt"
    ev $g-base test_id --model base &
    ev $g-base test_ood --model base --coarse "$C" &
    ev $g-coarse test_ood --model "$C" &
    for s in 0 1 2 3 4; do
      ev $g-ours-s$s test_id --model "$M" --sample-seed $s &
      ev $g-ours-s$s test_ood --model "$M" --sample-seed $s --coarse "$C" &
    done
    wait
  done
  C="$R/t_shirt-coarse.pt"
  for v in tensor normal lfgd; do
    ev tshirt-$v test_id --model "$R/ablation/t_shirt-$v.pt" &
    ev tshirt-$v test_ood --model "$R/ablation/t_shirt-$v.pt" --coarse "$C" &
  done
  for n in 20 10; do
    ev tshirt-ours-steps$n test_id --model "$R/t_shirt-wrinkles.pt" --steps $n &
  done
  wait
fi

log "done"
[ -f "$W/.eval_failed" ] && { log "some evaluations failed (see $W/logs/eval-*.log)"; exit 1; }
exit 0
