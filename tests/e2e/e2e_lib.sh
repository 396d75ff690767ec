# shellcheck shell=bash disable=SC2034  # src, build, bin, work, urdf: set here for the sourcing script
# Shared by the end-to-end scripts (source it; bash; it only defines):
#   e2e_init BUILD_DIR
#       the common preamble: $build (absolute), $bin ($build/tools), $work (a fresh temporary
#       folder, the current directory from then on); at exit, background jobs still running are
#       killed and $work is removed (kept, and named, with KEEP=1)
#   make_skin_map OUT.yaml [touchsim options...]
#       the true skin map skinbus-touchsim puts on the project's robot (cylinder patches on the
#       forearms, flat ones on the chest), every patch with the shipped model; $bin/skinbus-touchsim
#   patch_uid N
#       prints the hardware UID the skin maps give node N (0x5b followed by N in 14 hex digits)
#   record_bus OUT.log DURATION_S "NODE..." [skinbus-patchd options...]
#       one simulated patch daemon per node (its patch_uid, DURATION_S, the options), all at
#       once, their candump logs (patch_NODE.log) merged by time into OUT.log
#   use_loopback_dds
#       Cyclone DDS on loopback only (tools/dds/loopback.xml), unless CYCLONEDDS_URI is set
#   use_loopback_domain
#       use_loopback_dds, and $domain set to a DDS domain in 120..219 that no other test on this
#       machine holds while this one runs (a lock file per domain)
#   fail_with_logs MESSAGE...
#       prints FAIL MESSAGE and every *.err file of the current folder, and exits 1
#   wait_for PATTERN SECONDS FILE PID
#       waits until FILE (written by process PID) has a line matching PATTERN; fail_with_logs
#       when PID ends first or after SECONDS
# $src is the repository, $urdf the project's robot.
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
urdf=$src/body_map/robots/skinbot.urdf
e2e_init() {
  build=$(cd "${1:?usage: $(basename "$0") BUILD_DIR}" && pwd)
  bin=$build/tools
  work=$(mktemp -d)
  trap e2e_cleanup EXIT
  cd "$work" || exit 1
}
e2e_cleanup() {
  # shellcheck disable=SC2046  # one PID per word
  kill $(jobs -p) 2>/dev/null || true
  if [[ ${KEEP:-0} == 1 ]]; then echo "kept $work"; else rm -rf "$work"; fi
}
patch_uid() {
  printf '0x5b%014x' "$1"
}
# calibrate_node MAP NODE [KEY: VALUE ...]: identifies the simulated patch NODE's unit from its
# grid of presses (skinbus-dataset --fabricated with its UID, skinbus-identify: unitNODE.json)
# and names it in NODE's entry of the skin map MAP, with the extra settings given.
calibrate_node() {
  local map=$1 node=$2
  shift 2
  "$bin/skinbus-dataset" --plan grid --fabricated --uid "$(patch_uid "$node")" -o "unit$node.csv" \
    2>/dev/null
  "$bin/skinbus-identify" "unit$node.csv" -o "unit$node.json" 2>"identify$node.err" >/dev/null ||
    fail_with_logs "skinbus-identify failed"
  tail -3 "identify$node.err"
  python3 - "$map" "$node" "$@" <<'PY'
import re
import sys
path, node, extra = sys.argv[1], sys.argv[2], sys.argv[3:]
text = open(path).read()
entries = re.split(r"(?m)^  - ", text)
out = [entries[0]]
for e in entries[1:]:
    if re.match(rf"node: {node}\b", e):
        e = e.rstrip("\n") + f"\n    unit: unit{node}.json\n" + "".join(f"    {x}\n" for x in extra)
    out.append(e)
open(path, "w").write("  - ".join(out))
PY
  grep -A14 "node: $node$" "$map" | grep -q "unit:" || fail_with_logs "the unit was not added to the map"
}
fail_with_logs() {
  echo "FAIL $*"
  for f in *.err; do echo "--- $f"; cat "$f"; done
  exit 1
}
wait_for() {
  local deadline=$((SECONDS + $2))
  until grep -q "$1" "$3" 2>/dev/null; do
    kill -0 "$4" 2>/dev/null || fail_with_logs "the process writing $3 ended before '$1'"
    ((SECONDS < deadline)) || fail_with_logs "no '$1' in $3 within $2 s"
    sleep 0.05
  done
}
make_skin_map() {
  local out=$1 dir
  shift
  dir=$(mktemp -d)
  "$bin/skinbus-touchsim" --robot "$urdf" --out-dir "$dir" \
    --model "$src/estimators/models/nominal_seed_cnn" "$@" >/dev/null
  sed -e "s|^robot: .*|robot: \"$urdf\"|" "$dir/truth.yaml" >"$out"
  rm -rf "$dir"
}
use_loopback_dds() {
  export CYCLONEDDS_URI=${CYCLONEDDS_URI:-file://$src/tools/dds/loopback.xml}
}
use_loopback_domain() {
  # A domain no other test of this machine holds: the first free lock of 120..219 in random order,
  # kept until the script ends (its processes inherit it). The unit tests' DDS domains are 1..100
  # (dds_test_support.h), the soak's 220..231: the end-to-end tests publish the real topic names,
  # so two of them in one domain would hear each other.
  local d
  for d in $(shuf -i 120-219); do
    exec {domain_lock}>"${TMPDIR:-/tmp}/skinbus-dds-domain-$d.lock"
    if flock -n "$domain_lock"; then
      domain=$d
      use_loopback_dds
      return
    fi
    exec {domain_lock}>&-
  done
  domain=$((RANDOM % 100 + 120))
  use_loopback_dds
}
record_bus() {
  local out=$1 duration_s=$2 nodes=$3 n
  shift 3
  for n in $nodes; do
    "$bin/skinbus-patchd" --sim -i none --candump-out "patch_$n.log" --node "$n" \
      --uid "$(patch_uid "$n")" --duration "$duration_s" -q "$@" &
  done
  wait
  sort -s -k1,1 patch_*.log >"$out"
}
