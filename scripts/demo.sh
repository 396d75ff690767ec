#!/usr/bin/env bash
# The skinbus demo: simulated patches publish on a CAN bus, the decoder reads the bus.
#   scripts/demo.sh [--duration SECONDS] [--nodes 1-4]
# On a kernel with vcan (and the right to create it) the frames cross real SocketCAN; elsewhere
# they cross a pipe in candump format, exactly as `candump -L can0 | skinbus-decode` would.
set -euo pipefail
cd "$(dirname "$0")/.."
duration=3
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

vcan=
if ip link show vcan0 >/dev/null 2>&1 && [[ $(cat /sys/class/net/vcan0/mtu) == 72 ]]; then
  vcan=vcan0
elif ip link add dev skinbus0 type vcan 2>/dev/null && ip link set skinbus0 mtu 72 up 2>/dev/null; then
  vcan=skinbus0
  trap 'ip link del skinbus0 2>/dev/null || true' EXIT
fi

echo
if [[ -n $vcan ]]; then
  echo "== $duration s of traffic from patches $nodes on SocketCAN interface $vcan =="
  candump -L "$vcan" >"$out/bus.log" &
  dump=$!
  "$bin/skinbus-decode" -i "$vcan" --duration "$(awk -v d="$duration" 'BEGIN { print d + 1 }')" --stats >"$out/decoded.txt" 2>"$out/stats.txt" &
  dec=$!
  sleep 0.3
  "$bin/skinbus-gen" -i "$vcan" --nodes "$nodes" --duration "$duration"
  wait "$dec"
  kill "$dump"
else
  echo "== no vcan on this kernel (CONFIG_CAN off or no rights): the same frames cross a pipe in"
  echo "   candump format instead. (scripts/can_vm.sh runs real SocketCAN in a VM; see docs/testing.md)"
  echo "== $duration s of traffic from patches $nodes =="
  "$bin/skinbus-gen" --realtime --nodes "$nodes" --duration "$duration" | tee "$out/bus.log" |
    "$bin/skinbus-decode" --stats >"$out/decoded.txt" 2>"$out/stats.txt"
fi

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
echo "== decoder statistics =="
cat "$out/stats.txt"
echo
echo "demo: bus log in $out/bus.log, decoded messages in $out/decoded.txt"
