#!/usr/bin/env bash
# End-to-end bus checks on real SocketCAN with can-utils as the peer. Runs inside the CAN
# test VM (scripts/can_vm.sh), which provides vcan0 (CAN FD, MTU 72) and vcanc0 (classic).
#
#   1. skinbus-gen -> kernel -> candump -L -> skinbus-decode == what was sent (FD and classic)
#   2. canplayer -> kernel -> skinbus-decode -i (the project's receiver) == the log (FD and classic)
#   3. cansend of golden frames -> skinbus-decode -i prints them
#   4. candump's id:mask filters select one patch / one class as docs/protocol.md says
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_begin bus_e2e "${1:-}"

# The decoders here reassemble with a 1 s timeout instead of the default 50 ms: the emulated guest
# can stall a sender for tens of milliseconds between two frames of one message, which a real
# node does not do. (Seen once: a sample missing from the receiver's output with every frame
# received and no kernel drop.) Every message must still arrive, decoded.
stall_us=1000000

# 1. The project's sender, candump as the capture, the project's decoder.
# Classic samples take 18 frames: fewer patches keep the emulated guest's candump ahead of the
# bus (a capture that drops frames would fail the comparison, as it should).
for kind in fd classic; do
  if [[ $kind == fd ]]; then iface=vcan0; flag=; nodes=1-6; else iface=vcanc0; flag=--classic; nodes=1-2; fi
  candump -L -r 4000000 "$iface" >"cap_$kind.log" &
  dump=$!
  sleep 0.3
  "$bin/skinbus-gen" -i "$iface" $flag --nodes "$nodes" --duration 1.5 --expect "sent_$kind.txt" 2>/dev/null
  sleep 0.3
  kill "$dump"; wait "$dump" 2>/dev/null || true
  "$bin/skinbus-decode" --stats --timeout-us "$stall_us" "cap_$kind.log" >"decoded_$kind.txt" 2>"stats_$kind.txt"
  check_same "sender->candump->decoder ($kind)" "sent_$kind.txt" "decoded_$kind.txt"
done

# 2. canplayer replays a log onto the bus; the project's receiver decodes it live.
for kind in fd classic; do
  if [[ $kind == fd ]]; then iface=vcan0; flag=; else iface=vcanc0; flag=--classic; fi
  "$bin/skinbus-gen" $flag --nodes 3-5 --duration 1 --log-interface can0 --expect "play_$kind.txt" -o "play_$kind.log" 2>/dev/null
  "$bin/skinbus-decode" -i "$iface" --duration 4 --count "$(wc -l <"play_$kind.txt")" --stats \
    --timeout-us "$stall_us" \
    >"received_$kind.txt" 2>"received_stats_$kind.txt" &
  recv=$!
  # A second capture of the same bus: when the receiver misses a message, it tells whether the
  # frames were on the bus at all.
  candump -L -r 4000000 "$iface" >"played_$kind.log" &
  dump=$!
  sleep 0.5
  canplayer -I "play_$kind.log" "$iface=can0"
  wait "$recv"
  sleep 0.2
  kill "$dump"; wait "$dump" 2>/dev/null || true
  check_same "canplayer->receiver ($kind)" "play_$kind.txt" "received_$kind.txt"
  if ! diff -q "play_$kind.txt" "received_$kind.txt" >/dev/null; then
    echo "  frames: $(wc -l <"play_$kind.log") in the log, $(wc -l <"played_$kind.log") captured by candump; receiver:"
    sed 's/^/  /' "received_stats_$kind.txt"
  fi
done

# 3. cansend: single golden frames from docs/protocol.md, one FD and one classic.
"$bin/skinbus-decode" -i vcan0 --duration 4 --count 2 >cansend.txt &
recv=$!
sleep 0.5
cansend vcan0 08C#2007034A10000000
cansend vcan0 10C##12002010008010000
wait "$recv"
printf '%s\n' "command node=12 seq=7 op=set_rate rate_hz=41.70 arg=4A10000000" \
  "ack node=12 seq=2 op=tare status=ok cmd_seq=8 broadcast value=0" >cansend_expected.txt
check_same "cansend->receiver (fd)" cansend_expected.txt cansend.txt
"$bin/skinbus-decode" -i vcanc0 --duration 4 --count 2 >cansend_classic.txt &
recv=$!
sleep 0.5
cansend vcanc0 07F#2001785634120201
cansend vcanc0 10C#2001420109000000
wait "$recv"
printf '%s\n' "sync node=127 seq=1 counter=258 host_time_us=305419896" \
  "ack node=12 seq=1 op=unknown(0x42) status=unknown_opcode cmd_seq=9 value=0" >cansend_classic_expected.txt
check_same "cansend->receiver (classic)" cansend_classic_expected.txt cansend_classic.txt

# 4. candump filters: one class (samples: class 3 -> 0x180/0x780), one patch (node 4 -> 004/07F).
candump -L vcan0,180:780 >only_samples.log &
d1=$!
candump -L vcan0,004:07F >only_node4.log &
d2=$!
sleep 0.3
"$bin/skinbus-gen" -i vcan0 --nodes 3-5 --duration 1.2 2>/dev/null
sleep 0.3
kill "$d1" "$d2"; wait "$d1" "$d2" 2>/dev/null || true
"$bin/skinbus-decode" only_samples.log | cut -d' ' -f1 | sort -u >classes.txt
"$bin/skinbus-decode" only_node4.log | cut -d' ' -f2 | sort -u >nodes.txt
echo sample >classes_expected.txt
echo node=4 >nodes_expected.txt
check_same "candump class filter" classes_expected.txt classes.txt
check_same "candump patch filter" nodes_expected.txt nodes.txt

e2e_end bus_e2e
