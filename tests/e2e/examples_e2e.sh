#!/usr/bin/env bash
# The examples run and say what they should: estimate_recording finds a simulated press where it
# was made, and subscribe_contacts, another process, receives the contacts skinbus-host
# publishes from the same recording.
#   tests/e2e/examples_e2e.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"

# One simulated patch (node 1 of the project's skin map), pressed 2 mm deep at (10, -20) mm.
make_skin_map map.yaml
uid=$(patch_uid 1)
printf '# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node\n0.4,1.6,10,-20,2.0,5,1\n' \
  >presses.csv
"$bin/skinbus-patchd" --sim -i none --candump-out bus.log --node 1 --uid "$uid" \
  --contacts presses.csv --duration 2 -q

"$build/examples/estimate_recording" "$src/estimators/models/nominal_seed_cnn" <bus.log >est.txt
head -3 est.txt
python3 - est.txt <<'PY'
import re, statistics, sys
rows = [tuple(map(float, m.groups())) for m in
        (re.search(r"u (\S+) mm v (\S+) mm depth (\S+) mm", l) for l in open(sys.argv[1])) if m]
deep = [(u, v) for u, v, d in rows if d >= 1.0]
if len(deep) < 10:
    sys.exit(f"FAIL estimate_recording: {len(rows)} contact lines, {len(deep)} at least 1 mm deep")
u, v = statistics.median(r[0] for r in deep), statistics.median(r[1] for r in deep)
err = ((u - 10) ** 2 + (v + 20) ** 2) ** 0.5
if err > 2.5:
    sys.exit(f"FAIL estimate_recording: median ({u:.1f}, {v:.1f}) mm is {err:.1f} mm off (10, -20)")
print(f"PASS estimate_recording: {len(deep)} deep samples, median ({u:.1f}, {v:.1f}) mm")
PY

if [[ -x $build/examples/subscribe_contacts ]]; then
  use_loopback_domain
  "$build/examples/subscribe_contacts" 8 "$domain" >sub.txt 2>sub.err &
  sub=$!
  sleep 1.5
  "$bin/skinbus-host" --map map.yaml --replay bus.log --domain "$domain" -q 2>host.err
  wait "$sub" || { cat sub.err host.err; exit 1; }
  n=$(grep -c "track" sub.txt || true)
  head -2 sub.txt
  ((n > 0)) || { echo "FAIL subscribe_contacts received no contact"; cat sub.err host.err; exit 1; }
  echo "PASS subscribe_contacts: $n contacts received from skinbus-host"
fi
