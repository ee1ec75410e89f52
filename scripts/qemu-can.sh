#!/usr/bin/env bash
# qemu-can.sh: runs `gardefou monitor --can vcan0` on a real SocketCAN bus,
# inside a QEMU VM, for machines whose kernel has no CAN support.
#
# OPT-IN: no test runs this script. It needs root (apt-get, /dev/kvm) and
# network access for the packages, and takes a few minutes.
#
# What it does:
#   1. installs what is missing of qemu-system-x86, linux-image-amd64,
#      can-utils and busybox-static (Debian 12 package names), unless
#      QEMU_CAN_INSTALL=0;
#   2. builds gardefou (`cargo build --release`) and copies it, stripped, with
#      the shared libraries `ldd` lists;
#   3. writes the test data: the shipped sorting plant with a [can] table
#      (sensors on TPDO1 0x181, actuators on RPDO1 0x201, bits in declaration
#      order), the model learned from the normal hour, and the F2 run from
#      600 s to 606 s as `candump -L` frames (scripts/qemu-can/frames.awk):
#      C4 sticks at 1 from 602 s, and the diagnosers flag it at 605.69 s;
#   4. packs an initramfs: busybox, gardefou, candump and canplayer with
#      their libraries, the can, can-raw, can-dev and vcan modules of the
#      installed Debian kernel, the data, and scripts/qemu-can/init.sh as /init;
#   5. boots that kernel with it (QEMU's TCG emulation by default). The
#      guest creates vcan0, starts `gardefou monitor --can vcan0`, replays the
#      frames with canplayer at their own pace (times QEMU_CAN_SPEED), then
#      runs `gardefou diagnose` on the same frames as a candump file and
#      compares: the same verdict lines (part, verdict, labels, flags,
#      suspects; not times or reasons, which quote measured durations) and
#      def_C4 raised. It powers off;
#   6. prints "qemu-can: PASS" or "qemu-can: FAIL (why)" and exits 0 or 1.
#
# Settings (environment):
#   QEMU_CAN_INSTALL=0   never run apt-get; fail if a package is missing
#   QEMU_CAN_ACCEL=kvm   use KVM (default: tcg, which works everywhere; KVM
#                        nested in a VM hung at boot where this was tried)
#   QEMU_CAN_SPEED=1     how much faster than the log the frames go (default 1)
#   QEMU_CAN_SMP=2       virtual CPUs (default 2: canplayer and the monitor
#                        each get one)
#   QEMU_CAN_TIMEOUT=600 seconds before the VM is stopped (default 600)
#   QEMU_CAN_KEEP=DIR    build the VM's files in DIR and keep them
#
# Usage: sudo scripts/qemu-can.sh

set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
speed="${QEMU_CAN_SPEED:-1}"
timeout_s="${QEMU_CAN_TIMEOUT:-600}"

fail() {
    echo "qemu-can: FAIL ($*)"
    exit 1
}

step() {
    echo "qemu-can: $*"
}

# 1. Packages.
missing=()
for p in qemu-system-x86 linux-image-amd64 can-utils busybox-static; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
    [ "${QEMU_CAN_INSTALL:-1}" = 1 ] || fail "missing packages: ${missing[*]}"
    [ "$(id -u)" -eq 0 ] || fail "missing packages ${missing[*]}; run as root to install them"
    step "installing ${missing[*]}"
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${missing[@]}" >/dev/null ||
        fail "apt-get install ${missing[*]}"
fi
for tool in qemu-system-x86_64 busybox candump canplayer cpio gzip ldd strip; do
    command -v "$tool" >/dev/null || fail "no $tool"
done

# The newest installed Debian kernel that has the vcan module.
kernel=""
for k in $(ls -1 /boot/vmlinuz-* 2>/dev/null | sort -V -r); do
    v="${k#/boot/vmlinuz-}"
    if [ -f "/lib/modules/$v/kernel/drivers/net/can/vcan.ko" ]; then
        kernel="$k"
        version="$v"
        break
    fi
done
[ -n "$kernel" ] || fail "no /boot/vmlinuz-* with an uncompressed vcan.ko in /lib/modules (install linux-image-amd64)"
step "kernel $kernel"

# 2. The binary.
step "cargo build --release"
(cd "$repo" && cargo build --release --quiet) || fail "cargo build --release"
bin="$repo/target/release/gardefou"

if [ -n "${QEMU_CAN_KEEP:-}" ]; then
    work="$QEMU_CAN_KEEP"
    rm -rf "$work"
    mkdir -p "$work"
else
    work="$(mktemp -d)"
    trap 'rm -rf "$work"' EXIT
fi
root="$work/root"
mkdir -p "$root"/{bin,usr/bin,data,modules,proc,sys,dev,tmp}

# Copies a binary and the libraries it loads, at their own paths.
with_libs() {
    local exe="$1" dest="$2" lib
    cp "$exe" "$root$dest"
    for lib in $(ldd "$exe" | grep -o '/[^ ]*'); do
        mkdir -p "$root$(dirname "$lib")"
        cp -L "$lib" "$root$lib"
    done
}
with_libs "$bin" /usr/bin/gardefou
strip "$root/usr/bin/gardefou"
with_libs "$(command -v candump)" /usr/bin/candump
with_libs "$(command -v canplayer)" /usr/bin/canplayer
cp "$(command -v busybox)" "$root/bin/busybox"
file_of_busybox="$(file -b "$root/bin/busybox" 2>/dev/null || true)"
case "$file_of_busybox" in
*"statically linked"* | "") ;;
*) fail "busybox is not static ($file_of_busybox): install busybox-static" ;;
esac
for m in net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko; do
    cp "/lib/modules/$version/kernel/$m" "$root/modules/" || fail "no module $m for $version"
done

# 3. The data.
plant_src="$repo/datasets/data/sorting/normal/plant.toml"
signals() {
    # Names of the signals of one kind, in declaration order.
    awk -v kind="$1" '
        /^\[signals\]/ { on = 1; next }
        /^\[/ { on = 0 }
        on && $0 ~ "kind = \"" kind "\"" { print $1 }
    ' "$plant_src" | tr '\n' ' '
}
sensors="$(signals sensor)"
actuators="$(signals actuator)"
[ -n "$sensors" ] && [ -n "$actuators" ] || fail "no signals found in $plant_src"
{
    cat "$plant_src"
    echo
    echo "# CiA 401: TPDO1 of node 1 carries the inputs, RPDO1 the outputs."
    echo "[can]"
    i=0
    for s in $sensors; do
        echo "$s = { cob_id = 0x181, bit = $i }"
        i=$((i + 1))
    done
    i=0
    for a in $actuators; do
        echo "$a = { cob_id = 0x201, bit = $i }"
        i=$((i + 1))
    done
} >"$root/data/plant.toml"
cp "$repo/diagnoser/tests/fixtures/diagnosis/sorting-model.json" "$root/data/model.json"
frames() {
    awk -v from=600000 -v to=606000 -v speed="$1" -v iface=vcan0 \
        -v sensors="$sensors" -v actuators="$actuators" \
        -f "$here/qemu-can/frames.awk" "$repo/datasets/data/sorting/F2/events.csv"
}
# The log's own times, for `gardefou diagnose`; scaled by the speed, for canplayer.
frames 1 >"$root/data/slice.log"
frames "$speed" >"$root/data/play.log"
# The slice lasts 6 s of log time; the monitor runs that long (over the
# speed) plus a margin for canplayer to start.
duration="$(awk -v s="$speed" 'BEGIN { printf "%d", 6 / s + 10 }')s"
printf 'SPEED=%s\nDURATION=%s\n' "$speed" "$duration" >"$root/data/settings"
cp "$here/qemu-can/init.sh" "$root/init"
chmod +x "$root/init"

# 4. The initramfs.
(cd "$root" && find . | cpio -o -H newc --quiet | gzip -1) >"$work/initramfs.gz" ||
    fail "cannot pack the initramfs"
step "initramfs $(du -h "$work/initramfs.gz" | cut -f1)"

# 5. Boot.
# TCG by default: KVM inside a VM (nested) may hang at boot.
accel="${QEMU_CAN_ACCEL:-tcg}"
step "booting with -accel $accel (timeout ${timeout_s}s)"
console="$work/console.log"
set +e
timeout "$timeout_s" qemu-system-x86_64 -accel "$accel" -m 1024 -smp "${QEMU_CAN_SMP:-2}" -nographic -no-reboot \
    -kernel "$kernel" -initrd "$work/initramfs.gz" \
    -append "console=ttyS0 quiet loglevel=3 panic=-1" </dev/null 2>&1 | tee "$console"
qemu_status="${PIPESTATUS[0]}"
set -e

# 6. Verdict.
guest="$(tr -d '\r' <"$console" | grep -a '^guest: \(PASS\|FAIL\)' | tail -n 1 || true)"
case "$guest" in
"guest: PASS"*) echo "qemu-can: PASS" ;;
"guest: FAIL"*) echo "qemu-can: ${guest#guest: }"; exit 1 ;;
*)
    if [ "$qemu_status" -eq 124 ]; then
        fail "the VM did not finish within ${timeout_s}s"
    fi
    fail "the guest gave no result (qemu exit status $qemu_status)"
    ;;
esac
