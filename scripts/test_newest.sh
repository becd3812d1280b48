#!/usr/bin/env bash
# The newest-versions job (not part of CI's .ci/run; it may fail): a third venv (.venv-newest)
# holding the newest release of every package canopyblocks and its test extras allow, installed
# without the lock and without constraints, running the suite without the QGIS tests. A
# failure here is an upstream release that breaks canopyblocks, seen before a user meets it:
# fix the code, or bound the package in pyproject.toml and say why there.
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)
[ -x .venv-newest/bin/python ] || /usr/bin/python3 -m venv .venv-newest
.venv-newest/bin/python -m pip install -q --upgrade pip
.venv-newest/bin/python -m pip install -q --upgrade --upgrade-strategy eager -e ".[test]"
exec bash scripts/suite_in_venv.sh .venv-newest "$t0" "$@"
