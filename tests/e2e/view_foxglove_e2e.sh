#!/usr/bin/env bash
# skinbus-view's Foxglove WebSocket server (--foxglove-port) end to end, read by an independent
# client: simulated patch daemons write a candump log (presses on patches 1, 2 and 5, arms held
# bent); skinbus-host replays it and publishes on DDS (loopback only, a domain of the test's own);
# skinbus-joints publishes the same held pose on rt/joint_states; skinbus-view reads both and
# serves Foxglove; tests/interop/foxglove_check.mjs (@foxglove/ws-protocol's FoxgloveClient over
# `ws`, from npm) subscribes to every channel and checks what it received against the host's own
# --json output, the skin map, the URDF and the trajectory (see the script's head). No browser.
# Exits 77 (skipped) when node or tests/interop/node_modules is missing (scripts/setup.sh).
#   tests/e2e/view_foxglove_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
interop=$src/tests/interop
if ! command -v node >/dev/null; then
  echo "SKIP: node is not installed (scripts/setup.sh)"
  exit 77
fi
if [[ ! -d $interop/node_modules/@foxglove/ws-protocol || ! -d $interop/node_modules/ws ]]; then
  echo "SKIP: $interop/node_modules lacks @foxglove/ws-protocol or ws (scripts/setup.sh: npm ci)"
  exit 77
fi
e2e_init "$@"

make_skin_map map.yaml
# Node 5 (on the torso) is calibrated and slides: its contacts carry their shear (arrows).
calibrate_node map.yaml 5 "refine_shear: true"
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node[,u_end_mm,v_end_mm,friction]
0.8,1.9,10,-20,2.0,5,1
1.1,2.2,-30,35,2.5,5,2
1.4,2.6,-5,10,2.2,5,5,35,10,0.4
CSV
cat >joints.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint,right_elbow_joint,waist_yaw_joint
0,-0.4,0.6,0.9,0.2
CSV
record_bus bus.log 3.2 "1 2 3 4 5" --contacts presses.csv

use_loopback_domain
echo "DDS domain $domain (loopback only)"
"$bin/skinbus-view" --map map.yaml --domain "$domain" --port 0 --foxglove-port 0 --duration 90 \
  >view.out 2>view.err &
view=$!
wait_for "Foxglove WebSocket protocol at ws://" 30 view.out $view
url=$(grep -o 'ws://[^ ]*' view.out | head -1)
echo "skinbus-view serves Foxglove at $url"
"$bin/skinbus-joints" --trajectory joints.csv --robot "$urdf" --domain "$domain" --duration 60 \
  2>joints.err &
node "$interop/foxglove_check.mjs" --url "$url" --host-jsonl host.jsonl --map map.yaml \
  --urdf "$urdf" --joints joints.csv --ready ready --done finished --timeout 80 >check.err 2>&1 &
check=$!
wait_for "ready" 30 ready $check
sleep 1  # DDS discovery: the host's first publications must find skinbus-view matched
"$bin/skinbus-host" --map map.yaml --replay bus.log --joints joints.csv --domain "$domain" \
  --json >host.jsonl 2>host.err
sleep 1
touch finished
status=0
wait $check || status=1
cat check.err
kill $view 2>/dev/null || true
wait $view 2>/dev/null || true
tail -2 view.err
exit $status
