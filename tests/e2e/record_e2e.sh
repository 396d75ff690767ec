#!/usr/bin/env bash
# Recording and replay end to end: simulated patch daemons write two presses (one on a moving
# forearm) into a candump log; skinbus-host estimates it with a joint trajectory and records the
# session (--record s.mcap). Checked:
#   - independent readers (tests/interop/check_mcap.mjs: @mcap/core's indexed and streaming
#     readers, @foxglove/rosmsg2-serialization with each channel's own schema) read every
#     message, and the contacts and status equal what the host printed (--json --json-status);
#   - the recorded frames are the input log, line for line (skinbus-mcap candump);
#   - the recording replayed (its frames through skinbus-host --replay -, its joint states with
#     --joints s.mcap) gives the host's output again, byte for byte when fast, and at recorded
#     speed (the joint states moved to the new run's time) the same contacts at the same places;
#   - a damaged recording is an error naming the file and byte.
# Skipped (77) when Node.js or tests/interop's packages (scripts/setup.sh) are missing.
#   tests/e2e/record_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
interop=$src/tests/interop
if ! command -v node >/dev/null || [[ ! -d $interop/node_modules/@mcap/core ]]; then
  echo "SKIP: Node.js or the interop readers (scripts/setup.sh installs them) are missing"
  exit 77
fi

make_skin_map map.yaml
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.5,2.5,10,-20,2.0,5,1
1.0,3.5,-15,5,1.5,5,3
CSV
# The left arm moves through the whole log (the forearm press travels with it).
cat >arm.csv <<'CSV'
time_s,left_shoulder_pitch_joint,left_elbow_joint
0,-0.3,0.3
4,-1.0,1.3
CSV
record_bus bus.log 4 "1 2 3 4 5" --contacts presses.csv

"$bin/skinbus-host" --map map.yaml --replay bus.log --fast --joints arm.csv --json --json-status \
  --no-dds --record s.mcap >host.jsonl 2>host.err || fail_with_logs "skinbus-host --record failed"
grep "recorded" host.err
"$bin/skinbus-mcap" info s.mcap

node "$interop/check_mcap.mjs" s.mcap host.jsonl || fail_with_logs "the independent readers disagree"

"$bin/skinbus-mcap" candump s.mcap >frames.log 2>mcap.err || fail_with_logs "skinbus-mcap candump"
cmp frames.log bus.log || fail_with_logs "the recorded frames are not the input log"
echo "the recorded frames equal the input log ($(wc -l <bus.log) frames)"

# Replayed as fast as possible: the same output, byte for byte.
"$bin/skinbus-mcap" candump s.mcap |
  "$bin/skinbus-host" --map map.yaml --replay - --fast --joints s.mcap --json --json-status \
    --no-dds >fast.jsonl 2>fast.err || fail_with_logs "the fast replay failed"
cmp fast.jsonl host.jsonl || fail_with_logs "the fast replay of the recording differs from the run"
echo "fast replay: $(grep -c '"contacts":\[{' fast.jsonl) publications with contacts, identical"

# Replayed at recorded speed: a new time base, the joint states moved onto it.
"$bin/skinbus-mcap" candump s.mcap |
  "$bin/skinbus-host" --map map.yaml --replay - --joints s.mcap --json --no-dds \
    >paced.jsonl 2>paced.err || fail_with_logs "the paced replay failed"
python3 "$src/tests/e2e/check_replay.py" host.jsonl paced.jsonl ||
  fail_with_logs "the paced replay placed contacts elsewhere"

# The recorded contacts read back by the project's own reader equal the host's output.
"$bin/skinbus-mcap" contacts s.mcap >recorded.jsonl
python3 "$src/tests/e2e/check_replay.py" --same-times host.jsonl recorded.jsonl ||
  fail_with_logs "skinbus-mcap contacts differs from the host's output"

# A damaged chunk: an error naming the file and the byte, exit status 2.
python3 - <<'PY'
b = bytearray(open("s.mcap", "rb").read())
b[len(b) // 2] ^= 0xFF
open("bad.mcap", "wb").write(b)
PY
rc=0
"$bin/skinbus-mcap" candump bad.mcap >/dev/null 2>bad.err || rc=$?
cat bad.err
((rc == 2)) && grep -q "bad.mcap: byte [0-9]*:" bad.err || fail_with_logs "a damaged recording: status $rc"
echo "PASS"
