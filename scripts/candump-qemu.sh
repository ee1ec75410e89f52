#!/usr/bin/env bash
# candump-qemu.sh — capture a real `candump -L` log from a virtual CAN bus.
#
# OPT-IN, MANUAL: no CI job runs this script, and no test depends on it. The
# candump fixtures under logs/tests/fixtures/candump/ are written by hand in
# candump's exact output format; this script is how to check that format
# against the real can-utils on a kernel that has CAN, which the development
# machines (and CI containers) usually lack: their kernels have no `vcan`
# module, and creating a network device needs root (CAP_NET_ADMIN) anyway.
#
# What it does, in a Linux with the vcan module and can-utils (a laptop, a
# VM, or the QEMU guest described below):
#   1. loads vcan and creates the virtual bus:  ip link add dev vcan0 type vcan
#   2. starts                                   candump -L vcan0 > OUT
#   3. plays one turntable cycle of the sorting line with cansend, as a CANopen
#      (CiA 401) I/O node would put it on the bus:
#        - TPDO1 of node 1 (COB-ID 0x181), byte 0: bit 0 = C4, bit 1 = C5
#        - RPDO1 of node 1 (COB-ID 0x201), byte 1: bit 0 = A4 (bit 8 overall)
#      plus an NMT heartbeat (0x701), a remote frame and a CAN FD frame if the
#      interface takes them, which the reader must skip or accept;
#   4. stops candump and prints the log.
# The log reads with this plant fragment (see logs/tests/it/text_forms.rs):
#   [can]
#   C4 = { cob_id = 0x181, bit = 0 }
#   C5 = { cob_id = 0x181, bit = 1 }
#   A4 = { cob_id = 0x201, bit = 8 }
#
# Usage:
#   scripts/candump-qemu.sh help              this text
#   scripts/candump-qemu.sh check             what is missing here, and why
#   sudo scripts/candump-qemu.sh capture OUT  steps 1-4 on this machine
#   scripts/candump-qemu.sh qemu DISK.qcow2   boot DISK in QEMU with this
#                                             repository shared at /mnt/gardefou
#
# With QEMU (when this machine's kernel has no CAN):
#   - get a cloud or installer image of a distribution whose stock kernel has
#     CONFIG_CAN_VCAN=m (Debian, Ubuntu, Fedora all do), e.g. the Debian
#     "nocloud" qcow2 image, whose root account has no password;
#   - run `scripts/candump-qemu.sh qemu debian-12-nocloud-amd64.qcow2`
#     (qemu-system-x86_64; KVM is used when /dev/kvm is usable);
#   - in the guest, as root:
#       apt-get install -y can-utils iproute2
#       mkdir -p /mnt/gardefou
#       mount -t 9p -o trans=virtio gardefou /mnt/gardefou
#       /mnt/gardefou/scripts/candump-qemu.sh capture /mnt/gardefou/target/vcan0.log
#       poweroff
#   - the log is then in target/vcan0.log on the host. Compare its lines with
#     logs/tests/fixtures/candump/good.log, and read it with a plant file
#     holding the [can] table above.
#
# Nothing here is run by `cargo test`; `bash -n scripts/candump-qemu.sh` is the
# only check the script gets automatically.

set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
iface="${VCAN:-vcan0}"

usage() {
    # The header comment above, without its leading '# '.
    sed -n '2,/^$/{s/^# \{0,1\}//;p}' "${BASH_SOURCE[0]}"
}

have() {
    command -v "$1" >/dev/null 2>&1
}

check() {
    local missing=0
    for tool in ip candump cansend; do
        if have "$tool"; then
            echo "ok       $tool: $(command -v "$tool")"
        else
            echo "missing  $tool (ip: iproute2; candump, cansend: can-utils)"
            missing=1
        fi
    done
    if [ -d "/sys/module/vcan" ] || modinfo vcan >/dev/null 2>&1; then
        echo "ok       vcan kernel module"
    else
        echo "missing  vcan kernel module: this kernel ($(uname -r)) has no virtual CAN;"
        echo "         use the QEMU procedure ($0 help)"
        missing=1
    fi
    if [ "$(id -u)" -ne 0 ]; then
        echo "note     'capture' needs root to create $iface"
    fi
    if have qemu-system-x86_64; then
        echo "ok       qemu-system-x86_64 (for the 'qemu' procedure)"
    else
        echo "note     no qemu-system-x86_64 (only needed for the 'qemu' procedure)"
    fi
    return "$missing"
}

# cansend with a pause, so that candump's timestamps are spread like a PLC's.
send() {
    cansend "$iface" "$1"
    sleep "${2:-0.05}"
}

# Set by `capture`, read by `cleanup`.
dump=""
created=0

cleanup() {
    if [ -n "$dump" ]; then
        kill "$dump" 2>/dev/null || true
        wait "$dump" 2>/dev/null || true
    fi
    if [ "$created" -eq 1 ]; then
        ip link del "$iface" 2>/dev/null || true
    fi
}

capture() {
    local out="$1"
    check >/dev/null || { check; exit 1; }
    [ "$(id -u)" -eq 0 ] || { echo "capture: run as root (creating $iface needs CAP_NET_ADMIN)" >&2; exit 1; }

    modprobe vcan
    if ! ip link show "$iface" >/dev/null 2>&1; then
        ip link add dev "$iface" type vcan
        created=1
    fi
    # CAN FD frames need an MTU of 72; a vcan takes it, older kernels may not.
    local fd=0
    if ip link set "$iface" mtu 72 2>/dev/null; then
        fd=1
    fi
    ip link set up "$iface"

    candump -L "$iface" >"$out" &
    dump=$!
    # Stop candump and remove the bus we created, however we leave (globals:
    # the trap runs after this function's locals are gone).
    trap cleanup EXIT
    sleep 0.2

    send 701#05                 # heartbeat of node 1 (operational): not mapped
    send 181#01                 # C4 = 1, C5 = 0: the turntable at loading position
    send 201#0000               # A4 = 0
    send 201#0001 0.08          # RE(A4): rotate towards unloading
    send 181#00 2.9             # FE(C4) 80 ms later; rotation takes about 2.9 s
    send 181#02                 # RE(C5): at unloading position
    send 181#R                  # a remote request for TPDO1: no data, skipped
    send 201#0000 0.08          # FE(A4): return
    send 181#00 2.9             # FE(C5)
    if [ "$fd" -eq 1 ]; then
        send 181##101           # RE(C4), as a CAN FD frame with BRS set
    else
        send 181#01             # RE(C4)
    fi
    send 12345678#DEADBEEF      # an extended frame that is not mapped

    sleep 0.2
    kill "$dump"
    wait "$dump" 2>/dev/null || true
    dump=""
    echo "captured $(wc -l <"$out") frames in $out:" >&2
    cat "$out"
}

qemu() {
    local disk="$1"
    have qemu-system-x86_64 || { echo "qemu: qemu-system-x86_64 not found" >&2; exit 1; }
    [ -f "$disk" ] || { echo "qemu: no disk image '$disk'" >&2; exit 1; }
    local accel=()
    if [ -w /dev/kvm ]; then
        accel=(-enable-kvm -cpu host)
    fi
    mkdir -p "$repo/target"
    echo "booting $disk; in the guest, see '$0 help' (the repository is shared as 9p tag 'gardefou')" >&2
    # -snapshot: the image is left unchanged; only target/vcan0.log comes back.
    exec qemu-system-x86_64 "${accel[@]}" -m 1024 -smp 2 -nographic -snapshot \
        -drive "file=$disk,if=virtio" \
        -virtfs "local,path=$repo,mount_tag=gardefou,security_model=none" \
        -nic user,model=virtio-net-pci
}

case "${1:-help}" in
    help | -h | --help) usage ;;
    check) check ;;
    capture)
        [ $# -eq 2 ] || { echo "usage: $0 capture OUT.log" >&2; exit 2; }
        capture "$2"
        ;;
    qemu)
        [ $# -eq 2 ] || { echo "usage: $0 qemu DISK.qcow2" >&2; exit 2; }
        qemu "$2"
        ;;
    *)
        echo "unknown command '$1' (help, check, capture, qemu)" >&2
        exit 2
        ;;
esac
