#!/usr/bin/env bash
# README quick start, first command: sets up .venv (with the sim extra) and runs one complete simulated
# loading job.
# Extra arguments go to `dishbot run` (e.g. --dataset 2, --speed 4).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --sim  # the MuJoCo cell
export MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/dishbot run --sim --once "$@"
