#!/usr/bin/env bash
# Regenerate the locks in scripts/lock/, one per environment the project makes, for Debian 12's
# Python 3.11 on x86_64 Linux (glibc 2.36), with a pinned uv in a throw-away venv:
#   demo.txt          .venv for scripts/demo.sh (the 'all' extras)
#   test.txt          .venv for scripts/test.sh (the 'test' extras: all, dask, pytest, moto, ...)
#   qgis-runtime.txt  the plugin's runtime inside QGIS (scripts/install_qgis.sh, --no-deps)
#   min.txt           .venv-min for scripts/test_min_versions.sh: the oldest versions pyproject.toml
#                     allows (scripts/constraints-min.txt) with every extra, and the test tools
# scripts/constraints.txt holds the few ranges the locks must respect (numpy<2 for Debian's
# GDAL bindings, which QGIS loads). Commit the four files after a run; CI installs from them.
set -euo pipefail
cd "$(dirname "$0")/.."
UV_VERSION=0.13.9
tool=$(mktemp -d "${TMPDIR:-/tmp}/canopyblocks-uv.XXXXXX")
trap 'rm -rf "$tool"' EXIT
/usr/bin/python3 -m venv "$tool"
"$tool/bin/python" -m pip install -q --disable-pip-version-check "uv==$UV_VERSION"
compile() {
    "$tool/bin/uv" pip compile --quiet --python-version 3.11 \
        --python-platform x86_64-manylinux_2_36 \
        --custom-compile-command "bash scripts/update_locks.sh" "$@"
}
compile pyproject.toml scripts/lock/build.in --extra all -c scripts/constraints.txt -o scripts/lock/demo.txt
compile pyproject.toml scripts/lock/build.in --extra test -c scripts/constraints.txt -o scripts/lock/test.txt
compile scripts/lock/qgis-runtime.in --no-deps -o scripts/lock/qgis-runtime.txt
compile pyproject.toml scripts/lock/build.in scripts/lock/min-tools.in --extra all --extra dask \
    -c scripts/constraints-min.txt -o scripts/lock/min.txt
echo "canopyblocks: locks written to scripts/lock/ (review the diff, then commit)" >&2
