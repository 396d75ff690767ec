#!/usr/bin/env bash
# Configures and builds skinbus into build/ (Ninja, ccache when present, -Werror).
#   scripts/build.sh [extra cmake -D options]
set -euo pipefail
cd "$(dirname "$0")/.."
cmake -S . -B build -G Ninja -DSKINBUS_WERROR=ON "$@" >/dev/null
cmake --build build -j2
