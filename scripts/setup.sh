#!/usr/bin/env bash
# Creates .venv with Python >= 3.11 and installs dishbot into it: without a flag what the robot runs (the
# daemon on hardware, every client verb); --sim adds the MuJoCo cell (scripts/demo.sh); --dev adds the MuJoCo
# cell and the lint, type and test tools (scripts/test.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
    "") extra="" ;;
    --sim) extra="[sim]" ;;
    --dev) extra="[dev]" ;;
    *) echo "scripts/setup.sh: unknown option '$1' (use --sim, --dev or nothing)" >&2; exit 2 ;;
esac
py="${PYTHON:-python3}"
"$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "dishbot needs Python 3.11 or newer")'
[ -x .venv/bin/python ] || "$py" -m venv .venv
# One stamp per extra set, newer than pyproject.toml once that set is installed; a set that includes the one
# asked for will do (dev brings sim along, and either brings the plain install).
case "$extra" in
    "") enough=("" "[sim]" "[dev]") ;;
    "[sim]") enough=("[sim]" "[dev]") ;;
    "[dev]") enough=("[dev]") ;;
esac
current=false
for installed in "${enough[@]}"; do
    stamp=".venv/.dishbot-installed$installed"
    if [ -f "$stamp" ] && [ ! pyproject.toml -nt "$stamp" ]; then
        current=true
        break
    fi
done
if [ "$current" = false ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".$extra"
    touch ".venv/.dishbot-installed$extra"
fi
# dishbot's own bytecode, ahead of time (pip compiles the dependencies it installs, not an editable
# checkout): where Python may not write it (PYTHONDONTWRITEBYTECODE set, or a checkout the running user cannot
# write), every process would otherwise compile each of our modules it imports on every start: 60-80 ms of a
# `dishbot plan`. Only what changed is compiled again; a module that does not compile is named here and left
# to the import (and to ruff) to report.
.venv/bin/python -m compileall -q -j 0 validation description drivers perception planning statechart sim \
    wire recorder daemon replay cli bench tests || true
