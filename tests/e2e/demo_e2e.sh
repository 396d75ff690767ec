#!/usr/bin/env bash
# The README's main command, headless and bounded: scripts/demo.sh runs the whole-body demo (12
# patch daemons, the host, joint states, DDS) and the contacts a separate subscriber received must
# sit at the right places on the moving body (tests/e2e/check_demo.py).
#   tests/e2e/demo_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
out=$work/demo
"$src/scripts/demo.sh" --headless --no-setup --duration 15 --out "$out" --view-port 0 >"$work/demo.txt" 2>&1 || {
  tail -30 "$work/demo.txt"
  exit 1
}
tail -25 "$work/demo.txt"
"$src/tests/e2e/check_demo.py" "$out" "$src/sim/scenes/whole_body" "$build"
# Under an instruction-set cap (the e2e_demo_avx2 test), the host must have run those kernels.
if [[ -n ${SKINBUS_MAX_ISA:-} ]]; then
  grep -q "(kernels $SKINBUS_MAX_ISA " "$out/host.log" || {
    echo "FAIL: SKINBUS_MAX_ISA=$SKINBUS_MAX_ISA but the host ran:"
    grep "kernels\|portable\|onednn" "$out/host.log" || true
    exit 1
  }
  echo "PASS: the host ran the $SKINBUS_MAX_ISA kernels"
fi
