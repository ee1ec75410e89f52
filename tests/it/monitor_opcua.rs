//! `gardefou monitor --opcua`: against an OPC UA server written
//! independently (Python, asyncua: `tests/opcua/server.py`) replaying a slice
//! of the shipped F2 run, each change stamped with the log's time as its
//! SourceTimestamp.
//!
//! The plant file is the F2 one with an `[opcua]` table mapping two signals
//! to nodes the server names otherwise, so that both ways of finding a
//! variable are used: by NodeId, and by browse name (the rest, the flags
//! among them two levels down).
//!
//! `scripts/test` installs asyncua and sets `GARDEFOU_REQUIRE_PEERS=1`;
//! without it, a machine missing it skips these tests with a message.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::support::{free_port, peer_missing, repo as path, wait_for_port};

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
const PLANT: &str = "datasets/data/sorting/F2/plant.toml";
const EVENTS: &str = "datasets/data/sorting/F2/events.csv";
/// The slice replayed: C4 sticks before 602 890 ms, and `def_C4` is certain
/// at 605 690 ms.
const FROM_MS: i64 = 590_000;
const TO_MS: i64 = 612_000;
/// The server's pace, against the log's.
const SPEED: &str = "5";
/// The jitter the monitor allows between a change and its notification, in
/// the log's time: 100 ms of wall time at [`SPEED`].
const LATENESS_MS: f64 = 500.0;
/// Signals the server names otherwise, mapped by NodeId in `[opcua]`.
const RENAMED: [(&str, &str); 2] = [("C4", "TurntableAtLoading"), ("A4", "TurntableToUnloading")];
const ATTEMPTS: usize = 3;

/// The runs here take real time: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// The Python with asyncua; `None` (after saying why) when it is missing and
/// the peers are not required.
fn python() -> Option<String> {
    let python = std::env::var("GARDEFOU_PYTHON").unwrap_or_else(|_| "python3".into());
    let has = Command::new(&python)
        .args(["-c", "import asyncua"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if has {
        return Some(python);
    }
    let why = format!("needs {python} with asyncua (scripts/test installs it)");
    peer_missing("the OPC UA test", &why);
    None
}

/// A child whose stdout and stderr lines arrive on one channel, each marked
/// with its stream.
struct Lines {
    child: Child,
    rx: mpsc::Receiver<(bool, String)>,
    out: Vec<String>,
    err: Vec<String>,
}

impl Lines {
    fn spawn(cmd: &mut Command) -> Lines {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starts");
        let (tx, rx) = mpsc::channel();
        let out = child.stdout.take().expect("stdout");
        let err = child.stderr.take().expect("stderr");
        for (is_err, stream) in [
            (false, Box::new(out) as Box<dyn std::io::Read + Send>),
            (true, Box::new(err)),
        ] {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    if tx.send((is_err, line)).is_err() {
                        return;
                    }
                }
            });
        }
        Lines {
            child,
            rx,
            out: Vec::new(),
            err: Vec::new(),
        }
    }

    /// Waits for a line (of either stream) holding `needle`.
    fn wait_for(&mut self, needle: &str, within: Duration) -> bool {
        let end = Instant::now() + within;
        let seen = |l: &Vec<String>| l.iter().any(|x| x.contains(needle));
        while !seen(&self.out) && !seen(&self.err) {
            let Some(left) = end.checked_duration_since(Instant::now()) else {
                return false;
            };
            match self.rx.recv_timeout(left) {
                Ok((true, l)) => self.err.push(l),
                Ok((false, l)) => self.out.push(l),
                Err(_) => return false,
            }
        }
        true
    }

    /// Waits for the child to end, reading every line.
    fn finish(&mut self, within: Duration) {
        let end = Instant::now() + within;
        while let Ok((is_err, l)) = self
            .rx
            .recv_timeout(end.saturating_duration_since(Instant::now()))
        {
            if is_err {
                self.err.push(l)
            } else {
                self.out.push(l)
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Lines {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The F2 plant file with an `[opcua]` table for the renamed signals.
fn plant_file(dir: &Path) -> String {
    let mut text = std::fs::read_to_string(path(PLANT)).expect("reads the plant file");
    text.push_str("\n[opcua]\n");
    for (signal, name) in RENAMED {
        text.push_str(&format!(
            "{signal} = \"nsu=urn:gardefou:test:line;s=Line.{name}\"\n"
        ));
    }
    let file = dir.join("plant.toml");
    std::fs::write(&file, text).expect("writes the plant file");
    file.display().to_string()
}

/// The plant's flags, comma-separated, as the server serves them.
fn flag_names() -> String {
    let plant = diagnoser::Plant::from_path(Path::new(&path(PLANT))).expect("plant");
    plant
        .flags()
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

/// The slice as an events log: every signal's value at [`FROM_MS`], the
/// changes after it, and the end row at [`TO_MS`].
fn slice_log(dir: &Path) -> String {
    let text = std::fs::read_to_string(path(EVENTS)).expect("reads the F2 log");
    let mut initial = std::collections::BTreeMap::new();
    let mut later = String::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1].is_empty() {
            continue;
        }
        let t: i64 = f[0].parse().expect("numeric time");
        if t <= FROM_MS {
            initial.insert(f[1].to_string(), f[2].to_string());
        } else if t <= TO_MS {
            later.push_str(&format!("{line}\n"));
        }
    }
    let mut csv = String::from("t,signal,value\n");
    for (name, value) in initial {
        csv.push_str(&format!("{FROM_MS},{name},{value}\n"));
    }
    csv.push_str(&later);
    csv.push_str(&format!("{TO_MS},,\n"));
    let file = dir.join("slice.csv");
    std::fs::write(&file, csv).expect("writes the slice");
    file.display().to_string()
}

fn offline_verdicts(plant: &str, log: &str) -> Vec<String> {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["diagnose", "--plant", plant, "--model", &path(MODEL), log])
        .output()
        .expect("runs diagnose");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(String::from)
        .collect()
}

fn server(python: &str, port: u16, extra: &[&str]) -> Lines {
    let mut args: Vec<String> = vec![
        path("tests/opcua/server.py"),
        port.to_string(),
        path(EVENTS),
        FROM_MS.to_string(),
        TO_MS.to_string(),
        SPEED.to_string(),
        flag_names(),
    ];
    for (signal, name) in RENAMED {
        args.extend(["--rename".to_string(), format!("{signal}={name}")]);
    }
    args.extend(extra.iter().map(|a| a.to_string()));
    Lines::spawn(Command::new(python).args(args))
}

fn monitor(plant: &str, port: u16) -> Lines {
    Lines::spawn(
        Command::new(env!("CARGO_BIN_EXE_gardefou"))
            .args(["monitor", "--plant", plant, "--model", &path(MODEL)])
            .args(["--opcua", &format!("opc.tcp://127.0.0.1:{port}")])
            .args(["--speed", SPEED, "--lateness", &format!("{LATENESS_MS}ms")])
            .args(["--duration", "20s"]),
    )
}

/// How far behind the log's pace the server fell, from its end line.
fn most_late_ms(server: &Lines) -> f64 {
    let end = server
        .out
        .iter()
        .find(|l| l.contains("\"end\""))
        .expect("an end line");
    let v: serde_json::Value = serde_json::from_str(end).expect("JSON");
    v["most_late_ms"].as_f64().expect("most_late_ms")
}

/// One run: the server first, then the monitor; the server replays from the
/// monitor's first read, and both run to the end of the slice. The monitor
/// is stopped once it has seen the server go.
fn run(python: &str, plant: &str, extra: &[&str]) -> (Lines, Lines) {
    let port = free_port();
    let mut server = server(python, port, extra);
    assert!(
        server.wait_for("\"serving\"", Duration::from_secs(20)),
        "the server did not start: {:?} {:?}",
        server.out,
        server.err
    );
    wait_for_port(port, "the OPC UA server");
    let mut monitor = monitor(plant, port);
    assert!(
        server.wait_for("\"end\"", Duration::from_secs(30)),
        "the server did not end: {:?} {:?}\nmonitor: {:?}",
        server.out,
        server.err,
        monitor.err
    );
    server.finish(Duration::from_secs(5));
    assert!(
        monitor.wait_for("no deadline fires until", Duration::from_secs(10)),
        "the monitor did not see the server go: {:?}",
        monitor.err
    );
    let _ = monitor.child.kill();
    monitor.finish(Duration::from_secs(5));
    (monitor, server)
}

/// The monitor's verdict lines up to the end of the slice.
fn verdicts(monitor: &Lines) -> Vec<String> {
    monitor
        .out
        .iter()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .is_ok_and(|v| v["t"].as_i64().is_some_and(|t| t <= TO_MS))
        })
        .cloned()
        .collect()
}

/// The flags the verdict lines raise: their `def_` flags, and the
/// `suspect_` flag of each suspect.
fn raised_by(lines: &[String]) -> Vec<String> {
    let mut flags = Vec::new();
    for l in lines {
        let v: serde_json::Value = serde_json::from_str(l).expect("JSON");
        let names = |key: &str| -> Vec<String> {
            v[key]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|x| x.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default()
        };
        flags.extend(names("flags"));
        flags.extend(names("suspects").iter().map(|s| format!("suspect_{s}")));
    }
    flags
}

/// The flags the server was asked to raise.
fn flags_up(server: &Lines) -> Vec<String> {
    server
        .out
        .iter()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["value"].as_bool() == Some(true))
        .filter_map(|v| v["flag"].as_str().map(String::from))
        .collect()
}

/// The verdict lines of `diagnose` on the same slice, byte for byte, up to
/// its end; `def_C4` reaches the server as a write of its variable; the
/// server going away is a lost plant.
#[test]
fn opcua_gives_the_offline_verdicts_and_writes_the_flag_back() {
    let _serial = serial();
    let Some(python) = python() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let plant = plant_file(dir.path());
    let offline = offline_verdicts(&plant, &slice_log(dir.path()));
    assert!(
        offline.iter().any(|l| l.contains("\"flags\":[\"def_C4\"]")),
        "{offline:?}"
    );
    for attempt in 1..=ATTEMPTS {
        let (monitor, server) = run(&python, &plant, &[]);
        let late = most_late_ms(&server);
        let online = verdicts(&monitor);
        let err = monitor.err.join("\n");
        if late > LATENESS_MS && online != offline {
            eprintln!("attempt {attempt}: the server fell {late:.0} ms behind; run again\n{err}");
            continue;
        }
        assert_eq!(online, offline, "{err}");
        assert!(
            server
                .out
                .iter()
                .any(|l| l.contains("\"flag\": \"def_C4\", \"value\": true")),
            "the flag never reached the server: {:?}",
            server.out
        );
        let raised = raised_by(&online);
        for up in flags_up(&server) {
            assert!(
                raised.contains(&up),
                "{up} went up, raised by no verdict: {online:?}"
            );
        }
        assert!(err.contains("flags written to the PLC: def_C4"), "{err}");
        assert!(err.contains("the session closed"), "{err}");
        assert!(!err.contains("behind the watermark"), "{err}");
        return;
    }
    panic!("the server fell behind its pace in {ATTEMPTS} runs");
}

/// A connection closed under the monitor is a lost plant: it says so,
/// connects again, reads the plant anew and diagnoses on: the flag still
/// goes up, and is written on the new connection.
#[test]
fn a_dropped_connection_loses_the_plant_until_it_is_read_again() {
    let _serial = serial();
    let Some(python) = python() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let plant = plant_file(dir.path());
    let (monitor, server) = run(&python, &plant, &["--drop-at", "595000"]);
    let err = monitor.err.join("\n");
    assert!(
        server.out.iter().any(|l| l.contains("\"dropped\"")),
        "{:?}",
        server.out
    );
    assert!(err.contains("plant seen again after a gap"), "{err}");
    assert!(
        monitor
            .out
            .iter()
            .any(|l| l.contains("\"flags\":[\"def_C4\"]")),
        "{:?}\n{err}",
        monitor.out
    );
    assert!(err.contains("flags written to the PLC: def_C4"), "{err}");
}

/// A `def_` flag the server shows up was raised by an earlier run: the
/// monitor keeps it up, though its own diagnosers see nothing wrong yet.
#[test]
fn a_flag_found_up_on_the_server_stays_up() {
    let _serial = serial();
    let Some(python) = python() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let plant = plant_file(dir.path());
    let (monitor, server) = run(&python, &plant, &["--up", "def_P"]);
    let err = monitor.err.join("\n");
    assert!(
        err.contains("flags already up on the PLC, kept raised: def_P"),
        "{err}"
    );
    assert!(
        !server
            .out
            .iter()
            .any(|l| l.contains("\"flag\": \"def_P\", \"value\": false")),
        "the monitor lowered a flag found up: {:?}",
        server.out
    );
}

/// A URL that is not `opc.tcp://HOST:PORT`, or a plant file whose `[opcua]`
/// table is wrong, is bad input: one line, exit code 2, before any
/// connection.
#[test]
fn bad_urls_and_node_ids_are_one_line_errors() {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path(PLANT), "--model", &path(MODEL)])
        .args(["--opcua", "plc.example:4840"])
        .output()
        .expect("runs");
    crate::support::assert_bad_input(
        &o,
        "--opcua: 'plc.example:4840': expected opc.tcp://HOST:PORT",
    );
    let dir = tempfile::tempdir().expect("temp dir");
    let plant = dir.path().join("plant.toml");
    let mut text = std::fs::read_to_string(path(PLANT)).expect("reads the plant file");
    text.push_str("\n[opcua]\nC4 = \"ns=2;q=Line.C4\"\n");
    std::fs::write(&plant, &text).expect("writes");
    let line = text.lines().count();
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "monitor",
            "--plant",
            &plant.display().to_string(),
            "--model",
            &path(MODEL),
        ])
        .args(["--opcua", "opc.tcp://127.0.0.1:1"])
        .output()
        .expect("runs");
    crate::support::assert_bad_input(
        &o,
        &format!(
            "plant.toml:{line}:6: field 'opcua': 'C4': 'ns=2;q=Line.C4' is not a NodeId (unknown identifier type 'q=')"
        ),
    );
}

/// A signal the server has no variable for (C4 renamed, and not mapped)
/// stops the monitor with a one-line error naming it, exit code 2.
#[test]
fn a_signal_missing_on_the_server_is_bad_input() {
    let _serial = serial();
    let Some(python) = python() else {
        return;
    };
    let port = free_port();
    let mut server = server(&python, port, &[]);
    assert!(
        server.wait_for("\"serving\"", Duration::from_secs(20)),
        "the server did not start: {:?}",
        server.err
    );
    // The F2 plant file as shipped: no [opcua] table, so C4 is looked for
    // by its name, which the server does not use.
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path(PLANT), "--model", &path(MODEL)])
        .args([
            "--opcua",
            &format!("opc.tcp://127.0.0.1:{port}"),
            "--duration",
            "20s",
        ])
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("gardefou: opcua opc.tcp://127.0.0.1:")
            && last.contains("no variable for signal C4, A4: a signal is the variable of its name up to 4 levels below the Objects folder"),
        "{err}"
    );
}
