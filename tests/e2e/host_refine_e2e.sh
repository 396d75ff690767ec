#!/usr/bin/env bash
# Physics refinement through the tools, as a user deploys it: a patch's unit is identified from
# its own grid of presses (skinbus-dataset --fabricated with the board's UID, skinbus-identify),
# its skin-map entry names the unit file, and skinbus-host replays a log of that patch
# (skinbus-patchd --sim: the same fabricated unit) with and without refinement. Checked
# (check_refine.py): every contact of the refined run is refined (no unrefined flag, the fit's
# uncertainty), its (u, v) error over the held presses is well below the network's and within
# about the unit's noise limit; with --refine-budget-us 0 every contact is the network's answer,
# flagged unrefined.
#   tests/e2e/host_refine_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"

node=5  # a flat patch on the torso
make_skin_map map.yaml
calibrate_node map.yaml $node  # the map's entry for the node names its unit

cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.3,1.3,12,-25,2.5,5,5
1.6,2.6,-31,17,1.8,5,5
2.9,3.9,40,33,3.2,5,5
CSV
record_bus bus.log 4.2 "$node" --contacts presses.csv

for run in refined network overbudget; do
  opts=()
  [[ $run == network ]] && opts=(--no-refine)
  # (The budget is the overbudget run's test: here a preempted process on a loaded machine must
  # not leave a sample unrefined.)
  [[ $run == refined ]] && opts=(--record refined.mcap --refine-budget-us 1000000)
  [[ $run == overbudget ]] && opts=(--refine-budget-us 0)
  "$bin/skinbus-host" --map map.yaml --replay bus.log --fast --joints none --no-dds --json \
    --stats "${opts[@]}" >"$run.jsonl" 2>"$run.err" || fail_with_logs "skinbus-host ($run) failed"
  grep "refined\|estimated" "$run.err" || true
done
# The recording of the refined run carries the unit file the map names.
"$bin/skinbus-mcap" info refined.mcap | grep "attachment unit5.json (application/json" ||
  fail_with_logs "the recording does not carry the unit file"
python3 "$src/tests/e2e/check_refine.py" presses.csv refined.jsonl network.jsonl overbudget.jsonl ||
  fail_with_logs "the refinement check failed"
echo PASS
