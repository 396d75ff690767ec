# unit.sh of scripts/can_vm.sh --systemd: run by skinbus-vm.service once the guest has booted to
# basic.target; runs setup.sh and run.sh and leaves the command's output and status on the share.
d=$(dirname "$0")
cut -d' ' -f1 /proc/uptime >"$d/share/uptime"
# Devices found at boot (the CAN controller) processed, modules loaded.
udevadm settle --timeout=60 || echo "can_vm: udevadm settle timed out"
/bin/sh -e "$d/setup.sh" || exit 1
udevadm settle --timeout=60 || echo "can_vm: udevadm settle timed out"
/usr/bin/env -i /bin/sh "$d/run.sh" </dev/null >"$d/share/stdout" 2>"$d/share/stderr"
echo $? >"$d/share/status"
