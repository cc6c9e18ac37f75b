#!/usr/bin/env bash
# Set up geomgrasp on this machine: the system libraries pip cannot install, a virtual
# environment in .venv, the CPU build of torch, and the package itself.
#
#   scripts/setup.sh            # runtime only
#   scripts/setup.sh dev,dvc,gpu  # with extras (the tests need dev; tests/test_dvc.py needs dvc;
#                                 # tests/test_warp.py needs gpu: MuJoCo Warp, on its CPU device)
#
# Both README commands and .ci/run call this script, so CI takes the path a newcomer takes.
# System packages are installed with apt-get when this runs as root or with password-less sudo;
# otherwise the script prints the one command to run and stops. Rerunning it is cheap.
set -euo pipefail
cd "$(dirname "$0")/.."

EXTRAS="${1:-}"
PYTHON="${PYTHON:-python3}"

say() { printf 'setup: %s\n' "$*"; }
fail() { printf 'setup: error: %s\n' "$*" >&2; exit 1; }

command -v "$PYTHON" >/dev/null || fail "no $PYTHON found: install Python 3.11 or newer"
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
  fail "$("$PYTHON" -V 2>&1) is too old: install Python 3.11 or newer (or set PYTHON=python3.11)"

# --- System libraries -----------------------------------------------------------------------
# Debian package -> how to tell that it is there. open3d loads libusb, OpenGL/EGL and OpenMP at
# import even when used headless; the SDF lookup's CPU kernel is C compiled with cc; the
# trainer's torch.compile needs a C++ compiler and the Python headers; venv needs ensurepip.
# The linker cache is read once: piping `ldconfig -p` into `grep -q` under pipefail fails now and
# then (grep exits at the first match, ldconfig dies of SIGPIPE) and named present libraries missing.
libs=$(/sbin/ldconfig -p 2>/dev/null || ldconfig -p 2>/dev/null || true)
have_lib() { grep -qF "$1" <<<"$libs"; }
missing=()
have_lib 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)
have_lib 'libGL.so.1' || missing+=(libgl1)
have_lib 'libEGL.so.1' || missing+=(libegl1)
have_lib 'libEGL_mesa.so.0' || missing+=(libegl-mesa0)
have_lib 'libgomp.so.1' || missing+=(libgomp1)
command -v cc >/dev/null || missing+=(gcc)
command -v g++ >/dev/null || missing+=(g++)
command -v xz >/dev/null || missing+=(xz-utils)  # the GPU campaign's packs (scripts/gpu_campaign.py)
"$PYTHON" - <<'EOF' || missing+=(python3-dev)
import os, sys, sysconfig
sys.exit(not os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")))
EOF
if [ ! -d .venv ] && ! "$PYTHON" -c 'import ensurepip' 2>/dev/null; then
  missing+=(python3-venv)
fi

if [ ${#missing[@]} -gt 0 ]; then
  if ! command -v apt-get >/dev/null; then
    say "missing system libraries (Debian names): ${missing[*]}; install their equivalents with your package manager, then rerun"
    exit 1
  fi
  if [ "$(id -u)" -eq 0 ]; then
    sudo=()
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo=(sudo -n)
  else
    fail "missing system packages: run 'sudo apt-get install -y ${missing[*]}', then rerun this script"
  fi
  say "installing system packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  "${sudo[@]}" apt-get update -qq
  "${sudo[@]}" apt-get install -y -qq "${missing[@]}" >/dev/null ||
    fail "apt-get could not install ${missing[*]} (its message is above; 'sudo apt-get --fix-broken install' repairs a broken package state), then rerun this script"
fi

# --- Python environment ---------------------------------------------------------------------
if [ ! -x .venv/bin/python ]; then
  say "creating .venv"
  "$PYTHON" -m venv .venv
fi
. .venv/bin/activate
python -m pip install -q --upgrade pip
# torch first and pinned: an unpinned torch pulls gigabytes of CUDA wheels.
python -m pip install -q torch==2.13.0
if [ -n "$EXTRAS" ]; then
  python -m pip install -q -e ".[$EXTRAS]"
else
  python -m pip install -q -e .
fi
python -c 'import open3d, mujoco, torch, torchrl' ||
  fail "the installed packages do not import (see above)"
say "ready: activate it with '. .venv/bin/activate'"
