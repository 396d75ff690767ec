#!/usr/bin/env bash
# Measures the CAN traffic of one simulated patch node (skinbus-patchd --sim): frames, samples and
# heartbeats per second, idle and touched, in event and in stream mode, on CAN FD and classic CAN,
# over real SocketCAN (vcan) in the CAN test VM. Writes docs/benchmarks/patch_node.md.
#
#   scripts/measure_patch_traffic.sh [--seconds N] [--build DIR] [--out FILE]
#
# The guest side is tests/kernel/patch_traffic.sh (run through scripts/can_vm.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=10
build=$PWD/build
out=docs/benchmarks/patch_node.md
cmdline="scripts/measure_patch_traffic.sh"
while (($#)); do
  case $1 in
    --seconds) seconds=${2:?}; cmdline+=" --seconds $2"; shift 2 ;;
    --build) build=$(cd "${2:?}" && pwd); cmdline+=" --build $2"; shift 2 ;;
    --out) out=${2:?}; cmdline+=" --out $2"; shift 2 ;;
    -h | --help) sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "measure_patch_traffic.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ -x $build/tools/skinbus-patchd ]] || { echo "no $build/tools/skinbus-patchd: run scripts/build.sh" >&2; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
t_start=$(date +%s)
scripts/can_vm.sh --timeout 300 --fd-ifaces 1 --classic-ifaces 1 --out-dir "$tmp" -- \
  tests/kernel/patch_traffic.sh "$build" "$seconds"
elapsed=$(($(date +%s) - t_start))
res=$tmp/patch_traffic/results.tsv
[[ -s $res ]] || { echo "measure_patch_traffic.sh: no results from the guest" >&2; exit 1; }
kernel=$(cat "$tmp/patch_traffic/kernel.txt" 2>/dev/null || echo "?")
cpu=$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1)
qemu=$(qemu-system-x86_64 --version 2>/dev/null | head -1 || true)

# rates: bus mode state frames/s samples/s heartbeats/s contact% ratio
rates=$(awk -F'\t' 'NR > 1 {
    w = $5; key = $1 " " $2
    fr[key, $3] = $6 / w; row[NR] = $0
    printf "%s %s %s %.1f %.1f %.1f %s %s %s\n", $1, $2, $3, $6 / w, $9 / w, $10 / w,
      ($9 > 0 ? sprintf("%.0f%%", 100 * $11 / $9) : "-"), $12, $13
  }' "$res")
table=$(awk '
  { r[NR] = $0; f[$1, $2, $3] = $4 }
  END {
    print "| bus | mode | state | frames/s | samples/s | heartbeats/s | samples flagged contact | touched / idle (frames/s) |"
    print "|---|---|---|---|---|---|---|---|"
    for (i = 1; i <= NR; i++) {
      split(r[i], c, " ")
      ratio = "-"
      if (c[3] == "touched" && f[c[1], c[2], "idle"] > 0) ratio = sprintf("%.1fx", c[4] / f[c[1], c[2], "idle"])
      bus = c[1] == "fd" ? "CAN FD" : "classic"
      printf "| %s | %s | %s | %s | %s | %s | %s | %s |\n", bus, c[2], c[3], c[4], c[5], c[6], c[7], ratio
    }
  }' <<<"$rates")
gating=$(awk '{ f[$1, $2, $3] = $4 }
  END {
    for (b = 0; b < 2; b++) {
      bus = b == 0 ? "fd" : "classic"; name = b == 0 ? "CAN FD" : "classic CAN"
      s = f[bus, "stream", "idle"]; e = f[bus, "event", "idle"]
      if (e > 0) printf "- %s: an idle patch sends %.1f frames/s in event mode against %.1f in stream mode: event-mode gating cuts idle traffic %.1fx.\n", name, e, s, s / e
      else printf "- %s: an idle patch sent no frame at all in event mode (stream: %.1f frames/s).\n", name, s
    }
  }' <<<"$rates")
anomalies=$(awk '$8 != 0 || $9 != 0 { printf "- %s %s %s: the daemon counted %s sample overruns and %s send errors over its run.\n", $1, $2, $3, $8, $9 }' <<<"$rates")
[[ -n $anomalies ]] && anomalies=$'\nDaemon counters (whole run, not only the window):\n\n'"$anomalies"$'\n'

mkdir -p "$(dirname "$out")"
cat >"$out" <<EOF
# Patch node bus traffic: idle vs touched, event vs stream

What one patch node puts on the bus, measured rather than computed: the patch node daemon
\`skinbus-patchd --sim\` (16 emulated MLX90393 at the I2C transaction level, fed by the physics
simulator; default settings: 41.7 Hz, 1 Hz heartbeat, 250 ms event tail) publishes on real
SocketCAN (\`vcan\`) inside the CAN test VM (\`scripts/can_vm.sh\`: Debian's kernel under QEMU,
software emulation, 1 virtual CPU), and \`candump -L\` captures the bus. Per bus kind, four
daemons run at once on one interface, one per case (nodes 1..4: event idle, event touched,
stream idle, stream touched); "touched" is a 1.5 mm press (8 mm tip) held from 1 s after the
start to past the end of the run. Frames are counted per node by the kernel's receive
timestamps over a ${seconds} s window that starts 2 s after the daemons (start-up and the
initial baseline capture over); samples and heartbeats are the messages
\`skinbus-decode\` reassembles in that window. CAN FD: a sample is 2 frames, a heartbeat 1;
classic CAN: 18 and 6.

Command (about ${elapsed} s, VM boot included):

\`\`\`
scripts/build.sh && ${cmdline}
\`\`\`

Measured on $(date -u +%Y-%m-%d): host ${cpu:-?}, ${qemu:-QEMU}; guest kernel ${kernel}.

${table}

${gating}
${anomalies}
For comparison, the computed budget (docs/protocol.md, \`skinbus-budget --table\`) gives 84.4
frames/s per streaming patch and 1.0 for an idle one in event mode on CAN FD (756.6 and 6.0
on classic CAN).

What a vcan measurement cannot show: vcan has no bit timing or arbitration, so these are the
frames the node hands to the kernel, not bus load; the load follows from the frame counts with
the bus-load budget in docs/protocol.md.

Raw counts (\`tests/kernel/patch_traffic.sh\`, window ${seconds} s):

\`\`\`
$(column -t -s $'\t' "$res")
\`\`\`
EOF
echo "wrote $out"
cat "$out"
