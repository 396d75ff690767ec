#!/usr/bin/env bash
# Measures the host aggregator: the source of docs/benchmarks/aggregator.md.
#
#   scripts/host_report.sh
#
# Runs skinbus-bench host (stream and event mode; 16, 64, 200 patches; 100, 10, 0 % touched;
# model runtime on 1 and 2 threads), skinbus-bench ambient (a 50 uT field turned between tare
# and press) and host_aggregator_benchmark, writing the tables to build/host_report/*.txt, the
# CSV files and the plot to docs/benchmarks/. About 6 minutes on 2 cores; run it on a quiet
# machine (latency percentiles are wall-clock).
set -euo pipefail
cd "$(dirname "$0")/.."
[[ -x build/tools/skinbus-bench && -x build/host/host_aggregator_benchmark ]] || scripts/build.sh
out=build/host_report
mkdir -p "$out" docs/benchmarks
bench=build/tools/skinbus-bench
$bench host --mode stream --threads 1 --csv docs/benchmarks/aggregator_stream.csv | tee "$out/stream.txt"
$bench host --mode stream --threads 2 --csv docs/benchmarks/aggregator_stream_2threads.csv | tee "$out/stream_2threads.txt"
$bench host --mode event --threads 1 --csv docs/benchmarks/aggregator_event.csv | tee "$out/event.txt"
$bench ambient --count 1000 --csv docs/benchmarks/aggregator_ambient.csv | tee "$out/ambient.txt"
build/host/host_aggregator_benchmark --benchmark_min_time=0.5 2>&1 | tee "$out/google_benchmark.txt"
tools/plot_host.py docs/benchmarks/aggregator_latency.png docs/benchmarks/aggregator_stream.csv \
  docs/benchmarks/aggregator_event.csv
