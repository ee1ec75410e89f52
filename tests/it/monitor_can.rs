//! `gardefou monitor --can`: CANopen PDOs read as raw SocketCAN frames, here
//! over the UDP transport (this machine may have no CAN at all), decoded into
//! the same verdicts as the offline path.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use diagnoser::{Plant, SignalKind, time};

fn path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
const F2_LOG: &str = "datasets/data/sorting/F2/events.csv";
/// TPDO1 of node 1: the PLC's inputs (sensors).
const TPDO1: u32 = 0x181;
/// RPDO1 of node 1: the PLC's outputs (actuators).
const RPDO1: u32 = 0x201;
/// The slice of the F2 run sent as frames (ms): the turntable's C4 sticks at
/// 1 from 602 s, and the diagnosers flag it at 605.69 s.
const FROM: i64 = 600_000;
const TO: i64 = 606_000;
/// How much faster than the log the frames are sent (and the monitor's clock runs).
const SPEED: f64 = 5.0;
/// Largest difference allowed between online and offline verdict times, in
/// log milliseconds: a frame's arrival may lag its schedule by a few wall
/// milliseconds on a busy machine.
const TOLERANCE_MS: i64 = 60;
/// Wall time between the frames of one scan: less than the monitor's
/// gathering window (half the 10 ms scan period, over [`SPEED`]: 1 ms).
const FRAME_GAP: Duration = Duration::from_micros(300);
/// How long each monitor runs: the slice takes 1.2 s at [`SPEED`].
const DURATION: Duration = Duration::from_secs(3);
/// Runs tried before the test fails (see the test).
const ATTEMPTS: usize = 5;

/// The shipped sorting plant, with every sensor on TPDO1 and every actuator on
/// RPDO1, in declaration order from bit 0.
fn can_plant(dir: &Path) -> (PathBuf, Plant) {
    let shipped = path("datasets/data/sorting/normal/plant.toml");
    let text = std::fs::read_to_string(&shipped).expect("reads the shipped plant");
    let plant = Plant::parse(&text, &shipped).expect("the shipped plant parses");
    let mut can = String::from("\n[can]\n");
    let (mut inputs, mut outputs) = (0, 0);
    for (_, s) in plant.signals.iter() {
        let (id, bit) = match s.kind {
            SignalKind::Sensor => (TPDO1, &mut inputs),
            SignalKind::Actuator => (RPDO1, &mut outputs),
        };
        can.push_str(&format!(
            "{} = {{ cob_id = {id:#x}, bit = {bit} }}\n",
            s.name
        ));
        *bit += 1;
    }
    let file = dir.join("plant.toml");
    std::fs::write(&file, format!("{text}{can}")).expect("writes the plant");
    let plant = Plant::from_path(&file).expect("the CAN plant parses");
    assert_eq!(plant.can.len(), plant.signals.len());
    (file, plant)
}

/// A SocketCAN `struct can_frame`, as a raw socket delivers it.
fn can_frame(id: u32, data: &[u8]) -> [u8; 16] {
    let mut f = [0u8; 16];
    f[..4].copy_from_slice(&id.to_le_bytes());
    f[4] = data.len() as u8;
    f[8..8 + data.len()].copy_from_slice(data);
    f
}

/// The PDO of `id` for the signal values `values` (by signal index).
fn pdo(plant: &Plant, id: u32, values: &[bool]) -> [u8; 16] {
    let mut data = [0u8; 2];
    for b in plant.can.iter().filter(|b| b.cob_id == id) {
        if values[b.signal.index()] {
            data[usize::from(b.bit / 8)] |= 1 << (b.bit % 8);
        }
    }
    can_frame(id, &data)
}

/// Changes by time (ms): signal index and value.
type Changes = BTreeMap<i64, Vec<(usize, bool)>>;

/// The slice of the F2 run: every signal's value at [`FROM`], then the changes
/// up to [`TO`] by time (ms).
fn f2_slice(plant: &Plant) -> (Vec<bool>, Changes) {
    let text = std::fs::read_to_string(path(F2_LOG)).expect("reads the F2 log");
    let mut values = vec![false; plant.signals.len()];
    let mut later = Changes::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1].is_empty() {
            continue; // the end row
        }
        let t: i64 = f[0].parse().expect("numeric time");
        let s = plant.signals.id(f[1]).expect("known signal").index();
        let v = f[2] == "1";
        if t < FROM {
            values[s] = v;
        } else if t <= TO {
            later.entry(t).or_default().push((s, v));
        }
    }
    (values, later)
}

/// The slice as an events log, for `gardefou diagnose`.
fn slice_log(plant: &Plant, initial: &[bool], later: &Changes) -> String {
    let mut csv = String::from("t,signal,value\n");
    for (id, s) in plant.signals.iter() {
        csv.push_str(&format!(
            "{FROM},{},{}\n",
            s.name,
            u8::from(initial[id.index()])
        ));
    }
    for (t, changes) in later {
        for &(s, v) in changes {
            let name = &plant.signals.iter().nth(s).expect("signal").1.name;
            csv.push_str(&format!("{t},{name},{}\n", u8::from(v)));
        }
    }
    csv
}

/// A verdict line without its time and with the numbers of its reason masked
/// (durations measured online differ by the frames' jitter).
fn shape(v: &serde_json::Value) -> String {
    let mut v = v.clone();
    let mut reason = String::new();
    let mut in_number = false;
    for c in v["reason"].as_str().unwrap_or_default().chars() {
        let digit = c.is_ascii_digit() || (in_number && c == '.');
        if !digit {
            reason.push(c);
        } else if !in_number {
            reason.push('#');
        }
        in_number = digit;
    }
    v["reason"] = reason.into();
    v["t"] = serde_json::Value::Null;
    v.to_string()
}

/// What one online run gave.
struct Online {
    /// Verdict lines.
    verdicts: Vec<serde_json::Value>,
    /// Standard error.
    stderr: String,
    /// Most the sender was late on its schedule.
    late: Duration,
}

/// Runs the monitor on `udp:127.0.0.1:0` and sends it the slice as PDOs,
/// paced at [`SPEED`] times the log's pace, with garbage in between.
fn run_online(plant_file: &Path, plant: &Plant, initial: &[bool], later: &Changes) -> Online {
    let mut child = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .arg("monitor")
        .arg("--plant")
        .arg(plant_file)
        .arg("--model")
        .arg(path(MODEL))
        .args(["--can", "udp:127.0.0.1:0", "--speed", &SPEED.to_string()])
        .args(["--duration", &format!("{}s", DURATION.as_secs())])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts the monitor");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        for l in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let listening = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("the monitor says where it listens");
    // --duration counts from about now.
    let listening_at = Instant::now();
    let addr: SocketAddr = listening
        .strip_prefix("monitor: reading CAN frames from udp:")
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("unexpected first line: {listening}"));
    assert_ne!(addr.port(), 0);

    let socket = UdpSocket::bind("127.0.0.1:0").expect("binds");
    let send = |frames: &[[u8; 16]]| {
        let bytes: Vec<u8> = frames.concat();
        socket.send_to(&bytes, addr).expect("sends");
    };
    let mut values = initial.to_vec();
    // The initial process image: both PDOs in one datagram (a bridge may
    // forward several frames at once).
    send(&[pdo(plant, TPDO1, &values), pdo(plant, RPDO1, &values)]);
    let start = Instant::now();
    // Not frames, a TPDO too short for C8-C10, a remote request and a heartbeat.
    socket.send_to(b"not a CAN frame", addr).expect("sends");
    send(&[can_frame(TPDO1, &[0x00])]);
    send(&[can_frame(RPDO1 | 0x4000_0000, &[])]);
    send(&[can_frame(0x701, &[0x05])]);
    let mut late = Duration::ZERO;
    for (&t, changes) in later {
        let due = start + Duration::from_secs_f64((t - FROM) as f64 / 1000.0 / SPEED);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let mut ids = Vec::new();
        for &(s, v) in changes {
            values[s] = v;
            let id = plant
                .can
                .iter()
                .find(|b| b.signal.index() == s)
                .expect("mapped")
                .cob_id;
            if !ids.contains(&id) {
                ids.push(id);
            }
        }
        // One datagram per frame, the RPDO a little after the TPDO, as a
        // PLC's outputs follow its inputs on a bus: the monitor gathers them
        // into one scan.
        for (i, &id) in ids.iter().enumerate() {
            if i > 0 {
                std::thread::sleep(FRAME_GAP);
            }
            send(&[pdo(plant, id, &values)]);
        }
        late = late.max(Instant::now().saturating_duration_since(due));
    }
    assert!(
        listening_at.elapsed() + Duration::from_millis(500) < DURATION,
        "sending took {:?}, too close to --duration for the comparison to hold",
        listening_at.elapsed()
    );
    let output = child.wait_with_output().expect("the monitor ends");
    let mut err: Vec<String> = vec![listening];
    err.extend(rx.try_iter());
    let stderr = err.join("\n");
    assert!(output.status.success(), "{stderr}");
    let verdicts = String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON verdict"))
        .collect();
    Online {
        verdicts,
        stderr,
        late,
    }
}

/// Whether the online verdicts are the offline ones, at the same times (from
/// the first verdict on) up to [`TOLERANCE_MS`]; if not, why.
fn same_verdicts(
    online: &[serde_json::Value],
    offline: &[serde_json::Value],
) -> Result<(), String> {
    let shapes = |vs: &[serde_json::Value]| vs.iter().map(shape).collect::<Vec<_>>();
    if shapes(online) != shapes(offline) {
        let lines =
            |vs: &[serde_json::Value]| vs.iter().map(|v| format!("  {v}\n")).collect::<String>();
        return Err(format!(
            "verdicts differ; online:\n{}offline:\n{}",
            lines(online),
            lines(offline)
        ));
    }
    let online_t: Vec<i64> = online
        .iter()
        .map(|v| {
            let t = v["t"].as_str().expect("an RFC 3339 time");
            time::parse_rfc3339(t).expect("RFC 3339")
        })
        .collect();
    let offline_t: Vec<i64> = offline
        .iter()
        .map(|v| v["t"].as_i64().expect("ms") * 1_000_000)
        .collect();
    let ms = |ns: i64| ns as f64 / 1e6;
    for i in 0..online.len() {
        let (on, off) = (online_t[i] - online_t[0], offline_t[i] - offline_t[0]);
        if (on - off).abs() > TOLERANCE_MS * 1_000_000 {
            return Err(format!(
                "verdict {i}: {:.3} ms after the first online, {:.3} ms offline",
                ms(on),
                ms(off)
            ));
        }
    }
    Ok(())
}

/// The F2 slice sent as PDOs over UDP, paced at [`SPEED`] times its own pace,
/// gives the verdicts `gardefou diagnose` gives on the same slice, up to the
/// `def_C4` flag; garbage and a short frame in between are warnings.
///
/// The monitor stamps frames on its live clock when it reads them, so a busy
/// machine delaying the sender or the monitor by more than a few
/// milliseconds shifts an edge out of a learned window (the tightest here: C6
/// falls 10 ms after A3 rises, within [0, 20] ms). Such a run is reported and
/// tried again, up to [`ATTEMPTS`] times; a decoding fault fails every time.
#[test]
fn pdos_over_udp_give_the_offline_verdicts() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (plant_file, plant) = can_plant(dir.path());
    let (initial, later) = f2_slice(&plant);
    let log = dir.path().join("slice.csv");
    std::fs::write(&log, slice_log(&plant, &initial, &later)).expect("writes the slice");

    let offline = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .arg("diagnose")
        .arg("--plant")
        .arg(&plant_file)
        .arg("--model")
        .arg(path(MODEL))
        .arg(&log)
        .output()
        .expect("runs diagnose");
    assert!(
        offline.status.success(),
        "{}",
        String::from_utf8_lossy(&offline.stderr)
    );
    let offline: Vec<serde_json::Value> = String::from_utf8_lossy(&offline.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON verdict"))
        .collect();
    assert!(
        offline
            .iter()
            .any(|v| v["flags"] == serde_json::json!(["def_C4"])),
        "the slice must reach def_C4 offline: {offline:?}"
    );

    let mut failures = Vec::new();
    for attempt in 1..=ATTEMPTS {
        let online = run_online(&plant_file, &plant, &initial, &later);
        let err = &online.stderr;
        // Whatever the timing: the warnings, and the flag.
        assert!(
            err.contains("15 bytes received, not a whole number of 16-byte CAN frames"),
            "{err}"
        );
        assert!(
            err.contains("frame 181 has 1 data byte, but signal 'C8'"),
            "{err}"
        );
        assert_eq!(err.matches("warning:").count(), 2, "{err}");
        let verdicts = same_verdicts(&online.verdicts, &offline).and_then(|()| {
            if err.contains("flags: def_C4") {
                Ok(())
            } else {
                Err("no def_C4 in the summary".to_string())
            }
        });
        match verdicts {
            Ok(()) => return,
            Err(why) => {
                eprintln!(
                    "attempt {attempt}: sender late by up to {:?}; {why}\n{err}",
                    online.late
                );
                failures.push(why);
            }
        }
    }
    panic!("no run gave the offline verdicts: {failures:#?}");
}

fn one_line_failure(iface: &str) {
    let dir = tempfile::tempdir().expect("temp dir");
    let (plant_file, _) = can_plant(dir.path());
    let out = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .arg("monitor")
        .arg("--plant")
        .arg(&plant_file)
        .arg("--model")
        .arg(path(MODEL))
        .args(["--can", iface])
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with(&format!("gardefou: --can {iface}: ")),
        "{err}"
    );
    assert!(out.stdout.is_empty());
}

/// An interface that does not exist is a one-line error, with or without CAN
/// support in the kernel.
#[test]
fn a_missing_interface_is_a_one_line_error() {
    one_line_failure("nonexistent0");
}

/// `lo` exists but is no CAN interface: a one-line error too, whether the
/// kernel lacks CAN (this machine) or refuses to bind a CAN socket to it.
#[test]
fn a_non_can_interface_is_a_one_line_error() {
    one_line_failure("lo");
}

/// A malformed `udp:` address is a one-line error.
#[test]
fn a_bad_udp_address_is_a_one_line_error() {
    one_line_failure("udp:localhost");
}
