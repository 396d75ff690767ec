#!/usr/bin/env bash
# docs/guides/deploying.md done for real, in a CAN test VM that boots systemd (udevd, journald,
# systemd-networkd) and has a CTU CAN FD controller whose two channels share one emulated bus
# (scripts/can_vm.sh --systemd --ctucanfd). The guide's `console` lines are read from the guide
# and run as written, as root, from the repository, with build/ read as BUILD_DIR. Channel 0
# (can0) is a patch board's interface: the bit-timing lines set it up by hand. Channel 1 is the
# host's skin bus: from the persistent-name steps on, the guide's can0 is read as can1, which the
# guide's .link file renames to skinleft and systemd-networkd configures from 80-can.network.
# Checked: what `ip -details` shows, the controller's ID_PATH, the new name and the bit timing
# systemd-networkd gives, both daemons under their shipped units (the patch is simulated through
# its settings file, sim.enabled: the VM has no I2C chips), the patch daemon's user, groups and
# capabilities, the patch's frames on the other channel (candump) and at the host aggregator (its
# journal, then skinbus-listen and skinbus-top over DDS). Guide lines it does not know are listed
# as not exercised. It writes to /etc, so it refuses to run anywhere but in that VM.
#   scripts/can_vm.sh --systemd --ctucanfd --fd-ifaces 0 --classic-ifaces 0 -- tests/kernel/deploy_vm.sh BUILD_DIR
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
src=$(cd "$(dirname "$0")/../.." && pwd)
if [[ ${SKINBUS_VM:-} != 1 || ! -d /run/systemd/system || ! -d /sys/bus/pci/drivers/ctucanfd_pci ||
  $(findmnt -no FSTYPE /) != overlay ]]; then
  echo "deploy_vm.sh: writes to /etc; run it in the VM: scripts/can_vm.sh --systemd --ctucanfd -- $0 BUILD_DIR" >&2
  exit 2
fi
e2e_begin deploy_vm "${1:-}"
guide=$src/docs/guides/deploying.md
export CYCLONEDDS_URI=file:///etc/skinbus/cyclonedds.xml

# Runs one guide line from the repository; its output goes to out.txt and, indented, to the log.
run() {
  local rc=0
  (cd "$src" && bash -c "$1") >"$work/out.txt" 2>&1 || rc=$?
  sed 's/^/    | /' "$work/out.txt"
  return "$rc"
}
# Runs a guide line that must succeed.
step() {
  if run "$1"; then ok "$1"; else bad "$1 (exit status $?)"; fi
}
# Waits up to $1 s for the command $2... to succeed.
wait_for() {
  local t=$1 i
  shift
  for ((i = 0; i < t * 4; i++)); do
    "$@" >/dev/null 2>&1 && return 0
    sleep 0.25
  done
  return 1
}
# Checks `ip -details link show` output in out.txt: CAN FD at 1M / 5M, restart-ms 100.
check_timing() {
  local what=$1 f=$work/out.txt
  if grep -q 'can <FD>' "$f" && grep -Eq '^\s+bitrate 1000000 ' "$f" &&
    grep -Eq '^\s+dbitrate 5000000 ' "$f" && grep -q 'restart-ms 100' "$f"; then
    ok "$what: CAN FD, bitrate 1000000, dbitrate 5000000, restart-ms 100"
  else
    bad "$what: not CAN FD at bitrate 1000000, dbitrate 5000000 with restart-ms 100"
  fi
  # The controller leaves STOPPED on its first fault-confinement interrupt, which QEMU's model
  # of the CTU CAN FD core (QEMU 7.2) never raises: the driver reports STOPPED although frames
  # flow. Anything else (error-passive, bus-off) is a failure.
  if grep -q 'state ERROR-ACTIVE' "$f"; then
    ok "$what: ERROR-ACTIVE"
  elif grep -q 'state STOPPED' "$f" && [[ -d /sys/bus/pci/drivers/ctucanfd_pci ]]; then
    echo "NOTE $what: state STOPPED, not ERROR-ACTIVE (QEMU's CTU CAN FD model raises no fault-confinement interrupt)"
  else
    bad "$what: state $(grep -o 'state [A-Z-]*' "$f" | head -1)"
  fi
}

# What the guide's units and files need that is not a console line: the patch's settings (a
# simulated patch, pressed from 3 s on), the skin map with a model, all under /etc/skinbus (the
# host's unit hides /home and /root, where a checkout may live).
mkdir -p /etc/skinbus/models
cp "$src"/estimators/models/nominal_seed_cnn.* /etc/skinbus/models/
cp "$src/body_map/robots/skinbot.urdf" /etc/skinbus/
"$bin/skinbus-touchsim" --robot /etc/skinbus/skinbot.urdf --out-dir skin \
  --model /etc/skinbus/models/nominal_seed_cnn >/dev/null
sed -e 's|^robot: .*|robot: "/etc/skinbus/skinbot.urdf"|' \
  -e 's|^\( *model:\).*|\1 /etc/skinbus/models/nominal_seed_cnn|' skin/truth.yaml >/etc/skinbus/skin.yaml
printf '# t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node\n3,3600,10,-20,2.0,5,3\n' \
  >/etc/skinbus/presses.csv
cat >/etc/skinbus/patch.yaml <<'YAML'
# A simulated patch (docs/patch_node.md): emulated MLX90393s fed by the simulator.
node: 3
hardware_uid: 0x5b00000000000003
can:
  interface: can0
sim:
  enabled: true
  contacts: /etc/skinbus/presses.csv
YAML

# The guide's console lines, in order.
guide_commands "$guide" >lines.txt
host_bus=0 skipped=()
while IFS= read -r cmd; do
  cmd=${cmd//build\/tools\//$bin/}
  # From the persistent-name steps on, the guide's can0 is the host's controller: channel 1.
  [[ $cmd == udevadm\ info* ]] && host_bus=1
  ((host_bus)) && cmd=${cmd//can0/can1}
  case $cmd in
    "ip -details link show "*)
      iface=${cmd##* }
      # systemd-networkd brings a renamed interface up on its own: wait for it.
      wait_for 30 sh -c "ip link show $iface | grep -q ',UP'" || true
      step "$cmd"
      # can0's timing was set by hand above; the host's channel never was: systemd-networkd's.
      if [[ $iface == can? ]]; then check_timing "$iface"; else check_timing "$iface (from 80-can.network)"; fi
      if [[ $iface != can? ]] && grep -q 'qlen 1000' out.txt; then
        ok "$iface: qlen 1000 (TransmitQueueLength of the .link file)"
      elif [[ $iface != can? ]]; then
        bad "$iface: qlen is not 1000"
      fi ;;
    "ip link set "*) step "$cmd" ;;
    "udevadm info "*)
      step "$cmd"
      idpath=$(sed -n 's/^E: ID_PATH=//p' out.txt)
      if [[ -n $idpath ]]; then ok "ID_PATH of can1: $idpath"; else bad "no ID_PATH for can1"; fi
      if [[ $(udevadm info /sys/class/net/can0 | sed -n 's/^E: ID_PATH=//p') == "$idpath" ]]; then
        ok "can0 has the same ID_PATH (one controller, two channels)"
      fi ;;
    "cp tools/systemd/80-"*.link*)
      step "$cmd"
      # "edit Path= and Name=": the controller's ID_PATH, and (two channels share it) the
      # channel's kernel name, as the guide says; Name= stays skinleft.
      link=/etc/systemd/network/$(basename "$(awk '{print $2}' <<<"$cmd")")
      sed -i -e "s|^Path=.*|Path=${idpath:-none}|" -e 's|^#OriginalName=.*|OriginalName=can1|' "$link"
      sed 's/^/    | /' "$link" | grep -v '^    | #'
      grep -q '^OriginalName=can1$' "$link" || bad "$link: no OriginalName= line to give" ;;
    "udevadm trigger "*)
      step "$cmd"
      if wait_for 30 test -e /sys/class/net/skinleft; then
        ok "can1 renamed skinleft (80-skinleft.link)"
      else
        bad "can1 not renamed skinleft"
      fi ;;
    "getent group "*)
      # "both must exist": create what is missing, as the guide's comment says.
      if ! run "$cmd" >/dev/null; then
        for g in ${cmd#getent group }; do getent group "$g" >/dev/null || groupadd --system "$g"; done
        echo "    (created the missing groups with groupadd --system)"
      fi
      step "$cmd" ;;
    "systemctl enable --now "*)
      unit=${cmd##* }
      t0=$SECONDS
      step "$cmd"
      echo "    (took $((SECONDS - t0)) s)"
      # systemctl returns once the unit is started; the daemon must still be running later.
      sleep 3
      if systemctl is-active --quiet "$unit"; then ok "$unit is active"; else bad "$unit is not active: $(systemctl is-active "$unit")"; fi ;;
    "journalctl -u "*-f)
      unit=$(awk '{print $3}' <<<"$cmd")
      timeout 5 bash -c "$cmd" >out.txt 2>&1 || true
      sed 's/^/    | /' out.txt
      if grep -q "Started $unit" out.txt && systemctl is-active --quiet "$unit"; then
        ok "$cmd: started, running"
      else
        bad "$cmd: not started or not running"
      fi ;;
    "cp tools/systemd/skinbus-host.service "*)
      step "$cmd"
      # "edit --map and the -i list": the map is /etc/skinbus/skin.yaml; one skin bus here.
      sed -i 's/ -i skinright//' /etc/systemd/system/skinbus-host.service
      grep '^ExecStart=' /etc/systemd/system/skinbus-host.service | sed 's/^/    | /' ;;
    "cp "*) step "$cmd" ;;
    *) skipped+=("$cmd") ;;
  esac
done <lines.txt

# skinbus-host waits for network-online.target: systemd-networkd-wait-online must have found the
# CAN links online (RequiredForOnline=carrier in 80-can.network), not given up after 2 minutes.
if [[ $(systemctl show -p Result --value systemd-networkd-wait-online.service) == success ]] &&
  systemctl is-active --quiet network-online.target; then
  ok "network-online.target reached: systemd-networkd-wait-online found the CAN links online"
else
  bad "systemd-networkd-wait-online did not succeed: $(systemctl show -p Result --value systemd-networkd-wait-online.service)"
fi

# The patch daemon's privileges, as the guide describes them: a user of its own, the groups
# i2c and gpio, CAP_NET_RAW and nothing else.
pid=$(systemctl show -p MainPID --value skinbus-patchd)
if [[ $pid =~ ^[1-9][0-9]*$ && -r /proc/$pid/status ]]; then
  uid=$(awk '/^Uid:/ {print $3}' "/proc/$pid/status")
  caps=$(awk '/^CapEff:/ {print $2}' "/proc/$pid/status")
  groups=$(awk '/^Groups:/ {$1 = ""; print}' "/proc/$pid/status")
  want=0
  for g in i2c gpio; do
    gid=$(getent group "$g" | cut -d: -f3)
    [[ -n $gid && " $groups " == *" $gid "* ]] && want=$((want + 1))
  done
  echo "    | skinbus-patchd: uid $uid, groups$groups, effective capabilities $caps"
  if ((uid != 0)); then ok "skinbus-patchd runs as a user of its own (uid $uid)"; else bad "skinbus-patchd runs as root"; fi
  if ((want == 2)); then ok "skinbus-patchd has the groups i2c and gpio"; else bad "skinbus-patchd lacks the groups i2c, gpio"; fi
  # CAP_NET_RAW is bit 13.
  if [[ $caps == 0000000000002000 ]]; then ok "skinbus-patchd has CAP_NET_RAW only"; else bad "skinbus-patchd capabilities $caps, not CAP_NET_RAW only"; fi
else
  bad "skinbus-patchd has no main process"
fi

# The patch's frames cross the emulated bus: candump on the other channel (the host's skinleft).
timeout 4 candump -L skinleft >bus.log 2>&1 || true
frames=$(grep -c ' skinleft ' bus.log || true)
"$bin/skinbus-decode" <bus.log >decoded.txt 2>&1 || true
head -3 decoded.txt | sed 's/^/    | /'
if ((frames > 0)) && grep -q 'node=3 ' decoded.txt; then
  ok "candump on skinleft: $frames frames from the patch (node 3) on can0, decoded"
else
  bad "candump on skinleft: no frames from the patch ($frames)"
fi

# The host aggregator hears the patch: its journal, then what it publishes on DDS.
journalctl -u skinbus-host --no-pager -o cat >host.journal 2>&1 || true
grep -v '^Started\|^Starting' host.journal | head -5 | sed 's/^/    | /'
if grep -qi 'node 3' host.journal; then ok "skinbus-host's journal names node 3"; else bad "skinbus-host's journal does not name node 3"; fi
timeout 15 "$bin/skinbus-listen" --status --table >listen.txt 2>&1 || true
head -8 listen.txt | sed 's/^/    | /'
if grep -q 'skinleft' listen.txt; then ok "skinbus-listen --status --table: the patch on skinleft"; else bad "skinbus-listen --status --table: no patch on skinleft"; fi
if timeout 60 "$bin/skinbus-listen" --count 1 --timeout 50 >contacts.jsonl 2>listen.err; then
  ok "skinbus-listen: a contact array from the pressed patch"
else
  bad "skinbus-listen: no contacts ($(tail -1 listen.err))"
fi
if timeout 30 "$bin/skinbus-top" --map /etc/skinbus/skin.yaml --frames 1 --after 4 --plain >top.txt 2>&1 &&
  grep -Eq '^ +3 +[a-z_]+ +online' top.txt; then
  ok "skinbus-top --map /etc/skinbus/skin.yaml: patch 3 online"
  grep -E '^ *(node|track|[0-9]+ )' top.txt | head -4 | sed 's/^/    | /'
else
  bad "skinbus-top: patch 3 not shown online: $(tail -2 top.txt)"
fi

journalctl -b --no-pager >journal.txt 2>&1 || true
free -m | awk '/^Mem:/ {print "guest memory: " $3 " of " $2 " MB used"}'
for c in "${skipped[@]}"; do echo "not exercised here: $c"; done
e2e_end deploy_vm
