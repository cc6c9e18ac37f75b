#!/usr/bin/env bash
# The closing-practice test (results/cpu-closing-practice-2026-11-30/README.md): a comparison run
# whose hard objects ended on the first rung, continued from its last checkpoint's networks for
# 1 M env steps on the three hard objects alone, and, as the baseline, on all ten; nothing else
# differs.
#
#   results/cpu-closing-practice-2026-11-30/run.sh bbox com 1 ""          # runs/hard3, runs/all10
#   results/cpu-closing-practice-2026-11-30/run.sh sdf sdf 1 sdf-sdf-s1-   # runs/sdf-sdf-s1-hard3, ...
set -uo pipefail
if [ $# -ne 4 ]; then echo "usage: run.sh REPR REWARD SEED NAME_PREFIX" >&2; exit 2; fi
REPR=$1 REWARD=$2 SEED=$3 PREFIX=$4
cd "$(dirname "$0")/../.."
HERE=results/cpu-closing-practice-2026-11-30
FROM=results/cpu-comparison-2026-11-29/runs/cmp-$REPR-$REWARD-s$SEED
CFG=results/cpu-comparison-2026-11-29/comparison.toml
common=(--repr "$REPR" --reward "$REWARD" --seed "$SEED" --steps 1000000 --init-agent "$FROM")
CHUNK_EPISODES=0 FINAL_EPISODES=50 scripts/chunked_run.sh "$HERE" "${PREFIX}hard3" "$CFG" 400 \
  1000000000 "${common[@]}" --objects 029_plate,032_knife,062_dice
CHUNK_EPISODES=0 FINAL_EPISODES=50 scripts/chunked_run.sh "$HERE" "${PREFIX}all10" "$CFG" 400 \
  1000000000 "${common[@]}"
