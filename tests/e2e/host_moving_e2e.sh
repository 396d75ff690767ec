#!/usr/bin/env bash
# Accuracy while the robot moves: two simulated patches on limbs that swing +-90 degrees every
# 4 s (the Earth's field turns by up to ~100 uT against each patch) are pressed for 7 s.
# skinbus-host with its common-mode rejection places the presses within the model's error; with
# the rejection off (--ambient none) the same log must fail the same check, so the test shows
# the rejection is what holds the accuracy.
#   tests/e2e/host_moving_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"

make_skin_map map.yaml
cat >swing.yaml <<'YAML'
sim:
  limb_swing_deg: 90
  limb_period_s: 4
YAML
cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.5,7.5,10,-20,2.0,5,1
0.5,7.5,-30,35,2.5,5,2
CSV
record_bus bus.log 8 "1 2" --config swing.yaml --contacts presses.csv
awk -F, '!/^#/ {print $7, $3, $4}' presses.csv | "$bin/skinbus-locate" --map map.yaml - >truth.txt

status=0
"$bin/skinbus-host" --map map.yaml --replay bus.log --fast --json --no-dds --joints none -q \
  >with.jsonl
echo "== common-mode rejection on (default)"
"$src/tests/e2e/check_contacts.py" truth.txt with.jsonl --flags-allowed no_kinematics || status=1
"$bin/skinbus-host" --map map.yaml --replay bus.log --fast --json --no-dds --joints none -q \
  --ambient none >without.jsonl
echo "== common-mode rejection off: the same check must fail"
if "$src/tests/e2e/check_contacts.py" truth.txt without.jsonl --flags-allowed no_kinematics; then
  echo "FAIL the swinging limbs did not disturb the estimates: the test proves nothing"
  status=1
else
  echo "PASS without the rejection the moving limbs spoil the estimates"
fi
exit $status
