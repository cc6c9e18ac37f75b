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
set -uo pipefail
if [ $# -lt 2 ]; then echo "usage: scripts/comparison_runs.sh MINUTES ARM..." >&2; exit 2; fi
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
MINUTES=$1; shift
HERE=results/cpu-comparison-2026-11-29
for ARM in "$@"; do
  IFS=- read -r REPR REWARD SEED VARIANT <<< "$ARM"
  case "${VARIANT:-}" in
    "") SETS=() ;;
    shared) SETS=(--set ppo.shared_encoder=true) ;;
    authors) SETS=(--set ppo.shared_encoder=true --set "ppo.pointnet_hidden=[16,32,64]") ;;
    *) echo "$ARM: unknown variant '$VARIANT' (known: shared, authors)" >&2; exit 2 ;;
  esac
  # The arm's chunk, kept in results/ (chunked_run.sh): its budget is its total_steps, so
  # no budget in minutes, and no evaluation until then (at it: 50 episodes per object).
  CHUNK_EPISODES=0 FINAL_EPISODES=50 "$ROOT/scripts/chunked_run.sh" "$HERE" "cmp-$ARM" \
    "$HERE/comparison.toml" "$MINUTES" 1000000000 --repr "$REPR" --reward "$REWARD" \
    --seed "${SEED#s}" "${SETS[@]}"
done
