#!/usr/bin/env bash
# Creates .venv with Python >= 3.11 and installs dishbot into it (with --dev: the test tools too).
set -euo pipefail
cd "$(dirname "$0")/.."
py="${PYTHON:-python3}"
"$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "dishbot needs Python 3.11 or newer")'
[ -x .venv/bin/python ] || "$py" -m venv .venv
extra=""
[ "${1:-}" = "--dev" ] && extra="[dev]"
stamp=".venv/.dishbot-installed$extra"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".$extra"
    touch "$stamp"
fi
