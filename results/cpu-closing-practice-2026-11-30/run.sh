#!/usr/bin/env bash
# The closing-practice test (results/cpu-closing-practice-2026-11-30/README.md): bbox with the
# centre-of-mass reward, seed 1 (cmp-bbox-com-s1, all three hard objects on the first rung at
# 4.6 M env steps), continued from its last checkpoint's networks for 1 M env steps on the three
# hard objects alone, and, as the baseline, on all ten; nothing else differs.
set -uo pipefail
cd "$(dirname "$0")/../.."
HERE=results/cpu-closing-practice-2026-11-30
FROM=results/cpu-comparison-2026-11-29/runs/cmp-bbox-com-s1
CFG=results/cpu-comparison-2026-11-29/comparison.toml
common=(--repr bbox --reward com --seed 1 --steps 1000000 --init-agent "$FROM")
CHUNK_EPISODES=0 FINAL_EPISODES=50 scripts/chunked_run.sh "$HERE" hard3 "$CFG" 400 1000000000 \
  "${common[@]}" --objects 029_plate,032_knife,062_dice
CHUNK_EPISODES=0 FINAL_EPISODES=50 scripts/chunked_run.sh "$HERE" all10 "$CFG" 400 1000000000 \
  "${common[@]}"
