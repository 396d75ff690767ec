#!/usr/bin/env bash
# The skinbus whole-body demo: the project's humanoid (body_map/robots/skinbot.urdf) wears 12
# simulated patches (cylinder sections on the forearms and upper arms, flat patches on the chest),
# each its own patch node daemon (skinbus-patchd --sim: emulated MLX90393s fed by the physics
# simulator). Scripted touches land on them while the arms move (joint states on DDS from
# skinbus-joints). The host aggregator (skinbus-host) reads the bus, estimates every touched
# patch with the shipped model, places the contacts on the moving body and publishes them on the
# DDS topic rt/skin/contacts; skinbus-top draws them in the terminal and skinbus-view serves them
# in 3D to a web browser (http://localhost:8080/ while the demo runs; docs/view.md).
#
#   scripts/demo.sh [--duration SECONDS] [--headless] [--out DIR] [--no-setup] [--view-port P]
#                   [--no-calibrate] [--start-when FILE]
#
# On a kernel with vcan (and the right to create it) the patches send on real SocketCAN; elsewhere
# they send the same frames, in candump -L form, through a pipe to the host, and the demo says so.
# Either way the bus traffic is in OUT/bus.log (watch it: tail -f out/demo/bus.log).
#   --headless   no live view: a plain frame every 4 s (logs, tests)
#   --no-setup   skip scripts/setup.sh and the build (they are quick when done, not instant)
#   --view-port  the web view's port (default 8080; 0: any free port; off: no web view)
#   --no-calibrate  skip identifying the two chest patches' units (tens of seconds on a host
#                core, far longer on an emulated CPU): every patch runs the shipped network alone
#   --start-when FILE  start the host and the touches only once FILE exists, so that a program
#                driving the web view sees the scene from its first press (it creates FILE when
#                its page is up); the web view then serves until the demo ends
set -euo pipefail
cd "$(dirname "$0")/.."
src=$PWD
duration=16
headless=0
setup=1
out=out/demo
view_port=${SKINBUS_VIEW_PORT:-8080}
calibrate=1
start_when=
while (($#)); do
  case $1 in
    --duration) duration=$2; shift 2 ;;
    --headless) headless=1; shift ;;
    --out) out=$2; shift 2 ;;
    --no-setup) setup=0; shift ;;
    --view-port) view_port=$2; shift 2 ;;
    --no-calibrate) calibrate=0; shift ;;
    --start-when) start_when=$2; shift 2 ;;
    -h|--help) sed -n '2,24p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
if ((setup)); then
  scripts/setup.sh
  # Only the programs the demo runs (scripts/build.sh alone builds everything, tests too); the
  # calibration's two only when it calibrates.
  targets=(--target skinbus-touchsim --target skinbus-patchd --target skinbus-host
    --target skinbus-listen --target skinbus-joints --target skinbus-top --target skinbus-view)
  if ((calibrate)); then targets+=(--target skinbus-dataset --target skinbus-identify); fi
  scripts/build.sh "${targets[@]}"
fi
bin=$src/build/tools
scene=$src/sim/scenes/whole_body
mkdir -p "$out"
out=$(cd "$out" && pwd)
rm -f "$out"/{bus,host,listen,joints,view}.log "$out"/{contacts,host}.jsonl "$out"/bus_load.png

pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  [[ -n ${made_vcan:-} ]] && ip link del "$made_vcan" 2>/dev/null || true
}
trap cleanup EXIT
# Waits until FILE has a line matching PATTERN, PID exits, or TENTHS tenths of a second pass.
wait_for_line() {  # PATTERN FILE PID TENTHS
  local n
  for ((n = 0; n < $4; n++)); do
    grep -q "$1" "$2" 2>/dev/null && return 0
    kill -0 "$3" 2>/dev/null || return 0
    sleep 0.1
  done
}

# ---- The body and its skin ---------------------------------------------------------------------
"$bin/skinbus-touchsim" --robot "$src/body_map/robots/skinbot.urdf" --out-dir "$out/session" \
  --upper-arm-links left_upper_arm_link,right_upper_arm_link \
  --model "$src/estimators/models/nominal_seed_cnn" >/dev/null
cp "$out/session/truth.yaml" "$out/skin.yaml"
sed -i "s|^robot: .*|robot: \"$src/body_map/robots/skinbot.urdf\"|" "$out/skin.yaml"
patches=$(grep -c '^  - node:' "$out/skin.yaml")
echo "== the robot skinbot wears $patches patches (skin map: $out/skin.yaml)"
awk '/^  - node:/ {n=$3} /^    link:/ {print "   node " n " on " $2}' "$out/skin.yaml" |
  sort -k4 | awk '{l[$4] = l[$4] " " $2} END {for (k in l) print "   " k ":" l[k]}' | sort

# ---- Two chest patches calibrated: their units identified from a grid of presses -------------
# (docs/guides/calibration.md does this on a real unit.) The host then refines their contacts on
# the identified physics: node 9 looks for two presses at once (max_contacts: 2, its count started
# from the shipped proposer network's presses), node 10 for the shear of a sliding press
# (refine_shear: true). The simulated daemons' units are the fabricated
# units of their UIDs, pressed here by the simulated indentation robot.
if ((calibrate)); then
  mkdir -p "$out/units"
  for n in 9 10; do
    uid=$(printf '0x5b%014x' "$n")
    "$bin/skinbus-dataset" --plan grid --fabricated --uid "$uid" -o "$out/units/node$n.csv" 2>/dev/null
    "$bin/skinbus-identify" "$out/units/node$n.csv" -o "$out/units/node$n.json" \
      >"$out/units/node$n.txt" 2>&1 &
    pids+=($!)
  done
  wait "${pids[@]}"
  pids=()
  awk -v units="$out/units" -v proposer="$src/estimators/models/nominal_proposer" '
    /^  - node:/ {n = $3}
    {print}
    /^    model:/ && n == 9 {
      print "    unit: \"" units "/node9.json\"\n    max_contacts: 2\n    proposer: \"" proposer "\""
    }
    /^    model:/ && n == 10 {print "    unit: \"" units "/node10.json\"\n    refine_shear: true"}
  ' "$out/skin.yaml" >"$out/skin.yaml.tmp" && mv "$out/skin.yaml.tmp" "$out/skin.yaml"
  echo "== nodes 9 and 10 calibrated: $(grep -h '^identified' "$out"/units/node{9,10}.txt | tr '\n' ' ')"
  echo "   node 9 finds two fingers at once, node 10 the shear of a sliding press"
else
  echo "== no patch calibrated (--no-calibrate): every patch runs the shipped network"
fi

# ---- DDS: loopback only unless the caller configured Cyclone DDS ------------------------------
export CYCLONEDDS_URI=${CYCLONEDDS_URI:-file://$src/tools/dds/loopback.xml}
domain=${SKINBUS_DEMO_DOMAIN:-$((RANDOM % 200 + 20))}
echo "== DDS domain $domain ($CYCLONEDDS_URI)"

# ---- The bus: SocketCAN if the kernel has vcan, else a pipe ------------------------------------
vcan=
if ip link show vcan0 >/dev/null 2>&1 && [[ $(cat /sys/class/net/vcan0/mtu) == 72 ]]; then
  vcan=vcan0
elif ip link add dev skinbus0 type vcan 2>/dev/null && ip link set skinbus0 mtu 72 up 2>/dev/null; then
  vcan=skinbus0
  made_vcan=skinbus0
fi

# The web view: the robot in 3D in a browser, served while the demo runs.
view_url=
if [[ $view_port != off ]]; then
  # It reads the bus too, for the sensor panel: vcan, or a copy of the pipe's frames.
  if [[ -n $vcan ]]; then
    view_bus=(-i "$vcan")
  else
    view_fifo=$out/view_bus.fifo
    rm -f "$view_fifo"
    mkfifo "$view_fifo"
    view_bus=(--candump "$view_fifo")
  fi
  # (Until the demo ends when the touches wait for FILE: how long that takes is not known here.)
  view_s=$((duration + 4))
  [[ -n $start_when ]] && view_s=0
  "$bin/skinbus-view" --map "$out/skin.yaml" --domain "$domain" --port "$view_port" \
    "${view_bus[@]}" --duration $view_s >"$out/view.log" 2>&1 &
  pids+=($!)
  wait_for_line 'http://' "$out/view.log" "${pids[-1]}" 50
  view_url=$(grep -o 'http://[^ ]*' "$out/view.log" 2>/dev/null | head -1) || true
  if [[ -n $view_url ]]; then
    port=${view_url##*:}
    port=${port%/}
    echo "== the web view: $view_url (open it in a browser while the demo runs; from another"
    echo "   machine: ssh -L $port:localhost:$port THIS_HOST, then http://localhost:$port/)"
  else
    echo "== no web view: $(tail -1 "$out/view.log" 2>/dev/null) (see $out/view.log)"
  fi
fi

if [[ -n $start_when ]]; then
  echo "== the host and the touches start once $start_when exists"
  for ((n = 0; n < 1200; n++)); do
    [[ -e $start_when ]] && break
    sleep 0.1
  done
  [[ -e $start_when ]] || { echo "demo: $start_when did not appear within 120 s" >&2; exit 1; }
fi

# Subscribers first: a separate process records every contact array (JSON lines) for the record.
"$bin/skinbus-listen" --domain "$domain" --status --timeout $((duration + 30)) \
  >"$out/contacts.jsonl" 2>"$out/listen.log" &
pids+=($!)

host_args=(--map "$out/skin.yaml" --joints dds --domain "$domain" --json-status
           --status-period 1 --stats)
start_patches() {  # extra patchd arguments...
  local n cfg
  for ((n = 1; n <= patches; n++)); do
    cfg=()
    ((n <= 6)) && cfg=(--config "$scene/limb_patch.yaml")  # arm patches: limbs turn
    "$bin/skinbus-patchd" --sim "${cfg[@]}" --node "$n" --uid "$(printf '0x5b%014x' "$n")" \
      --contacts "$scene/presses.csv" --duration "$duration" -q "$@" &
    pids+=($!)
  done
}

if [[ -n $vcan ]]; then
  echo "== $patches patch daemons on SocketCAN $vcan (CAN FD), host reading it"
  candump -L "$vcan" >"$out/bus.log" &
  pids+=($!)
  "$bin/skinbus-host" "${host_args[@]}" -i "$vcan" --duration $((duration + 2)) \
    >"$out/host.jsonl" 2>"$out/host.log" &
  host=$!
  pids+=("$host")
  # The daemons start once the host has built its estimators (networks, refiners' start tables:
  # seconds on a slow or emulated CPU); started earlier, their first presses would be late.
  wait_for_line "patches in the map" "$out/host.log" "$host" 1200
  sleep 1
  start_patches -i "$vcan"
else
  echo "== no vcan on this kernel (CONFIG_CAN off, or no right to create it): the $patches patch"
  echo "   daemons send the same frames as candump -L lines through a pipe to the host"
  echo "   (scripts/can_vm.sh runs real SocketCAN in a VM; docs/testing.md)"
  fifo=$out/bus.fifo
  rm -f "$fifo"
  mkfifo "$fifo"
  "$bin/skinbus-host" "${host_args[@]}" --replay - --live <"$fifo" >"$out/host.jsonl" \
    2>"$out/host.log" &
  host=$!
  pids+=("$host")
  sleep 1
  # Every daemon writes whole lines into one pipe; tee keeps the bus log.
  # (-p: the host's pipe goes on if the web view goes away.)
  tee_to=("$out/bus.log")
  [[ -n $view_url && -n ${view_fifo:-} ]] && tee_to+=("$view_fifo")
  { start_patches -i none --candump-out -; wait; } | tee -p "${tee_to[@]}" >"$fifo" &
  pids+=($!)
fi
"$bin/skinbus-joints" --trajectory "$scene/arms.csv" --domain "$domain" --duration "$duration" \
  2>"$out/joints.log" &
pids+=($!)

echo "== $duration s of scripted touches while the arms move (touches: $scene/presses.csv)"
echo
top_args=(--map "$out/skin.yaml" --domain "$domain" --width 64 --height 22)
if ((headless)) || [[ ! -t 1 ]]; then
  timeout $((duration + 1)) "$bin/skinbus-top" "${top_args[@]}" --plain --period 4 --after 2 ||
    true
else
  timeout $((duration + 1)) "$bin/skinbus-top" "${top_args[@]}" --period 0.25 || true
fi
wait "$host" || echo "demo: skinbus-host exited with an error (see $out/host.log)"
sleep 1

echo
echo "== the bus, as candump -L shows it (first 4 of $(wc -l <"$out/bus.log") frames)"
head -4 "$out/bus.log" | cut -c1-110
echo
echo "== the host: $(grep -m1 'frames' "$out/host.log" | sed 's/^skinbus-host: //')"
grep -m1 'latency' "$out/host.log" | sed 's/^skinbus-host: /   /' || true
echo
echo "== contacts received over DDS by skinbus-listen (another process), per link"
python3 - "$out/contacts.jsonl" <<'PY'
import json, sys
seen = {}
arrays = 0
for line in open(sys.argv[1]):
    j = json.loads(line)
    if j["type"] != "contacts":
        continue
    arrays += 1
    for c in j["contacts"]:
        s = seen.setdefault((c["link"], c["node"]), [0, 0.0])
        s[0] += 1
        s[1] = max(s[1], c["depth_mm"])
print(f"   {arrays} contact arrays")
for (link, node), (n, d) in sorted(seen.items()):
    print(f"   {link:22s} node {node:3d}: {n:4d} contacts, deepest {d:.1f} mm")
PY
tools/plot_bus_load.py "$out/bus.log" "$out/bus_load.png" || true
echo
echo "demo: everything is in $out: skin.yaml, bus.log (candump -L), contacts.jsonl and host.jsonl"
echo "      (JSON lines), host.log, bus_load.png. Watch a live bus: tail -f $out/bus.log"
