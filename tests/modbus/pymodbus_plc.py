"""An independent Modbus TCP server (pymodbus) standing in for a PLC.

It serves a recorded run of a plant with the default register map of
gardefou's plant files (sensors: discrete inputs 0, 1, ... in file order;
actuators: coils 0, 1, ...; flags: coils from 100, every def_ flag in
partition order, then every suspect_ flag), replaying the log's events between
two times at a chosen speed. Every flag coil a client writes is printed on
stdout as one JSON line, e.g. {"flag": "def_C4", "coil": 100, "value": true};
the last line gives how far behind the log's times the replay fell at worst,
e.g. {"end": true, "most_late_ms": 1.2}.

Usage: pymodbus_plc.py PLANT.toml EVENTS.csv PORT FROM_MS TO_MS SPEED [FLAG...]

The FLAGs given are up from the start (as an earlier monitor left them).
"""

import asyncio
import csv
import json
import sys
import time
import tomllib

from pymodbus.datastore import (
    ModbusSequentialDataBlock,
    ModbusServerContext,
    ModbusSlaveContext,
)
from pymodbus.server import StartAsyncTcpServer

FLAGS_FROM = 100


def register_map(plant):
    places = {}
    inputs = coils = 0
    for name, signal in plant["signals"].items():
        if signal["kind"] == "sensor":
            places[name] = ("di", inputs)
            inputs += 1
        else:
            places[name] = ("co", coils)
            coils += 1
    partitions = list(plant.get("partitions", {}).keys())
    flags = [f"def_{p}" for p in partitions] + [f"suspect_{p}" for p in partitions]
    flag_coils = {FLAGS_FROM + i: f for i, f in enumerate(flags)}
    return places, flag_coils


class Device(ModbusSlaveContext):
    """Prints the flag coils that clients write (function codes 5 and 15)."""

    def __init__(self, flag_coils, **kwargs):
        super().__init__(**kwargs)
        self.flag_coils = flag_coils

    def setValues(self, fc_as_hex, address, values):
        super().setValues(fc_as_hex, address, values)
        if fc_as_hex in (5, 15):
            for i, v in enumerate(values):
                flag = self.flag_coils.get(address + i)
                if flag is not None:
                    print(json.dumps({"flag": flag, "coil": address + i, "value": bool(v)}), flush=True)


async def replay(device, places, events, start_ms, end_ms, speed):
    origin = time.monotonic()
    # How far behind the log's times an event was served at worst, in the
    # log's milliseconds: a loaded machine makes the replay late, and a late
    # edge is a different run for any observer.
    most_late_ms = 0.0
    for t, name, value in events:
        if t <= start_ms:
            continue
        if t > end_ms:
            break
        due = (t - start_ms) / 1000.0 / speed
        delay = due - (time.monotonic() - origin)
        if delay > 0:
            await asyncio.sleep(delay)
        table, address = places[name]
        device.setValues(2 if table == "di" else 1, address, [value])
        late = (time.monotonic() - origin - due) * 1000.0 * speed
        most_late_ms = max(most_late_ms, late)
    await asyncio.sleep(2.0)
    print(json.dumps({"end": True, "most_late_ms": round(most_late_ms, 3)}), flush=True)
    asyncio.get_running_loop().stop()


async def main():
    plant_path, events_path, port, start_ms, end_ms, speed = sys.argv[1:7]
    preset = sys.argv[7:]
    start_ms, end_ms, speed = float(start_ms), float(end_ms), float(speed)
    with open(plant_path, "rb") as f:
        plant = tomllib.load(f)
    places, flag_coils = register_map(plant)
    with open(events_path, newline="") as f:
        rows = [(float(r["t"]), r["signal"], r["value"] == "1") for r in csv.DictReader(f)]
    device = Device(
        flag_coils,
        di=ModbusSequentialDataBlock(0, [False] * 64),
        co=ModbusSequentialDataBlock(0, [False] * 256),
        zero_mode=True,
    )
    for coil, flag in flag_coils.items():
        if flag in preset:
            device.setValues(1, coil, [True])
    # The state at the start time: every event up to it.
    for t, name, value in rows:
        if t > start_ms:
            break
        table, address = places[name]
        device.setValues(2 if table == "di" else 1, address, [value])
    asyncio.get_running_loop().create_task(
        replay(device, places, rows, start_ms, end_ms, speed)
    )
    print(json.dumps({"serving": int(port)}), flush=True)
    await StartAsyncTcpServer(
        context=ModbusServerContext(slaves=device, single=True),
        address=("127.0.0.1", int(port)),
    )


if __name__ == "__main__":
    try:
        asyncio.run(main())
    except RuntimeError:
        # The replay stops the loop when it is done.
        pass
