#!/usr/bin/env bash
# The web view end to end: the whole-body demo (scripts/demo.sh, 12 patches, moving arms) with its
# web view, the page driven in headless Chromium (tests/e2e/cdp.py) while the demo runs. One patch
# daemon is stopped mid-run (node 11, after its press), so the page must show it going stale and
# offline; hostile clients hit the server meanwhile. tests/e2e/check_view.py reads the page back
# and checks it; the screenshot is kept in BUILD_DIR/e2e_view/.
#   tests/e2e/view_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
command -v chromium >/dev/null || { echo "FAIL: chromium missing: run scripts/setup.sh"; exit 1; }
out=$work/demo
duration=26
ready=$work/page_ready  # check_view.py creates it once its page is up; the scene starts then
"$src/scripts/demo.sh" --headless --no-setup --duration $duration --out "$out" --view-port 0 \
  --start-when "$ready" >"$work/demo.txt" 2>&1 &
demo=$!
wait_for "the web view: http" 60 "$work/demo.txt" $demo
url=$(grep -o 'http://[^ ]*' "$work/demo.txt" | head -1)
echo "the demo serves its web view at $url"
# Node 11 is pressed from 4.0 to 6.5 s of the scene; its daemon stops at 8.5 s (stale 3 s later,
# offline at 10 s).
(
  wait_for "time zero" 180 "$out/joints.log" $demo
  sleep 8.5
  pkill -f -- "skinbus-patchd .*--node 11 " || echo "could not stop node 11"
) &
mkdir -p "$build/e2e_view"
status=0
"$src/tests/e2e/check_view.py" "$url" "$out" "$src/sim/scenes/whole_body" "$build" \
  "$build/e2e_view" $((duration + 4)) "$ready" || status=1
wait $demo || { echo "FAIL: the demo failed"; tail -20 "$work/demo.txt"; status=1; }
grep "skinbus-view:" "$out/view.log" | tail -2
exit $status
