#!/usr/bin/env python3
"""Writes the fuzz targets' seed corpora (fuzz/corpus/TARGET/) afresh.

The seeds come from what the project ships: the first minutes of the shipped
sorting-line and cylinder-rig logs (datasets/data), kept to the turntable's
signals (C4, C5, A4: the plant of the log targets, see src/lib.rs) and written
in every log form; the fixtures of the readers' own tests; the shipped plant
files; a model learned from the shipped normal log; libFAUDES's files. Parquet
seeds are written by pyarrow, a writer independent of the one under test.

    python3 -m venv /tmp/seeds && /tmp/seeds/bin/pip install pyarrow==26.0.1
    /tmp/seeds/bin/python fuzz/seeds.py target/release/gardefou

The model seed needs a built gardefou (its path is the argument). Inputs
the fuzzer found that are worth keeping as seeds are named `found-*` and stay.
"""

import csv
import json
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"
SIGNALS = ["C4", "C5", "A4"]
SHIPPED = [
    "sorting/normal", "sorting/F2", "sorting/F5", "sorting/F7", "sorting/F11",
]


def shipped_events(run, limit=60):
    """Initial values and the first `limit` events of the turntable's signals."""
    rows = list(csv.DictReader(open(ROOT / "datasets/data" / run / "events.csv")))
    t0 = int(rows[0]["t"])
    initial = {r["signal"]: r["value"] == "1" for r in rows if int(r["t"]) == t0}
    events = [
        (int(r["t"]), r["signal"], r["value"] == "1")
        for r in rows
        if r["signal"] in SIGNALS and int(r["t"]) > t0
    ][:limit]
    return t0, {s: initial[s] for s in SIGNALS}, events


def events_csv(t0, initial, events):
    lines = ["t,signal,value"] + [f"{t0},{s},{int(v)}" for s, v in initial.items()]
    lines += [f"{t},{s},{int(v)}" for t, s, v in events]
    return "\n".join(lines) + "\n"


def intervals(t0, initial, events):
    """(signal, value, t_start, t_end) rows, in t_end order, the last ones open."""
    current = {s: (v, t0) for s, v in initial.items()}
    rows = []
    for t, s, v in events:
        value, start = current[s]
        rows.append((s, value, start, t))
        current[s] = (v, t)
    rows += [(s, v, start, None) for s, (v, start) in current.items()]
    return rows


def intervals_csv(rows):
    lines = ["signal,value,t_start,t_end"]
    lines += [f"{s},{int(v)},{a},{'' if b is None else b}" for s, v, a, b in rows]
    return "\n".join(lines) + "\n"


def scans(t0, initial, events):
    """A row at the start, then at each event's time and one scan later."""
    values, out, times = dict(initial), [], sorted({t0} | {t for t, _, _ in events})
    rows = sorted(set(times) | {t + 10 for t in times})
    i = 0
    for t in rows:
        while i < len(events) and events[i][0] <= t:
            values[events[i][1]] = events[i][2]
            i += 1
        out.append((t, dict(values)))
    return out


def scans_csv(rows):
    lines = ["t," + ",".join(SIGNALS)]
    lines += [f"{t}," + ",".join(str(int(v[s])) for s in SIGNALS) for t, v in rows]
    return "\n".join(lines) + "\n"


def candump(t0, initial, events, epoch=1_436_509_052_000):
    """TPDO 0x181 (C4 bit 0, C5 bit 1) and RPDO 0x201 (A4 bit 8), sent on change."""
    values, lines = dict(initial), []

    def frames(t):
        stamp = f"({(epoch + t) / 1000:.6f})"
        sensors = int(values["C4"]) | int(values["C5"]) << 1
        lines.append(f"{stamp} can0 181#{sensors:02X}")
        lines.append(f"{stamp} can0 201#00{int(values['A4']):02X}")

    lines.append(f"({(epoch + t0) / 1000:.6f}) can0 701#05")
    frames(t0)
    for t, s, v in events:
        values[s] = v
        frames(t)
    return "\n".join(lines) + "\n"


def vcd(t0, initial, events):
    codes = {"C4": "!", "C5": '"', "A4": "#"}
    head = ["$timescale 1 ms $end", "$scope module plant $end"]
    head += [f"$var wire 1 {codes[s]} {s} $end" for s in SIGNALS]
    head += ["$upscope $end", "$enddefinitions $end", f"#{t0}", "$dumpvars"]
    head += [f"{int(v)}{codes[s]}" for s, v in initial.items()] + ["$end"]
    body, last = [], t0
    for t, s, v in events:
        if t != last:
            body.append(f"#{t}")
            last = t
        body.append(f"{int(v)}{codes[s]}")
    return "\n".join(head + body) + "\n"


def stdin_lines(t0, initial, events):
    lines = [json.dumps({"t": t0, "signal": s, "value": int(v)}) for s, v in initial.items()]
    for t, s, v in events:
        lines.append(json.dumps({"t": t, "signal": s, "value": bool(v)}))
        lines.append(json.dumps({"t": t + 5}))
    return "\n".join(lines) + "\n"


def parquet_seeds(name, t0, initial, events):
    """Each Parquet form, with the variants the reader accepts."""
    ev = [(t0, s, v) for s, v in initial.items()] + events
    out = {}
    tables = {
        "events": pa.table({
            "t": pa.array([t for t, _, _ in ev], pa.int64()),
            "signal": pa.array([s for _, s, _ in ev]).dictionary_encode(),
            "value": pa.array([v for _, _, v in ev], pa.bool_()),
        }),
        "events_text": pa.table({
            "t": pa.array([float(t) for t, _, _ in ev]),
            "signal": pa.array([s for _, s, _ in ev]),
            "value": pa.array(["1" if v else "0" for _, _, v in ev]),
        }),
    }
    rows = intervals(t0, initial, events)
    tables["intervals"] = pa.table({
        "signal": pa.array([r[0] for r in rows]),
        "value": pa.array([int(r[1]) for r in rows], pa.int64()),
        "t_start": pa.array([r[2] for r in rows], pa.int64()),
        "t_end": pa.array([r[3] for r in rows], pa.int64()),
    })
    srows = scans(t0, initial, events)
    columns = {"t": pa.array([t for t, _ in srows], pa.int64())}
    columns.update({s: pa.array([v[s] for _, v in srows], pa.bool_()) for s in SIGNALS})
    tables["scans"] = pa.table(columns)
    for form, table in tables.items():
        path = CORPUS / "parquet" / f"{name}_{form}.parquet"
        # Small row groups, so that the reader crosses them.
        pq.write_table(table, path, row_group_size=16, compression="snappy")
        out[form] = path
    return out


def copy_all(target, pattern_dirs):
    for directory, pattern in pattern_dirs:
        for f in sorted((ROOT / directory).glob(pattern)):
            shutil.copy(f, CORPUS / target / f"{Path(directory).name}_{f.name}")


def modbus_seeds():
    """Requests a Modbus TCP client sends: reads and writes of every kind."""
    def adu(transaction, pdu):
        return struct.pack(">HHHB", transaction, 0, len(pdu) + 1, 1) + pdu

    requests = {
        "read_coils": struct.pack(">BHH", 1, 0, 8),
        "read_inputs": struct.pack(">BHH", 2, 0, 3),
        "write_coil": struct.pack(">BHH", 5, 0, 0xFF00),
        "write_coils": struct.pack(">BHHB", 15, 0, 3, 1) + b"\x05",
        "write_registers": struct.pack(">BHHB", 16, 0, 1, 2) + b"\x00\x01",
        "read_holding": struct.pack(">BHH", 3, 0, 2),
    }
    for i, (name, pdu) in enumerate(requests.items()):
        (CORPUS / "modbus_requests" / name).write_bytes(adu(i, pdu))
    session = b"".join(adu(i, pdu) for i, pdu in enumerate(requests.values()))
    (CORPUS / "modbus_requests" / "session").write_bytes(session)


def expressions():
    exprs = set()
    for plant in sorted((ROOT / "datasets/data").glob("*/normal/plant.toml")):
        for line in plant.read_text().splitlines():
            for key in ("expr = ", "set = ", "reset = ", "toggle = "):
                for part in line.split(key)[1:]:
                    exprs.add(part.split('"')[1])
    for i, e in enumerate(sorted(exprs)):
        (CORPUS / "expression" / f"{i:03}").write_text(e)


def gen_products():
    """Plants of two or three components, joined by NUL bytes: the tutorial's
    generators paired, and turntables (independent, or sharing an event)."""
    faudes = ROOT / "diagnoser/tests/fixtures/faudes"
    gens = sorted(faudes.glob("*.gen"))
    out = CORPUS / "gen_product"
    for i, (a, b) in enumerate(zip(gens, gens[1:] + gens[:1])):
        (out / f"pair_{i:02}").write_bytes(a.read_bytes() + b"\0" + b.read_bytes())

    def turntable(i, shared):
        release = "go" if shared else f"r_{i}"
        return (f'<Generator> "t{i}" <Alphabet> a_{i} c5_{i} {release} c4_{i} f_{i} +o+ m_{i} +o+ '
                f"</Alphabet> <States> 1 2 3 4 5 6 7 8 </States> <TransRel> "
                f"1 a_{i} 2 2 c5_{i} 3 3 {release} 4 4 c4_{i} 1 1 f_{i} 5 "
                f"5 a_{i} 6 6 m_{i} 7 7 {release} 8 8 c4_{i} 5 </TransRel> "
                f"<InitStates> 1 </InitStates> </Generator>\n")
    for shared in (False, True):
        for n in (2, 3):
            text = "\0".join(turntable(i, shared) for i in range(n))
            (out / f"turntables_{n}_{'shared' if shared else 'apart'}").write_text(text)


def main():
    gardefou = sys.argv[1] if len(sys.argv) > 1 else str(ROOT / "target/release/gardefou")
    targets = ["events_csv", "intervals_csv", "scans_csv", "parquet", "candump", "vcd",
               "detect", "plant_toml", "model_json", "gen", "failure_map", "stdin_lines",
               "modbus_requests", "expression", "gen_product"]
    for t in targets:
        (CORPUS / t).mkdir(parents=True, exist_ok=True)
        # Inputs the fuzzer found (`found-*`) stay; the seeds are written anew.
        for f in (CORPUS / t).iterdir():
            if not f.name.startswith("found-"):
                f.unlink()
    for run in SHIPPED:
        name = run.replace("/", "_")
        t0, initial, events = shipped_events(run)
        forms = {
            "events_csv": events_csv(t0, initial, events),
            "intervals_csv": intervals_csv(intervals(t0, initial, events)),
            "scans_csv": scans_csv(scans(t0, initial, events)),
            "candump": candump(t0, initial, events),
            "vcd": vcd(t0, initial, events),
            "stdin_lines": stdin_lines(t0, initial, events),
        }
        for target, text in forms.items():
            (CORPUS / target / f"{name}").write_text(text)
            if target not in ("stdin_lines",):
                (CORPUS / "detect" / f"{name}_{target}").write_text(text)
        for form, path in parquet_seeds(name, t0, initial, events).items():
            shutil.copy(path, CORPUS / "detect" / f"{name}_{form}.parquet")
    copy_all("events_csv", [("logs/tests/fixtures/logs/events", "*.csv")])
    copy_all("intervals_csv", [("logs/tests/fixtures/logs/intervals", "*.csv")])
    copy_all("scans_csv", [("logs/tests/fixtures/logs/scans", "*.csv")])
    copy_all("candump", [("logs/tests/fixtures/candump", "*.log")])
    copy_all("vcd", [("logs/tests/fixtures/vcd", "*.vcd")])
    copy_all("detect", [("logs/tests/fixtures/ingest", "*.csv"), ("logs/tests/fixtures/ingest", "*.txt")])
    copy_all("plant_toml", [("vocabulary/tests/fixtures/plants", "*.toml"),
                            ("datasets/data/sorting/normal", "plant.toml")])
    shutil.copy(ROOT / "datasets/data/cylinders/normal/plant.toml",
                CORPUS / "plant_toml" / "cylinders_plant.toml")
    copy_all("gen", [("diagnoser/tests/fixtures/faudes", "*.gen")])
    copy_all("failure_map", [("diagnoser/tests/fixtures/faudes", "*typemap*.txt"),
                             ("diagnoser/tests/fixtures/faudes", "semantics_f*.txt")])
    model = CORPUS / "model_json" / "sorting_normal.json"
    subprocess.run([gardefou, "learn", str(ROOT / "datasets/data/sorting/normal/events.csv"),
                    "--plant", str(ROOT / "datasets/data/sorting/normal/plant.toml"),
                    "-o", str(model)], check=True, stderr=subprocess.DEVNULL)
    modbus_seeds()
    expressions()
    gen_products()


if __name__ == "__main__":
    main()
