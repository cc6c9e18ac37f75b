#!/usr/bin/env bash
# One long run in chunks that outlive a work session: the bin pair of issue 63
# (results/cpu-bin-table1-2026-11-29/), the 78 together of issue 62 (configs/cpu-ycb.toml) and
# each arm of the comparison (scripts/comparison_runs.sh).
#
#   scripts/chunked_run.sh RESULTS_DIR NAME CONFIG MINUTES BUDGET_MINUTES [TRAINER_RUN_ARGS...]
#
# The run lives in runs/NAME and is kept in RESULTS_DIR/runs/NAME: it continues from there (or
# starts from CONFIG with the extra `trainer run` arguments), trains until its training time in
# all reaches MINUTES (`trainer run --minutes`), then copies back what the next chunk needs
# (config.json, metrics.csv, launches.csv, grasp_starts.pt, checkpoints/last.pt) and evaluates the chunk:
# CHUNK_EPISODES (20; 0: none) episodes per object into eval-<env steps>M/. Once the run has
# trained BUDGET_MINUTES (or reached its total_steps) it is evaluated, once, with FINAL_EPISODES (50) per
# object into eval/ (what `trainer report` reads), and a bin run also on bins of BIN_EVAL (10)
# objects into eval-bin10/ and on bins of its own size it never trained on into eval-new/. With VIDEO_OBJECT set, each chunk also films the policy's picks of
# that object (the successes first) into RESULTS_DIR/media/NAME-<env steps>M.mp4. Stop a chunk
# early with SIGTERM to its `trainer run` (it checkpoints); rerun to copy back and continue.
# Environment: DATA_DIR (data), RUNS_DIR (runs), STEPS (a resumed run's total env steps, to
# extend its budget: `trainer run --resume --steps`; a run evaluated at its old budget is
# refused: extend a copy without its eval/).
#
#   nohup scripts/chunked_run.sh results/cpu-bin-table1-2026-11-29 bin5-table1-lift \
#       results/cpu-bin-table1-2026-11-29/bin5-table1-lift.toml 120 480 > logs/bin-lift.log 2>&1 &
set -uo pipefail
usage="usage: scripts/chunked_run.sh RESULTS_DIR NAME CONFIG MINUTES BUDGET_MINUTES [TRAINER_RUN_ARGS...]"
if [ $# -lt 5 ]; then echo "$usage" >&2; exit 2; fi
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
HERE=$1 NAME=$2 CONFIG=$3 MINUTES=$4 BUDGET=$5
shift 5
for number in "$MINUTES" "$BUDGET"; do
  [[ $number =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "$number: MINUTES and BUDGET_MINUTES are numbers of minutes; $usage" >&2; exit 2; }
done
RUN=${RUNS_DIR:-runs}/$NAME
SAVED=$HERE/runs/$NAME
if [ ! -f "$SAVED/checkpoints/last.pt" ] && [ ! -f "$RUN/checkpoints/last.pt" ] && [ ! -f "$CONFIG" ]; then
  echo "$CONFIG: no such config, and no run $NAME to continue" >&2; exit 2
fi
if [ -n "${STEPS:-}" ] && { [ -d "$SAVED/eval" ] || [ -d "$RUN/eval" ]; }; then
  echo "$NAME: STEPS extends a run whose eval/ is of its old budget: extend a copy without eval/" >&2; exit 2
fi
if [ ! -d "$RUN" ] && [ -f "$SAVED/checkpoints/last.pt" ]; then
  mkdir -p "$(dirname "$RUN")" && cp -r "$SAVED" "$RUN"
fi
echo "== $NAME: $(date -u +%FT%TZ)"
if [ -f "$RUN/checkpoints/last.pt" ]; then
  trainer run --resume "$RUN" --minutes "$MINUTES" ${STEPS:+--steps "$STEPS"}
else
  trainer run --config "$CONFIG" --data-dir "${DATA_DIR:-data}" --run-dir "$RUN" --minutes "$MINUTES" "$@"
fi
[ -f "$RUN/checkpoints/last.pt" ] || { echo "== $NAME: no checkpoint written" >&2; exit 1; }
mkdir -p "$SAVED/checkpoints"
cp "$RUN/config.json" "$RUN/metrics.csv" "$SAVED/"
[ -f "$RUN/launches.csv" ] && cp "$RUN/launches.csv" "$SAVED/"
[ -f "$RUN/grasp_starts.pt" ] && cp "$RUN/grasp_starts.pt" "$SAVED/"
cp "$RUN/checkpoints/last.pt" "$SAVED/checkpoints/last.pt"
# where the run stands: env steps (M, one decimal), at the budget or not, its task
read -r STEPS DONE TASK < <(python - "$RUN" "$BUDGET" <<'EOF'
import csv, json, sys
run, budget = sys.argv[1], float(sys.argv[2])
rows = list(csv.DictReader(open(f"{run}/metrics.csv")))
config = json.load(open(f"{run}/config.json"))
steps = int(rows[-1]["env_steps"]) if rows else 0
minutes = float(rows[-1]["wall_time_s"]) / 60 if rows else 0.0
done = steps >= config["run"]["total_steps"] or minutes >= budget - 0.5
print(f"{steps / 1e6:.1f}", int(done), config["env"].get("task", "lift"))
EOF
)
echo "== $NAME: saved to $SAVED (${STEPS} M env steps)"
if [ "$DONE" = 1 ] && [ -f "$SAVED/eval/per_object.csv" ]; then
  echo "== $NAME: at its budget and evaluated already ($SAVED/eval)"
elif [ "$DONE" = 1 ]; then
  trainer eval "$RUN" --episodes-per-object "${FINAL_EPISODES:-50}" && cp -r "$RUN/eval" "$SAVED/"
  if [ "$TASK" = bin ]; then
    trainer eval "$RUN" --episodes-per-object "${FINAL_EPISODES:-50}" --bin-objects "${BIN_EVAL:-10}" \
      && cp -r "$RUN/eval-bin${BIN_EVAL:-10}" "$SAVED/"
    trainer eval "$RUN" --episodes-per-object "${FINAL_EPISODES:-50}" --new-bins \
      && cp -r "$RUN/eval-new" "$SAVED/"
  fi
elif [ "${CHUNK_EPISODES:-20}" -gt 0 ]; then
  trainer eval "$RUN" --episodes-per-object "${CHUNK_EPISODES:-20}" --out "eval-${STEPS}M" \
    && cp -r "$RUN/eval-${STEPS}M" "$SAVED/"
fi
if [ -n "${VIDEO_OBJECT:-}" ]; then
  mkdir -p "$HERE/media"
  MUJOCO_GL=${MUJOCO_GL:-egl} trainer play "$RUN" --object "$VIDEO_OBJECT" --episodes 2 --tries 8 \
    --video "$HERE/media/${NAME}-${STEPS}M.mp4"
fi
echo "== $NAME: done $(date -u +%FT%TZ)"
