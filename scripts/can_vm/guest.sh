# guest.sh of scripts/can_vm.sh, run by the initramfs' busybox sh from the run's share: mounts
# the host root at $r and builds the file system around it, then runs the command: in a chroot
# (read-only root), or with --systemd by booting systemd on a writable overlay of the root into
# a unit that runs it. The run's settings come from vars.sh beside it (written by can_vm.sh).
set -u
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
. /share/vars.sh

# The host root. cache=loose: the guest keeps what it read in its page cache, which makes loading
# binaries and libraries several times faster than uncached 9p; fine for a read-only view that
# lives for one run. The run share stays uncached, so everything written there is on the host
# when the guest powers off. With --systemd the root is the lower layer of an overlay whose upper
# layer is a tmpfs that takes every write, so systemd, udev and the command can write anywhere.
if [ "$SYSTEMD" = 1 ]; then
    r=/newroot
    insmod "/lib/modules/$OVERLAY_MODULE.ko" || exit 1
    mkdir -p /lower /rw $r
    mount -t 9p -o "trans=virtio,version=9p2000.L,ro,cache=loose,msize=$MSIZE" host /lower || exit 1
    mount -t tmpfs -o mode=755 tmpfs /rw
    mkdir -p /rw/upper /rw/work
    mount -t overlay -o lowerdir=/lower,upperdir=/rw/upper,workdir=/rw/work overlay $r || exit 1
else
    r=/mnt
    mount -t 9p -o "trans=virtio,version=9p2000.L,ro,cache=loose,msize=$MSIZE" host $r || exit 1
fi
mount -t proc proc $r/proc
mount -t sysfs sysfs $r/sys
mount -t devtmpfs devtmpfs $r/dev
mkdir -p $r/dev/pts $r/dev/shm
mount -t devpts devpts $r/dev/pts
mount -t tmpfs tmpfs $r/dev/shm
mount -t tmpfs -o mode=755 tmpfs $r/run
# Stage the kernel dir before the tmpfs on /tmp can hide it (the cache may live under the
# host's /tmp).
mount --bind "$r$KERNEL_CACHE" /kroot || exit 1
# A caller working under the host's /tmp (a CI checkout, say) keeps its working directory: stage
# it the same way and put it back at its own path, read-only.
if [ -n "$CWD_UNDER_TMP" ]; then
    mkdir -p /cwd && mount --bind "$r$CWD_UNDER_TMP" /cwd || exit 1
fi
mount -t tmpfs -o mode=1777 tmpfs $r/tmp
if [ -n "$CWD_UNDER_TMP" ]; then
    mkdir -p "$r$CWD_UNDER_TMP" && mount --move /cwd "$r$CWD_UNDER_TMP" || exit 1
fi
mkdir -p "$r$GUEST_OUT" "$r$GUEST_KROOT"
mount --bind /share/out "$r$GUEST_OUT" || exit 1
mount --move /kroot "$r$GUEST_KROOT" || exit 1
cp /share/vars.sh /share/setup.sh /share/run.sh "$r$GUEST_DIR/"

if [ "$SYSTEMD" = 1 ]; then
    # The guest kernel's modules where modprobe and udev look for them.
    mkdir -p "$r/lib/modules/$KERNEL_VERSION"
    mount --bind "$r$GUEST_KROOT/lib/modules/$KERNEL_VERSION" "$r/lib/modules/$KERNEL_VERSION" || exit 1
    # The unit that runs the command, the target that boots to it, and the masks.
    cp /share/unit.sh "$r$GUEST_DIR/"
    cp /share/skinbus-vm.service /share/skinbus-vm.target $r/etc/systemd/system/
    ln -sf skinbus-vm.target $r/etc/systemd/system/default.target
    for u in $SYSTEMD_MASK; do ln -sf /dev/null "$r/etc/systemd/system/$u"; done
    # /tmp is a fresh tmpfs already: systemd-tmpfiles must not empty it at boot (its tmp.conf
    # says D), which would take $GUEST_DIR and the share's files with it.
    mkdir -p $r/etc/tmpfiles.d
    echo 'd /tmp 1777 root root -' >$r/etc/tmpfiles.d/tmp.conf
    # udev loads no drivers by itself (80-drivers.rules, emptied): under emulation the machine's
    # ATA, floppy, KVM and crypto modules cost seconds, and none is used. setup.sh loads the CAN
    # modules.
    mkdir -p $r/etc/udev/rules.d
    : >$r/etc/udev/rules.d/80-drivers.rules
    # The share goes along: unit.sh writes the command's output and status there.
    mkdir -p "$r$GUEST_DIR/share"
    mount --move /share "$r$GUEST_DIR/share" || exit 1
    touch /switch-root
else
    # Through the host's sh: a bare "chroot $r modprobe" would run busybox's own modprobe
    # applet, which lacks -d.
    chroot $r /bin/sh -e "$GUEST_DIR/setup.sh" || exit 1
    chroot $r /usr/bin/env -i /bin/sh "$GUEST_DIR/run.sh" </dev/null >/share/stdout 2>/share/stderr
    echo $? >/share/status
fi
