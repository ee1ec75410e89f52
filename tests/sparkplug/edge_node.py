"""A Sparkplug B edge node replaying a recorded run of a plant, for the
monitor's tests: written on paho-mqtt and pysparkplug's payloads, with
nothing of gardefou's.

    edge_node.py PORT EVENTS_CSV FROM_MS TO_MS SPEED GROUP/EDGE/DEVICE FLAGS
        [--gap-at MS] [--up FLAG]...

It connects to the broker on 127.0.0.1:PORT with an NDEATH will, publishes
NBIRTH (seq 0, bdSeq) and DBIRTH: every signal of the log, at its value at
FROM_MS, and the flags FLAGS (comma-separated) as boolean metrics, down but
for those given with --up. Then it publishes one DDATA per time of the log
in (FROM_MS, TO_MS], by alias, stamped with the log's time, at SPEED times
the log's pace, and a last DDATA without metrics at TO_MS. With --gap-at, the
first DDATA at or after MS skips one sequence number.

A DCMD writing a flag metric sets it, prints {"flag": NAME, "value": V,
"t": T} and publishes the new value in a DDATA. An NCMD with
"Node Control/Rebirth" publishes the births again (seq from 0), with the
values of the moment, and prints {"rebirth": T}. At the end it prints
{"end": TO_MS, "most_late_ms": L} (how far behind the log's pace it fell at
worst, in the log's milliseconds), publishes NDEATH and disconnects.
"""

import csv
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from pysparkplug import DataType, DBirth, DCmd, DData, Metric, NBirth, NCmd, NDeath

REBIRTH = "Node Control/Rebirth"


def say(obj):
    print(json.dumps(obj), flush=True)


def read_log(path, from_ms, to_ms):
    """Values at from_ms, and the changes after it up to to_ms by time."""
    initial, later = {}, {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if not row["signal"]:
                continue
            t, name, value = int(row["t"]), row["signal"], row["value"] == "1"
            if t <= from_ms:
                initial[name] = value
            elif t <= to_ms:
                later.setdefault(t, []).append((name, value))
    return initial, sorted(later.items())


class Node:
    def __init__(self, port, group, edge, device, values, flags, up):
        self.group, self.edge, self.device = group, edge, device
        self.values = dict(values)
        self.flags = {f: (f in up) for f in flags}
        names = sorted(self.values) + flags
        self.alias = {name: i + 1 for i, name in enumerate(names)}
        self.lock = threading.Lock()
        self.seq = 0
        self.bd_seq = 0
        self.now_ms = 0
        self.client = mqtt.Client(client_id=f"edge-{edge}", clean_session=True)
        death = NDeath(timestamp=None, bd_seq_metric=self.bd_seq_metric())
        self.client.will_set(self.topic("NDEATH"), death.encode(), qos=1)
        self.client.on_message = self.on_message
        self.client.connect("127.0.0.1", port, keepalive=5)
        self.client.subscribe(self.topic("NCMD"), qos=1)
        self.client.subscribe(self.topic("DCMD", device=True), qos=1)
        self.client.loop_start()

    def topic(self, kind, device=False):
        t = f"spBv1.0/{self.group}/{kind}/{self.edge}"
        return f"{t}/{self.device}" if device else t

    def bd_seq_metric(self):
        return Metric(timestamp=None, name="bdSeq", datatype=DataType.UINT64, value=self.bd_seq)

    def next_seq(self):
        s = self.seq
        self.seq = (self.seq + 1) % 256
        return s

    def metric(self, name, value, t, birth):
        return Metric(
            timestamp=t,
            name=name if birth else None,
            alias=self.alias[name],
            datatype=DataType.BOOLEAN,
            value=value,
        )

    def births(self, t):
        """NBIRTH and DBIRTH; the caller holds the lock."""
        self.seq = 0
        nbirth = NBirth(timestamp=t, seq=self.next_seq(), metrics=(self.bd_seq_metric(),))
        self.client.publish(self.topic("NBIRTH"), nbirth.encode(), qos=0)
        metrics = [self.metric(n, v, t, True) for n, v in sorted(self.values.items())]
        metrics += [self.metric(n, v, t, True) for n, v in self.flags.items()]
        dbirth = DBirth(timestamp=t, seq=self.next_seq(), metrics=tuple(metrics))
        self.client.publish(self.topic("DBIRTH", device=True), dbirth.encode(), qos=0)

    def data(self, t, changes, skip=False):
        with self.lock:
            self.now_ms = t
            for name, value in changes:
                (self.flags if name in self.flags else self.values)[name] = value
            if skip:
                self.next_seq()
            metrics = tuple(self.metric(n, v, t, False) for n, v in changes)
            payload = DData(timestamp=t, seq=self.next_seq(), metrics=metrics)
            self.client.publish(self.topic("DDATA", device=True), payload.encode(), qos=0)

    def on_message(self, _client, _userdata, message):
        kind = message.topic.split("/")[2]
        if kind == "NCMD":
            cmd = NCmd.decode(message.payload)
            if any(m.name == REBIRTH and m.value for m in cmd.metrics):
                with self.lock:
                    say({"rebirth": self.now_ms})
                    self.births(self.now_ms)
        elif kind == "DCMD":
            cmd = DCmd.decode(message.payload)
            written = [(m.name, bool(m.value)) for m in cmd.metrics if m.name in self.flags]
            for name, value in written:
                say({"flag": name, "value": value, "t": self.now_ms})
            if written:
                self.data(self.now_ms, written)

    def end(self):
        with self.lock:
            death = NDeath(timestamp=self.now_ms, bd_seq_metric=self.bd_seq_metric())
            info = self.client.publish(self.topic("NDEATH"), death.encode(), qos=1)
        info.wait_for_publish(5)
        self.client.disconnect()
        self.client.loop_stop()


def main():
    args = sys.argv[1:]
    port, log, from_ms, to_ms, speed, target, flags = args[:7]
    from_ms, to_ms, speed = int(from_ms), int(to_ms), float(speed)
    group, edge, device = target.split("/")
    rest = args[7:]
    gap_at, up = None, set()
    while rest:
        opt, value, rest = rest[0], rest[1], rest[2:]
        if opt == "--gap-at":
            gap_at = int(value)
        elif opt == "--up":
            up.add(value)
    initial, later = read_log(log, from_ms, to_ms)
    node = Node(int(port), group, edge, device, initial, [f for f in flags.split(",") if f], up)
    with node.lock:
        node.now_ms = from_ms
        node.births(from_ms)
    say({"serving": target})
    start = time.monotonic()
    most_late = 0.0
    for t, changes in later + [(to_ms, [])]:
        due = start + (t - from_ms) / 1000.0 / speed
        pause = due - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        most_late = max(most_late, (time.monotonic() - due) * 1000.0 * speed)
        skip = gap_at is not None and t >= gap_at
        if skip:
            gap_at = None
        node.data(t, changes, skip)
    # Commands still on their way are served before the node goes.
    time.sleep(1.0)
    say({"end": to_ms, "most_late_ms": most_late})
    node.end()


if __name__ == "__main__":
    main()
