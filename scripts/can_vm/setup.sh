# setup.sh of scripts/can_vm.sh, run by the host's /bin/sh -e inside the guest's root: the CAN
# modules and interfaces of the run (vars.sh beside it). A failure here is a setup failure (exit
# 125), not the command's.
. "$(dirname "$0")/vars.sh"
modprobe -a -d "$GUEST_KROOT" $CAN_MODULES $EXTRA_MODULES
if [ "$CTUCANFD" = 1 ]; then
    # Probing registers both channels before modprobe returns.
    modprobe -d "$GUEST_KROOT" ctucanfd_pci
    test -e /sys/class/net/can0 && test -e /sys/class/net/can1 ||
        { echo 'can_vm: the CTU CAN FD driver found no can0 and can1' >&2; exit 1; }
fi
ip link set lo up
i=0
while [ $i -lt "$FD_IFACES" ]; do
    ip link add dev vcan$i type vcan
    ip link set vcan$i mtu 72 up
    i=$((i + 1))
done
i=0
while [ $i -lt "$CLASSIC_IFACES" ]; do
    ip link add dev vcanc$i type vcan
    ip link set vcanc$i mtu 16 up
    i=$((i + 1))
done
