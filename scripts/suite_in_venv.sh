#!/usr/bin/env bash
# The common tail of scripts/test_min_versions.sh and scripts/test_newest.sh: check the venv
# given first, print its key versions and the set-up time (since the second argument, epoch
# seconds), and run the suite in it without the QGIS tests. Further arguments go to pytest.
set -euo pipefail
venv=$1 t0=$2
shift 2
"$venv/bin/python" -m pip check >&2
"$venv/bin/python" -m pip list --format=freeze | grep -iE \
    '^(numpy|scipy|pandas|geopandas|shapely|pyproj|h5py|matplotlib|pyarrow|laspy|rasterio|s3fs|numba|distributed|pytest)=' \
    | tr '\n' ' ' >&2
echo >&2
echo "canopyblocks: $venv set up in $(( $(date +%s) - t0 )) s" >&2
exec "$venv/bin/python" -m pytest -p no:cacheprovider --ignore=tests/qgis -m "not qgis" "$@"
