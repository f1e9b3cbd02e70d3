#!/usr/bin/env bash
# Sets up .venv (if needed) and runs lint, type checks and the test suite. README quick start, second command.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --dev
export MUJOCO_GL="${MUJOCO_GL:-egl}"
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/mypy
.venv/bin/lint-imports --no-cache
.venv/bin/pytest --durations=15 "$@"
