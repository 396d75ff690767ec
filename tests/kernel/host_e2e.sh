#!/usr/bin/env bash
# The host aggregator end to end on real SocketCAN, inside the CAN test VM (scripts/can_vm.sh):
# three simulated patch daemons publish on vcan0; skinbus-host reads vcan0 and publishes on DDS
# (loopback only); skinbus-listen, another process, receives the contacts, which must lie where
# the scene pressed, in the robot's base frame, within the model's error. Then an interface that
# goes down and up: no crash, both events in the patch status, contacts again afterwards. At the
# same time a recorded log (patch 5, pressed) is replayed on a second bus (--live-and-replay).
# The guest emulates its CPU, so the host keeps up only by estimating each patch's newest sample.
#
#   scripts/can_vm.sh --fd-ifaces 1 -- tests/kernel/host_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
# shellcheck source=../e2e/e2e_lib.sh
source "$(dirname "$0")/../e2e/e2e_lib.sh"
e2e_begin host_e2e "${1:-}"
ip link set lo up 2>/dev/null || true

make_skin_map map.yaml
# The presses begin 2 s after each daemon starts. With presses at 0.8-1 s, two full VM runs
# placed node 2's contacts 42 mm from its press: what a press held through the whole baseline
# capture gives (its release reads as a touch; 39-43 mm in a native replay whose press lands with
# the daemon's first reading), which no patch can tell from its rest field (patch_fw/gate.h). That
# a starved guest began sampling that late is the likely cause, not one observed directly.
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
2.0,6.0,10,-20,2.0,5,1
2.0,6.0,-30,35,2.5,5,2
2.0,6.0,25,10,1.8,5,5
CSV
cat >joints.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint
0,-0.4,0.6
CSV
use_loopback_dds
domain=$((RANDOM % 200 + 20))
# The recorded log of patch 5, for the second bus.
"$bin/skinbus-patchd" --sim -i none --candump-out replay.log --node 5 \
  --uid "$(printf '0x5b%014x' 5)" --contacts presses.csv --duration 6.5 -q

"$bin/skinbus-listen" --domain "$domain" --timeout 60 --status >listen.jsonl 2>listen.err &
listener=$!
"$bin/skinbus-host" --map map.yaml -i vcan0 --joints joints.csv --domain "$domain" --json \
  --json-status --status-period 0.5 --duration 19 --stats --replay replay.log --live-and-replay \
  >host.jsonl 2>host.err &
host=$!
sleep 2
pids=()
for n in 1 2 3; do
  "$bin/skinbus-patchd" --sim -i vcan0 --node "$n" --uid "$(printf '0x5b%014x' "$n")" \
    --contacts presses.csv --duration 6.5 -q &
  pids+=($!)
done
wait "${pids[@]}" || bad "a patch daemon failed"
# The interface goes down and comes back while the host runs.
sleep 0.5
ip link set vcan0 down
sleep 2.5
ip link set vcan0 up
sleep 0.5
"$bin/skinbus-patchd" --sim -i vcan0 --node 1 --uid "$(printf '0x5b%014x' 1)" \
  --contacts presses.csv --duration 3.5 -q
wait "$host" && ok "skinbus-host ran to its end" || bad "skinbus-host failed: $(tail -3 host.err)"
sleep 1
kill "$listener" 2>/dev/null || true
wait "$listener" 2>/dev/null || true
cat host.err

awk -F, '!/^#/ {print $7, $3, $4}' presses.csv | "$bin/skinbus-locate" --map map.yaml \
  --joints joints.csv - >truth.txt
# The guest emulates the CPU (no AVX, TCG): a model run takes most of a second, so the host
# estimates only each patch's newest sample (the rest are superseded, as designed) and few
# contacts come out; their number is not the point here, their place is.
if "$src/tests/e2e/check_contacts.py" truth.txt listen.jsonl --reference host.jsonl \
  --min-arrays 3 --min-per-node 1; then
  ok "contacts over SocketCAN and DDS match the scene"
else
  bad "contacts over SocketCAN and DDS"
fi
if grep -q '"event":"interface_down"' host.jsonl && grep -q '"event":"interface_up"' host.jsonl; then
  ok "interface down and up reported in the patch status"
else
  bad "interface events missing from the patch status"
fi
# Node 1 pressed again after the interface came back (its second run): contacts after the up.
if python3 - <<'PY'
import json
up = None
after = 0
for line in open("host.jsonl"):
    j = json.loads(line)
    if j["type"] == "patch_status":
        for e in j["events"]:
            if e["event"] == "interface_up":
                up = e["time_us"]
    elif up is not None and any(c["node"] == 1 for c in j["contacts"]):
        after += 1
print(f"{after} contact arrays with node 1 after the interface came back")
raise SystemExit(0 if after >= 1 else 1)
PY
then ok "contacts flow again after the interface came back"; else bad "no contacts after the interface came back"; fi
e2e_end host_e2e
