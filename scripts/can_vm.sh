#!/usr/bin/env bash
# Run a command with real SocketCAN (vcan, can-raw, CAN FD) on a machine whose own
# kernel is built without CAN.
#
# How: boot Debian's own kernel under QEMU (TCG) with a tiny busybox initramfs, share
# the host root file system into the guest read-only over 9p and chroot into it, so
# the guest runs the host's binaries (test build, can-utils, iproute2) unchanged.
# A second, writable 9p share carries the per-run scripts in and the command's
# stdout, stderr, exit status and result files out, so the output reaching the
# caller is never mixed with kernel console noise.
#
# Two more modes, for tests that need a real system rather than a chroot:
#   --ctucanfd  QEMU emulates a CTU CAN FD controller (PCI, two channels, can0 and can1,
#               on one emulated bus); Debian's kernel lacks its driver, so it is built
#               out of tree from Debian's kernel source and headers packages, once per
#               kernel, and cached next to the kernel.
#   --systemd   the guest boots systemd as PID 1 (with udevd, journald) on a writable
#               overlay of the host root, and runs the command from a unit.
#
# The kernel package is fetched with `apt-get download` and unpacked into a cache;
# it is never installed into /boot.
set -euo pipefail

readonly PROG=${0##*/}
# The guest's scripts and units (the initramfs /init, guest.sh, setup.sh, unit.sh, the systemd
# units), files of their own; each run writes their settings into vars.sh beside them.
GUEST_FILES=$(cd "$(dirname "${BASH_SOURCE[0]}")/can_vm" && pwd)
readonly GUEST_FILES
readonly META_PKG=linux-image-amd64

# virtio and 9p modules the initramfs needs to mount the shares; each needs the
# ones before it, and busybox insmod does not resolve dependencies.
readonly BOOT_MODULES=(virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev
                       virtio_pci netfs fscache 9pnet 9pnet_virtio 9p)
# Modules loaded in every guest (modprobe pulls in can and can-dev).
readonly CAN_MODULES=(can-raw vcan)
# --systemd: the initramfs also carries overlayfs, for the writable root.
readonly OVERLAY_MODULE=overlay
# --ctucanfd: the driver of QEMU's ctucan_pci device, built by build_ctucanfd
# (ctucanfd_pci needs ctucanfd, which needs can-dev).
readonly CTUCANFD_MODULES=(ctucanfd ctucanfd_pci)
# --systemd: units the test guest does not need, masked so that it boots quickly
# under emulation (the command's unit needs only basic.target: journald, udevd and
# the device coldplug). Boot-time updates of caches in /etc and /var, clocks,
# consoles, timers and whatever the host enables are left out.
readonly SYSTEMD_MASK=(systemd-firstboot.service systemd-remount-fs.service
    systemd-machine-id-commit.service systemd-hwdb-update.service
    systemd-journal-catalog-update.service systemd-update-done.service ldconfig.service
    systemd-update-utmp.service systemd-random-seed.service systemd-timesyncd.service
    systemd-sysctl.service systemd-journal-flush.service
    systemd-pstore.service systemd-binfmt.service proc-sys-fs-binfmt_misc.automount
    systemd-modules-load.service modprobe@.service systemd-sysusers.service
    console-setup.service keyboard-setup.service apparmor.service e2scrub_reap.service
    systemd-boot-system-token.service systemd-boot-random-seed.service
    dev-hugepages.mount dev-mqueue.mount sys-kernel-debug.mount sys-kernel-tracing.mount
    sys-kernel-config.mount sys-fs-fuse-connections.mount
    timers.target cryptsetup.target veritysetup.target integritysetup.target
    remote-fs.target swap.target)

# Where the guest sees things inside the chroot (on its private tmpfs /tmp).
readonly GUEST_DIR=/tmp/skinbus-vm
readonly GUEST_OUT=$GUEST_DIR/out       # writable, copied out by --out-dir
readonly GUEST_KROOT=$GUEST_DIR/kernel  # unpacked kernel package, for modprobe -d

# Larger 9p messages make reading binaries over the share much faster than the
# 8 KiB default.
readonly MSIZE=262144

# Debian packages this script relies on (can-utils only for the usual tests;
# make and gcc-12 to build the --ctucanfd driver, udev for --systemd).
readonly HOST_PACKAGES="qemu-system-x86 busybox-static kmod iproute2 xz-utils can-utils make gcc-12 udev"

# Host variables passed through to the command (glob patterns), besides --env.
readonly PASS_ENV=(PATH LD_LIBRARY_PATH HOME USER LOGNAME LANG LANGUAGE 'LC_*' TZ
                   'SKINBUS_*' 'GTEST_*' 'CYCLONEDDS_*' ASAN_OPTIONS UBSAN_OPTIONS
                   LSAN_OPTIONS TSAN_OPTIONS)

usage() {
    cat <<EOF
Usage:
  $PROG [OPTIONS] -- COMMAND [ARGS...]
  $PROG --prepare
  $PROG --help

Runs COMMAND as root inside a QEMU guest that boots Debian's kernel, which has
SocketCAN. The guest sees the host's root file system read-only, so host binaries
(the test build, can-utils) run unchanged, in the caller's working directory.
COMMAND is run as an argument vector (no shell); for shell syntax use
  $PROG -- sh -c 'candump -L any & sleep 0.5; cansend vcan0 123#DEADBEEF; kill \$!'

Options:
  --timeout SECONDS    kill the guest after this long (default 300); exit 124
  --fd-ifaces N        CAN FD interfaces vcan0..vcan<N-1>, mtu 72 (default 1)
  --classic-ifaces N   classic CAN interfaces vcanc0..vcanc<N-1>, mtu 16 (default 1)
  --modules LIST       extra kernel modules to load, comma separated
                       (e.g. can-isotp,can-gw,can-j1939,vxcan,can-bcm)
  --env NAME           also pass the host variable NAME (repeatable)
  --out-dir DIR        after the run, copy the files the command wrote into
                       \$SKINBUS_VM_OUT to DIR on the host (created if missing)
  --memory MB          guest memory (default 512; /tmp gets half of it)
  --ctucanfd           add a CTU CAN FD controller (QEMU's ctucan_pci): two real CAN
                       FD channels, can0 and can1, on one emulated bus, driver loaded,
                       interfaces down and unconfigured (set bit timing with ip link)
  --systemd            boot systemd as PID 1 on a writable root (see below)
  --verbose            show the guest's kernel console log on stderr afterwards
  --prepare            only fetch and unpack the kernel and build the initramfs
                       (with --ctucanfd: and build the controller's driver)
  --help               show this help

Inside the guest:
  - Everything except /tmp, /run and /dev/shm is read-only: the build tree cannot
    be written. /tmp is an empty tmpfs (except the working directory, when it lies
    under the host's /tmp: it stays visible, read-only); other host paths under /tmp
    are not visible. Result files meant for the host go into
    \$SKINBUS_VM_OUT (see --out-dir).
  - Passed from the host: PATH (plus the sbin directories), LD_LIBRARY_PATH,
    HOME, USER, LOGNAME, LANG, LANGUAGE, LC_*, TZ, SKINBUS_*, GTEST_*,
    CYCLONEDDS_*, {A,UB,L,T}SAN_OPTIONS, and those named with --env.
  - Also set: SKINBUS_VM=1, SKINBUS_VM_OUT=$GUEST_OUT,
    SKINBUS_VM_MODROOT=$GUEST_KROOT, so more modules load with
      modprobe -d "\$SKINBUS_VM_MODROOT" MODULE
    (plain modprobe cannot find them: the host has no /lib/modules for this kernel).
  - stdin is /dev/null; the loopback interface is up; there is no other network.

With --systemd the guest's PID 1 is the host's systemd (/lib/systemd/systemd), on
an overlay whose lower layer is the host root (read-only, 9p) and whose upper layer
is a tmpfs: the whole file system is writable (/etc, /usr/local, the build tree),
and every change is gone when the guest powers off. The boot goes as far as
basic.target (journald, udevd, the device coldplug), with many units masked for
speed; then a unit runs COMMAND, as above (clean environment, the caller's working
directory, \$SKINBUS_VM_OUT), and powers off when it ends. /lib/modules holds the
guest kernel's modules, so plain modprobe works (udev loads no drivers by itself:
the emulated machine's own would cost seconds), and systemctl, journalctl,
udevadm and systemd-networkd behave as on a real machine.

The command's stdout and stderr reach the caller's after the guest powers off, and
the exit status is the command's. 124 means the timeout hit, 125 that the guest
failed to boot or set up (the console log tail is printed).

Cache: \${SKINBUS_CACHE_DIR:-\$HOME/.cache/skinbus}/can-vm (about 450 MB), refreshed
when the candidate of Debian's $META_PKG package changes; the --ctucanfd driver
is rebuilt with it (downloading about 150 MB of Debian kernel source and headers
packages, deleted after the build; its log stays in ctucanfd.log).
Host packages needed: $HOST_PACKAGES.
EOF
}

die() {
    echo "$PROG: $*" >&2
    exit 125
}

note() {
    echo "$PROG: $*" >&2
}

# Quote a string for POSIX sh: wrap in single quotes, each ' becomes '\''.
shquote() {
    printf "'%s'" "${1//\'/\'\\\'\'}"
}

is_count() {
    [[ $1 =~ ^[0-9]+$ ]] && (( 10#$1 <= 256 ))
}

# depmod and modprobe live in /usr/sbin, which a non-root PATH may lack.
find_tool() {
    PATH="$PATH:/usr/sbin:/sbin" command -v "$1" 2>/dev/null
}

check_host_tools() {
    local missing=() tool
    for tool in qemu-system-x86_64 timeout flock dpkg apt-get apt-cache sha256sum; do
        command -v "$tool" >/dev/null || missing+=("$tool")
    done
    # depmod runs here; modprobe and ip run in the guest, from this file system.
    for tool in depmod modprobe ip; do
        find_tool "$tool" >/dev/null || missing+=("$tool")
    done
    # The initramfs has no libc, so busybox must be the static build.
    if [[ $(dpkg-query -W -f='${db:Status-Status}' busybox-static 2>/dev/null) != installed ]]; then
        missing+=("busybox-static")
    fi
    if (( CTUCANFD )); then
        # The kernel headers package names gcc-12 as its compiler.
        for tool in make gcc-12 dpkg-deb tar; do
            command -v "$tool" >/dev/null || missing+=("$tool")
        done
    fi
    if (( SYSTEMD )); then
        [[ -x /lib/systemd/systemd ]] || missing+=("systemd")
        [[ -x /lib/systemd/systemd-udevd ]] || missing+=("udev")
    fi
    if (( ${#missing[@]} )); then
        die "missing on this host: ${missing[*]}
Run the project's setup script, scripts/setup.sh, which installs them
(Debian packages used here: $HOST_PACKAGES)."
    fi
}

# ---------------------------------------------------------------------------
# Cache: unpacked kernel package and initramfs
# ---------------------------------------------------------------------------

# Sets KPKG and KVER from the candidate of the kernel metapackage
# (e.g. linux-image-6.1.0-56-amd64 6.1.192-2). Fails when apt has no lists.
resolve_kernel() {
    local dep
    dep=$(apt-cache show --no-all-versions "$META_PKG" 2>/dev/null |
          sed -n 's/^Depends: *\(linux-image-[^ ,]*\) *(= *\([^)]*\)).*/\1 \2/p' |
          head -n1) || true
    [[ -n $dep ]] || return 1
    read -r KPKG KVER <<<"$dep"
    # Remember the answer (see want_kernel); rename so readers never see half.
    echo "$KPKG $KVER" >"$CACHE/resolved.$$"
    mv "$CACHE/resolved.$$" "$CACHE/resolved"
}

apt_update() {
    if (( EUID != 0 )); then
        die "apt has no package lists for $META_PKG; run 'apt-get update' as root"
    fi
    note "apt package lists missing or stale; running apt-get update"
    apt-get update -q >"$CACHE/apt.log" 2>&1 || { cat "$CACHE/apt.log" >&2; die "apt-get update failed"; }
}

# Download and unpack $KPKG=$KVER into $CACHE/kernel, with a modules.dep (the
# package leaves that to its maintainer scripts, which we do not run).
fetch_kernel() {
    local tmp deb
    tmp=$(mktemp -d "$CACHE/tmp.fetch.XXXXXX")
    # The download dir must be ours; apt warns if its _apt user cannot write it.
    if ! (cd "$tmp" && apt-get download -q=2 "$KPKG=$KVER") >"$CACHE/apt.log" 2>&1; then
        rm -rf "$tmp"
        return 1
    fi
    deb=$(echo "$tmp"/*.deb)
    mkdir "$tmp/root"
    dpkg -x "$deb" "$tmp/root"
    rm -f "$deb"
    local kv
    kv=$(ls "$tmp/root/lib/modules")
    [[ -f $tmp/root/boot/vmlinuz-$kv ]] || die "no boot/vmlinuz-$kv in $KPKG"
    "$(find_tool depmod)" -b "$tmp/root" "$kv"
    echo "$KPKG $KVER" >"$tmp/root/stamp"
    rm -rf "$CACHE/kernel"
    mv "$tmp/root" "$CACHE/kernel"
    rmdir "$tmp"
}

# Under TCG, decompressing the xz bzImage takes about 3 s of every boot. Debian's
# kernel has CONFIG_PVH, so QEMU can boot the uncompressed ELF vmlinux directly
# (no real-mode setup, no decompressor): unpack it once. On any surprise, write
# a marker instead and keep booting the bzImage.
extract_vmlinux() {
    local kdir=$1 kv=$2 off
    local bz=$kdir/boot/vmlinuz-$kv out=$kdir/vmlinux
    if grep -q '^CONFIG_PVH=y' "$kdir/boot/config-$kv" &&
       grep -q '^CONFIG_KERNEL_XZ=y' "$kdir/boot/config-$kv"; then
        # The payload is an xz stream somewhere inside; try each xz magic.
        for off in $(LC_ALL=C grep -obUaP '\xfd7zXZ\x00' "$bz" | cut -d: -f1 | head -n 4); do
            # xz stops after the stream, so tail may die of SIGPIPE: ignore that.
            if { tail -c +$((off + 1)) "$bz" || true; } | xz -dcq --single-stream >"$out.tmp" 2>/dev/null &&
               [[ $(head -c 4 "$out.tmp") == $'\x7fELF' ]]; then
                mv "$out.tmp" "$out"
                return 0
            fi
        done
    fi
    rm -f "$out.tmp"
    note "cannot unpack vmlinux from $bz; booting the compressed kernel (slower)"
    touch "$kdir/vmlinux.none"
}

# What the initramfs /init (can_vm/init) reads: the modules to load, in order, and the 9p
# message size.
initramfs_env() {
    echo "BOOT_MODULES=$(shquote "${BOOT_MODULES[*]}")"
    echo "MSIZE=$MSIZE"
}

# Decompress a module if the distribution compressed it (busybox insmod only
# takes plain ELF). Debian's 6.1 kernels ship them uncompressed.
copy_module() {
    local src=$1 dst=$2
    case $src in
        *.ko)     cp "$src" "$dst" ;;
        *.ko.xz)  xz -dc "$src" >"$dst" ;;
        *.ko.zst) zstd -qdc "$src" >"$dst" ;;
        *.ko.gz)  gzip -dc "$src" >"$dst" ;;
    esac
}

build_initramfs() {
    local kv=$1 stamp=$2 tmp m src
    tmp=$(mktemp -d "$CACHE/tmp.initramfs.XXXXXX")
    mkdir -p "$tmp/root"/{bin,dev,proc,sys,mnt,share,kroot,lib/modules}
    cp /bin/busybox "$tmp/root/bin/busybox"
    for m in "${BOOT_MODULES[@]}" "$OVERLAY_MODULE"; do
        src=$(find "$CACHE/kernel/lib/modules/$kv/kernel" -name "$m.ko" -o -name "$m.ko.*" | head -n1)
        [[ -n $src ]] || die "module $m not found in $KPKG"
        copy_module "$src" "$tmp/root/lib/modules/$m.ko"
    done
    cp "$GUEST_FILES/init" "$tmp/root/init"
    chmod 755 "$tmp/root/init"
    initramfs_env >"$tmp/root/can_vm.env"
    # Uncompressed: it is small (~3 MB) and the kernel unpacks it faster.
    (cd "$tmp/root" && find . | busybox cpio -o -H newc -R 0:0 2>/dev/null) >"$tmp/initramfs.cpio"
    mv "$tmp/initramfs.cpio" "$CACHE/initramfs.cpio"
    echo "$stamp" >"$CACHE/initramfs.stamp"
    rm -rf "$tmp"
}

# Sets KPKG and KVER to the kernel the cache should hold. Skips apt-cache (half
# a second per run) while apt's lists are unchanged since the last look.
want_kernel() {
    local have=$1 lists
    # apt-get update renames fresh lists into this directory, touching its mtime.
    lists=$(apt-config shell lists Dir::State::Lists/d | sed -n "s/^lists='\(.*\)'$/\1/p") || true
    if [[ -n $have && -f $CACHE/resolved && -d $lists && $CACHE/resolved -nt $lists ]]; then
        read -r KPKG KVER <"$CACHE/resolved"
        return 0
    fi
    resolve_kernel && return 0
    # No apt lists (offline machine): keep using what is cached.
    [[ -n $have ]] || return 1
    read -r KPKG KVER <<<"$have"
}

cached_kernel() {
    cat "$CACHE/kernel/stamp" 2>/dev/null || true
}

# Identifies the initramfs: kernel package plus the text of /init and the modules.
initramfs_stamp() {
    echo "$KPKG $KVER $({ cat "$GUEST_FILES/init"; initramfs_env; echo "$OVERLAY_MODULE"; } | sha256sum | cut -c1-16)"
}

# The --ctucanfd driver lives inside the kernel folder, so a new kernel drops it.
have_ctucanfd() {
    [[ $(cat "$CACHE/kernel/ctucanfd.stamp" 2>/dev/null) == "$KPKG $KVER" ]]
}

cache_is_current() {
    [[ $(cached_kernel) == "$KPKG $KVER" ]] &&
    [[ -f $CACHE/kernel/vmlinux || -f $CACHE/kernel/vmlinux.none ]] &&
    [[ -f $CACHE/initramfs.cpio ]] &&
    [[ $(cat "$CACHE/initramfs.stamp" 2>/dev/null) == "$(initramfs_stamp)" ]] &&
    { (( ! CTUCANFD )) || have_ctucanfd; }
}

# Bring the cache up to date; the caller holds the exclusive lock.
update_cache() {
    local have kv
    # Leftovers of an interrupted build (nobody else builds while we hold the lock).
    rm -rf "$CACHE"/tmp.*
    have=$(cached_kernel)
    if ! want_kernel "$have"; then
        apt_update
        resolve_kernel || die "apt cannot resolve $META_PKG to a kernel package"
    fi
    if [[ $have != "$KPKG $KVER" ]]; then
        note "fetching $KPKG $KVER into $CACHE"
        if ! fetch_kernel; then
            # A missing or outdated list makes the download 404; refresh and retry.
            apt_update
            resolve_kernel || die "apt cannot resolve $META_PKG to a kernel package"
            fetch_kernel || { cat "$CACHE/apt.log" >&2; die "cannot download $KPKG=$KVER"; }
        fi
    fi
    kv=$(ls "$CACHE/kernel/lib/modules")
    if [[ ! -f $CACHE/kernel/vmlinux && ! -f $CACHE/kernel/vmlinux.none ]]; then
        extract_vmlinux "$CACHE/kernel" "$kv"
    fi
    if [[ ! -f $CACHE/initramfs.cpio ||
          $(cat "$CACHE/initramfs.stamp" 2>/dev/null) != "$(initramfs_stamp)" ]]; then
        build_initramfs "$kv" "$(initramfs_stamp)"
    fi
    if (( CTUCANFD )) && ! have_ctucanfd; then
        build_ctucanfd "$kv"
    fi
}

# apt-get download PACKAGE=VERSION... into the current directory; on failure
# (missing or outdated lists make it 404) refresh the lists and retry once.
download_debs() {
    (apt-get download -q=2 "$@") >>"$CACHE/apt.log" 2>&1 && return 0
    apt_update
    (apt-get download -q=2 "$@") >>"$CACHE/apt.log" 2>&1 ||
        { cat "$CACHE/apt.log" >&2; die "cannot download $*"; }
}

# The version of the series package $1 (linux-source-6.1, linux-kbuild-6.1) to build with:
# $KVER when the lists have it, else the newest of the same upstream version. Those two are the
# series' packages, and a security update can rebuild them (6.1.192-3) while the flavour's image
# and headers stay at theirs (6.1.192-2): the same sources. Nothing known: $KVER.
series_version() {
    local v
    v=$(apt-cache madison "$1" 2>/dev/null | awk -F'|' -v kver="$KVER" -v up="${KVER%-*}-" '
        { gsub(/ /, "", $2) }
        $2 == kver { exact = 1 }
        index($2, up) == 1 { print $2 }
        END { if (exact) print "EXACT" }' | sort -V)
    if [[ -z $v ]] || grep -qx EXACT <<<"$v"; then
        echo "$KVER"
    else
        tail -n 1 <<<"$v"
    fi
}

# The packages build_ctucanfd needs for kernel $1 (series $2, flavour $3), with versions.
ctucanfd_debs() {
    echo "linux-source-$2=$(series_version "linux-source-$2")" "linux-headers-$1=$KVER" \
        "linux-headers-${1%-"$3"}-common=$KVER" "linux-kbuild-$2=$(series_version "linux-kbuild-$2")"
}

# The driver of QEMU's ctucan_pci device (drivers/net/can/ctucanfd: ctucanfd.ko and
# ctucanfd_pci.ko). Debian's kernel does not build it (CONFIG_CAN_CTUCANFD_PCI is not
# set), so build it out of tree, exactly for the cached kernel, from Debian's own
# packages of the same version: the source tarball (only the driver's folder is
# unpacked), the headers of this flavour and of all flavours, and kbuild. The modules
# are unsigned: the kernel loads them and marks itself tainted. They go into the
# kernel's lib/modules/$kv/extra, so modprobe finds them and a new kernel drops them.
build_ctucanfd() {
    local kv=$1 series flavour tmp hdr log=$CACHE/ctucanfd.log m debs
    [[ $kv =~ ^([0-9]+\.[0-9]+)\.[0-9]+-[0-9]+-([a-z0-9]+)$ ]] ||
        die "cannot tell the kernel series and flavour from '$kv'"
    series=${BASH_REMATCH[1]} flavour=${BASH_REMATCH[2]}
    note "building the CTU CAN FD driver for $kv from Debian's linux-source-$series"
    tmp=$(mktemp -d "$CACHE/tmp.ctucanfd.XXXXXX")
    : >"$CACHE/apt.log"
    read -ra debs <<<"$(ctucanfd_debs "$kv" "$series" "$flavour")"
    if ! (cd "$tmp" && apt-get download -q=2 "${debs[@]}") >>"$CACHE/apt.log" 2>&1; then
        apt_update  # the versions may have moved on: choose them again from fresh lists
        read -ra debs <<<"$(ctucanfd_debs "$kv" "$series" "$flavour")"
        (cd "$tmp" && download_debs "${debs[@]}")
    fi
    mkdir "$tmp/root" "$tmp/src"
    for m in "$tmp"/linux-headers-*.deb "$tmp"/linux-kbuild-*.deb; do
        dpkg -x "$m" "$tmp/root"
    done
    hdr=$tmp/root/usr/src/linux-headers-$kv
    [[ -f $hdr/Makefile ]] || die "no usr/src/linux-headers-$kv in linux-headers-$kv"
    # The flavour's Makefile includes the common one by its installed path.
    sed -i "s|^include /usr/src/|include $tmp/root/usr/src/|" "$hdr/Makefile"
    # Stream the tarball (1.4 GB unpacked) and keep only the driver's folder.
    if ! dpkg-deb --fsys-tarfile "$tmp"/linux-source-*.deb |
         tar -xOf - "./usr/src/linux-source-$series.tar.xz" | xz -dc |
         tar -xf - -C "$tmp/src" --strip-components=5 "linux-source-$series/drivers/net/can/ctucanfd"; then
        rm -rf "$tmp"
        die "cannot unpack drivers/net/can/ctucanfd from linux-source-$series"
    fi
    rm -f "$tmp"/*.deb
    # Two small files: -j2 at most, the machine is shared.
    if ! env -u MAKEFLAGS -u MAKELEVEL make -C "$hdr" M="$tmp/src" -j2 \
             CONFIG_CAN_CTUCANFD=m CONFIG_CAN_CTUCANFD_PCI=m modules >"$log" 2>&1; then
        tail -n 20 "$log" >&2
        rm -rf "$tmp"
        die "building the CTU CAN FD driver failed (log: $log)"
    fi
    mkdir -p "$CACHE/kernel/lib/modules/$kv/extra"
    for m in "${CTUCANFD_MODULES[@]}"; do
        [[ $("$(find_tool modinfo)" -F vermagic "$tmp/src/$m.ko") == "$kv "* ]] ||
            die "$m.ko was not built for $kv (log: $log)"
        cp "$tmp/src/$m.ko" "$CACHE/kernel/lib/modules/$kv/extra/"
    done
    "$(find_tool depmod)" -b "$CACHE/kernel" "$kv"
    echo "$KPKG $KVER" >"$CACHE/kernel/ctucanfd.stamp"
    rm -rf "$tmp"
}

# Make the cache current and set KERNEL_IMAGE and INITRD. Runs hold a shared
# lock on the cache for as long as their guest uses it (QEMU inherits the fd);
# rebuilding takes the exclusive lock, so it waits for running guests and runs
# never see a half-built cache, while parallel runs do not block each other.
prepare() {
    mkdir -p "$CACHE"
    exec 9>"$CACHE/.lock"
    flock -s 9
    if ! { want_kernel "$(cached_kernel)" && cache_is_current; }; then
        # flock converts by unlocking first, so two converting runs cannot
        # deadlock; the second one finds the cache current and does nothing.
        flock -x 9
        update_cache
        flock -s 9
    fi
    local kv
    kv=$(ls "$CACHE/kernel/lib/modules")
    if [[ -f $CACHE/kernel/vmlinux ]]; then
        KERNEL_IMAGE=$CACHE/kernel/vmlinux
    else
        KERNEL_IMAGE=$CACHE/kernel/boot/vmlinuz-$kv
    fi
    INITRD=$CACHE/initramfs.cpio
}

# ---------------------------------------------------------------------------
# One run
# ---------------------------------------------------------------------------

# The run's share: the guest's scripts (can_vm/) and vars.sh, their settings for this run, each
# value quoted for sh.
write_guest_files() {
    local kv name cwd_under_tmp=""
    kv=$(ls "$CACHE/kernel/lib/modules")
    [[ $PWD == /tmp/* ]] && cwd_under_tmp=$PWD
    cp "$GUEST_FILES/guest.sh" "$GUEST_FILES/setup.sh" "$SHARE/"
    if (( SYSTEMD )); then
        cp "$GUEST_FILES/unit.sh" "$GUEST_FILES/skinbus-vm.target" "$SHARE/"
        sed "s|@GUEST_DIR@|$GUEST_DIR|g" "$GUEST_FILES/skinbus-vm.service.in" \
            >"$SHARE/skinbus-vm.service"
    fi
    {
        echo "# Written by can_vm.sh for one run; read by guest.sh, setup.sh and unit.sh."
        for name in SYSTEMD CTUCANFD FD_IFACES CLASSIC_IFACES MSIZE OVERLAY_MODULE GUEST_DIR \
                    GUEST_OUT GUEST_KROOT; do
            echo "$name=$(shquote "${!name}")"
        done
        echo "KERNEL_VERSION=$(shquote "$kv")"
        echo "KERNEL_CACHE=$(shquote "$CACHE/kernel")"
        echo "CWD_UNDER_TMP=$(shquote "$cwd_under_tmp")"
        echo "CAN_MODULES=$(shquote "${CAN_MODULES[*]}")"
        echo "EXTRA_MODULES=$(shquote "${EXTRA_MODULES[*]}")"
        echo "SYSTEMD_MASK=$(shquote "${SYSTEMD_MASK[*]}")"
    } >"$SHARE/vars.sh"
}

# run.sh: run by the host's /bin/sh inside the chroot, with a clean environment.
write_run_script() {
    local name pattern arg
    {
        # compgen -v lists set variables; the patterns select those we pass on.
        for name in $(compgen -v); do
            for pattern in "${PASS_ENV[@]}" "${EXTRA_ENV[@]}"; do
                # shellcheck disable=SC2053  # glob match on purpose
                if [[ $name == $pattern && -v $name ]] && declare -p "$name" 2>/dev/null | grep -q '^declare -[^ ]*x'; then
                    echo "export $name=$(shquote "${!name}")"
                    break
                fi
            done
        done
        echo "export SKINBUS_VM=1 SKINBUS_VM_OUT=$GUEST_OUT SKINBUS_VM_MODROOT=$GUEST_KROOT"
        # The command runs as root; a non-root caller's PATH may lack ip, modprobe.
        # shellcheck disable=SC2016  # expanded by the guest's sh
        echo 'PATH=${PATH:+$PATH:}/usr/local/sbin:/usr/sbin:/sbin; export PATH'
        local msg="$PROG: working directory $PWD is not visible in the guest"
        [[ $PWD == /tmp || $PWD == /tmp/* ]] && msg+=" (its /tmp is a fresh tmpfs)"
        echo "cd $(shquote "$PWD") 2>/dev/null || { echo $(shquote "$msg") >&2; exit 125; }"
        printf 'exec'
        for arg in "${COMMAND[@]}"; do
            printf ' %s' "$(shquote "$arg")"
        done
        printf '\n'
    } >"$SHARE/run.sh"
}

# Escape commas for QEMU's option parser.
qemu_path() {
    printf '%s' "${1//,/,,}"
}

run_vm() {
    local work console qemu_pid rc=0 interrupted=0 append="console=ttyS0 panic=-1"
    work=$(mktemp -d "${TMPDIR:-/tmp}/can_vm.XXXXXX")
    # shellcheck disable=SC2064  # expand $work now
    trap "rm -rf $(shquote "$work")" EXIT
    SHARE=$work/share
    console=$work/console.log
    mkdir -p "$SHARE/out"
    write_guest_files
    write_run_script
    (( VERBOSE )) || append+=" quiet"
    local devices=()
    if (( SYSTEMD )); then
        # The host's /etc/fstab describes the host, not this guest.
        append+=" fstab=no"
    fi
    if (( CTUCANFD )); then
        # One CTU CAN FD controller whose two channels share one emulated bus.
        devices+=(-object "can-bus,id=skinbus" -device "ctucan_pci,canbus0=skinbus,canbus1=skinbus")
    fi

    # KVM guests hang on these machines, so emulate (TCG). -cpu max lets binaries
    # built for newer x86-64 levels (AVX2) run; a second vCPU made boots slower.
    # qboot (shipped with QEMU) starts the kernel a little sooner than SeaBIOS.
    local bios=()
    [[ -f /usr/share/qemu/qboot.rom ]] && bios=(-bios /usr/share/qemu/qboot.rom)
    # Run in the background and wait, so Ctrl-C reaches the trap at once.
    timeout --kill-after=10 "$TIMEOUT" \
        qemu-system-x86_64 -nographic -no-reboot -nodefaults -serial stdio \
            -accel tcg -cpu max -smp 1 -m "$MEMORY" "${bios[@]}" \
            -kernel "$KERNEL_IMAGE" -initrd "$INITRD" -append "$append" \
            -virtfs "local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap" \
            -virtfs "local,path=$(qemu_path "$SHARE"),mount_tag=share,security_model=none,multidevs=remap" \
            "${devices[@]}" \
        </dev/null >"$console" 2>&1 &
    qemu_pid=$!
    trap 'interrupted=130; kill -TERM $qemu_pid 2>/dev/null' INT
    trap 'interrupted=143; kill -TERM $qemu_pid 2>/dev/null' TERM
    wait "$qemu_pid" || rc=$?
    # An interrupted wait returns early; wait again for the real status.
    while kill -0 "$qemu_pid" 2>/dev/null; do
        rc=0
        wait "$qemu_pid" || rc=$?
    done
    trap - INT TERM

    [[ -f $SHARE/stdout ]] && cat "$SHARE/stdout"
    [[ -f $SHARE/stderr ]] && cat "$SHARE/stderr" >&2
    if (( VERBOSE )); then
        echo "----- guest console -----" >&2
        cat "$console" >&2
        if [[ -f $SHARE/uptime ]]; then
            note "systemd started the command $(<"$SHARE/uptime") s after the guest's kernel"
        fi
    fi
    if [[ -n $OUT_DIR ]]; then
        mkdir -p "$OUT_DIR"
        cp -a "$SHARE/out/." "$OUT_DIR/"
    fi

    local status=""
    [[ -f $SHARE/status ]] && status=$(<"$SHARE/status")
    if [[ $status =~ ^[0-9]+$ ]]; then
        return "$status"
    fi
    if (( interrupted )); then
        note "interrupted"
        return "$interrupted"
    fi
    if (( ! VERBOSE )); then
        echo "----- guest console (last 30 lines) -----" >&2
        tail -n 30 "$console" >&2
    fi
    if (( rc == 124 || rc == 137 )); then
        note "timed out after ${TIMEOUT}s"
        return 124
    fi
    note "the guest did not run the command (QEMU exit status $rc)"
    return 125
}

main() {
    TIMEOUT=300 FD_IFACES=1 CLASSIC_IFACES=1 MEMORY=512 VERBOSE=0 OUT_DIR="" CTUCANFD=0 SYSTEMD=0
    EXTRA_MODULES=() EXTRA_ENV=() COMMAND=()
    local prepare_only=0 mods
    while (( $# )); do
        case $1 in
            --help|-h) usage; exit 0 ;;
            --prepare) prepare_only=1; shift ;;
            --timeout|--fd-ifaces|--classic-ifaces|--modules|--env|--out-dir|--memory)
                (( $# >= 2 )) || die "$1 needs a value"
                case $1 in
                    --timeout) TIMEOUT=$2 ;;
                    --fd-ifaces) FD_IFACES=$2 ;;
                    --classic-ifaces) CLASSIC_IFACES=$2 ;;
                    --modules) IFS=', ' read -r -a mods <<<"$2"; EXTRA_MODULES+=("${mods[@]}") ;;
                    --env) EXTRA_ENV+=("$2") ;;
                    --out-dir) OUT_DIR=$2 ;;
                    --memory) MEMORY=$2 ;;
                esac
                shift 2 ;;
            --verbose) VERBOSE=1; shift ;;
            --ctucanfd) CTUCANFD=1; shift ;;
            --systemd) SYSTEMD=1; shift ;;
            --) shift; COMMAND=("$@"); break ;;
            *) die "unknown argument '$1' (see --help)" ;;
        esac
    done
    [[ $TIMEOUT =~ ^[0-9]+(\.[0-9]+)?[smh]?$ ]] || die "bad --timeout '$TIMEOUT'"
    is_count "$FD_IFACES" || die "bad --fd-ifaces '$FD_IFACES'"
    is_count "$CLASSIC_IFACES" || die "bad --classic-ifaces '$CLASSIC_IFACES'"
    if ! [[ $MEMORY =~ ^[0-9]+$ ]] || (( MEMORY < 128 )); then
        die "bad --memory '$MEMORY'"
    fi
    FD_IFACES=$((10#$FD_IFACES)) CLASSIC_IFACES=$((10#$CLASSIC_IFACES))
    local m
    for m in "${EXTRA_MODULES[@]}"; do
        [[ $m =~ ^[A-Za-z0-9_-]+$ ]] || die "bad module name '$m'"
    done
    for m in "${EXTRA_ENV[@]}"; do
        [[ $m =~ ^[A-Za-z_][A-Za-z0-9_]*$ ]] || die "bad variable name '$m'"
    done
    if (( ! prepare_only && ${#COMMAND[@]} == 0 )); then
        usage >&2
        exit 125
    fi

    check_host_tools
    mkdir -p "${SKINBUS_CACHE_DIR:-${HOME:?HOME is not set}/.cache/skinbus}/can-vm"
    # Canonical (symlink-free) path: the guest resolves it under its own mount.
    CACHE=$(cd "${SKINBUS_CACHE_DIR:-$HOME/.cache/skinbus}/can-vm" && pwd -P)
    prepare
    if (( prepare_only )); then
        note "ready: $KPKG $KVER in $CACHE"
        exit 0
    fi
    local rc=0
    run_vm || rc=$?
    exit "$rc"
}

main "$@"
