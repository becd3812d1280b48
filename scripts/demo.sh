#!/usr/bin/env bash
# Install canopyblocks (and the PDAL command line) and run the whole chain on the bundled real
# airborne tile: simulate ICESat-2 photons over it, compute block heights, build the PDAL
# reference rasters, validate, and write layers, plots and an HTML report to ./demo_out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_pdal.sh
bash scripts/setup_env.sh all
.venv/bin/canopyblocks run tests/data/als/lasR_bcts_1.laz tests/data/als/lasR_bcts_2.laz \
    --simulate --seed 1 --calibrate -o demo_out "$@"
echo "canopyblocks: open demo_out/report.html" >&2
