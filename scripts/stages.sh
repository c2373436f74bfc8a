# The stages of the scripts that make the shipped models (train_pretrained.sh, train_deepwrinkles.sh,
# train_gsnet.sh), sourced once W is set:
#   source "$(dirname "$0")/stages.sh" "DEFAULT STAGES" "EVERY STAGE"
# STAGES (the environment's, else the default) is checked against every stage (exit 2 naming the
# unknown one); log LINE appends to $W/logs/pipeline.log (the script makes $W/logs); stage NAME is
# true when NAME runs.
STAGES=" ${STAGES:-$1} "
for s in $STAGES; do
  [[ " $2 " == *" $s "* ]] || { echo "STAGES: unknown stage '$s' ($2, space-separated)" >&2; exit 2; }
done
log() { echo "[$(date +%T)] $*" | tee -a "$W/logs/pipeline.log"; }
stage() { [[ "$STAGES" == *" $1 "* ]]; }
