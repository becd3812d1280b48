#!/usr/bin/env bash
# Run every benchmark and print its figures: bash bench/run_all.sh
# (one core each; the machines are shared, so quote medians of several runs).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
echo "== block engine and ATL03 file path (bench/bench_blocks.py)"
"$PY" bench/bench_blocks.py "$@"
echo "== simulator (bench/bench_simulate.py)"
"$PY" bench/bench_simulate.py
echo "== granule scale (bench/bench_granule.py)"
"$PY" bench/bench_granule.py
echo "== a granule in object storage (bench/bench_remote.py)"
"$PY" bench/bench_remote.py
echo "== many granules (bench/bench_batch.py)"
"$PY" bench/bench_batch.py
echo "== GEDI waveforms (bench/bench_waveforms.py)"
"$PY" bench/bench_waveforms.py
echo "== GEDI waveform simulation (bench/bench_simulate_waveforms.py)"
"$PY" bench/bench_simulate_waveforms.py
echo "== reference rasters (bench/bench_rasters.py)"
"$PY" bench/bench_rasters.py
echo "== co-registration (bench/bench_coregistration.py)"
"$PY" bench/bench_coregistration.py
echo "== per-block sigma on unseen tiles (bench/bench_block_sigma.py)"
"$PY" bench/bench_block_sigma.py
echo "== block reference bias per block length (bench/bench_reference_length_bias.py)"
"$PY" bench/bench_reference_length_bias.py
