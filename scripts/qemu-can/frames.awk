# frames.awk: a slice of an events log (t,signal,value; t in ms) as `candump -L`
# lines of CANopen (CiA 401) PDOs: sensors on TPDO1 of node 1 (0x181), actuators
# on RPDO1 (0x201), each in plant-file declaration order from bit 0 (the [can]
# table that qemu-can.sh appends to the plant file).
#
# Variables (awk -v): from, to (ms: the slice), speed (the candump times run
# that much faster than the log), iface, sensors, actuators (signal names,
# space-separated, in declaration order).
#
# The values at `from` go out as both PDOs; then, at each later time with
# changes, the PDOs carrying them (TPDO1 first), with their whole image.

function hex_image(names, n,    i, bytes, out, b, byte) {
    out = ""
    bytes = int((n + 7) / 8)
    for (b = 0; b < bytes; b++) {
        byte = 0
        for (i = 0; i < 8 && b * 8 + i < n; i++)
            if (value[names[b * 8 + i + 1]] == 1)
                byte += 2 ^ i
        out = out sprintf("%02X", byte)
    }
    return out
}

function stamp(t,    s) {
    s = 1700000000 + (t - from) / 1000.0 / speed
    return sprintf("(%.6f)", s)
}

function emit(t, tpdo, rpdo) {
    if (tpdo) printf "%s %s 181#%s\n", stamp(t), iface, hex_image(sn, ns)
    if (rpdo) printf "%s %s 201#%s\n", stamp(t), iface, hex_image(an, na)
}

BEGIN {
    FS = ","
    ns = split(sensors, sn, " ")
    na = split(actuators, an, " ")
    for (i = 1; i <= ns; i++) kind[sn[i]] = "s"
    for (i = 1; i <= na; i++) kind[an[i]] = "a"
    started = 0
    pending = -1
}

NR == 1 { next }

{
    t = $1 + 0
    if (t < from) { value[$2] = $3 + 0; next }
    if (t > to) exit
    if (!started) { emit(from, 1, 1); started = 1 }
    if (t != pending && pending >= 0) { emit(pending, ts, ta); ts = 0; ta = 0 }
    pending = t
    value[$2] = $3 + 0
    if (kind[$2] == "s") ts = 1; else ta = 1
}

END {
    if (!started) emit(from, 1, 1)
    if (pending >= 0) emit(pending, ts, ta)
}
