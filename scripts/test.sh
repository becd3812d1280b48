#!/usr/bin/env bash
# Install everything the test suite needs (QGIS 3.40 from Debian bookworm-backports, the PDAL
# command line from Debian bullseye into a private prefix, the Python environment) and run it.
# Extra arguments go to pytest.  Under CI=true a missing QGIS or PDAL fails the tests.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)
bash scripts/install_qgis.sh
bash scripts/install_pdal.sh
bash scripts/setup_env.sh test
echo "canopyblocks: set-up took $(( $(date +%s) - t0 )) s" >&2
.venv/bin/ruff check --quiet core qgis_plugin tests bench scripts
.venv/bin/mypy --no-error-summary
export QT_QPA_PLATFORM=offscreen
exec .venv/bin/python -m pytest "$@"
