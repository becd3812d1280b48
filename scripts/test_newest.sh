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
rm -rf .venv-newest
/usr/bin/python3 -m venv .venv-newest
.venv-newest/bin/python -m pip install -q --upgrade pip uv
# uv resolves the newest releases in seconds (pip's resolver backtracks for many minutes over
# s3fs/aiobotocore/botocore ranges); the list is kept beside the venv and compared with the lock
.venv-newest/bin/uv pip compile -q pyproject.toml --extra test --python-version 3.11 \
    --python-platform x86_64-manylinux_2_36 -o .venv-newest/newest.txt
diff <(grep -E '^[a-z0-9_.-]+==' scripts/lock/test.txt) \
     <(grep -E '^[a-z0-9_.-]+==' .venv-newest/newest.txt) | grep '^>' | sed 's/^> /newer than the lock: /' >&2 || true
.venv-newest/bin/python -m pip install -q -r .venv-newest/newest.txt
.venv-newest/bin/python -m pip install -q --no-deps --no-build-isolation -e .
exec bash scripts/suite_in_venv.sh .venv-newest "$t0" "$@"
