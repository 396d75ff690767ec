#!/usr/bin/env bash
# The red-team regression suite: each reproducer of what an adversarial user broke (unbounded
# lines, hangs, silent wrong output, silent data loss, torn files, unclear messages) as one case
# that fails on the old behaviour and passes on the new.
#
#   tests/redteam/redteam.sh BUILD_DIR fixture FIXTURE_DIR     # a skin map and logs (about 4 s)
#   tests/redteam/redteam.sh BUILD_DIR CASE FIXTURE_DIR        # one case (seconds)
#   tests/redteam/redteam.sh BUILD_DIR list                    # the cases
#
# CTest runs the fixture once (FIXTURES_SETUP) and every case as its own test (redteam_<case>).
# A case prints PASS/FAIL lines and exits non-zero on a failure.
set -uo pipefail
build=$(cd "${1:?usage: redteam.sh BUILD_DIR CASE [FIXTURE_DIR]}" && pwd)
case_name=${2:?usage: redteam.sh BUILD_DIR CASE [FIXTURE_DIR]}
fixture=${3:-$build/redteam_fixture}
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../.." && pwd)
bin=$build/tools
logtool=$here/logtool.py
modeltool=$here/modeltool.py
fail=0
ok() { echo "PASS $1"; }
bad() {
  echo "FAIL $1"
  fail=1
}
check() {  # check NAME COMMAND...: PASS when the command succeeds
  local name=$1
  shift
  if "$@"; then ok "$name"; else bad "$name"; fi
}
now_ms() { echo $(($(date +%s%N) / 1000000)); }
# Runs a command (stdin: the caller's) under /usr/bin/time: its peak resident memory (KB) into
# $out.kb and its exit status into $out.rc.
measure() {
  local out=$1
  shift
  /usr/bin/time -f '%M' -o "$out.time" "$@"
  echo $? >"$out.rc"
  tail -1 "$out.time" >"$out.kb"
}
# Waits at most $2 seconds for process $1 to end; 0 when it ended.
ends_within() {
  local pid=$1 limit_ms=$(($2 * 1000)) start
  start=$(now_ms)
  while kill -0 "$pid" 2>/dev/null; do
    (($(now_ms) - start > limit_ms)) && return 1
    sleep 0.02
  done
  return 0
}
host() { "$bin/skinbus-host" --no-dds --joints none "$@"; }

# ---- the fixture: the true skin map of the project's robot, and a bus log of three simulated
# patch daemons (nodes 1-3; 1 and 2 pressed), 3 s; plus node 2 claiming node 1's hardware UID.
make_fixture() {
  rm -rf "$fixture"
  mkdir -p "$fixture"
  cd "$fixture" || exit 1
  # shellcheck source-path=SCRIPTDIR source=../e2e/e2e_lib.sh
  source "$src/tests/e2e/e2e_lib.sh"
  make_skin_map skin.yaml
  cat >presses.csv <<'CSV'
# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node
0.5,2.0,10,-20,2.0,5,1
0.5,2.0,-30,35,2.5,5,2
CSV
  uid() { printf '0x5b%014x' "$1"; }
  for n in 1 2 3; do
    "$bin/skinbus-patchd" --sim -i none --candump-out "p$n.log" --node "$n" --uid "$(uid "$n")" \
      --contacts presses.csv --duration 3 -q &
  done
  # A second board that claims node 1's hardware UID, on node 2.
  "$bin/skinbus-patchd" --sim -i none --candump-out clone.log --node 2 --uid "$(uid 1)" \
    --contacts presses.csv --duration 3 -q &
  wait
  python3 "$logtool" merge bus.log p1.log p2.log p3.log
  python3 "$logtool" merge dupuid.log p1.log clone.log
  for _ in $(seq 300); do cat bus.log; done >big.log
  echo "fixture: $(wc -l <bus.log) frames in bus.log, $(wc -l <big.log) in big.log"
}

# ---- the cases ------------------------------------------------------------------------------

# 1. Out of memory: the line readers had no length limit.
case_decode_endless_line() {
  { head -c 300000000 /dev/zero; printf '\n'; head -2 "$fixture/bus.log"; } |
    measure "$work/d" "$bin/skinbus-decode" --stats 2>"$work/err.txt" >"$work/out.txt"
  local kb rc
  kb=$(cat "$work/d.kb") rc=$(cat "$work/d.rc")
  check "decoder exits 0 (rc $rc)" test "$rc" = 0
  check "a 300 MB line is reported as too long with its number" \
    grep -q "stdin:1: line_too_long: longer than 1024 bytes" "$work/err.txt"
  check "the good lines after it are decoded" grep -q "bad_lines 1 " "$work/err.txt"
  check "peak memory stays small (${kb} KB < 30 MB)" test "$kb" -lt 30000
}
case_host_endless_line() {
  { head -c 300000000 /dev/zero; printf '\n'; cat "$fixture/bus.log"; } |
    measure "$work/h" "$bin/skinbus-host" --no-dds --joints none --map "$fixture/skin.yaml" \
      --replay - --fast --json 2>"$work/err.txt" >"$work/out.txt"
  local kb rc
  kb=$(cat "$work/h.kb") rc=$(cat "$work/h.rc")
  check "host exits 0 (rc $rc)" test "$rc" = 0
  check "the long line is counted" grep -q "1 log line(s) could not be parsed" "$work/err.txt"
  check "contacts still come from the log after it" grep -q '"node":1' "$work/out.txt"
  check "peak memory does not grow with the line (${kb} KB < 250 MB)" test "$kb" -lt 250000
}

# 2. Hangs: a timestamp gap slept through, SIGINT/SIGTERM ignored, a quiet stdin, SIGPIPE.
case_replay_time_jump() {
  python3 "$logtool" jump "$work/gap.log" "$fixture/bus.log" 150 94608000  # +3 years
  local start
  start=$(now_ms)
  timeout 30 "$bin/skinbus-host" --no-dds --joints none --map "$fixture/skin.yaml" \
    --replay "$work/gap.log" --max-gap-s 1 --json >/dev/null 2>"$work/err.txt"
  rc=$?
  check "a +3-year jump at recorded speed ends (rc $rc, $(($(now_ms) - start)) ms)" test "$rc" = 0
  check "the jump is reported (log_time)" \
    grep -q "log_time: .*gap.log:150: the log's time jumps 94608000.0 s ahead" "$work/err.txt"
}
case_replay_signals() {
  python3 "$logtool" jump "$work/gap.log" "$fixture/bus.log" 150 60  # a minute of silence
  local sig start
  for sig in INT TERM; do
    "$bin/skinbus-host" --no-dds --joints none --map "$fixture/skin.yaml" \
      --replay "$work/gap.log" -q >/dev/null 2>&1 &
    local pid=$!
    sleep 2  # inside the silence
    start=$(now_ms)
    kill -"$sig" "$pid"
    if ends_within "$pid" 2; then
      wait "$pid"
      ok "SIG$sig ends a paced replay in a silence ($(($(now_ms) - start)) ms)"
    else
      kill -9 "$pid"
      bad "SIG$sig ignored by a paced replay"
    fi
  done
}
case_quiet_stdin_signal() {
  local start pid
  mkfifo "$work/fifo"
  "$bin/skinbus-host" --no-dds --joints none --map "$fixture/skin.yaml" --replay - -q \
    <"$work/fifo" >/dev/null 2>&1 &
  pid=$!
  exec 3>"$work/fifo"  # a writer that never writes
  sleep 1
  start=$(now_ms)
  kill -INT "$pid"
  if ends_within "$pid" 1; then ok "host: SIGINT ends a read of a quiet stdin ($(($(now_ms) - start)) ms)"; else
    kill -9 "$pid"
    bad "host: SIGINT does not end a read of a quiet stdin"
  fi
  "$bin/skinbus-decode" <"$work/fifo" >/dev/null 2>&1 &
  pid=$!
  sleep 0.5
  start=$(now_ms)
  kill -TERM "$pid"
  if ends_within "$pid" 1; then ok "decode: SIGTERM ends a read of a quiet stdin ($(($(now_ms) - start)) ms)"; else
    kill -9 "$pid"
    bad "decode: SIGTERM does not end a read of a quiet stdin"
  fi
  exec 3>&-
}
case_sigpipe() {
  local start statuses
  start=$(now_ms)
  "$bin/skinbus-decode" "$fixture/big.log" | head -1 >/dev/null
  statuses=("${PIPESTATUS[@]}")
  check "decode | head -1 ends by SIGPIPE (status ${statuses[0]}, $(($(now_ms) - start)) ms)" \
    test "${statuses[0]}" = 141
  host --map "$fixture/skin.yaml" --replay "$fixture/big.log" --fast --json -q | head -1 >/dev/null
  statuses=("${PIPESTATUS[@]}")
  check "host --json | head -1 ends by SIGPIPE (status ${statuses[0]})" test "${statuses[0]}" = 141
  # A parent that ignores SIGPIPE (so writes fail with EPIPE): still quiet, still at once.
  (
    trap '' PIPE
    "$bin/skinbus-decode" "$fixture/big.log" 2>"$work/epipe.txt" | head -1 >/dev/null
    exit "${PIPESTATUS[0]}"
  )
  rc=$?
  check "with SIGPIPE ignored by the parent, decode still ends at once (status $rc)" test "$rc" = 141
  check "  and says nothing" test ! -s "$work/epipe.txt"
}

# 3. Silent wrong output.
case_uid_on_two_nodes() {
  host --map "$fixture/skin.yaml" --replay "$fixture/dupuid.log" --fast --json --json-status \
    >"$work/out.jsonl" 2>"$work/err.txt"
  rc=$?
  check "host exits 0 (rc $rc)" test "$rc" = 0
  python3 - "$work/out.jsonl" <<'PY' || fail=1
import json, sys
placed_from_2, last = 0, None
for line in open(sys.argv[1]):
    j = json.loads(line)
    if j["type"] == "contacts":
        placed_from_2 += sum(1 for c in j["contacts"] if c["node"] == 2)
    else:
        last = j
p = {s["node"]: s for s in last["patches"]}
ok = True
def check(name, cond):
    global ok
    print(("PASS " if cond else "FAIL ") + name)
    ok = ok and cond
check(f"no contact of node 2 (node 1's UID) placed at patch 1's place ({placed_from_2})", placed_from_2 == 0)
check("node 1 is marked duplicate_id", p[1]["duplicate_id"])
check("node 2 is marked duplicate_id", p[2]["duplicate_id"])
check("both are degraded, not online", p[1]["state"] == "degraded" and p[2]["state"] == "degraded")
sys.exit(0 if ok else 1)
PY
  check "the duplicate is a WARNING on stderr" grep -q "WARNING duplicate_id:.*DUPLICATE hardware UID" "$work/err.txt"
}
case_dataset_repeated_column() {
  "$bin/skinbus-dataset" --plan halton --count 30 -o "$work/t.csv" 2>/dev/null
  # The second u_mm column (the press numbers, renamed) would replace the labels.
  sed -e '/^press,/s/^press,/u_mm,/' "$work/t.csv" >"$work/twice.csv"
  "$bin/skinbus-train" "$work/twice.csv" -o "$work/m" --arch mlp --hidden 8 --epochs 1 -q \
    2>"$work/err.txt"
  rc=$?
  check "a dataset with u_mm twice is refused (rc $rc)" test "$rc" = 2
  check "  naming the file, line and both columns" \
    grep -q "twice.csv:[0-9]*: column 'u_mm' (column 3) repeats column 1" "$work/err.txt"
}
case_dataset_no_press_column() {
  "$bin/skinbus-dataset" --plan halton --count 30 -o "$work/t.csv" 2>/dev/null
  awk '/^#/ {print; next} {sub(/^[^,]*,/, ""); print}' "$work/t.csv" >"$work/nopress.csv"
  { printf '\xef\xbb\xbf'; cat "$work/t.csv"; } >"$work/bom.csv"
  local f
  for f in nopress bom; do
    "$bin/skinbus-train" "$work/$f.csv" -o "$work/m_$f" --arch mlp --hidden 8 --epochs 1 -q \
      2>"$work/$f.txt"
    rc=$?
    local split
    split=$(grep -o "[0-9]* train / [0-9]* validation locations" "$work/$f.txt")
    check "$f: trains (rc $rc)" test "$rc" = 0
    check "$f: the split is by the 30 press locations, not by sample: $split" \
      test "$(echo "$split" | awk '{print $1 + $4}')" = 30
  done
}
case_touch_log_duplicates() {
  "$bin/skinbus-touchsim" --robot "$src/body_map/robots/skinbot.urdf" --out-dir "$work/s" \
    >/dev/null
  awk '/^#/ || /^node,/ {print; next} {print; print}' "$work/s/touches.csv" >"$work/twice.csv"
  "$bin/skinbus-calibrate" --map "$work/s/initial.yaml" --touches "$work/twice.csv" \
    --out "$work/cal.yaml" >/dev/null 2>"$work/err.txt"
  rc=$?
  check "a touch log with every row twice is refused (rc $rc)" test "$rc" != 0
  check "  naming both lines" grep -q "line [0-9]*: repeats the touch of line [0-9]* exactly" \
    "$work/err.txt"
  check "  and nothing written" test ! -e "$work/cal.yaml"
}

# 4. Silent data loss.
case_fast_time_backwards() {
  python3 "$logtool" reverse "$work/rev.log" "$fixture/bus.log"
  host --map "$fixture/skin.yaml" --replay "$work/rev.log" --fast --json >/dev/null \
    2>"$work/rev.txt"
  rc=$?
  check "a log with reversed stamps is refused (rc $rc)" test "$rc" = 1
  check "  saying it is not in time order" grep -q "not in time order" "$work/rev.txt"
  # A clock set back 2 s in the middle: every contact still comes out, and it is reported.
  python3 "$logtool" jump "$work/back.log" "$fixture/bus.log" 150 -2
  host --map "$fixture/skin.yaml" --replay "$fixture/bus.log" --fast --json 2>/dev/null |
    grep -c '"node"' >"$work/n0"
  host --map "$fixture/skin.yaml" --replay "$work/back.log" --fast --json 2>"$work/back.txt" |
    grep -c '"node"' >"$work/n1"
  check "a clock step back loses no contact ($(cat "$work/n1") of $(cat "$work/n0") publications)" \
    test "$(cat "$work/n1")" -ge "$(cat "$work/n0")"
  check "  and is reported (log_time)" grep -q "log_time: .*back.log:150: the log's time goes back" \
    "$work/back.txt"
}
case_model_non_finite() {
  python3 "$modeltool" overflow "$src/estimators/models/nominal_seed_cnn" "$work/overflow"
  sed -e "s|model: .*|model: $work/overflow|" "$fixture/skin.yaml" >"$work/map.yaml"
  host --map "$work/map.yaml" --replay "$fixture/bus.log" --fast --json-status \
    >"$work/out.jsonl" 2>"$work/err.txt"
  rc=$?
  check "host exits 0 (rc $rc)" test "$rc" = 0
  python3 - "$work/out.jsonl" <<'PY' || fail=1
import json, sys
last = [json.loads(l) for l in open(sys.argv[1])][-1]
p = {s["node"]: s for s in last["patches"]}
ok = p[1]["state"] == "degraded" and "no estimate from its model" in p[1]["detail"] \
    and "non_finite" in p[1]["detail"]
print(("PASS" if ok else "FAIL") + f" the pressed patch is degraded with the reason: {p[1]['state']}: {p[1]['detail']}")
sys.exit(0 if ok else 1)
PY
}
case_patch_far_away() {
  awk 'BEGIN{n=0} /position_mm:/ && n==0 {sub(/\[.*\]/, "[100000000, 45, 0]"); n=1} {print}' \
    "$fixture/skin.yaml" >"$work/far.yaml"
  host --map "$work/far.yaml" --replay "$fixture/bus.log" --fast --json >/dev/null \
    2>"$work/err.txt"
  rc=$?
  check "a patch placed 1e8 mm from its link is refused (rc $rc)" test "$rc" = 1
  check "  naming the key and line" \
    grep -q "far.yaml: patches\[0\].position_mm (line [0-9]*): the patch is 100000.000000 m" \
    "$work/err.txt"
}
case_interface_mismatch() {
  host --map "$fixture/skin.yaml" --replay "$fixture/bus.log" --fast --json -i can7 >/dev/null \
    2>"$work/err.txt"
  rc=$?
  check "-i naming none of the log's interfaces exits 1 (rc $rc)" test "$rc" = 1
  check "  saying which the log has" \
    grep -q "none of its [0-9]* frames is on an interface named with -i (can7); the log has can0" \
    "$work/err.txt"
  check "  and the skipped interface is an event" \
    grep -q "bad_frames: frames on interface 'can0' are skipped" "$work/err.txt"
}
case_directory_input() {
  "$bin/skinbus-decode" "$work" 2>"$work/d.txt" >/dev/null
  rc=$?
  check "decode: a directory is refused (rc $rc)" test "$rc" = 1
  check "  as a directory" grep -q "is a directory" "$work/d.txt"
  host --map "$fixture/skin.yaml" --replay "$work" --fast 2>"$work/h.txt" >/dev/null
  rc=$?
  check "host: a directory is refused (rc $rc)" test "$rc" = 1
  check "  as a directory" grep -q "candump log $work: is a directory" "$work/h.txt"
  "$bin/skinbus-train" "$work" -o "$work/m" -q 2>"$work/t.txt"
  rc=$?
  check "train: a directory is refused (rc $rc)" test "$rc" != 0
  check "  as a directory" grep -q "directory" "$work/t.txt"
}

# 5. Torn files.
case_model_torn_pair() {
  "$bin/skinbus-dataset" --plan halton --count 30 -o "$work/t.csv" 2>/dev/null
  local train=("$bin/skinbus-train" "$work/t.csv" --arch mlp --hidden 8 --epochs 1 -q)
  "${train[@]}" -o "$work/m" --seed 1 2>/dev/null
  cp "$work/m.json" "$work/old.json"
  "${train[@]}" -o "$work/m" --seed 2 2>/dev/null
  cp "$work/old.json" "$work/m.json"  # new weights, old metadata: killed between the two files
  sed -e "s|model: .*|model: $work/m|" "$fixture/skin.yaml" >"$work/map.yaml"
  host --map "$work/map.yaml" --replay "$fixture/bus.log" --fast >/dev/null 2>"$work/err.txt"
  rc=$?
  check "new weights with old metadata are refused (rc $rc)" test "$rc" = 1
  check "  saying the two files come from different writes" \
    grep -q "m.safetensors: does not match its metadata" "$work/err.txt"
  # A write that fails (the file size limit stands in for a full disk): an error, no 'wrote', and
  # the model that was there is untouched.
  "${train[@]}" -o "$work/m" --seed 3 2>/dev/null
  local before
  before=$(cat "$work/m.json" "$work/m.safetensors" | md5sum)
  (
    trap '' XFSZ
    ulimit -f 1  # KiB
    exec "${train[@]}" -o "$work/m" --seed 4
  ) 2>"$work/full.txt"
  rc=$?
  check "a failed write exits 1 (rc $rc)" test "$rc" = 1
  check "  naming the file and the cause" grep -q "write to model weights $work/m.safetensors failed: File too large" "$work/full.txt"
  check "  without claiming it wrote" bash -c "! grep -q '^wrote' '$work/full.txt'"
  check "  the old model intact" test "$(cat "$work/m.json" "$work/m.safetensors" | md5sum)" = "$before"
  check "  and no temporary file left" bash -c "! ls '$work'/m.*.tmp.* 2>/dev/null"
}

# 6. Unclear.
case_reorder_not_loss() {
  python3 "$logtool" swap "$work/swap.log" "$fixture/bus.log" 1 3
  "$bin/skinbus-decode" --stats -q "$work/swap.log" 2>"$work/d.txt"
  check "one swapped pair: no gap" grep -q " gaps 0 .* reorders 1 " "$work/d.txt"
  host --map "$fixture/skin.yaml" --replay "$work/swap.log" --fast --json >/dev/null \
    2>"$work/h.txt"
  check "  and no 'sample(s) lost' from the host" bash -c "! grep -q 'sample(s) lost' '$work/h.txt'"
  local n
  n=$(python3 "$logtool" shuffle "$work/shuffle.log" "$fixture/bus.log" 0.1 7)
  "$bin/skinbus-decode" --stats -q "$work/shuffle.log" 2>"$work/s.txt"
  check "a 10 % shuffle ($n pairs): no gap" grep -q " gaps 0 " "$work/s.txt"
}
case_nan_cell_trains() {
  "$bin/skinbus-dataset" --plan halton --count 30 -o "$work/t.csv" 2>/dev/null
  awk -F, -v OFS=, 'BEGIN{done=0} !/^#/ && !/^press/ && !done {$10="nan"; done=1} {print}' \
    "$work/t.csv" >"$work/nan.csv"
  "$bin/skinbus-train" "$work/nan.csv" -o "$work/m" --arch mlp --hidden 8 --epochs 2 -q \
    2>"$work/err.txt"
  rc=$?
  check "one NaN cell (allowed by the dataset format) trains (rc $rc)" test "$rc" = 0
  check "  its row left out and said so" grep -q "1 of [0-9]* rows left out: a NaN field value" \
    "$work/err.txt"
}
case_dead_channel_identifies() {
  "$bin/skinbus-dataset" --plan grid --grid 9 --pitch 15 --fabricated --uid 0x5B07 \
    -o "$work/unit.csv" 2>/dev/null
  local col
  col=$(head -200 "$work/unit.csv" | grep -m1 '^press,' | tr , '\n' | grep -n '^s07_bz_ut$' | cut -d: -f1)
  awk -F, -v OFS=, -v c="$col" '!/^#/ && !/^press/ {$c="nan"} {print}' "$work/unit.csv" \
    >"$work/dead.csv"
  "$bin/skinbus-identify" "$work/dead.csv" -o "$work/unit.json" >"$work/out.txt" 2>"$work/err.txt"
  rc=$?
  check "a dead channel identifies (rc $rc)" test "$rc" = 0
  check "  leaving it out of the fit" grep -q "field value(s) not finite (dead channels): left out" \
    "$work/out.txt"
  check "  with a residual near the noise" \
    awk '/^fit .*residual RMS/ {for (i = 1; i < NF; ++i) if ($i == "RMS") v = $(i + 1)} END {exit !(v > 0 && v < 1.2)}' \
    "$work/out.txt"
}
case_no_usable_model() {
  sed -e "s|model: .*|model: $work/missing|" "$fixture/skin.yaml" >"$work/map.yaml"
  host --map "$work/map.yaml" --replay "$fixture/bus.log" --fast --json >/dev/null \
    2>"$work/err.txt"
  rc=$?
  check "no usable model: exit 1 (rc $rc)" test "$rc" = 1
  check "  saying why" grep -q "no patch of .* has a usable model: nothing to estimate" "$work/err.txt"
  host --map "$work/map.yaml" --replay "$fixture/bus.log" --fast --allow-no-models --json-status \
    >/dev/null 2>&1
  rc=$?
  check "  --allow-no-models runs anyway (rc $rc)" test "$rc" = 0
}
case_json_number_message() {
  python3 "$modeltool" number "$src/estimators/models/nominal_seed_cnn" "$work/big_number"
  sed -e "s|model: .*|model: $work/big_number|" "$fixture/skin.yaml" >"$work/map.yaml"
  host --map "$work/map.yaml" --replay "$fixture/bus.log" --fast >/dev/null 2>"$work/err.txt"
  check "a JSON number 1e400 is named as such" grep -q "not valid JSON: .*number overflow.*1e400" \
    "$work/err.txt"
}

cases=(decode_endless_line host_endless_line replay_time_jump replay_signals quiet_stdin_signal
  sigpipe uid_on_two_nodes dataset_repeated_column dataset_no_press_column touch_log_duplicates
  fast_time_backwards model_non_finite patch_far_away interface_mismatch directory_input
  model_torn_pair reorder_not_loss nan_cell_trains dead_channel_identifies no_usable_model
  json_number_message)

case "$case_name" in
  list) printf '%s\n' "${cases[@]}" ;;
  fixture) make_fixture ;;
  *)
    if ! declare -F "case_$case_name" >/dev/null; then
      echo "redteam.sh: unknown case '$case_name' (list: redteam.sh BUILD list)" >&2
      exit 2
    fi
    [[ -f $fixture/bus.log ]] || {
      echo "redteam.sh: no fixture in $fixture (run: redteam.sh BUILD fixture $fixture)" >&2
      exit 2
    }
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
    "case_$case_name"
    exit "$fail"
    ;;
esac
