#!/usr/bin/env bash
# The minimum-versions job: a second venv (.venv-min) holding the oldest versions
# pyproject.toml allows (scripts/constraints-min.txt), running the suite without the QGIS
# tests (QGIS's Python brings its own, newer, system packages: those are the main venv's).
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=/usr/bin/python3
if [ ! -x .venv-min/bin/python ]; then
    "$PY" -m venv .venv-min
fi
.venv-min/bin/python -m pip install -q --upgrade pip >/dev/null
.venv-min/bin/python -m pip install -q -c scripts/constraints-min.txt \
    -e ".[raster,las,parquet,plot,fast]" "pytest>=7" "hypothesis>=6.50"
.venv-min/bin/python -m pip list --format=freeze | grep -iE \
    '^(numpy|scipy|pandas|geopandas|shapely|pyproj|h5py|matplotlib|pyarrow|laspy|rasterio)=' >&2
exec .venv-min/bin/python -m pytest -p no:cacheprovider --ignore=tests/qgis \
    -m "not qgis" "$@"
