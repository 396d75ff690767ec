#!/usr/bin/env bash
# A host that cannot keep up must cost latency, never correctness. Both arms swing (about
# 0.8 rad/s at the shoulders, joint states on DDS from skinbus-joints) while four forearm patches
# are pressed at once; their daemons write their frames into a pipe that skinbus-host reads live
# (--replay - --live, as the demo does without vcan). The host's estimator is starved on purpose:
# --model-delay-us makes every estimate cost 40 ms (~370x the seed CNN's 109 us here), so the
# four presses need 160 ms a period of 24 ms. skinbus-listen, another process, records what the
# host publishes on DDS. Checked (check_lag.py): every contact lies where its press was at the
# contact's time (skinbus-locate on the same trajectory), while the presses moved far more than
# that during the host's latency; the host superseded late samples and said so in its log and on
# the status topic; its latency stayed within the bound.
#   tests/e2e/host_lag_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
max_lag_ms=100
delay_us=${LAG_MODEL_DELAY_US:-40000}

make_skin_map map.yaml  # patches 1-2 on the left forearm, 3-4 on the right, 5-10 on the chest

# Four presses at once, from 0.5 s to 5.5 s of the daemons' time.
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.5,5.5,10,-20,2.2,5,1
0.5,5.5,-15,25,2.0,5,2
0.5,5.5,20,15,2.5,5,3
0.5,5.5,-25,-10,2.0,5,4
CSV
# Both arms swing, a half period of 1.2 s.
{
  echo "time_s,left_shoulder_pitch_joint,left_elbow_joint,right_shoulder_pitch_joint,right_elbow_joint"
  for k in 0 1 2 3 4 5 6 7 8 9 10; do
    t=$(awk -v k="$k" 'BEGIN {printf "%.1f", 1.2 * k}')
    if ((k % 2 == 0)); then echo "$t,-0.7,0.3,0.3,1.1"; else echo "$t,0.3,1.1,-0.7,0.3"; fi
  done
} >arms.csv

use_loopback_domain
echo "DDS domain $domain (loopback only); every estimate delayed by $delay_us us"

"$bin/skinbus-listen" --domain "$domain" --timeout 60 --status >listen.jsonl 2>listen.err &
listener=$!
# The bus: a pipe. This script holds a write end (fd 3) so the host opens it and subscribes to
# the joint states before the daemons start; no other process may inherit it (3>&-), or the host
# would never see the end of the stream.
mkfifo bus.fifo
exec 3<>bus.fifo
"$bin/skinbus-host" --map map.yaml --replay - --live --joints dds --domain "$domain" \
  --model-delay-us "$delay_us" --max-lag-ms "$max_lag_ms" --json-status --status-period 0.5 \
  --stats <bus.fifo >host.jsonl 2>host.err 3>&- &
host=$!
"$bin/skinbus-joints" --trajectory arms.csv --robot "$urdf" --domain "$domain" --wait-match 30 \
  2>joints.err 3>&- &
joints=$!
wait_for "time zero" 30 joints.err "$joints"
sleep 0.5  # the listener matched, the arms are moving
(  # a subshell: its `wait` is for the daemons alone
  for n in 1 2 3 4 5 6; do
    "$bin/skinbus-patchd" --sim -i none --candump-out - --node "$n" \
      --uid "$(patch_uid "$n")" --contacts presses.csv --duration 6 -q &
  done
  wait
) >bus.fifo 3>&-
exec 3>&-  # the last write end: the host reads to the end and exits

rc=0
wait "$host" || rc=$?
((rc == 0)) || fail_with_logs "skinbus-host exited with status $rc"
kill -TERM "$joints" 2>/dev/null || true
wait "$joints" || true
sleep 1
kill "$listener" 2>/dev/null || true
wait "$listener" 2>/dev/null || true
cat host.err

t0=$(sed -n 's/.*time zero \([0-9]*\) us.*/\1/p' joints.err)
[[ -n $t0 ]] || fail_with_logs "skinbus-joints did not print its time zero"
"$src/tests/e2e/check_lag.py" listen.jsonl --host-log host.err --locate "$bin/skinbus-locate" \
  --map map.yaml --presses presses.csv --trajectory arms.csv --start "$t0" \
  --max-lag-ms "$max_lag_ms"
