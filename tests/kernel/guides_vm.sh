#!/usr/bin/env bash
# The guides' `console` commands that a kernel with SocketCAN can run, inside the CAN test VM
# (scripts/can_vm.sh): each line of docs/guides/debugging.md and docs/guides/deploying.md that
# starts with a prompt ("$ " or "# ") and names candump, cansend, skinbus-* or `ip link`, with can0
# read as vcan0, against a simulated patch (node 3) on vcan0. Streaming commands (candump, a live
# decoder) run for 3 s and must print something; the others must succeed. What needs a real
# controller and system (bit timing, which vcan lacks; udev names, cp into /etc, systemd) is left
# to tests/kernel/deploy_vm.sh, which runs deploying.md whole on an emulated CAN FD controller
# under systemd, and listed as such; anything else not run is listed as not exercised. Then the
# `console` lines of docs/guides/scaling.md: hosts on three named buses, two hosts with
# namespaces in one DDS domain, and a listener on one namespace.
#   scripts/can_vm.sh --fd-ifaces 1 -- tests/kernel/guides_vm.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
src=$(cd "$(dirname "$0")/../.." && pwd)
e2e_begin guides_vm "${1:-}"
export PATH=$bin:$PATH
printf '0.5,60,10,-20,2.0,5,3\n' >presses.csv
skinbus-patchd --sim -i vcan0 --node 3 --contacts presses.csv --duration 90 -q &
patchd=$!
sleep 1.5
skipped=() deployed=()
for guide in "$src/docs/guides/debugging.md" "$src/docs/guides/deploying.md"; do
  # (no process substitution: the guest has no /dev/fd)
  guide_commands "$guide" >lines.txt
  while IFS= read -r cmd; do
    guide_cmd=$cmd
    cmd=${cmd//can0/vcan0}
    case $cmd in
      *"type can bitrate"*|udevadm*|cp\ *|systemctl*|journalctl*|getent*|*skinleft*|*" down")
        deployed+=("$guide_cmd")
        continue ;;
      candump*|"skinbus-decode -i"*)
        timeout 3 bash -c "$cmd" >out.txt 2>&1 || true
        if [[ -s out.txt ]]; then ok "$cmd"; else bad "$cmd: printed nothing"; fi ;;
      skinbus-*|cansend*|ip\ *)
        if timeout 20 bash -c "$cmd" >out.txt 2>&1; then ok "$cmd"; else bad "$cmd: $(tail -2 out.txt)"; fi ;;
      *) skipped+=("$cmd") ;;
    esac
  done <lines.txt
done
kill "$patchd" 2>/dev/null || true
wait "$patchd" 2>/dev/null || true

# docs/guides/scaling.md: its `console` lines (prompts "$ " and "host X$ ") on three vcan buses
# named as in the guide, one host per line in one DDS domain (loopback only), with a simulated
# patch pressed on skinleft (node 1) and on skintorso (node 7). A host line must keep running
# and report its patches online; `skinbus-listen --namespace arm_left` must
# receive what the arm_left host publishes. ROS 2 is not in Debian bookworm.
# shellcheck source=tests/e2e/e2e_lib.sh
source "$src/tests/e2e/e2e_lib.sh"
use_loopback_dds
ip link set lo up 2>/dev/null || true
for bus in skinleft skinright skintorso; do
  ip link add dev "$bus" type vcan && ip link set "$bus" mtu 72 up
done
make_skin_map skin.yaml
printf '0.5,80,10,-20,2.0,5,1\n0.5,80,-20,10,2.0,5,7\n' >scaling_presses.csv
skinbus-patchd --sim -i skinleft --node 1 --uid 0x5b00000000000001 --contacts scaling_presses.csv \
  --duration 80 -q &
left=$!
skinbus-patchd --sim -i skintorso --node 7 --uid 0x5b00000000000007 \
  --contacts scaling_presses.csv --duration 80 -q &
torso=$!
sleep 1.5
guide_commands "$src/docs/guides/scaling.md" '(host [A-Z])?[$] ' >lines.txt
hosts=()
n=0
while IFS= read -r cmd; do
  n=$((n + 1))
  case $cmd in
    skinbus-host*)
      # A host runs until stopped: it must stay up and report its patches online (a patch is
      # online at its first heartbeat; the emulated CPU is slow, so allow 40 s).
      bash -c "exec $cmd" >"host$n.out" 2>"host$n.err" &
      hosts+=($!)
      for _ in $(seq 80); do
        grep -q " online$" "host$n.err" && break
        kill -0 "${hosts[-1]}" 2>/dev/null || break
        sleep 0.5
      done
      if ! kill -0 "${hosts[-1]}" 2>/dev/null; then
        bad "$cmd: exited: $(tail -2 "host$n.err")"
      elif grep -q "online" "host$n.err"; then
        ok "$cmd ($(grep -o '[a-z]*: node [0-9]* online' "host$n.err" | sort -u | paste -sd, -))"
      else
        bad "$cmd: no patch came online:"; sed "s/^/    /" "host$n.err" | tail -8
      fi
      # (the guide's first host stands alone; the emulated CPU runs one network at a time)
      [[ $cmd == *--namespace* ]] || kill "${hosts[-1]}" 2>/dev/null || true ;;
    skinbus-listen*)
      timeout 30 bash -c "$cmd --count 3" >listen.out 2>&1 || true
      # node 1 is on arm_left's bus; node 7 (body's) must not leak into this namespace
      if grep -q '"node":7' listen.out; then
        bad "$cmd: received node 7, published by the host of another namespace"
      elif grep -q '"node":1' listen.out; then ok "$cmd (contacts of node 1 only)"; else
        bad "$cmd: received nothing: $(tail -2 listen.out)"
      fi ;;
    *) skipped+=("$cmd") ;;
  esac
done <lines.txt
kill "${hosts[@]}" "$left" "$torso" 2>/dev/null || true
wait 2>/dev/null || true
for c in "${deployed[@]}"; do echo "exercised by deploy_vm.sh (real controller, systemd): $c"; done
for c in "${skipped[@]}"; do echo "not exercised here: $c"; done
e2e_end guides_vm
