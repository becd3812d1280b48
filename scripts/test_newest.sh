#!/usr/bin/env bash
# The newest-versions job (not part of CI's .ci/run; it may fail): a third venv (.venv-newest)
# holding the newest release of every package canopyblocks and its test extras allow, installed
# without the lock and without constraints, running the suite without the QGIS tests. A
# failure here is an upstream release that breaks canopyblocks, seen before a user meets it:
# fix the code, or bound the package in pyproject.toml and say why there.
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=/usr/bin/python3
t0=$(date +%s)
if [ ! -x .venv-newest/bin/python ]; then
    "$PY" -m venv .venv-newest
fi
.venv-newest/bin/python -m pip install -q --upgrade pip
.venv-newest/bin/python -m pip install -q --upgrade --upgrade-strategy eager -e ".[test]"
.venv-newest/bin/python -m pip check >&2
.venv-newest/bin/python -m pip list --format=freeze | grep -iE \
    '^(numpy|scipy|pandas|geopandas|shapely|pyproj|h5py|matplotlib|pyarrow|laspy|rasterio|s3fs|numba|distributed|pytest)=' \
    | tr '\n' ' ' >&2
echo >&2
echo "canopyblocks: newest-versions set-up took $(( $(date +%s) - t0 )) s" >&2
exec .venv-newest/bin/python -m pytest -p no:cacheprovider --ignore=tests/qgis -m "not qgis" "$@"
