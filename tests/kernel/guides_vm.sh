#!/usr/bin/env bash
# The guides' `console` commands that a kernel with SocketCAN can run, inside the CAN test VM
# (scripts/can_vm.sh): each line of docs/guides/debugging.md and docs/guides/deploying.md that
# starts with a prompt ("$ " or "# ") and names candump, cansend, skinbus-* or `ip link`, with can0
# read as vcan0, against a simulated patch (node 3) on vcan0. Streaming commands (candump, a live
# decoder) run for 3 s and must print something; the others must succeed. What cannot run here
# (bit timing, which vcan lacks; systemd, udev and cp into /etc, which need a real system) is
# listed as not exercised.
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
skipped=()
for guide in "$src/docs/guides/debugging.md" "$src/docs/guides/deploying.md"; do
  # (no process substitution: the guest has no /dev/fd)
  awk '/^```console/ {on = 1; next} /^```/ {on = 0} on && /^[$#] / {print}' "$guide" >lines.txt
  while IFS= read -r line; do
    cmd=${line#??}
    cmd=${cmd%%  #*}
    cmd=${cmd//can0/vcan0}
    case $cmd in
      *"type can bitrate"*|udevadm*|cp\ *|systemctl*|journalctl*)
        skipped+=("$cmd")
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
for c in "${skipped[@]}"; do echo "not exercised here: $c"; done
e2e_end guides_vm
