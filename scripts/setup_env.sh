#!/usr/bin/env bash
# Create ./.venv on Debian's Python (the one QGIS's bindings are built for) and install
# canopyblocks into it, editable, with its optional parts. Idempotent.
# Usage: bash scripts/setup_env.sh [extras]   (default extras: all; the tests use "test")
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-all}"
PY=/usr/bin/python3
if [ ! -x "$PY" ] || ! "$PY" -c 'import venv, ensurepip' 2>/dev/null; then
    echo "canopyblocks: installing Debian's python3 with venv support" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends python3 python3-venv python3-pip >/dev/null
fi
if [ ! -x .venv/bin/python ]; then
    # --system-site-packages: the venv sees Debian's QGIS bindings when they are installed.
    "$PY" -m venv --system-site-packages .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
# numpy<2: Debian's GDAL/scipy/matplotlib (seen by QGIS) are built on numpy 1.x;
# attrs>=23.2: Debian's attrs 22.2 breaks rasterio's affine.
# --ignore-installed: take every dependency from PyPI into the venv, even where Debian's copy
# (pulled in by QGIS: scipy, rasterio, matplotlib, ...) would satisfy the range, so the
# environment is the same with and without QGIS on the machine.
.venv/bin/python -m pip install -q --ignore-installed -c scripts/constraints.txt -e ".[${extras}]"

# Debian's python3-matplotlib (pulled in by QGIS) ships mpl_toolkits as a *regular* package,
# which shadows the pip matplotlib's namespace package and breaks its 3-D axes (a warning on
# every plot).  Make the venv's own mpl_toolkits regular too, so it wins on sys.path.
mpl_dir=$(.venv/bin/python - <<'PY'
import importlib.util, pathlib, sys
spec = importlib.util.find_spec("matplotlib")
if spec and spec.origin and str(pathlib.Path(spec.origin)).startswith(sys.prefix):
    print(pathlib.Path(spec.origin).parents[1] / "mpl_toolkits")
PY
)
if [ -n "$mpl_dir" ] && [ -d "$mpl_dir" ] && ls /usr/lib/python3/dist-packages/matplotlib-*-nspkg.pth >/dev/null 2>&1; then
    # Debian's matplotlib-*-nspkg.pth imports mpl_toolkits at start-up; import ours first
    # (the venv's .pth files run before the system's), so its __path__ starts with ours.
    [ -e "$mpl_dir/__init__.py" ] || echo "# made regular by canopyblocks' scripts/setup_env.sh" > "$mpl_dir/__init__.py"
    echo "import mpl_toolkits" > "$(dirname "$mpl_dir")/canopyblocks-mpl-toolkits.pth"
fi
echo "canopyblocks: environment ready in $(pwd)/.venv" >&2
