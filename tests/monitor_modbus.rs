//! `gardefou monitor --modbus`: against an independent Modbus TCP server
//! (pymodbus, from PyPI) replaying a recorded run of the sorting line. The
//! monitor must read it with the default register map, detect the fault, write
//! the flag coils, and survive a PLC that is killed and restarted or a peer
//! that answers garbage, without losing a raised flag.
//!
//! Needs `python3 -m pip install pymodbus==3.6.9` (`.ci/run` installs it).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard, mpsc};
use std::time::{Duration, Instant};

fn path(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
const PLANT: &str = "datasets/data/sorting/F2/plant.toml";
const EVENTS: &str = "datasets/data/sorting/F2/events.csv";

/// The tests here run one at a time: each is a real-time run whose timing a
/// loaded machine would blur (two cores, a Python server, a PLC at 4×).
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// A child process whose stdout lines arrive on a channel.
struct Lines {
    child: Child,
    rx: mpsc::Receiver<String>,
    seen: Vec<String>,
}

impl Lines {
    fn spawn(cmd: &mut Command) -> Lines {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starts");
        let out = child.stdout.take().expect("stdout");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        Lines {
            child,
            rx,
            seen: Vec::new(),
        }
    }

    /// Waits for a line containing `needle`, at most `within`.
    fn wait_for(&mut self, needle: &str, within: Duration) -> Option<String> {
        let end = Instant::now() + within;
        loop {
            let left = end.checked_duration_since(Instant::now())?;
            match self.rx.recv_timeout(left) {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if l.contains(needle) {
                        return Some(l);
                    }
                }
                Err(_) => return None,
            }
        }
    }

    fn stderr(&mut self) -> String {
        let mut s = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = e.read_to_string(&mut s);
        }
        s
    }
}

impl Drop for Lines {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The pymodbus PLC replaying the F2 run from `from_ms` to `to_ms` at `speed`.
fn python_plc(port: u16, from_ms: u64, to_ms: u64, speed: f64) -> Lines {
    python_plc_with(port, from_ms, to_ms, speed, &[])
}

/// The same, with `flags` up from the start.
fn python_plc_with(port: u16, from_ms: u64, to_ms: u64, speed: f64, flags: &[&str]) -> Lines {
    let probe = Command::new("python3")
        .args(["-c", "import pymodbus"])
        .status()
        .expect("python3 runs");
    assert!(
        probe.success(),
        "pymodbus is missing: python3 -m pip install pymodbus==3.6.9"
    );
    let mut plc = Lines::spawn(
        Command::new("python3")
            .args([
                &path("tests/modbus/pymodbus_plc.py"),
                &path(PLANT),
                &path(EVENTS),
                &port.to_string(),
                &from_ms.to_string(),
                &to_ms.to_string(),
                &speed.to_string(),
            ])
            .args(flags),
    );
    assert!(
        plc.wait_for("serving", Duration::from_secs(20)).is_some(),
        "the pymodbus server did not start: {}",
        plc.stderr()
    );
    // Serving is announced just before the socket is bound.
    let end = Instant::now() + Duration::from_secs(5);
    while TcpStream::connect(("127.0.0.1", port)).is_err() && Instant::now() < end {
        std::thread::sleep(Duration::from_millis(20));
    }
    plc
}

fn monitor(port: u16, http: Option<u16>, duration: &str) -> Lines {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args(["monitor", "--plant", &path(PLANT), "--model", &path(MODEL)])
        .args(["--modbus", &format!("127.0.0.1:{port}")])
        .args(["--speed", "2", "--duration", duration]);
    if let Some(h) = http {
        cmd.args(["--http", &format!("127.0.0.1:{h}")]);
    }
    Lines::spawn(&mut cmd)
}

fn http_get(port: u16, route: &str) -> String {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("HTTP connects");
    write!(
        s,
        "GET {route} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .expect("request");
    let mut body = String::new();
    s.read_to_string(&mut body).expect("response");
    body
}

/// The monitor reads the pymodbus PLC with the default map, labels F2 certain,
/// writes `def_C4` to coil 100, and shows it on `/status` and `/metrics`.
#[test]
fn the_monitor_diagnoses_and_flags_an_independent_modbus_server() {
    let _serial = serial();
    let port = free_port();
    let http = free_port();
    // F2 (C4 stuck at 1) starts at 602 s; RE(C5) settles it about 3.7 s later.
    let mut plc = python_plc(port, 596_000, 608_000, 2.0);
    let mut mon = monitor(port, Some(http), "8s");
    // Other parts may see a polling artefact (an edge a few ms outside its
    // learned window); the turntable's verdict is what is checked.
    let certain = mon.wait_for("\"labels\":[\"F2\"]", Duration::from_secs(15));
    let certain = certain.unwrap_or_else(|| panic!("no certain verdict: {:?}", mon.seen));
    assert!(certain.contains("\"part\":\"turntable\""), "{certain}");
    assert!(certain.contains("\"verdict\":\"certain\""), "{certain}");
    assert!(certain.contains("\"flags\":[\"def_C4\"]"), "{certain}");
    let written = plc.wait_for(
        "\"flag\": \"def_C4\", \"coil\": 100, \"value\": true",
        Duration::from_secs(5),
    );
    assert!(written.is_some(), "def_C4 not written: {:?}", plc.seen);
    let status = http_get(http, "/status");
    assert!(status.starts_with("HTTP/1.1 200"), "{status}");
    assert!(status.contains("\"connected\": true"), "{status}");
    assert!(status.contains("\"def_C4\""), "{status}");
    let metrics = http_get(http, "/metrics");
    assert!(
        metrics.contains("gardefou_flag{flag=\"def_C4\"} 1"),
        "{metrics}"
    );
    assert!(
        metrics.contains("gardefou_part_certain{part=\"turntable\"} 1"),
        "{metrics}"
    );
    let events: u64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("gardefou_events_total "))
        .and_then(|v| v.parse().ok())
        .expect("an events counter");
    assert!(events > 0, "{metrics}");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("flags: def_C4"), "{err}");
}

/// The PLC is killed after the flag is written and a fresh one (coils all 0)
/// takes its place: the monitor reports the gap, reconnects and writes
/// `def_C4` again.
#[test]
fn a_restarted_plc_gets_the_raised_flag_back() {
    let _serial = serial();
    let port = free_port();
    let mut first = python_plc(port, 596_000, 608_000, 2.0);
    let mut mon = monitor(port, None, "14s");
    let written = first.wait_for(
        "\"flag\": \"def_C4\", \"coil\": 100, \"value\": true",
        Duration::from_secs(15),
    );
    assert!(
        written.is_some(),
        "def_C4 not written: {:?} / {:?}",
        first.seen,
        mon.seen
    );
    drop(first);
    std::thread::sleep(Duration::from_millis(300));
    let mut second = python_plc(port, 610_000, 640_000, 2.0);
    let again = second.wait_for(
        "\"flag\": \"def_C4\", \"coil\": 100, \"value\": true",
        Duration::from_secs(10),
    );
    assert!(
        again.is_some(),
        "def_C4 not written again: {:?}",
        second.seen
    );
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("connection lost"), "{err}");
    assert!(err.contains("plant seen again after a gap of"), "{err}");
    assert!(err.contains("flags: def_C4"), "{err}");
}

/// A peer that answers garbage is a lost connection, not a crash; the monitor
/// keeps trying and ends cleanly.
#[test]
fn garbage_on_the_socket_is_a_lost_connection() {
    let _serial = serial();
    let listener = TcpListener::bind("127.0.0.1:0").expect("binds");
    let port = listener.local_addr().expect("address").port();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { continue };
            let mut buf = [0u8; 260];
            let _ = s.read(&mut buf);
            // A reply that is not Modbus: wrong protocol id, absurd length.
            let _ = s.write_all(&[0xde, 0xad, 0xbe, 0xef, 0xff, 0xff, 0x01, 0x02, 0x03]);
        }
    });
    let mut mon = monitor(port, None, "2s");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("reconnecting"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// The whole loop on loopback: the virtual PLC (safe control by constraints
/// and the rewritable filter) runs the sorting line at 4 times real time with
/// C4 stuck at 1 from 40 s; the monitor polls it, labels F2, writes `def_C4`;
/// the PLC's filter switches C4 to its estimate and boxes keep being delivered
/// without damage.
#[test]
fn the_monitor_flags_a_virtual_plc_which_goes_on_safely() {
    let _serial = serial();
    let dir = tempfile::tempdir().expect("temporary directory");
    let run = dir.path().join("run");
    let model = dir.path().join("model.json");
    let bin = env!("CARGO_BIN_EXE_gardefou");
    let ok = |out: std::process::Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    // The model is learned from the same control: one fault-free hour.
    ok(Command::new(bin)
        .args(["simulate", "--control", "constraints", "--duration", "1h"])
        .args(["--seed", "7", "--out"])
        .arg(&run)
        .output()
        .expect("simulate runs"));
    // Polling adds up to half a scan to every edge, and a loaded machine's
    // scheduling a few milliseconds more (times the speed): wider guards.
    ok(Command::new(bin)
        .args(["learn", "--margin", "50ms", "--plant"])
        .arg(run.join("plant.toml"))
        .arg(run.join("events.csv"))
        .arg("-o")
        .arg(&model)
        .output()
        .expect("learn runs"));

    let mut plc = Command::new(bin)
        .args(["simulate", "--serve-modbus", "127.0.0.1:0", "--realtime"])
        .args(["--speed", "4", "--duration", "140s", "--fault", "F2@40s"])
        .arg("--model")
        .arg(&model)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the virtual PLC starts");
    let mut plc_err = BufReader::new(plc.stderr.take().expect("stderr"));
    let mut first = String::new();
    plc_err.read_line(&mut first).expect("a first line");
    let port: u16 = first
        .split("127.0.0.1:")
        .nth(1)
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no port in: {first}"));

    let mut mon = Lines::spawn(
        Command::new(bin)
            .args(["monitor", "--plant"])
            .arg(run.join("plant.toml"))
            .arg("--model")
            .arg(&model)
            .args(["--modbus", &format!("127.0.0.1:{port}")])
            .args(["--speed", "4", "--duration", "33s"]),
    );
    let certain = mon.wait_for("\"labels\":[\"F2\"]", Duration::from_secs(30));
    let certain = certain.unwrap_or_else(|| panic!("F2 never certain: {:?}", mon.seen));
    assert!(certain.contains("\"part\":\"turntable\""), "{certain}");
    assert!(certain.contains("def_C4"), "{certain}");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("flags written to the PLC: def_C4"), "{err}");

    let out = plc.wait_with_output().expect("the virtual PLC ends");
    let mut rest = String::new();
    plc_err.read_to_string(&mut rest).expect("stderr");
    assert!(out.status.success(), "{first}{rest}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("a JSON summary");
    let flags = summary["flags"].as_array().expect("flags");
    let def_c4 = flags
        .iter()
        .find(|f| f["flag"] == "def_C4")
        .unwrap_or_else(|| panic!("the PLC never read def_C4: {summary}"));
    // Raised after the fault began, and read by the PLC.
    let at = def_c4["t_ms"].as_u64().expect("t_ms");
    assert!((40_000..140_000).contains(&at), "{summary}");
    assert_eq!(summary["damage"], serde_json::json!([]), "{summary}");
    // Some 90 s of line after the flag at ~300 boxes/h: about seven boxes.
    let since = summary["delivered_since_flag"].as_u64().expect("a count");
    assert!(since >= 4, "{summary}");
}

/// A monitor started afresh finds `def_C4` up on the PLC (raised by an earlier
/// run, before a restart of the monitor): it keeps it raised and never writes
/// it down, though its own diagnosers, new to the plant, see nothing wrong.
#[test]
fn a_fresh_monitor_keeps_the_flags_it_finds_raised() {
    let _serial = serial();
    let port = free_port();
    // A fault-free stretch of the run, before F2 begins at 602 s.
    let mut plc = python_plc_with(port, 100_000, 108_000, 2.0, &["def_C4"]);
    let mut mon = monitor(port, None, "3s");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("kept raised: def_C4"), "{err}");
    assert!(err.contains("flags: def_C4"), "{err}");
    let _ = plc.wait_for("never printed", Duration::from_millis(300));
    assert!(
        plc.seen
            .iter()
            .any(|l| l.contains("\"flag\": \"def_C4\", \"coil\": 100, \"value\": true")),
        "{:?}",
        plc.seen
    );
    assert!(
        !plc.seen
            .iter()
            .any(|l| l.contains("\"flag\": \"def_C4\", \"coil\": 100, \"value\": false")),
        "def_C4 was written down: {:?}",
        plc.seen
    );
}
