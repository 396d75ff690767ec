#!/usr/bin/env bash
# End-to-end checks of the patch node daemon (skinbus-patchd --sim) on real SocketCAN, with
# can-utils as the host side. Runs inside the CAN test VM (scripts/can_vm.sh), which provides
# vcan0 (CAN FD) and vcanc0 (classic):
#
#   a. three daemons (nodes 3 stream, 4 and 5 event) publish at once on vcan0, pressed by one
#      shared contact script (node column); per node, candump -L -> skinbus-decode == the
#      daemon's --expect file, and the event nodes send samples only around their presses
#   b. one daemon with --classic on vcanc0: the same equality
#   c. host commands to one daemon, by cansend (frames from skinbus-cmd --print) and by
#      skinbus-cmd -i: mode, tare, rate, sync-mode + SYNC, identify, info, a malformed command
#      (NACK), reboot; every answer and its effect checked in the capture
#   d. two daemons with the same node ID warn about it on stderr
#
#   scripts/can_vm.sh --fd-ifaces 1 --classic-ifaces 1 -- tests/kernel/patchd_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_begin patchd_e2e "${1:-}"
check() {  # check NAME DETAIL COMMAND...: PASS when COMMAND succeeds, else FAIL with DETAIL
  local name=$1 detail=$2
  shift 2
  if "$@"; then ok "$name"; else bad "$name: $detail"; fi
}
now() { date +%s.%N; }
# Starts candump -L on interface $1 into file $2 (its pid in $dump); a slow guest needs a moment.
start_dump() {
  candump -L -r 4000000 "$1" >"$2" &
  dump=$!
  sleep 1
}
stop_dump() {
  sleep 1
  kill "$1"
  wait "$1" 2>/dev/null || true
}
# Median of the differences between consecutive numbers on stdin (one per line).
median_step() {
  awk 'NR > 1 { print $1 - prev } { prev = $1 }' | sort -n |
    awk '{ v[NR] = $1 } END { if (NR == 0) print 0; else print v[int((NR + 1) / 2)] }'
}
# Lines of file $1 after the ack of command sequence $2 up to the ack of command sequence $3.
between() {
  awk -v a=" cmd_seq=$2 " -v b=" cmd_seq=$3 " \
    '$1 == "ack" && index($0, b) { on = 0 } on { print } $1 == "ack" && index($0, a) { on = 1 }' "$1"
}
count() { grep -c "$@" || true; }
# The runs of sample flags on stdin as letters: flag_runs contact=C event_tail=T gives "CT" for
# contact samples followed by tail samples (the first flag named wins; others: O).
flag_runs() {
  awk -v spec="$*" 'BEGIN { n = split(spec, kv, " ") }
    { f = $0; sub(/.* flags=/, "", f); sub(/ .*/, "", f); c = "O"
      for (i = 1; i <= n; i++) { split(kv[i], p, "="); if (("," f ",") ~ ("," p[1] ",")) { c = p[2]; break } }
      if (c != last) printf "%s", c; last = c }'
}
# The decoder's --stats summary shows no lost or broken messages.
stats_clean() {
  awk '$1 == "frames" { seen = 1; for (i = 1; i < NF; i += 2)
         if ($i ~ /^(integrity_failures|gaps|duplicates|resyncs|stale_parts|evictions|conflicts|rejected|bad_lines)$/ && $(i + 1) != 0) bad = 1 }
       END { exit !(seen && !bad) }' "$1"
}

# ---- a. Three daemons at once on CAN FD; b. one on classic CAN.
# Times are seconds since each daemon started; the last column names the node pressed.
cat >contacts.csv <<'EOF'
t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
2.5,3.5,30,-30,1.5,8,3
1.5,3.0,10,10,1.5,8,4
2.0,3.5,-20,5,1.5,8,5
1.0,2.0,20,-10,1.5,8,6
EOF
declare -A t_from=([4]=1.5 [5]=2.0) t_to=([4]=3.0 [5]=3.5)
tail_s=0.25  # the daemon's event tail (NodeConfig::event_tail_ms)
start_dump vcan0 cap_fd.log
t0=$(now)
pids=()
for n in 3 4 5; do
  mode=event
  ((n == 3)) && mode=stream
  "$bin/skinbus-patchd" --sim -q -i vcan0 --node $n --mode $mode --contacts contacts.csv \
    --duration 5 --expect sent_$n.txt 2>patchd_$n.err &
  pids+=($!)
done
status=0
for p in "${pids[@]}"; do wait "$p" || status=$?; done
stop_dump "$dump"
check "three daemons exit 0" "exit status $status; $(cat patchd_[345].err)" test "$status" = 0
"$bin/skinbus-decode" --stats cap_fd.log >/dev/null 2>stats_fd.txt
for n in 3 4 5; do
  "$bin/skinbus-decode" --patch $n cap_fd.log >decoded_$n.txt 2>/dev/null
  check_same "daemon node $n -> candump -> decoder (fd, $(grep -o 'mode=[a-z]*' sent_$n.txt | head -1))" \
    sent_$n.txt decoded_$n.txt
done
# Stream: every sample, idle or touched; heartbeats too.
n3=$(count '^sample' decoded_3.txt)
check "stream node 3 sends idle and touched samples" "$n3 samples, $(count -E '^sample.*flags=[a-z_,]*contact' decoded_3.txt) touched" \
  test "$n3" -ge 100 -a "$(count -E '^sample.*flags=[a-z_,]*contact' decoded_3.txt)" -ge 10 \
  -a "$(count -Ev 'flags=([a-z_]+,)*contact' decoded_3.txt)" -ge 40
# Event: samples only while pressed (flag contact), then a short tail (flag event_tail);
# nothing before the press or after the tail; heartbeats all along.
for n in 4 5; do
  "$bin/skinbus-decode" -t --patch $n cap_fd.log 2>/dev/null | grep ' sample ' >timed_$n.txt || true
  touched=$(count -E 'flags=([a-z_]+,)*contact' timed_$n.txt)
  tails=$(count -E 'flags=([a-z_]+,)*event_tail' timed_$n.txt)
  others=$(grep -c -v -E 'flags=([a-z_]+,)*(contact|event_tail)' timed_$n.txt || true)
  press=$(awk -v a="${t_from[$n]}" -v b="${t_to[$n]}" 'BEGIN { print b - a }')
  check "event node $n: samples flagged contact during the press ($touched, then $tails tail)" \
    "$touched contact samples for a ${press} s press at 41.7 Hz" \
    awk -v n="$touched" -v p="$press" 'BEGIN { exit !(n >= 0.6 * p * 41.7 && n <= (p + 0.5) * 41.7) }'
  check "event node $n: tail samples after the press, no idle samples" \
    "$tails event_tail samples, $others samples neither contact nor event_tail" \
    test "$tails" -ge 3 -a "$others" = 0
  # Contact samples form one block, then the tail; times (capture clock, from the daemons' start).
  order=$(flag_runs contact=C event_tail=T <timed_$n.txt)
  first=$(head -1 timed_$n.txt | tr -d '()' | awk -v t0="$t0" '{ printf "%.3f", $1 - t0 }')
  last=$(tail -1 timed_$n.txt | tr -d '()' | awk -v t0="$t0" '{ printf "%.3f", $1 - t0 }')
  check "event node $n: one press block then its tail, within the scripted window (first sample ${first} s, last ${last} s; press ${t_from[$n]}..${t_to[$n]} s)" \
    "block order '$order', first sample at ${first} s, last at ${last} s (press ${t_from[$n]}..${t_to[$n]} s, tail $tail_s s)" \
    awk -v o="$order" -v f="$first" -v l="$last" -v a="${t_from[$n]}" -v b="${t_to[$n]}" -v tl="$tail_s" \
    'BEGIN { exit !(o == "CT" && f >= a && f <= a + 1.5 && l >= b && l <= b + tl + 1.5) }'
  hb=$(count "^heartbeat node=$n .*mode=event" decoded_$n.txt)
  check "event node $n: heartbeats while idle" "$hb heartbeats in 5 s" test "$hb" -ge 4
done
check "fd capture: decoder statistics clean (no gaps, integrity failures, stale parts)" \
  "$(grep '^frames' stats_fd.txt)" stats_clean stats_fd.txt

# b. Classic CAN: 18 frames a sample.
start_dump vcanc0 cap_classic.log
status=0
"$bin/skinbus-patchd" --sim -q -i vcanc0 --classic --node 6 --mode stream --contacts contacts.csv \
  --duration 3 --expect sent_6.txt 2>patchd_6.err || status=$?
stop_dump "$dump"
check "classic daemon exits 0" "exit status $status; $(cat patchd_6.err)" test "$status" = 0
"$bin/skinbus-decode" --patch 6 cap_classic.log >decoded_6.txt 2>/dev/null
check_same "daemon node 6 -> candump -> decoder (classic, stream)" sent_6.txt decoded_6.txt
frames6=$(grep -c ' vcanc0 1[89A-Fa-f][0-9A-Fa-f]#' cap_classic.log || true)
check "classic samples are 18 frames each" "$frames6 sample frames for $(count '^sample' sent_6.txt) samples" \
  test "$frames6" = "$(($(count '^sample' sent_6.txt) * 18))"
check "classic node 6 reports its press" "$(count -E 'flags=([a-z_]+,)*contact' decoded_6.txt) contact samples" \
  test "$(count -E 'flags=([a-z_]+,)*contact' decoded_6.txt)" -ge 15

# ---- c. Commands from the host: cansend with frames from skinbus-cmd --print, and skinbus-cmd -i.
node=7
cmd_print() { "$bin/skinbus-cmd" --node $node --print "$@"; }
send() {  # send SEQ COMMAND [ARG]: cansend of the frame skinbus-cmd builds
  local seq=$1
  shift
  cansend vcan0 "$(cmd_print --seq "$seq" "$@")"
}
cmd() {  # cmd SEQ COMMAND [ARG]: skinbus-cmd -i; its output into cmd_SEQ.txt
  local seq=$1 rc=0
  shift
  "$bin/skinbus-cmd" -i vcan0 --node $node --seq "$seq" --timeout-ms 3000 "$@" >"cmd_$seq.txt" 2>&1 || rc=$?
  check "skinbus-cmd $* (seq $seq) exits 0" "exit $rc: $(cat "cmd_$seq.txt")" test $rc = 0
}
start_dump vcan0 cap_cmd.log
# --expect - appends to one file across the reboot (the daemon re-executes itself).
"$bin/skinbus-patchd" --sim -i vcan0 --node $node --mode event --duration 50 \
  --expect - >sent_cmd.txt 2>patchd_cmd.err &
pd=$!
sleep 1.5 # started, tared, idle: heartbeats only
cmd 1 mode stream
sleep 1.5
send 2 tare
sleep 1.5
send 3 rate 20
sleep 2
cmd 4 sync-mode on
sleep 0.5
nsync=5
for k in $(seq 1 $nsync); do
  cansend vcan0 "$("$bin/skinbus-cmd" sync --print --sync-counter "$k" --seq "$k")"
  sleep 0.4
done
send 5 sync-mode off
sleep 0.5
cmd 6 mode off
sleep 2.2
send 7 identify 5
sleep 1.5
cmd 8 info
cansend vcan0 "$(printf '%03X##1%02X%02X%02X%02X%08X' $((0x80 | node)) 0x20 9 2 9 0)"  # set_mode 9
sleep 0.5
cmd 10 reboot
sleep 1.5
kill "$pd" 2>/dev/null || true
wait "$pd" 2>/dev/null || true
stop_dump "$dump"
"$bin/skinbus-decode" cap_cmd.log >decoded_cmd.txt 2>decode_cmd.err
grep -v -E '^(command|sync) ' decoded_cmd.txt >decoded_cmd_patch.txt || true
# Up to the reboot's ack, the capture decodes to exactly what the daemon sent. After the reboot
# the frames are compared one by one (--frames): the reassembled view may drop the restarted
# node's first heartbeats as duplicates, since they are byte-identical to the first ones of the
# previous start (same sequence, uptime, status) while those are among the last 16 heartbeats
# the decoder remembers.
reboot_ack="ack node=$node seq=9 op=reboot status=ok cmd_seq=10 value=0"
upto_reboot() { awk -v l="$reboot_ack" '{ print } $0 == l { exit }' "$1"; }
upto_reboot sent_cmd.txt >sent_cmd_before.txt
upto_reboot decoded_cmd_patch.txt >decoded_cmd_before.txt
check_same "command phase: daemon node $node -> candump -> decoder (until the reboot)" \
  sent_cmd_before.txt decoded_cmd_before.txt
"$bin/skinbus-decode" --frames cap_cmd.log 2>/dev/null | grep '^frame ' |
  awk -v l="frame $reboot_ack" 'on && $2 != "command" && $2 != "sync" { print } $0 == l { on = 1 }' >frames_after_reboot.txt
awk -v l="$reboot_ack" 'on { print $1, $2, $3 } $0 == l { on = 1 }' sent_cmd.txt >sent_after_reboot.txt
awk '{ print $2, $3, $4 }' frames_after_reboot.txt >got_after_reboot.txt
check_same "after the reboot: every message of the restarted daemon on the bus" \
  sent_after_reboot.txt got_after_reboot.txt
declare -A op=([1]=set_mode [2]=tare [3]=set_rate [4]=sync_mode [5]=sync_mode [6]=set_mode
  [7]=identify [8]=get_info [10]=reboot)
declare -A val=([1]=1 [2]=0 [3]=2000 [4]=1 [5]=0 [6]=0 [7]=5 [8]=0 [10]=0)
for s in 1 2 3 4 5 6 7 8 10; do
  line="ack node=$node seq=$((s - 1)) op=${op[$s]} status=ok cmd_seq=$s value=${val[$s]}"
  check "ack ${op[$s]} (cmd_seq $s) in the capture" "no line '$line'; acks: $(grep -c '^ack' decoded_cmd.txt)" \
    test "$(grep -cxF "$line" decoded_cmd.txt)" = 1
done
check "malformed set_mode 9 -> NACK bad_argument" "$(grep "cmd_seq=9 " decoded_cmd.txt || echo 'no ack')" \
  grep -qx "ack node=$node seq=8 op=set_mode status=bad_argument cmd_seq=9 value=1" decoded_cmd.txt
for s in 1 4 6 8 10; do
  check "skinbus-cmd seq $s printed the ack seen on the bus" "$(head -1 cmd_$s.txt)" \
    grep -qxF "$(head -1 cmd_$s.txt)" decoded_cmd.txt
done
check "info: skinbus-cmd printed ack + info, both on the bus" "$(cat cmd_8.txt)" \
  bash -c "[[ \$(wc -l <cmd_8.txt) == 2 ]] && grep -q '^info node=$node seq=0 uid=5eed000000000007 ' cmd_8.txt &&
    grep -qxF \"\$(sed -n 2p cmd_8.txt)\" decoded_cmd.txt"
# Event, idle: no samples before "mode stream"; stream: samples flow.
pre=$(awk '$1 == "ack" { exit } $1 == "sample"' decoded_cmd.txt | wc -l)
hb_pre=$(awk '$1 == "ack" { exit } $1 == "heartbeat"' decoded_cmd.txt | wc -l)
check "event mode, idle: heartbeats only" "$pre samples, $hb_pre heartbeats before the first command" \
  test "$pre" = 0 -a "$hb_pre" -ge 1
between decoded_cmd.txt 1 2 | grep '^sample' >stream.txt || true
check "mode stream: untouched samples flow ($(wc -l <stream.txt) in ~1.5 s)" "$(wc -l <stream.txt) samples in ~1.5 s, $(count contact stream.txt) flagged contact" \
  test "$(wc -l <stream.txt)" -ge 30 -a "$(count contact stream.txt)" = 0
# Tare: the samples right after its ack capture a new baseline (tare_active), then tared again.
between decoded_cmd.txt 2 3 | grep '^sample' >tare.txt || true
tare_flags=$(flag_runs tare_active=A tared=T <tare.txt)
check "tare: tare_active samples right after the ack, tared after ($(count tare_active tare.txt) tare_active)" \
  "flag runs '$tare_flags' ($(count tare_active tare.txt) tare_active)" \
  test "$tare_flags" = AT -a "$(count tare_active tare.txt)" -ge 8
# Rate: median spacing of the sample timestamps before and after "rate 20".
m_before=$({ grep -o 't_us=[0-9]*' stream.txt || true; } | cut -d= -f2 | median_step)
between decoded_cmd.txt 3 4 | grep '^sample' >rate20.txt || true
m_after=$({ grep -o 't_us=[0-9]*' rate20.txt || true; } | cut -d= -f2 | median_step)
check "rate 20 Hz: sample spacing ~2.1x that at 41.7 Hz (median t_us step $m_before -> $m_after us)" \
  "median t_us step ${m_before} us before, ${m_after} us after ($(wc -l <rate20.txt) samples)" \
  awk -v a="$m_before" -v b="$m_after" 'BEGIN { exit !(a > 0 && b / a > 1.7 && b / a < 2.5) }'
# Sync mode: one sample per SYNC, flagged synced, and nothing else until sync mode ends.
between decoded_cmd.txt 4 5 | grep '^sample' >synced.txt || true
check "sync-mode on + $nsync SYNC frames -> exactly $nsync synced samples" \
  "$(wc -l <synced.txt) samples between the acks, $(count -E 'flags=([a-z_]+,)*synced' synced.txt) synced; $(count -E 'flags=([a-z_]+,)*synced' decoded_cmd.txt) synced in all" \
  test "$(wc -l <synced.txt)" = $nsync -a "$(count -E 'flags=([a-z_]+,)*synced' synced.txt)" = $nsync \
  -a "$(count -E 'flags=([a-z_]+,)*synced' decoded_cmd.txt)" = $nsync
hb_sync=$(between decoded_cmd.txt 4 5 | grep -c '^heartbeat.* status=sync,' || true)
check "sync mode shows in the heartbeat status" "$hb_sync heartbeats with status sync" test "$hb_sync" -ge 1
n_free=$(between decoded_cmd.txt 5 6 | grep -c '^sample' || true)
check "sync-mode off: free-running samples again" "$n_free samples in ~0.5 s" test "$n_free" -ge 3
# Off: no samples, heartbeats go on (mode=off).
off_samples=$(between decoded_cmd.txt 6 10 | grep -c '^sample' || true)
off_hb=$(between decoded_cmd.txt 6 7 | grep -c '^heartbeat.* mode=off ' || true)
check "mode off: samples stop, heartbeats continue" "$off_samples samples, $off_hb mode=off heartbeats in ~2 s" \
  test "$off_samples" = 0 -a "$off_hb" -ge 2
# Identify: the heartbeats after its ack say so; none before.
id_before=$(awk '$1 == "ack" && index($0, " cmd_seq=7 ") { exit } /^heartbeat.* status=[a-z,]*identify/' decoded_cmd.txt | wc -l)
id_after=$(between decoded_cmd.txt 7 8 | grep -c '^heartbeat.* status=[a-z,]*identify' || true)
check "identify: heartbeat status shows identify" "$id_before before, $id_after after the ack" \
  test "$id_before" = 0 -a "$id_after" -ge 1
# Reboot: acknowledged, then the node starts again (heartbeat seq 0, uptime 0, the started mode).
rb=$(grep -m1 '^frame heartbeat' frames_after_reboot.txt || true)
check "reboot: the node restarts" "first heartbeat after the ack: '${rb:-none}'" \
  grep -qE "^frame heartbeat node=$node seq=0 .* state=1 mode=2 rate=41.7 uptime=0 " <<<"$rb"
check "command daemon logged no error" "$(grep -iE 'error|fail' patchd_cmd.err | head -3)" \
  bash -c "! grep -iE 'error|fail' patchd_cmd.err | grep -v ' 0 send errors' | grep -q ."

# ---- d. Two daemons with the same node ID: both notice.
status=0
pids=()
for k in 1 2; do
  "$bin/skinbus-patchd" --sim -i vcan0 --node 9 --mode stream --duration 2 2>dup_$k.err &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p" || status=$?; done
check "same node ID twice: both daemons warn about a duplicate node ID" \
  "exit $status; $(grep -h duplicate dup_1.err dup_2.err | head -2)" \
  test "$(grep -l 'duplicate node ID' dup_1.err dup_2.err | wc -l)" = 2

e2e_end patchd_e2e
