#!/usr/bin/env bash
# Guest side of scripts/measure_patch_traffic.sh: bus traffic of one simulated patch node
# (skinbus-patchd --sim) idle and touched, in event and in stream mode, on real SocketCAN.
#
# Per bus (vcan0 CAN FD, then vcanc0 classic) four daemons run at once, one per case:
#   node 1 event idle, node 2 event touched, node 3 stream idle, node 4 stream touched;
# "touched" is a press held from 1 s after the start to past the end. candump -L captures the
# bus; frames, samples and heartbeats are counted per node over a window that starts 2 s after
# the daemons (start-up and the initial baseline capture are over) and lasts SECONDS.
#
# Writes $SKINBUS_VM_OUT/patch_traffic/results.tsv (one row per case; see the header) and
# prints it.
#
#   scripts/can_vm.sh -- tests/kernel/patch_traffic.sh BUILD_DIR [SECONDS]
set -euo pipefail
bin=${1:?usage: patch_traffic.sh BUILD_DIR [SECONDS]}/tools
window=${2:-10}
work=${SKINBUS_VM_OUT:-$(mktemp -d)}/patch_traffic
mkdir -p "$work"
cd "$work"
warm=2
run_s=$(awk -v w="$window" -v m="$warm" 'BEGIN { print w + m + 1 }')
# Presses away from the patch centre (there a shallow press changes the field by less than the
# gate's on-threshold); held from 1 s to past the end of the run.
cat >contacts.csv <<EOF
t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
1.0,$((${run_s%.*} + 5)),20,-10,1.5,8,2
1.0,$((${run_s%.*} + 5)),20,-10,1.5,8,4
EOF
printf 'bus\tmode\tstate\tnode\twindow_s\tframes\tsample_frames\theartbeat_frames\tsamples\theartbeats\tcontact_samples\tdaemon_overruns\tdaemon_send_errors\n' >results.tsv
for bus in fd classic; do
  if [[ $bus == fd ]]; then iface=vcan0; flag=; else iface=vcanc0; flag=--classic; fi
  candump -L -r 4000000 "$iface" >"cap_$bus.log" &
  dump=$!
  sleep 1
  t0=$(date +%s.%N)
  pids=()
  for node in 1 2 3 4; do
    mode=event
    ((node >= 3)) && mode=stream
    "$bin/skinbus-patchd" --sim -i "$iface" $flag --node $node --mode $mode \
      --contacts contacts.csv --duration "$run_s" 2>"patchd_${bus}_$node.err" &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
  sleep 1
  kill "$dump"
  wait "$dump" 2>/dev/null || true
  from=$(awk -v t="$t0" -v m="$warm" 'BEGIN { printf "%.6f", t + m }')
  to=$(awk -v t="$from" -v w="$window" 'BEGIN { printf "%.6f", t + w }')
  # Frames per node and class, by the kernel's receive timestamps.
  awk -v a="$from" -v b="$to" '
    function hex(s,  i, v) {
      v = 0; s = toupper(s)
      for (i = 1; i <= length(s); i++) v = v * 16 + index("0123456789ABCDEF", substr(s, i, 1)) - 1
      return v
    }
    {
      ts = substr($1, 2, length($1) - 2) + 0
      if (ts < a || ts >= b) next
      split($3, f, "#"); id = hex(f[1]); node = id % 128; cls = int(id / 128)
      frames[node]++; per[node, cls]++
    } END { for (n in frames) print n, frames[n], per[n, 3] + 0, per[n, 5] + 0 }' \
    "cap_$bus.log" | sort -n >"frames_$bus.txt"
  # Messages per node (time of their last frame).
  "$bin/skinbus-decode" -t "cap_$bus.log" 2>"decode_$bus.err" |
    awk -v a="$from" -v b="$to" '{
      ts = substr($1, 2, length($1) - 2) + 0
      if (ts < a || ts >= b) next
      node = $4; sub(/node=/, "", node)
      if ($3 == "sample") { s[node]++; if ($0 ~ / flags=([a-z_]+,)*contact[, ]/) c[node]++ }
      if ($3 == "heartbeat") h[node]++
    } END { for (n in s) print n, "s", s[n], c[n] + 0; for (n in h) print n, "h", h[n] }' \
      >"messages_$bus.txt"
  for node in 1 2 3 4; do
    mode=event
    ((node >= 3)) && mode=stream
    state=idle
    ((node % 2 == 0)) && state=touched
    read -r _ frames sframes hframes <<<"$(awk -v n=$node '$1 == n { print; f = 1 } END { if (!f) print n, 0, 0, 0 }' "frames_$bus.txt")"
    read -r _ _ samples contact <<<"$(awk -v n=$node '$1 == n && $2 == "s" { print; f = 1 } END { if (!f) print n, "s", 0, 0 }' "messages_$bus.txt")"
    read -r _ _ hbs <<<"$(awk -v n=$node '$1 == n && $2 == "h" { print; f = 1 } END { if (!f) print n, "h", 0 }' "messages_$bus.txt")"
    stopped=$(grep -o 'stopped: .*' "patchd_${bus}_$node.err" || echo "stopped: ?")
    overruns=$(sed -nE 's/.* ([0-9]+) overruns.*/\1/p' <<<"$stopped")
    send_errors=$(sed -nE 's/.* ([0-9]+) send errors.*/\1/p' <<<"$stopped")
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$bus" $mode $state $node "$window" \
      "$frames" "$sframes" "$hframes" "$samples" "$hbs" "$contact" "${overruns:-?}" "${send_errors:-?}" >>results.tsv
  done
done
uname -r >kernel.txt
column -t -s $'\t' results.tsv
