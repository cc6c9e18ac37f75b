#!/usr/bin/env bash
# The comparison's runs (issue 61; results/cpu-comparison-2026-11-29/README.md) in chunks that
# outlive a work session: each ARM (REPR-REWARD-sSEED, e.g. sq-sdf-s0, bbox-none-s1) continues
# from its committed folder (results/cpu-comparison-2026-11-29/runs/cmp-ARM) or starts, trains
# until its time budget in all reaches MINUTES of training (or its 4.6 M env steps), then copies
# what the next chunk needs back into results/ (config.json, metrics.csv, grasp_starts.pt,
# checkpoints/last.pt) and, once the arm reached its budget, evaluates it (50 episodes per
# object, eval/ kept beside). An arm may end in a named variant of the network, an arm of its own:
# -shared ([ppo] shared_encoder = true: one encoder for the policy and the value), e.g.
# pc512-sdf-s0-shared; -authors (that, with the per-point MLP of the authors' public code,
# 16-32-64: pc128 at 0.5 of env-only stepping, results/bench-pointnet-2026-11-29/). Arms run one after the other; start two of these for the two cores:
#
#   nohup scripts/comparison_runs.sh 240 sq-sdf-s0 sdf-sdf-s1 > logs/cmp-a.log 2>&1 &
#   nohup scripts/comparison_runs.sh 240 com-sdf-s0 bbox-com-s0 > logs/cmp-b.log 2>&1 &
#
# A run stopped by SIGTERM (kill PID of its `trainer run`) writes a checkpoint; rerun this
# script with the arm to copy it back and continue.
#
# The comparison at a larger budget: with EXTEND_TO=STEPS each ARM's run at the budget (cmp-ARM,
# evaluated) is copied to ext-ARM without its evaluation (and runs/cmp-ARM, its checkpoint
# history, to runs/ext-ARM where it exists) and continued to STEPS env steps with nothing else
# changed, then evaluated on the same episodes; the budget's folder stays as it was. Once
# evaluated, the run's curriculum history is kept as its curriculum.csv where the history is here.
#
#   EXTEND_TO=6900000 nohup nice -n 5 scripts/comparison_runs.sh 400 pc128-sdf-s1-authors \
#       pc512-sdf-s0-authors > logs/ext-a.log 2>&1 &
set -uo pipefail
if [ $# -lt 2 ]; then echo "usage: scripts/comparison_runs.sh MINUTES ARM..." >&2; exit 2; fi
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
MINUTES=$1; shift
HERE=${COMPARISON_DIR:-results/cpu-comparison-2026-11-29}
RUNS=${RUNS_DIR:-runs}
if [ -n "${EXTEND_TO:-}" ] && ! [[ $EXTEND_TO =~ ^[0-9]+$ ]]; then
  echo "EXTEND_TO=$EXTEND_TO: a number of env steps (e.g. 6900000)" >&2; exit 2
fi
# copy FOLDER TO [TAR EXCLUDES...]: under a temporary name, then renamed, so that an
# interrupted copy never looks like a run to continue.
copy() {
  local from=$1 to=$2; shift 2
  rm -rf "$to.partial" && mkdir -p "$to.partial" \
    && (cd "$from" && tar -c "$@" .) | tar -x -C "$to.partial" && mv "$to.partial" "$to"
}
for ARM in "$@"; do
  IFS=- read -r REPR REWARD SEED VARIANT <<< "$ARM"
  case "${VARIANT:-}" in
    "") SETS=() ;;
    shared) SETS=(--set ppo.shared_encoder=true) ;;
    authors) SETS=(--set ppo.shared_encoder=true --set "ppo.pointnet_hidden=[16,32,64]") ;;
    *) echo "$ARM: unknown variant '$VARIANT' (known: shared, authors)" >&2; exit 2 ;;
  esac
  NAME=cmp-$ARM
  if [ -n "${EXTEND_TO:-}" ]; then
    NAME=ext-$ARM
    # bbox seed 0 is the run whose env steps set the budget (the comparison's README)
    FROM=$HERE/runs/cmp-$ARM
    [ "$ARM" = bbox-sdf-s0 ] && [ ! -d "$FROM" ] && FROM=results/cpu-together-starts50-2026-11-27/run
    if [ ! -d "$HERE/runs/$NAME" ]; then
      if [ ! -f "$FROM/eval/per_object.csv" ] || [ ! -f "$FROM/checkpoints/last.pt" ]; then
        echo "$ARM: $FROM is not a run evaluated at the budget: run the arm first" >&2; exit 2
      fi
      copy "$FROM" "$HERE/runs/$NAME" --exclude='./eval*' --exclude='./curriculum.*' \
        || { echo "$ARM: copying $FROM to $HERE/runs/$NAME failed" >&2; exit 1; }
      if [ -d "$RUNS/cmp-$ARM/checkpoints" ] && [ ! -d "$RUNS/$NAME" ]; then
        copy "$RUNS/cmp-$ARM" "$RUNS/$NAME" --exclude='./eval*' \
          || { echo "$ARM: copying $RUNS/cmp-$ARM to $RUNS/$NAME failed" >&2; exit 1; }
      fi
    fi
  fi
  # The arm's chunk, kept in results/ (chunked_run.sh): its budget is its total_steps, so
  # no budget in minutes, and no evaluation until then (at it: 50 episodes per object).
  if [ -n "${EXTEND_TO:-}" ] && [ -f "$HERE/runs/$NAME/eval/per_object.csv" ]; then
    echo "== $NAME: extended and evaluated already ($HERE/runs/$NAME/eval)"
  else
    STEPS=${EXTEND_TO:-} CHUNK_EPISODES=0 FINAL_EPISODES=50 "$ROOT/scripts/chunked_run.sh" \
      "$HERE" "$NAME" "$HERE/comparison.toml" "$MINUTES" 1000000000 --repr "$REPR" \
      --reward "$REWARD" --seed "${SEED#s}" "${SETS[@]}"
  fi
  # The curriculum's history lives in the local checkpoints only; keep it with the run.
  if [ -f "$HERE/runs/$NAME/eval/per_object.csv" ] && [ ! -f "$HERE/runs/$NAME/curriculum.csv" ] \
      && [ -d "$RUNS/$NAME/checkpoints" ]; then
    python "$ROOT/scripts/object_curriculum.py" "$RUNS/$NAME" --csv "$HERE/runs/$NAME/curriculum.csv"
  fi
done
