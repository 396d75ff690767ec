#!/usr/bin/env bash
# The skinbus demo: simulated patches (the patch node daemon on emulated sensors fed by the
# physics simulator) publish on a CAN bus while presses land on them; the decoder reads the bus.
#   scripts/demo.sh [--duration SECONDS] [--nodes 1-4]
# On a kernel with vcan (and the right to create it) the frames cross real SocketCAN; elsewhere
# they cross a pipe in candump format, exactly as `candump -L can0 | skinbus-decode` would.
set -euo pipefail
cd "$(dirname "$0")/.."
duration=4
nodes=1-4
while (($#)); do
  case $1 in
    --duration) duration=$2; shift 2 ;;
    --nodes) nodes=$2; shift 2 ;;
    -h|--help) sed -n '2,5p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
scripts/setup.sh
scripts/build.sh
bin=build/tools
out=out/demo
mkdir -p "$out"

echo
echo "== bus budget for this demo (CAN FD 1/5 Mbit/s, 41.7 Hz per patch) =="
"$bin/skinbus-budget" --patches "$(build/tools/skinbus-gen --nodes "$nodes" --duration 0 2>&1 | sed -n 's/.* from \([0-9]*\) patches.*/\1/p')"

# Presses on the simulated patches (docs/patch_node.md): t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_mm,node
cat >"$out/presses.csv" <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.8,1.8,10,-20,1.5,8,1
1.2,2.2,-35,40,2.0,8,2
2.0,2.6,25,10,1.0,5,3
CSV
node_list=$(python3 -c "import sys
out=[]
for part in sys.argv[1].split(','):
    a,_,b=part.partition('-'); out+=range(int(a),int(b or a)+1)
print(' '.join(map(str,out)))" "$nodes")

vcan=
if ip link show vcan0 >/dev/null 2>&1 && [[ $(cat /sys/class/net/vcan0/mtu) == 72 ]]; then
  vcan=vcan0
elif ip link add dev skinbus0 type vcan 2>/dev/null && ip link set skinbus0 mtu 72 up 2>/dev/null; then
  vcan=skinbus0
  trap 'ip link del skinbus0 2>/dev/null || true' EXIT
fi

echo
pids=()
if [[ -n $vcan ]]; then
  echo "== $duration s: simulated patches $nodes (skinbus-patchd --sim, event mode) on SocketCAN $vcan =="
  candump -L "$vcan" >"$out/bus.log" &
  dump=$!
  sleep 0.3
  for n in $node_list; do
    "$bin/skinbus-patchd" --sim -i "$vcan" --node "$n" --contacts "$out/presses.csv" --duration "$duration" -q &
    pids+=($!)
  done
  wait "${pids[@]}"
  sleep 0.3
  kill "$dump"
else
  echo "== no vcan on this kernel (CONFIG_CAN off or no rights): each simulated patch writes its frames"
  echo "   as a candump log instead, merged in time order. (scripts/can_vm.sh runs real SocketCAN in a"
  echo "   VM; see docs/testing.md)"
  echo "== $duration s: simulated patches $nodes (skinbus-patchd --sim, event mode) =="
  for n in $node_list; do
    "$bin/skinbus-patchd" --sim -i none --candump-out "$out/patch_$n.log" --node "$n" --contacts "$out/presses.csv" --duration "$duration" -q &
    pids+=($!)
  done
  wait "${pids[@]}"
  sort -s -k1,1 "$out"/patch_*.log >"$out/bus.log"
  rm -f "$out"/patch_*.log
fi
"$bin/skinbus-decode" --stats "$out/bus.log" >"$out/decoded.txt" 2>"$out/stats.txt"

echo
echo "== the bus, as candump -L shows it (first 6 frames of $(wc -l <"$out/bus.log")) =="
head -6 "$out/bus.log" | cut -c1-110
echo
echo "== one frame decoded on its own (skinbus-decode --frames) =="
sed -n 3p "$out/bus.log" | "$bin/skinbus-decode" --frames | head -1 | cut -c1-160
echo
echo "== decoded messages: heartbeats and the first touched samples (of $(wc -l <"$out/decoded.txt")) =="
grep -m4 '^heartbeat' "$out/decoded.txt" | cut -c1-160
grep -m4 'flags=contact' "$out/decoded.txt" | cut -c1-160
echo
echo "== samples per patch: idle patches send only heartbeats (event mode) =="
for n in $node_list; do
  printf 'node %-3s samples %4d (touched %4d, tail %3d)  heartbeats %d\n' "$n" \
    "$(grep -c "^sample node=$n " "$out/decoded.txt")" "$(grep -c "^sample node=$n .*flags=contact" "$out/decoded.txt")" \
    "$(grep -c "^sample node=$n .*event_tail" "$out/decoded.txt")" "$(grep -c "^heartbeat node=$n " "$out/decoded.txt")"
done
echo
echo "== decoder statistics =="
cat "$out/stats.txt"
echo
echo "demo: bus log in $out/bus.log, decoded messages in $out/decoded.txt"
