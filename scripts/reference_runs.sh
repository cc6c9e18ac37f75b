#!/usr/bin/env bash
# Short fixed-seed training runs and evaluations of the three task setups, for checking that a
# change of the code changes nothing the runs measure (compare two outputs with
# scripts/compare_runs.py): lift (configs/cpu.toml, bbox, 2 built-in objects, 32 envs, 4
# iterations), bin (configs/cpu-bin.toml, 7 built-in objects in bins of 5, 32 envs, 4 iterations)
# and the floating hand (sdf, the dice, 16 envs, 2 iterations, eager). About 8 minutes on 2 cores.
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
for name in ("cpu", "cpu-bin", "floating"):
    text = Path(f"configs/{name}.toml").read_text() if name != "floating" else ""
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
echo "reference runs in $OUT"
