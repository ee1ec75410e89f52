#!/bin/busybox sh
# /init of the qemu-can.sh guest: a real SocketCAN bus (vcan0), gardefou
# monitoring it, canplayer replaying the F2 slice onto it. Prints
# "guest: PASS" or "guest: FAIL (why)" and powers off.
# Settings come from /data/settings (written by qemu-can.sh).

/bin/busybox --install -s /bin
export PATH=/bin:/usr/bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev
mkdir -p /tmp
mount -t tmpfs tmpfs /tmp
. /data/settings

result() {
    echo "guest: $1"
    sync
    poweroff -f
    # Should poweroff fail, the host's timeout still ends the VM.
    sleep 600
}

step() { echo "guest: $*"; }

step "kernel $(uname -r)"
for m in can can-raw can-dev vcan; do
    insmod "/modules/$m.ko" || result "FAIL (insmod $m)"
done
ip link add dev vcan0 type vcan || result "FAIL (ip link add vcan0)"
ip link set up vcan0 || result "FAIL (ip link set up vcan0)"
step "vcan0 up: $(ip link show vcan0 | head -n 1)"

candump -L vcan0 > /tmp/bus.log &
dump=$!

gardefou monitor --plant /data/plant.toml --model /data/model.json \
    --can vcan0 --speed "$SPEED" --duration "$DURATION" \
    > /tmp/online.jsonl 2> /tmp/online.err &
monitor=$!

# Wait for the monitor to say it reads vcan0 (it has opened the socket).
i=0
until grep -q "reading CAN frames from vcan0" /tmp/online.err 2>/dev/null; do
    i=$((i + 1))
    if [ "$i" -gt 600 ] || ! kill -0 "$monitor" 2>/dev/null; then
        cat /tmp/online.err
        result "FAIL (the monitor did not open vcan0)"
    fi
    sleep 0.1
done
step "$(head -n 1 /tmp/online.err)"

step "replaying $(wc -l < /data/play.log) frames with canplayer"
canplayer -I /data/play.log || result "FAIL (canplayer)"
wait "$monitor"
status=$?
kill "$dump" 2>/dev/null
wait "$dump" 2>/dev/null

echo "guest: --- monitor stderr"
cat /tmp/online.err
echo "guest: --- monitor verdicts (--can vcan0)"
cat /tmp/online.jsonl
echo "guest: --- frames seen on vcan0 (candump -L): $(wc -l < /tmp/bus.log)"
# How late each frame went on the bus against canplayer's schedule (relative
# to the first frame): the jitter the monitor's clock saw.
awk 'NR == FNR { gsub(/[()]/, "", $1); want[FNR] = $1; next }
     { gsub(/[()]/, "", $1); if (FNR == 1) { w0 = want[1]; b0 = $1 }
       d = ($1 - b0) - (want[FNR] - w0); if (d < 0) d = -d; if (d > max) max = d }
     END { printf "guest: largest frame delay against the schedule: %.3f ms\n", max * 1000 }' \
    /data/play.log /tmp/bus.log

gardefou diagnose --plant /data/plant.toml --model /data/model.json /data/slice.log \
    > /tmp/offline.jsonl 2> /tmp/offline.err || {
    cat /tmp/offline.err
    result "FAIL (gardefou diagnose on the candump slice)"
}
echo "guest: --- offline verdicts (gardefou diagnose on the same frames as a candump -L file)"
cat /tmp/offline.jsonl

# Verdicts without their times and reasons (a reason quotes measured durations).
shape() {
    sed -e 's/^{"t":[^,]*,//' -e 's/"reason":"[^"]*"//' "$1"
}
shape /tmp/online.jsonl > /tmp/online.shape
shape /tmp/offline.jsonl > /tmp/offline.shape

[ "$status" -eq 0 ] || result "FAIL (the monitor exited with status $status)"
grep -q '"flags":\["def_C4"\]' /tmp/online.jsonl || result "FAIL (no def_C4 from the monitor)"
grep -q "flags: def_C4" /tmp/online.err || result "FAIL (the monitor's summary has no def_C4)"
if grep -q "^warning:" /tmp/online.err; then
    result "FAIL (the monitor warned: $(grep '^warning:' /tmp/online.err | head -n 1))"
fi
if cmp -s /tmp/online.shape /tmp/offline.shape; then
    result "PASS (the $(wc -l < /tmp/offline.shape) verdict lines of the offline path, def_C4 raised)"
fi
# Every offline line must come online, in order; extra online lines come from
# the live clock's jitter against windows learned at exact scan times.
missing=$(awk 'NR == FNR { off[++n] = $0; next } i < n && $0 == off[i + 1] { i++ }
    END { print n - i }' /tmp/offline.shape /tmp/online.shape)
[ "$missing" -eq 0 ] || result "FAIL ($missing offline verdict lines missing online, or out of order)"
extra=$(( $(wc -l < /tmp/online.shape) - $(wc -l < /tmp/offline.shape) ))
echo "guest: note: $extra verdict lines online beyond the offline ones (the live clock's jitter):"
diff /tmp/offline.shape /tmp/online.shape | grep '^+"' || true
result "PASS (every offline verdict line online, in order, def_C4 raised; $extra extra)"
