#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (ASan + UBSan) and runs each for a bounded time,
# starting from the corpus checked in under tests/fuzz/corpus/. New inputs the fuzzer finds go
# to a scratch folder (pass --update-corpus to merge them into the checked-in corpus).
#
#   scripts/fuzz.sh                 # 20 s per target, one target a core at a time
#   SKINBUS_FUZZ_SECONDS=300 scripts/fuzz.sh --update-corpus
# Environment: SKINBUS_FUZZ_JOBS (targets at a time; default: the cores).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${SKINBUS_FUZZ_SECONDS:-20}
update=0
[[ ${1:-} == --update-corpus ]] && update=1
build=${SKINBUS_FUZZ_BUILD_DIR:-build-fuzz}

command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ missing: run scripts/setup.sh" >&2; exit 1; }
cmake -S . -B "$build" -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DSKINBUS_FUZZ=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
targets=(frame_decoder reassembler candump line_reader dataset settings body_map model_file aggregator
  joint_trajectory unit_file design_file websocket mcap correction_file)
cmake --build "$build" -j2 --target "${targets[@]/#/fuzz_}"
# The longest input per target: past the readers' own bounds where a target has one (a candump
# line: 1024 bytes; the line reader's bound is at most 256), so that the fuzzer reaches them.
declare -A max_len=([candump]=4096 [line_reader]=4096 [dataset]=16384 [body_map]=16384
  [model_file]=65536 [unit_file]=16384 [correction_file]=16384 [joint_trajectory]=8192 [websocket]=16384
  [mcap]=65536)

scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
# One target a core at a time (SKINBUS_FUZZ_JOBS, default: the cores): each still fuzzes for
# `seconds` on a core of its own, the whole run in a fraction of the time.
jobs=${SKINBUS_FUZZ_JOBS:-$(nproc)}
fuzz_one() { # target: its exit status into $scratch/target.rc
  local target=$1 limit=()
  mkdir -p "$scratch/$target" "tests/fuzz/corpus/$target"
  [[ -n ${max_len[$target]:-} ]] && limit=(-max_len="${max_len[$target]}")
  local rc=0
  "$build/tests/fuzz/fuzz_$target" -max_total_time="$seconds" -print_final_stats=1 "${limit[@]}" \
    -artifact_prefix="$scratch/$target-" "$scratch/$target" "tests/fuzz/corpus/$target" \
    >"$scratch/$target.log" 2>&1 || rc=$?
  echo "$rc" >"$scratch/$target.rc"
}
status=0
for ((i = 0; i < ${#targets[@]}; i += jobs)); do
  batch=("${targets[@]:i:jobs}")
  for target in "${batch[@]}"; do
    echo "fuzz: $target for ${seconds}s"
    fuzz_one "$target" &
  done
  wait
  for target in "${batch[@]}"; do
    if [[ $(cat "$scratch/$target.rc") != 0 ]]; then
      echo "fuzz: $target FAILED; last lines of its log:" >&2
      tail -40 "$scratch/$target.log" >&2
      mkdir -p fuzz-artifacts
      cp "$scratch/$target"-* fuzz-artifacts/ 2>/dev/null || true
      status=1
      continue
    fi
    echo "fuzz: $target"
    grep -E "stat::number_of_executed_units|stat::new_units_added" "$scratch/$target.log" | sed "s/^/  /"
    if ((update)); then
      "$build/tests/fuzz/fuzz_$target" -merge=1 "tests/fuzz/corpus/$target" "$scratch/$target" >/dev/null 2>&1
    fi
  done
done
exit $status
