#!/usr/bin/env bash
# The device side of the GPU campaign (scripts/gpu_campaign.py says how it is packed and called):
# on a lent GPU machine, from the repository root, one call per part of .gpu-pack/carry/.
#
#   bash scripts/gpu-campaign.sh stage [PART...]   keep the carried part(s) for the next call
#   bash scripts/gpu-campaign.sh bench             unpack, then time the physics in contact
#                                                  (bench/env_throughput.py --policy, the run's
#                                                  config and GPU_CAMPAIGN_BENCH's variants):
#                                                  bench.log and the kernel cache in $OUT
#   bash scripts/gpu-campaign.sh phases            unpack, then time the physics step phase by
#                                                  phase (bench/step_phases.py --policy, the
#                                                  run's config and GPU_CAMPAIGN_PHASES'
#                                                  variants): phases.log and the kernel cache
#   bash scripts/gpu-campaign.sh run               unpack every part, train the campaign's next
#                                                  chunk, evaluate it, put the files in $OUT:
#                                                  last.pt, chunk.tar (metrics.csv, config.json,
#                                                  launches.csv, chunk.json, eval.json), chunk.log and the
#                                                  kernel cache (kcache.tar.xz.0, .1, ...)
#
# A chunk trains until GPU_CAMPAIGN_DEADLINE seconds (default 560) after this command started,
# less GPU_CAMPAIGN_RESERVE for the last iteration's overrun, the copies and the evaluation
# (default 60 s without one, 200 s with one), then stops with a
# checkpoint (trainer run --minutes; `timeout -s INT` is the backstop: the trainer checkpoints
# on SIGINT too). The run is results/gpu-table1-campaign/run: resumed if it holds a checkpoint,
# else started from results/gpu-table1-campaign/campaign.toml.
# For a check on the CPU (scripts/gpu_campaign.py check, tests/test_gpu_campaign.py):
# GPU_CAMPAIGN_STAGE (the staging folder), GPU_CAMPAIGN_PYTHON, GPU_CAMPAIGN_SITE=none (use the
# interpreter's own packages, no parts), GPU_CAMPAIGN_RUN (the run folder),
# GPU_CAMPAIGN_OVERRIDE (TOML whose keys replace the campaign config's in a new run),
# GPU_CAMPAIGN_STEPS (trainer run --steps: the run's total env steps after this chunk),
# GPU_CAMPAIGN_EPISODES (eval episodes per object, default 0: no eval on the GPU, whose time is
# better spent training while the training success rate is near 0), GPU_CAMPAIGN_PIECE
# (bytes per returned piece of the kernel cache, default 15,000,000).
set -uo pipefail
start=$(date +%s)
STAGE=${GPU_CAMPAIGN_STAGE:-/tmp/gpu-campaign}
PY=${GPU_CAMPAIGN_PYTHON:-python3}
SITE=${GPU_CAMPAIGN_SITE:-$STAGE/site}
RUN=${GPU_CAMPAIGN_RUN:-results/gpu-table1-campaign/run}
CONFIG=results/gpu-table1-campaign/campaign.toml
DEADLINE=${GPU_CAMPAIGN_DEADLINE:-560}
EPISODES=${GPU_CAMPAIGN_EPISODES:-0}
# Measured on an H100 (2026-11-26): an iteration of the campaign takes 25-35 s once hands touch
# objects, and the trainer stops after the iteration that crosses --minutes; an eval of 20
# episodes per object did not finish in the 65 s left to it.
if [ "$EPISODES" -gt 0 ]; then RESERVE=${GPU_CAMPAIGN_RESERVE:-200}; else RESERVE=${GPU_CAMPAIGN_RESERVE:-60}; fi
# The campaign never renders; a machine whose environment names an OpenGL backend it lacks
# (MUJOCO_GL=egl without libEGL) would fail at `import mujoco` (seen 2026-11-26).
export MUJOCO_GL=disable
PIECE=${GPU_CAMPAIGN_PIECE:-15000000}
: "${OUT:?OUT must name the folder the files go to}"
mkdir -p "$STAGE/parts" "$OUT"
log() { echo "gpu-campaign [$(( $(date +%s) - start )) s] $*" | tee -a "$OUT/chunk.log"; }

case "${1:-}" in
  stage)
    shift
    parts=("$@")
    [ ${#parts[@]} -gt 0 ] || parts=(.gpu-pack/carry/part-*)
    cp "${parts[@]}" "$STAGE/parts/" || exit 1
    log "staged: $(ls "$STAGE/parts" | tr '\n' ' ')"
    exit 0 ;;
  run|bench|phases) mode=$1 ;;
  *) echo "usage: bash scripts/gpu-campaign.sh stage [PART...] | run | bench | phases" >&2; exit 2 ;;
esac

# Warp's compiled kernels, so that the next call need not compile them: in pieces of 15 MB,
# if they fit beside the rest (64 MiB, 8 files).
return_kernels() {
  if [ -n "${WARP_CACHE_PATH:-}" ] && [ -n "$(ls -A "$WARP_CACHE_PATH" 2>/dev/null)" ]; then
    tar -C "$WARP_CACHE_PATH" -cf - . | xz -T0 -3 -c > "$STAGE/kcache.tar.xz"
    size=$(stat -c %s "$STAGE/kcache.tar.xz")
    room=$(( 63 * 1048576 - $(du -cb "$OUT"/* | tail -1 | cut -f1) ))
    if [ "$size" -le "$room" ] && [ "$size" -le $(( 5 * PIECE )) ]; then
      split -b "$PIECE" -d -a 1 "$STAGE/kcache.tar.xz" "$OUT/kcache.tar.xz."
    else
      log "kernel cache of $size bytes left behind (room for $room)"
    fi
  fi
}

if [ "$SITE" != none ]; then
  cp .gpu-pack/carry/part-* "$STAGE/parts/" 2>/dev/null
  # Every part the manifest lists, unchanged, or no run (a part lost with a released machine).
  "$PY" - "$STAGE/parts" .gpu-pack/carry/MANIFEST.json <<'EOF' || exit 1
import hashlib, json, sys
from pathlib import Path
parts, manifest = Path(sys.argv[1]), json.loads(Path(sys.argv[2]).read_text())
bad = [p["name"] for p in manifest["parts"] if not (parts / p["name"]).is_file()
       or hashlib.sha256((parts / p["name"]).read_bytes()).hexdigest() != p["sha256"]]
if bad:
    sys.exit(f"gpu-campaign: part(s) {', '.join(bad)} missing or damaged: stage them first "
             "(one call each, within the machine's idle release)")
EOF
  if [ ! -f "$SITE/.complete" ]; then
    names=$("$PY" -c 'import json,sys; print(" ".join(p["name"] for p in json.load(open(sys.argv[1]))["parts"]))' .gpu-pack/carry/MANIFEST.json)
    (cd "$STAGE/parts" && cat $names) | xz -dc | tar -x -C "$STAGE" || exit 1
    log "unpacked $(du -sh "$STAGE" | cut -f1)"
  fi
  export PYTHONPATH="$SITE:$PWD${PYTHONPATH:+:$PYTHONPATH}"
  export WARP_CACHE_PATH="$STAGE/kcache"
  # The config's data_dir, .gpu-pack/data, is the unpacked data (here already, where packed).
  mkdir -p .gpu-pack
  { [ -d .gpu-pack/data ] && [ ! -L .gpu-pack/data ]; } || ln -sfn "$STAGE/data" .gpu-pack/data
fi
# The cuts of the hand's step measured on the CPU (results/bench-step-phases-2026-11-29/), each
# alone, the two that keep every grasp together (tip-hulls and no-slip 2 lose some of the knife's
# pinches), and the capsule hand of 2026-11-23 for reference, against the run's own config.
CUTS="--variant physics.noslip_iterations=2 --variant physics.table_plane=true \
  --variant robot.hand_geometry=tip-hulls \
  --variant 'warp.contacts_per_world=64 warp.constraints_per_world=256' \
  --variant 'physics.table_plane=true warp.contacts_per_world=64 warp.constraints_per_world=256' \
  --variant robot.hand_geometry=capsules"
if [ "$mode" = bench ] || [ "$mode" = phases ]; then
  # What the physics costs in contact: the campaign's policy drives the run's own config and each
  # variant at 16,384 envs, until the deadline. bench: env steps/s with the policy
  # (bench/env_throughput.py --policy); phases: where one physics step's time goes
  # (bench/step_phases.py). GPU_CAMPAIGN_BENCH / GPU_CAMPAIGN_PHASES replace the arguments
  # (shell words: quote a variant of several keys).
  if [ "$mode" = bench ]; then
    script=bench/env_throughput.py
    eval "args=(${GPU_CAMPAIGN_BENCH:-"--envs 16384 --advance 30 --steps 8 --rounds 2 $CUTS"})"
  else
    script=bench/step_phases.py
    eval "args=(${GPU_CAMPAIGN_PHASES:-"--envs 16384 --advance 30 --repeats 3 --rounds 2 $CUTS"})"
  fi
  log "$mode: ${args[*]}"
  timeout -s INT $(( DEADLINE - ($(date +%s) - start) - 30 )) "$PY" "$script" \
    --backend "${GPU_CAMPAIGN_BENCH_BACKEND:-warp}" --device "${GPU_CAMPAIGN_BENCH_DEVICE:-cuda}" --policy "$RUN" "${args[@]}" 2>&1 | grep -v -i warning | tee "$OUT/$mode.log"
  return_kernels
  log "done: $(ls "$OUT" | tr '\n' ' ')"
  exit 0
fi
steps=()
[ -z "${GPU_CAMPAIGN_STEPS:-}" ] || steps=(--steps "$GPU_CAMPAIGN_STEPS")
export PYTHONUNBUFFERED=1
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee -a "$OUT/chunk.log"

# Train until the deadline less the reserve: --minutes counts a resumed run's earlier chunks.
budget=$(( DEADLINE - RESERVE - ($(date +%s) - start) ))
[ $budget -gt 60 ] || { log "only ${budget} s left for training: nothing run"; exit 1; }
# trainer run with ARGS until $minutes (the log without its progress bar); sets $status.
train() {
  timeout -s INT $(( budget + 60 )) "$PY" -m trainer.cli run "$@" --minutes "$minutes" "${steps[@]}" 2>&1 |
    tr '\r' '\n' | grep --line-buffered -v '%|' | tee -a "$OUT/chunk.log"
  status=${PIPESTATUS[0]}
}
if [ -f "$RUN/checkpoints/last.pt" ]; then
  before=$("$PY" -c 'import csv,sys; r=list(csv.DictReader(open(sys.argv[1]))); print(float(r[-1]["wall_time_s"]) if r else 0)' "$RUN/metrics.csv")
  minutes=$("$PY" -c "print(round(($before + $budget) / 60, 2))")
  log "resuming $RUN (trained $before s) until $minutes min"
  train --resume "$RUN"
else
  config="$CONFIG"
  if [ -n "${GPU_CAMPAIGN_OVERRIDE:-}" ]; then
    config="$STAGE/campaign-override.toml"
    "$PY" - "$CONFIG" "$config" <<'EOF' || exit 1
import os, sys, tomllib
from pathlib import Path
# The override's keys replace the campaign's (a TOML table may not be defined twice).
base = tomllib.loads(Path(sys.argv[1]).read_text())
for key, value in tomllib.loads(os.environ["GPU_CAMPAIGN_OVERRIDE"]).items():
    base[key] = {**base.get(key, {}), **value} if isinstance(value, dict) else value
def fmt(v):
    if isinstance(v, bool): return "true" if v else "false"
    if isinstance(v, str): return '"' + v + '"'
    if isinstance(v, list): return "[" + ", ".join(fmt(x) for x in v) + "]"
    return repr(v)
lines = [f"{k} = {fmt(v)}" for k, v in base.items() if not isinstance(v, dict)]
for k, v in base.items():
    if isinstance(v, dict):
        lines += [f"[{k}]"] + [f"{kk} = {fmt(vv)}" for kk, vv in v.items()]
Path(sys.argv[2]).write_text("\n".join(lines) + "\n")
EOF
  fi
  minutes=$("$PY" -c "print(round($budget / 60, 2))")
  log "starting $RUN from $config for $minutes min"
  train --config "$config" --run-dir "$RUN"
fi
log "training ended (status $status)"
[ -f "$RUN/checkpoints/last.pt" ] || { log "no checkpoint: nothing to bring back"; exit 1; }
cp "$RUN/checkpoints/last.pt" "$RUN/metrics.csv" "$RUN/config.json" "$OUT/"
[ -f "$RUN/launches.csv" ] && cp "$RUN/launches.csv" "$OUT/"

# The deterministic policy on every object, within what is left of the deadline.
left=$(( DEADLINE - ($(date +%s) - start) - 10 ))
if [ $left -gt 20 ] && [ "$EPISODES" -gt 0 ]; then
  rm -rf "$RUN/eval"
  timeout -s INT $left "$PY" -m trainer.cli eval "$RUN" --episodes-per-object "$EPISODES" 2>&1 | tr '\r' '\n' | grep -v '%|' | tail -20 | tee -a "$OUT/chunk.log"
  [ -f "$RUN/eval/per_object.csv" ] && "$PY" - "$RUN/eval/per_object.csv" "$OUT/eval.json" <<'EOF'
import csv, json, sys
rows = list(csv.DictReader(open(sys.argv[1])))
json.dump({r["object"]: {"episodes": int(r["episodes"]), "successes": int(r["successes"])}
           for r in rows}, open(sys.argv[2], "w"), indent=1)
EOF
fi
"$PY" - "$RUN/metrics.csv" "$OUT/chunk.json" "$start" <<'EOF'
import csv, json, platform, sys, time
rows = list(csv.DictReader(open(sys.argv[1])))
last = rows[-1]
device = "cpu"
try:
    import torch
    device = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu"
except Exception:
    pass
json.dump({
    "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "device": device,
    "python": platform.python_version(), "iteration": int(last["iteration"]),
    "env_steps": int(last["env_steps"]), "train_wall_s": round(float(last["wall_time_s"]), 1),
    "fps_last": round(float(last["fps"])), "object_success_rate": last.get("object_success_rate", ""),
    "command_s": round(time.time() - float(sys.argv[3])),
}, open(sys.argv[2], "w"), indent=1)
EOF
# A call returns at most 8 files: the small ones travel as one tar beside last.pt and the log.
small=(metrics.csv config.json chunk.json)
[ -f "$OUT/eval.json" ] && small+=(eval.json)
[ -f "$OUT/launches.csv" ] && small+=(launches.csv)
tar -C "$OUT" -cf "$OUT/chunk.tar" "${small[@]}" && (cd "$OUT" && rm "${small[@]}")
return_kernels
log "done: $(ls "$OUT" | tr '\n' ' ')"
