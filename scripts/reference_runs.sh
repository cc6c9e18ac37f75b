#!/usr/bin/env bash
# Short fixed-seed training runs and evaluations of the three task setups, for checking that a
# change of the code changes nothing the runs measure (compare two outputs with
# scripts/compare_runs.py): lift (configs/cpu.toml, bbox, 2 built-in objects, 32 envs, 4
# iterations), bin (configs/cpu-bin.toml, 7 built-in objects in bins of 5, 32 envs, 4 iterations)
# the floating hand (sdf, the dice, 16 envs, 2 iterations, eager), grasp starts
# (configs/cpu-table1.toml's relative hand actions and half the episodes from the top grasp's
# states, 2 built-in objects, 16 envs, 4 iterations) and a warmup (the same on the sphere
# first, its agent's unseen features silenced). About 12 minutes on 2 cores.
#
#   scripts/reference_runs.sh OUT [--legacy]
#
# --legacy: the runs seed every generator with the seed itself (run.random_streams = false), as
# the code before the derived random streams (2026-11-25) did: its runs compare with those.
# The built-in objects are built into OUT/../reference-data (reused by later calls).
set -euo pipefail
if [ $# -lt 1 ]; then echo "usage: scripts/reference_runs.sh OUT [--legacy]" >&2; exit 2; fi
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=$(realpath -m "$1"); LEGACY=${2:-}
DATA=$(dirname "$OUT")/reference-data
rm -rf "$OUT"; mkdir -p "$OUT/configs"
cd "$ROOT"
geomprep --data-dir "$DATA" build-all --objects builtin --no-progress > "$OUT/build.log" 2>&1
python - "$OUT/configs" "$LEGACY" <<'PY'
import sys
from pathlib import Path
out, legacy = Path(sys.argv[1]), sys.argv[2] == "--legacy"
# starts and warmup: cpu-table1.toml's setup, its [run] replaced (top-grasp starts; a warmup).
table1 = Path("configs/cpu-table1.toml").read_text()
table1 = table1[: table1.index("\n[run]\n") + 1] + '[run]\ngrasp_starts = 0.5\ngrasp_start_family = "top"\n'
warmup = 'warmup_objects = "builtin_sphere"\nwarmup_steps = 512\ninit_agent_unseen = "silence"\n'
for name in ("cpu", "cpu-bin", "floating", "starts", "warmup"):
    text = {"floating": "", "starts": table1, "warmup": table1 + warmup}.get(name)
    text = Path(f"configs/{name}.toml").read_text() if text is None else text
    if legacy:
        text = (text.replace("\n[run]\n", "\n[run]\nrandom_streams = false\n") if "\n[run]\n" in text
                else text + "\n[run]\nrandom_streams = false\n")
    (out / f"{name}.toml").write_text(text)
PY
C=$OUT/configs
trainer run --config $C/cpu.toml --objects builtin_box,builtin_sphere --repr bbox --num-envs 32 \
  --steps 4096 --seed 3 --data-dir "$DATA" --run-dir "$OUT/lift" > "$OUT/lift.log" 2>&1
trainer eval "$OUT/lift" --episodes-per-object 4 >> "$OUT/lift.log" 2>&1
trainer run --config $C/cpu-bin.toml --objects builtin --num-envs 32 --steps 4096 --seed 3 \
  --data-dir "$DATA" --run-dir "$OUT/bin" > "$OUT/bin.log" 2>&1
trainer eval "$OUT/bin" --episodes-per-object 2 --max-rounds 3 >> "$OUT/bin.log" 2>&1
trainer run --config $C/floating.toml --objects builtin_dice --robot floating --repr sdf \
  --num-envs 16 --steps 1024 --seed 5 --no-compile --data-dir "$DATA" --run-dir "$OUT/floating" \
  > "$OUT/floating.log" 2>&1
trainer eval "$OUT/floating" --episodes-per-object 3 >> "$OUT/floating.log" 2>&1
for run in starts warmup; do
  trainer run --config $C/$run.toml --objects builtin_cylinder,builtin_box --repr bbox \
    --num-envs 16 --steps 1024 --seed 3 --data-dir "$DATA" --run-dir "$OUT/$run" \
    > "$OUT/$run.log" 2>&1
  trainer eval "$OUT/$run" --episodes-per-object 4 >> "$OUT/$run.log" 2>&1
done
echo "reference runs in $OUT"
