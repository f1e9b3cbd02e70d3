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
# The suite on pytest-xdist workers: most of a serial run's wall time is waiting (daemons, subprocesses,
# Zenoh links, systemd), which overlaps well; 3 workers suit two shared cores (README, "Tests").
# DISHBOT_TEST_WORKERS=0 runs it serially in this process.
workers="${DISHBOT_TEST_WORKERS:-3}"
parallel=()
if [ "$workers" != 0 ]; then
    parallel=(-n "$workers" --dist loadgroup)
fi
.venv/bin/pytest "${parallel[@]}" --durations=15 "$@"
