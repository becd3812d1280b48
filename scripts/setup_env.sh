#!/usr/bin/env bash
# Create ./.venv on Debian's Python 3.11 and install canopyblocks into it, editable, with every
# package at the version of the committed lock (scripts/lock/, written by
# scripts/update_locks.sh): a fresh machine today and in three months gets what CI tested.
# Idempotent: an existing .venv made from the same lock is kept; any other is made anew.
#
# The venv does not see Debian's Python packages (no --system-site-packages): a Debian
# pyOpenSSL, requests or matplotlib pulled in by QGIS would otherwise be imported by the
# command line beside the lock's packages. When QGIS is installed, only its bindings (qgis,
# PyQt5, sip, osgeo and the Processing plugins) are made visible, through one .pth file
# (scripts/qgis_bindings.py), so the QGIS tests run QGIS in-process with the locked wheels.
#
# Usage: bash scripts/setup_env.sh [all|test]   (default all: the demo's; the tests use test)
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-all}"
case "$extras" in
    all) lock=scripts/lock/demo.txt ;;
    test) lock=scripts/lock/test.txt ;;
    *) echo "setup_env.sh: unknown environment '$extras' (all or test)" >&2; exit 2 ;;
esac
PIP_VERSION=26.3
PY=/usr/bin/python3
if [ ! -x "$PY" ] || ! "$PY" -c 'import venv, ensurepip' 2>/dev/null; then
    echo "canopyblocks: installing Debian's python3 with venv support" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends python3 python3-venv python3-pip >/dev/null
fi

stamp=".venv/canopyblocks-lock.txt"
want="$(sha256sum "$lock" pyproject.toml scripts/qgis_bindings.py | sha256sum | cut -c1-64) $lock"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x .venv/bin/python ]; then
    "$PY" scripts/qgis_bindings.py .venv >&2
    echo "canopyblocks: environment ready in $(pwd)/.venv (from $lock)" >&2
    exit 0
fi
if [ -e .venv ]; then
    echo "canopyblocks: .venv was made from another lock or by hand; making it anew" >&2
    rm -rf .venv
fi
"$PY" -m venv .venv
log=$(mktemp)
pip_quiet() {  # pip's own chatter (setuptools' editable-install notice) only when it fails
    if ! .venv/bin/python -m pip install -q --disable-pip-version-check "$@" >"$log" 2>&1; then
        cat "$log" >&2; rm -f "$log"
        echo "setup_env.sh: pip could not install $* (see above)" >&2
        exit 1
    fi
}
pip_quiet "pip==$PIP_VERSION"
echo "canopyblocks: installing $(grep -c '==' "$lock") locked packages from $lock (a few minutes the first time)" >&2
pip_quiet -r "$lock"
pip_quiet --no-deps --no-build-isolation -e .
rm -f "$log"
"$PY" scripts/qgis_bindings.py .venv >&2
echo "$want" > "$stamp"
echo "canopyblocks: environment ready in $(pwd)/.venv (from $lock)" >&2
