#!/usr/bin/env bash
# End to end on the host (no kernel CAN needed): simulated patch daemons write their frames as a
# candump log; skinbus-host replays it at recorded speed and publishes on DDS; skinbus-listen, a
# separate process on a loopback-only DDS configuration, receives the contacts, which must lie
# where the scene pressed, in the robot's base frame, within the model's error.
#   tests/e2e/host_replay_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"

# The skin map: the true layout skinbus-touchsim puts on the project's robot (cylinder patches
# on the forearms, flat ones on the chest), every patch with the shipped model.
make_skin_map map.yaml

# The scene: presses on patches 1, 2 and 5 (patch 3 and 4 stay untouched), arms held bent.
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.6,1.9,10,-20,2.0,5,1
1.0,2.2,-30,35,2.5,5,2
1.4,2.6,25,10,1.8,5,5
CSV
cat >joints.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint,right_elbow_joint
0,-0.4,0.6,0.9
CSV

# Five simulated patch daemons (event mode), each with the hardware UID the map gives it.
record_bus bus.log 3 "1 2 3 4 5" --contacts presses.csv

# DDS on loopback only, in a domain of its own.
use_loopback_domain
echo "DDS domain $domain (loopback only)"

"$bin/skinbus-listen" --domain "$domain" --timeout 30 --status --diagnostics >listen.jsonl 2>listen.err &
listener=$!
sleep 1.5
"$bin/skinbus-host" --map map.yaml --replay bus.log --joints joints.csv --domain "$domain" \
  --json --stats >host.jsonl 2>host.err
sleep 1
kill "$listener" 2>/dev/null || true
wait "$listener" 2>/dev/null || true
cat host.err

# The truth: where each press lies on the robot at the held pose.
awk -F, '!/^#/ {print $7, $3, $4}' presses.csv | "$bin/skinbus-locate" --map map.yaml \
  --joints joints.csv - >truth.txt

"$src/tests/e2e/check_contacts.py" truth.txt listen.jsonl --reference host.jsonl

# The patches' health on rt/diagnostics, as another process received it: all five patches, OK
# once they are online (the replay has no faults), named by node and link.
python3 - listen.jsonl <<'PY'
import json, sys
last = None
for line in open(sys.argv[1]):
    j = json.loads(line)
    if j.get("type") == "diagnostics":
        last = j
if last is None:
    sys.exit("no diagnostics line received")
names = sorted(s["name"] for s in last["status"])
levels = {s["name"]: s["level"] for s in last["status"]}
print("diagnostics:", levels)
if len(names) != 5 or not all(n.startswith("skinbus patch ") for n in names):
    sys.exit("expected the five patches, got %s" % names)
bad = {n: l for n, l in levels.items() if l != "OK"}
if bad:
    sys.exit("patches not OK: %s" % bad)
if any(s["values"].get("dead_sensors") != "none" for s in last["status"]):
    sys.exit("dead sensors reported on healthy patches")
PY
