"""An OPC UA server replaying a recorded run of a plant, for the monitor's
tests: written on asyncua, with nothing of gardefou's.

    server.py PORT EVENTS_CSV FROM_MS TO_MS SPEED FLAGS
        [--rename SIGNAL=NAME]... [--up FLAG]... [--drop-at MS]

It serves opc.tcp://127.0.0.1:PORT/ (security policy None, anonymous) with
namespace urn:gardefou:test:line. Every signal of the log is a Boolean
variable of the object Objects/Line, NodeId ns=N;s=Line.NAME and browse name
NAME (the signal's name, or the one given with --rename). The flags FLAGS
(comma-separated) are writable Boolean variables of Objects/Line/Flags,
NodeId ns=N;s=Flags.FLAG, down but for those given with --up.

Every variable starts at its value at FROM_MS, with SourceTimestamp FROM_MS
milliseconds after the Unix epoch. A PLC's clock runs from before anyone
reads it: the replay starts when a client first reads a signal, and from
then on sets each change of the log in (FROM_MS, TO_MS] at SPEED times the
log's pace, with SourceTimestamp the log's time. With --drop-at, the
connections of every client are closed once, at the first time at or after
MS (a network failure); the replay goes on.

It prints {"serving": URL, "namespace": N} once listening, {"replay": T}
when the replay starts, {"flag": NAME, "value": V, "t": T} for each write of
a flag variable that the server takes, and {"dropped": T} for a drop. At the
end it waits a second (writes still on their way are served), prints
{"end": TO_MS, "most_late_ms": L} (how far behind the log's pace it fell at
worst, in the log's milliseconds) and stops.
"""

import asyncio
import csv
import json
import sys
import time
from datetime import datetime, timedelta, timezone

from asyncua import Server, ua
from asyncua.common.callback import CallbackType

NAMESPACE = "urn:gardefou:test:line"
EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def say(obj):
    print(json.dumps(obj), flush=True)


def stamp(ms):
    return EPOCH + timedelta(milliseconds=ms)


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


def options(rest):
    renames, up, drop_at = {}, set(), None
    while rest:
        opt, value, rest = rest[0], rest[1], rest[2:]
        if opt == "--rename":
            signal, name = value.split("=", 1)
            renames[signal] = name
        elif opt == "--up":
            up.add(value)
        elif opt == "--drop-at":
            drop_at = int(value)
        else:
            raise SystemExit(f"unknown option {opt}")
    return renames, up, drop_at


class Plant:
    def __init__(self, server, idx, from_ms):
        self.server, self.idx = server, idx
        self.now_ms = from_ms
        self.signals, self.flags = {}, {}
        self.read = asyncio.Event()

    async def build(self, initial, renames, flags, up):
        objects = self.server.nodes.objects
        line = await objects.add_object(ua.NodeId("Line", self.idx), ua.QualifiedName("Line", self.idx))
        for name, value in sorted(initial.items()):
            shown = renames.get(name, name)
            node = await line.add_variable(
                ua.NodeId(f"Line.{shown}", self.idx),
                ua.QualifiedName(shown, self.idx),
                ua.Variant(value, ua.VariantType.Boolean),
            )
            self.signals[name] = node
        folder = await line.add_object(ua.NodeId("Flags", self.idx), ua.QualifiedName("Flags", self.idx))
        for name in flags:
            node = await folder.add_variable(
                ua.NodeId(f"Flags.{name}", self.idx),
                ua.QualifiedName(name, self.idx),
                ua.Variant(name in up, ua.VariantType.Boolean),
            )
            await node.set_writable()
            self.flags[node.nodeid] = name
        for name, value in initial.items():
            await self.set(name, value, self.now_ms)

    async def set(self, name, value, t):
        dv = ua.DataValue(
            ua.Variant(value, ua.VariantType.Boolean),
            SourceTimestamp=stamp(t),
            ServerTimestamp=datetime.now(timezone.utc),
        )
        await self.server.write_attribute_value(self.signals[name].nodeid, dv)

    async def on_read(self, event, _dispatcher):
        nodes = {n.nodeid for n in self.signals.values()}
        if any(r.NodeId in nodes for r in event.request_params.NodesToRead):
            self.read.set()

    async def on_write(self, event, _dispatcher):
        results = event.response_params or []
        for i, w in enumerate(event.request_params.NodesToWrite):
            name = self.flags.get(w.NodeId)
            good = i < len(results) and results[i].is_good()
            if name is not None and good:
                say({"flag": name, "value": bool(w.Value.Value.Value), "t": self.now_ms})


def drop_clients(server):
    """Closes every client's connection, as a network failure would."""
    for protocol in list(server.bserver.clients):
        if protocol.transport is not None:
            protocol.transport.abort()


async def main():
    args = sys.argv[1:]
    port, log, from_ms, to_ms, speed, flags = args[:6]
    from_ms, to_ms, speed = int(from_ms), int(to_ms), float(speed)
    flags = [f for f in flags.split(",") if f]
    renames, up, drop_at = options(args[6:])
    initial, later = read_log(log, from_ms, to_ms)

    server = Server()
    await server.init()
    url = f"opc.tcp://127.0.0.1:{port}/"
    server.set_endpoint(url)
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    idx = await server.register_namespace(NAMESPACE)
    plant = Plant(server, idx, from_ms)
    await plant.build(initial, renames, flags, up)
    server.subscribe_server_callback(CallbackType.PostRead, plant.on_read)
    server.subscribe_server_callback(CallbackType.PostWrite, plant.on_write)
    async with server:
        say({"serving": url, "namespace": idx})
        await plant.read.wait()
        say({"replay": from_ms})
        start = time.monotonic()
        most_late = 0.0
        for t, changes in later:
            due = start + (t - from_ms) / 1000.0 / speed
            pause = due - time.monotonic()
            if pause > 0:
                await asyncio.sleep(pause)
            most_late = max(most_late, (time.monotonic() - due) * 1000.0 * speed)
            if drop_at is not None and t >= drop_at:
                drop_at = None
                drop_clients(server)
                say({"dropped": t})
            plant.now_ms = t
            for name, value in changes:
                await plant.set(name, value, t)
        due = start + (to_ms - from_ms) / 1000.0 / speed
        await asyncio.sleep(max(due - time.monotonic(), 0))
        plant.now_ms = to_ms
        # Writes still on their way are served before the server goes.
        await asyncio.sleep(1.0)
        say({"end": to_ms, "most_late_ms": most_late})


if __name__ == "__main__":
    asyncio.run(main())
