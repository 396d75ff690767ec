#!/usr/bin/env bash
# End to end with joint states over DDS that stop and resume: simulated patch daemons write a
# long press on a forearm patch into a candump log; skinbus-host replays it at recorded speed
# with --joints dds while skinbus-joints, a separate process, publishes a trajectory that moves
# the left arm for 2.5 s and then exits (the stream stops); 4 s after its start a second
# skinbus-joints holds another pose (the stream resumes). skinbus-listen, a third process on a
# loopback-only DDS configuration, records contacts and patch status. Checked
# (check_joint_stream.py): contacts follow the arm while the stream runs (skinbus-locate at the
# same trajectory time), carry stale_kinematics at the last pose after it stops and not after
# it resumes (then at the new pose); the status has the kinematics_stale and kinematics_fresh
# events; every process exits with status 0.
#   tests/e2e/host_joints_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"

# The skin map: the true layout skinbus-touchsim puts on the project's robot, every patch with
# the shipped model (as host_replay_e2e.sh).
make_skin_map map.yaml

# The scene: one long press on patch 1 (left_forearm_link) from 0.5 s to 7.8 s of the log;
# patches 2-5 stay untouched.
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.5,7.8,10,-20,2.0,5,1
CSV
# The first stream: shoulder and elbow move for 2.5 s (the press point travels ~170 mm), then
# the publisher exits. The second: another pose, held.
cat >arm.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint
0,-0.3,0.3
2.5,-1.0,1.3
CSV
cat >hold.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint
0,-0.6,0.6
CSV

record_bus bus.log 8.5 "1 2 3 4 5" --contacts presses.csv

# DDS on loopback only, in a domain of its own.
use_loopback_domain
echo "DDS domain $domain (loopback only)"

"$bin/skinbus-listen" --domain "$domain" --timeout 60 --status >listen.jsonl 2>listen.err &
listener=$!
sleep 1.5
"$bin/skinbus-host" --map map.yaml --replay bus.log --joints dds --domain "$domain" \
  --json --json-status --status-period 0.5 --stats >host.jsonl 2>host.err &
host=$!
# The first publisher starts after the press (no joint states yet: no_kinematics), waits for
# the host's joint-state reader, and takes that match as its time zero.
sleep 0.7
"$bin/skinbus-joints" --trajectory arm.csv --robot "$urdf" --domain "$domain" --wait-match 30 \
  --duration 2.5 2>joints1.err &
joints1=$!
wait_for "time zero" 60 joints1.err "$joints1"
sleep 4
"$bin/skinbus-joints" --trajectory hold.csv --robot "$urdf" --domain "$domain" --wait-match 30 \
  2>joints2.err &
joints2=$!

rc=0
wait "$host" || rc=$?
((rc == 0)) || fail_with_logs "skinbus-host exited with status $rc"
rc=0
wait "$joints1" || rc=$?
((rc == 0)) || fail_with_logs "the first skinbus-joints exited with status $rc"
kill -TERM "$joints2" 2>/dev/null || true
rc=0
wait "$joints2" || rc=$?
((rc == 0)) || fail_with_logs "the second skinbus-joints exited with status $rc (SIGTERM: 0 expected)"
sleep 1
kill "$listener" 2>/dev/null || true
wait "$listener" 2>/dev/null || true
cat host.err joints1.err joints2.err

t0=$(sed -n 's/.*time zero \([0-9]*\) us.*/\1/p' joints1.err)
stop=$(sed -n 's/.*the last stamped \([0-9]*\) us.*/\1/p' joints1.err)
t1=$(sed -n 's/.*time zero \([0-9]*\) us.*/\1/p' joints2.err)
[[ -n $t0 && -n $stop && -n $t1 ]] || fail_with_logs "the publishers did not print their times"
press=$(awk -F, '!/^#/ {print $7, $3, $4}' presses.csv)

"$src/tests/e2e/check_joint_stream.py" listen.jsonl --reference host.jsonl \
  --locate "$bin/skinbus-locate" --map map.yaml --press "$press" \
  --trajectory arm.csv --start "$t0" --stop "$stop" --hold hold.csv --restart "$t1"
