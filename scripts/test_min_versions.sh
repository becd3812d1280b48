#!/usr/bin/env bash
# The minimum-versions job: a second venv (.venv-min) holding the oldest versions
# pyproject.toml allows, running the suite without the QGIS tests (QGIS's Python brings its
# own, newer, system packages: those are the main venv's). Every extra's minimum is installed
# (cloud, numba and dask included), so every lower bound pyproject.toml writes is tried.
# The versions come from scripts/lock/min.txt, made by scripts/update_locks.sh from
# scripts/constraints-min.txt (the minimums) and scripts/lock/min-tools.in (pytest, moto, ...).
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=/usr/bin/python3
t0=$(date +%s)
if [ ! -x .venv-min/bin/python ]; then
    "$PY" -m venv .venv-min
fi
.venv-min/bin/python -m pip install -q pip==26.3
.venv-min/bin/python -m pip install -q -r scripts/lock/min.txt
.venv-min/bin/python -m pip install -q --no-deps --no-build-isolation -e .
exec bash scripts/suite_in_venv.sh .venv-min "$t0" "$@"
