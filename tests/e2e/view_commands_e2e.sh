#!/usr/bin/env bash
# The web view's commands: a page can tare a patch or set its mode only when skinbus-view runs with
# --allow-commands. Two servers on one skin map, one read-only (the default), one allowing
# commands (written as candump -L lines, --commands-out); the page in headless Chromium sends the
# same commands to both (tests/e2e/check_view_commands.py); the frames written are decoded by
# skinbus-decode and must be exactly the allowed server's commands.
#   tests/e2e/view_commands_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
use_loopback_domain
make_skin_map skin.yaml
"$bin/skinbus-view" --map skin.yaml --domain "$domain" --port 0 --duration 60 >ro.err 2>&1 &
ro=$!
"$bin/skinbus-view" --map skin.yaml --domain "$domain" --port 0 --duration 60 --allow-commands \
  --commands-out commands.log >rw.err 2>&1 &
rw=$!
wait_for "serving http" 20 ro.err $ro
wait_for "serving http" 20 rw.err $rw
ro_url=$(grep -o 'http://[^ ]*' ro.err | head -1)
rw_url=$(grep -o 'http://[^ ]*' rw.err | head -1)
status=0
"$src/tests/e2e/check_view_commands.py" "$ro_url" "$rw_url" || status=1
kill $ro $rw 2>/dev/null || true
wait $ro $rw 2>/dev/null || true
echo "commands written by the allowing server (decoded):"
"$bin/skinbus-decode" commands.log | tee decoded.txt
if [[ $(grep -c "" decoded.txt) == 2 ]] && grep -q "^command node=3 .*op=tare" decoded.txt &&
   grep -q "^command node=3 .*op=set_mode mode=stream" decoded.txt; then
  echo "PASS the allowed commands reached the bus output, and nothing else"
else
  echo "FAIL the command frames: expected a tare and a mode stream to node 3"
  status=1
fi
exit $status
