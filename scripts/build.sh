#!/usr/bin/env bash
# Configures and builds skinbus into build/ (Ninja, ccache when present, -Werror).
#   scripts/build.sh [--target T ...] [extra cmake -D options]
#     --target T   build only T (repeatable; default: everything, tests and benchmarks too)
set -euo pipefail
cd "$(dirname "$0")/.."
targets=()
while (($#)) && [[ $1 == --target ]]; do
  targets+=(--target "$2")
  shift 2
done
cmake -S . -B build -G Ninja -DSKINBUS_WERROR=ON "$@" >/dev/null
cmake --build build -j2 "${targets[@]}"
