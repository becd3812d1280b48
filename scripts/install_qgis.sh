#!/usr/bin/env bash
# Install QGIS 3.40 LTR (Python bindings, data providers and the `qgis_process` command line)
# from Debian bookworm-backports. Idempotent and quiet; needs root (or sudo).
#
# Usage: bash scripts/install_qgis.sh [--no-qgis-process] [--no-runtime]
#   --no-qgis-process  install only python3-qgis + qgis-providers (no GUI package `qgis`,
#                      hence no `qgis_process`; the plugin and the in-process tests still work).
#   --no-runtime       skip the Python runtime for the plugin inside QGIS (see below).
#
# Afterwards QGIS's Python is Debian's /usr/bin/python3; the project venv (scripts/setup_env.sh)
# sees only QGIS's bindings (scripts/qgis_bindings.py) and runs QGIS in-process with its wheels.
#
# Inside the QGIS application and `qgis_process` (not in a Python process) the executable links
# GEOS, PROJ, GDAL and HDF5 into the global symbol scope, and PyPI wheels that bundle their own
# copies (shapely >= 2.1, h5py, rasterio, pyproj) then call QGIS's older copies and fail
# ("WKB output dimension must be 2 or 3", h5py "Not a datatype", free(): invalid size).  So the
# runtime for the plugin is Debian's builds of h5py/pyproj/rasterio/scipy/pandas/matplotlib
# (linked to the same libraries as QGIS) plus, in RUNTIME (default /opt/canopyblocks-qgis-python,
# env CANOPYBLOCKS_QGIS_RUNTIME), shapely 2.0.x (GEOS C API <= 3.11, which bookworm has),
# geopandas 1.0.x, laspy and lazrs (LAZ; a self-contained Rust extension that links none of
# QGIS's libraries), at the versions of scripts/lock/qgis-runtime.txt, without dependencies.
# Debian's xvfb lets the QGIS application
# run headless (the project's tests of the real application).  Use it with
#     PYTHONPATH=RUNTIME:<checkout>/core qgis   (or qgis_process)
# or install canopyblocks itself there: python3 -m pip install --no-deps --target RUNTIME <checkout>
set -euo pipefail

with_process=1
with_runtime=1
RUNTIME="${CANOPYBLOCKS_QGIS_RUNTIME:-/opt/canopyblocks-qgis-python}"
for arg in "$@"; do
    case "$arg" in
        --no-qgis-process) with_process=0 ;;
        --no-runtime) with_runtime=0 ;;
        -h|--help) sed -n '2,26p' "$0"; exit 0 ;;
        *) echo "install_qgis.sh: unknown argument '$arg'" >&2; exit 2 ;;
    esac
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "install_qgis.sh: run as root (or install sudo)" >&2; exit 1
    fi
fi

. /etc/os-release
if [ "${VERSION_CODENAME:-}" != "bookworm" ]; then
    echo "install_qgis.sh: written for Debian 12 (bookworm); this is '${PRETTY_NAME:-unknown}'." >&2
    echo "  On other systems install QGIS >= 3.22 with its Python bindings from your distribution." >&2
    exit 1
fi

pkgs=(python3-qgis qgis-providers)
[ "$with_process" -eq 1 ] && pkgs+=(qgis)
# Debian builds of the core's compiled dependencies, linked to QGIS's GEOS/PROJ/GDAL/HDF5
runtime_pkgs=(python3-h5py python3-pandas python3-rasterio python3-scipy python3-matplotlib
              python3-pyproj python3-click python3-tqdm python3-pip python3-fiona xvfb)
[ "$with_runtime" -eq 1 ] && pkgs+=("${runtime_pkgs[@]}")

install_runtime() {
    [ "$with_runtime" -eq 1 ] || return 0
    # the versions of scripts/lock/qgis-runtime.txt, exactly (a stamp beside them)
    local lock want
    lock="$(cd "$(dirname "$0")" && pwd)/lock/qgis-runtime.txt"
    want="$(sha256sum "$lock" | cut -c1-64)"
    if [ "$(cat "$RUNTIME/.canopyblocks-lock" 2>/dev/null)" = "$want" ] && \
        PYTHONPATH="$RUNTIME" /usr/bin/python3 -c 'import shapely, geopandas, laspy, lazrs' \
        2>/dev/null; then
        return 0
    fi
    echo "canopyblocks: installing shapely 2.0.x, geopandas 1.0.x, laspy and lazrs into $RUNTIME" >&2
    $SUDO mkdir -p "$RUNTIME"
    local log; log=$(mktemp)
    if ! $SUDO /usr/bin/python3 -m pip install -q --disable-pip-version-check --no-deps \
            --root-user-action=ignore --target "$RUNTIME" --upgrade \
            -r "$lock" >"$log" 2>&1; then
        cat "$log" >&2; rm -f "$log"
        echo "install_qgis.sh: pip could not install the plugin runtime into $RUNTIME" >&2
        exit 1
    fi
    rm -f "$log"
    echo "$want" | $SUDO tee "$RUNTIME/.canopyblocks-lock" >/dev/null
}

# Already there?  (idempotent, no network)
have_all=1
for p in "${pkgs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || have_all=0
done
if [ "$have_all" -eq 1 ] && /usr/bin/python3 -c 'import qgis.core' 2>/dev/null; then
    install_runtime
    echo "canopyblocks: QGIS already installed ($(dpkg-query -W -f='${Version}' python3-qgis))" >&2
    exit 0
fi

src=/etc/apt/sources.list.d/bookworm-backports.sources
if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    echo "canopyblocks: adding the bookworm-backports apt source ($src)" >&2
    $SUDO tee "$src" >/dev/null <<'EOF'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
fi

export DEBIAN_FRONTEND=noninteractive
echo "canopyblocks: apt-get update" >&2
$SUDO apt-get update -qq
echo "canopyblocks: installing ${pkgs[*]} from bookworm-backports (a few minutes)" >&2
$SUDO apt-get install -y -qq -t bookworm-backports --no-install-recommends "${pkgs[@]}" >/dev/null

if ! /usr/bin/python3 -c 'import qgis.core' 2>/dev/null; then
    echo "install_qgis.sh: installed, but '/usr/bin/python3 -c \"import qgis.core\"' fails" >&2
    exit 1
fi
install_runtime
echo "canopyblocks: QGIS $(dpkg-query -W -f='${Version}' python3-qgis) installed" >&2
[ "$with_runtime" -eq 1 ] && echo "canopyblocks: plugin runtime: PYTHONPATH=$RUNTIME:<checkout>/core" >&2
exit 0
