//! `gardefou monitor --mqtt --sparkplug`: against a real MQTT broker
//! (Debian's mosquitto) and an edge node written independently (Python,
//! paho-mqtt and pysparkplug's payloads: `tests/sparkplug/edge_node.py`)
//! replaying a slice of the shipped F2 run, stamped with the log's times.
//!
//! `scripts/test` installs both and sets `GARDEFOU_REQUIRE_PEERS=1`; without
//! it, a machine missing either skips these tests with a message.

use std::io::{BufRead, BufReader, Write};
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
/// The edge node's pace, against the log's.
const SPEED: &str = "5";
/// The jitter the monitor allows between the node's messages, in the log's
/// time: 100 ms of wall time at [`SPEED`].
const LATENESS_MS: f64 = 500.0;
const TARGET: &str = "line/plc1/io";
const ATTEMPTS: usize = 3;

/// The runs here take real time: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// The Python with pysparkplug, and mosquitto; `None` (after saying why)
/// when one is missing and the peers are not required.
fn peers() -> Option<(String, String)> {
    let python = std::env::var("GARDEFOU_PYTHON").unwrap_or_else(|_| "python3".into());
    let has_python = Command::new(&python)
        .args(["-c", "import paho.mqtt.client, pysparkplug"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    let mosquitto = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .into_iter()
        .find(|p| Path::new(p).exists());
    match (has_python, mosquitto) {
        (true, Some(m)) => Some((python, m.to_string())),
        _ => {
            let why = format!(
                "needs mosquitto and {python} with paho-mqtt and pysparkplug (scripts/test installs them)"
            );
            peer_missing("the Sparkplug B test", &why);
            None
        }
    }
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

/// A mosquitto broker of the test's own on a free loopback port.
struct Broker {
    child: Child,
    port: u16,
    _dir: tempfile::TempDir,
}

impl Broker {
    fn start(mosquitto: &str) -> Broker {
        let dir = tempfile::tempdir().expect("temp dir");
        let port = free_port();
        let conf = dir.path().join("mosquitto.conf");
        let mut f = std::fs::File::create(&conf).expect("writes the configuration");
        writeln!(
            f,
            "listener {port} 127.0.0.1\nallow_anonymous true\npersistence false"
        )
        .expect("writes");
        let child = Command::new(mosquitto)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto starts");
        wait_for_port(port, "mosquitto");
        Broker {
            child,
            port,
            _dir: dir,
        }
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The plant's flags, comma-separated, as the edge node declares them.
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

fn offline_verdicts(log: &str) -> Vec<String> {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "diagnose",
            "--plant",
            &path(PLANT),
            "--model",
            &path(MODEL),
            log,
        ])
        .output()
        .expect("runs diagnose");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(String::from)
        .collect()
}

fn monitor(port: u16, duration: &str) -> Lines {
    Lines::spawn(
        Command::new(env!("CARGO_BIN_EXE_gardefou"))
            .args(["monitor", "--plant", &path(PLANT), "--model", &path(MODEL)])
            .args([
                "--mqtt",
                &format!("mqtt://127.0.0.1:{port}"),
                "--sparkplug",
                TARGET,
            ])
            .args(["--speed", SPEED, "--lateness", &format!("{LATENESS_MS}ms")])
            .args(["--duration", duration]),
    )
}

fn edge_node(python: &str, port: u16, extra: &[&str]) -> Lines {
    Lines::spawn(
        Command::new(python)
            .arg(path("tests/sparkplug/edge_node.py"))
            .arg(port.to_string())
            .arg(path(EVENTS))
            .args([
                &FROM_MS.to_string(),
                &TO_MS.to_string(),
                SPEED,
                TARGET,
                &flag_names(),
            ])
            .args(extra),
    )
}

/// How far behind the log's pace the edge node fell, from its end line.
fn most_late_ms(node: &Lines) -> f64 {
    let end = node
        .out
        .iter()
        .find(|l| l.contains("\"end\""))
        .expect("an end line");
    let v: serde_json::Value = serde_json::from_str(end).expect("JSON");
    v["most_late_ms"].as_f64().expect("most_late_ms")
}

/// One run: the monitor first, then the edge node, both to their end.
fn run(python: &str, broker: &Broker, extra: &[&str]) -> (Lines, Lines) {
    let mut monitor = monitor(broker.port, "14s");
    assert!(
        monitor.wait_for("connected to", Duration::from_secs(10)),
        "the monitor did not connect: {:?}",
        monitor.err
    );
    let mut node = edge_node(python, broker.port, extra);
    assert!(
        node.wait_for("\"end\"", Duration::from_secs(40)),
        "the edge node did not end: {:?} {:?}",
        node.out,
        node.err
    );
    node.finish(Duration::from_secs(5));
    monitor.finish(Duration::from_secs(20));
    (monitor, node)
}

/// The verdict lines of `diagnose` on the same slice, byte for byte, up to
/// its end; the flag reaches the edge node as a DCMD, and its data showing
/// the flag up is what the monitor counts as written; the node's NDEATH is
/// a lost plant.
#[test]
fn sparkplug_gives_the_offline_verdicts_and_writes_the_flag_back() {
    let _serial = serial();
    let Some((python, mosquitto)) = peers() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let offline = offline_verdicts(&slice_log(dir.path()));
    assert!(
        offline.iter().any(|l| l.contains("\"flags\":[\"def_C4\"]")),
        "{offline:?}"
    );
    let broker = Broker::start(&mosquitto);
    for attempt in 1..=ATTEMPTS {
        let (monitor, node) = run(&python, &broker, &[]);
        let late = most_late_ms(&node);
        let online: Vec<String> = monitor
            .out
            .iter()
            .filter(|l| {
                serde_json::from_str::<serde_json::Value>(l)
                    .is_ok_and(|v| v["t"].as_i64().is_some_and(|t| t <= TO_MS))
            })
            .cloned()
            .collect();
        let err = monitor.err.join("\n");
        if late > LATENESS_MS && online != offline {
            eprintln!(
                "attempt {attempt}: the edge node fell {late:.0} ms behind; run again\n{err}"
            );
            continue;
        }
        assert_eq!(online, offline, "{err}");
        assert!(
            node.out
                .iter()
                .any(|l| l.contains("\"flag\": \"def_C4\", \"value\": true")),
            "the flag never reached the edge node: {:?}",
            node.out
        );
        assert!(err.contains("flags written to the PLC: def_C4"), "{err}");
        assert!(err.contains("NDEATH: the edge node went offline"), "{err}");
        assert!(!err.contains("behind the watermark"), "{err}");
        return;
    }
    panic!("the edge node fell behind its pace in {ATTEMPTS} runs");
}

/// A skipped sequence number is a lost plant: the monitor says so, asks for
/// the births again, and diagnoses on from them: the flag still goes up.
#[test]
fn a_sequence_gap_loses_the_plant_until_the_rebirth() {
    let _serial = serial();
    let Some((python, mosquitto)) = peers() else {
        return;
    };
    let broker = Broker::start(&mosquitto);
    let (monitor, node) = run(&python, &broker, &["--gap-at", "595000"]);
    let err = monitor.err.join("\n");
    assert!(err.contains("sequence gap: expected"), "{err}");
    assert!(
        node.out.iter().any(|l| l.contains("\"rebirth\"")),
        "no rebirth asked: {:?}",
        node.out
    );
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

/// A `def_` flag the node's birth shows up was raised by an earlier run: the
/// monitor keeps it up, though its own diagnosers see nothing wrong yet.
#[test]
fn a_flag_found_up_in_the_birth_stays_up() {
    let _serial = serial();
    let Some((python, mosquitto)) = peers() else {
        return;
    };
    let broker = Broker::start(&mosquitto);
    let (monitor, node) = run(&python, &broker, &["--up", "def_P"]);
    let err = monitor.err.join("\n");
    assert!(
        err.contains("flags already up on the PLC, kept raised: def_P"),
        "{err}"
    );
    assert!(
        !node
            .out
            .iter()
            .any(|l| l.contains("\"flag\": \"def_P\", \"value\": false")),
        "the monitor lowered a flag found up: {:?}",
        node.out
    );
}
