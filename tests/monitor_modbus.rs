//! `gardefou monitor --modbus`: against an independent Modbus TCP server
//! (pymodbus, from PyPI) replaying a recorded run of the sorting line. The
//! monitor must read it with the default register map, detect the fault, write
//! the flag coils, and survive a PLC that is killed and restarted or a peer
//! that answers garbage, without losing a raised flag.
//!
//! Needs pymodbus 3.6.9: `scripts/test` installs it in a virtual environment
//! of the project's own and names its interpreter in `GARDEFOU_PYTHON`;
//! without that variable, `python3` must have it.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard, mpsc};
use std::time::{Duration, Instant};

#[path = "it/support/mod.rs"]
mod support;
use crate::support::{free_port, repo as path};
use support::netfault::{Faults, Proxy};

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
const PLANT: &str = "datasets/data/sorting/F2/plant.toml";
const EVENTS: &str = "datasets/data/sorting/F2/events.csv";

/// The tests here run one at a time: each is a real-time run whose timing a
/// loaded machine would blur (two cores, a Python server, a PLC at 4×).
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs of a real-time test made at most, when the PLC keeps falling behind.
const ATTEMPTS: usize = 5;

/// A real-time run that fails is evidence only if the PLC served its plant on
/// time: on a loaded machine the replay or the virtual PLC falls behind, and
/// its edges then come late for any observer. `run` returns how far behind it
/// fell (`Err`, in the plant's milliseconds) when a failure came with such
/// lateness ([`excused_if_late`]); such a run is made again, and `ATTEMPTS`
/// of them fail the test.
fn on_time(what: &str, mut run: impl FnMut() -> Result<(), f64>) {
    for attempt in 1..=ATTEMPTS {
        match run() {
            Ok(()) => return,
            Err(late) => eprintln!(
                "{what}: run {attempt}: the PLC fell {late:.1} ms behind real time; \
                 the run is made again"
            ),
        }
    }
    panic!("{what}: the PLC fell behind real time in {ATTEMPTS} runs");
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
    let python = std::env::var("GARDEFOU_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&python)
        .args(["-c", "import pymodbus"])
        .status()
        .unwrap_or_else(|e| panic!("{python} does not run: {e}"));
    assert!(
        probe.success(),
        "pymodbus is missing from {python}: run the tests with scripts/test, which installs it"
    );
    let mut plc = Lines::spawn(
        Command::new(&python)
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

/// How far the pymodbus PLC's replay fell behind the log's times at worst, in
/// the log's milliseconds, read from its last line (it waits for the replay's end,
/// which a wait for another line may already have read).
fn python_most_late_ms(plc: &mut Lines) -> f64 {
    let seen = plc.seen.iter().find(|l| l.contains("\"end\"")).cloned();
    let end = seen
        .or_else(|| plc.wait_for("\"end\"", Duration::from_secs(30)))
        .unwrap_or_else(|| panic!("the pymodbus PLC never ended: {:?}", plc.seen));
    let v: serde_json::Value = serde_json::from_str(&end).expect("a JSON line");
    v["most_late_ms"].as_f64().expect("most_late_ms")
}

/// The pymodbus replay's lateness that leaves the shipped model's guards
/// meaningful: one scan of the log.
const PYTHON_LATE_MS: f64 = 10.0;

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
    on_time(
        "independent server",
        diagnose_and_flag_an_independent_server,
    );
}

fn diagnose_and_flag_an_independent_server() -> Result<(), f64> {
    let port = free_port();
    let http = free_port();
    // F2 (C4 stuck at 1) starts at 602 s; RE(C5) settles it about 3.7 s later.
    let mut plc = python_plc(port, 596_000, 608_000, 2.0);
    let mut mon = monitor(port, Some(http), "8s");
    // Other parts may see a polling artefact (an edge a few ms outside its
    // learned window); the turntable's verdict is what is checked.
    let certain = mon.wait_for("\"labels\":[\"F2\"]", Duration::from_secs(15));
    let Some(certain) = certain else {
        let failure = Some(format!("no certain verdict: {:?}", mon.seen));
        return excused_if_late(failure, || python_most_late_ms(&mut plc), PYTHON_LATE_MS);
    };
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
    Ok(())
}

/// The PLC is killed after the flag is written and a fresh one (coils all 0)
/// takes its place: the monitor reports the gap, reconnects and writes
/// `def_C4` again.
#[test]
fn a_restarted_plc_gets_the_raised_flag_back() {
    let _serial = serial();
    on_time("restarted PLC", restart_the_plc);
}

fn restart_the_plc() -> Result<(), f64> {
    let port = free_port();
    let mut first = python_plc(port, 596_000, 608_000, 2.0);
    let mut mon = monitor(port, None, "14s");
    let written = first.wait_for(
        "\"flag\": \"def_C4\", \"coil\": 100, \"value\": true",
        Duration::from_secs(15),
    );
    if written.is_none() {
        let failure = Some(format!(
            "def_C4 not written: {:?} / {:?}",
            first.seen, mon.seen
        ));
        return excused_if_late(failure, || python_most_late_ms(&mut first), PYTHON_LATE_MS);
    }
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
    Ok(())
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
    on_time("virtual PLC goes on", flag_a_virtual_plc_which_goes_on);
}

fn flag_a_virtual_plc_which_goes_on() -> Result<(), f64> {
    let (_dir, run_plant, model) = learned_virtual_plc();
    let (mut plc, port) = virtual_plc(model, "140s", Some("F2@40s"));
    let mut mon = monitor_at_4x(run_plant, model, port, "33s");
    let certain = mon.wait_for("\"labels\":[\"F2\"]", Duration::from_secs(30));
    let Some(certain) = certain else {
        let failure = Some(format!("F2 never certain: {:?}", mon.seen));
        return excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS);
    };
    assert!(certain.contains("\"part\":\"turntable\""), "{certain}");
    assert!(certain.contains("def_C4"), "{certain}");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(err.contains("flags written to the PLC: def_C4"), "{err}");

    let out = plc.wait_with_output().expect("the virtual PLC ends");
    assert!(
        out.status.success(),
        "the virtual PLC failed: {:?}",
        out.status
    );
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
    // Without --probe, no probe coil is ever written.
    assert_eq!(summary["probe_writes"], 0, "{summary}");
    Ok(())
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

/// A plant file and a model learned from one fault-free hour of the virtual
/// PLC's control, once for the tests that need them.
fn learned_virtual_plc() -> &'static (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    static LEARNED: std::sync::OnceLock<(
        tempfile::TempDir,
        std::path::PathBuf,
        std::path::PathBuf,
    )> = std::sync::OnceLock::new();
    LEARNED.get_or_init(|| {
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
        ok(Command::new(bin)
            .args(["simulate", "--control", "constraints", "--duration", "1h"])
            .args(["--seed", "7", "--out"])
            .arg(&run)
            .output()
            .expect("simulate runs"));
        // Polling adds up to half a scan to every edge, and a loaded
        // machine's scheduling a few milliseconds more (times the speed):
        // wider guards.
        ok(Command::new(bin)
            .args(["learn", "--margin", "50ms", "--plant"])
            .arg(run.join("plant.toml"))
            .arg(run.join("events.csv"))
            .arg("-o")
            .arg(&model)
            .output()
            .expect("learn runs"));
        let plant = run.join("plant.toml");
        (dir, plant, model)
    })
}

/// The virtual PLC at 4× for `duration`, with `fault` if any; its port.
fn virtual_plc(model: &Path, duration: &str, fault: Option<&str>) -> (Child, u16) {
    virtual_plc_at(4, model, duration, fault)
}

/// The virtual PLC at `speed`, and its port.
fn virtual_plc_at(speed: u32, model: &Path, duration: &str, fault: Option<&str>) -> (Child, u16) {
    virtual_plc_with(speed, model, duration, fault, &[])
}

/// The same, with more arguments.
fn virtual_plc_with(
    speed: u32,
    model: &Path,
    duration: &str,
    fault: Option<&str>,
    extra: &[&std::ffi::OsStr],
) -> (Child, u16) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args(["simulate", "--serve-modbus", "127.0.0.1:0", "--realtime"])
        .args(["--speed", &speed.to_string(), "--duration", duration])
        .arg("--model")
        .arg(model)
        .args(extra);
    if let Some(f) = fault {
        cmd.args(["--fault", f]);
    }
    let mut plc = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the virtual PLC starts");
    let mut err = BufReader::new(plc.stderr.take().expect("stderr"));
    let mut first = String::new();
    err.read_line(&mut first).expect("a first line");
    let port: u16 = first
        .split("127.0.0.1:")
        .nth(1)
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no port in: {first}"));
    // The rest of its stderr is drained, so that it never blocks.
    std::thread::spawn(move || std::io::copy(&mut err, &mut std::io::sink()));
    (plc, port)
}

/// The monitor at 4× on `port` for `duration`.
fn monitor_at_4x(plant: &Path, model: &Path, port: u16, duration: &str) -> Lines {
    monitor_at(4, plant, model, port, duration)
}

/// The monitor at `speed` on `port` for `duration`.
fn monitor_at(speed: u32, plant: &Path, model: &Path, port: u16, duration: &str) -> Lines {
    monitor_with(speed, plant, model, port, duration, &[])
}

/// The same, with more arguments.
fn monitor_with(
    speed: u32,
    plant: &Path,
    model: &Path,
    port: u16,
    duration: &str,
    extra: &[&str],
) -> Lines {
    Lines::spawn(
        Command::new(env!("CARGO_BIN_EXE_gardefou"))
            .args(["monitor", "--plant"])
            .arg(plant)
            .arg("--model")
            .arg(model)
            .args(["--modbus", &format!("127.0.0.1:{port}")])
            .args(["--speed", &speed.to_string(), "--duration", duration])
            .args(extra),
    )
}

/// A healthy virtual PLC read through a slow network: 1 % of the replies
/// delayed by 50–300 ms, then 5 % by up to 1 s, then 5 % by up to 300 ms
/// overtaken by later ones, with 1 % lost. Late replies delay the watermark,
/// never a timestamp, and a lost one costs a sample; the monitor joins the
/// running plant mid-cycle, with its clocks unknown: no verdict leaves normal
/// and no flag is written. `GARDEFOU_SLOW_NETWORK_SECONDS` sets each run's wall time.
#[test]
fn a_slow_network_gives_no_verdict_and_writes_no_flag() {
    let _serial = serial();
    let (_dir, plant, model) = learned_virtual_plc();
    let seconds: u64 = std::env::var("GARDEFOU_SLOW_NETWORK_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let lossy = Faults {
        in_order: false,
        drop_share: 0.01,
        ..Faults::delays(0.05, Duration::ZERO, Duration::from_millis(300), 3)
    };
    for (run, faults) in [
        Faults::delays(
            0.01,
            Duration::from_millis(50),
            Duration::from_millis(300),
            11,
        ),
        Faults::delays(0.05, Duration::ZERO, Duration::from_secs(1), 11),
        lossy,
    ]
    .into_iter()
    .enumerate()
    {
        let what = format!("slow network {}", faults.delay_share);
        on_time(&what, || {
            slow_network_run(plant, model, seconds, run, faults.clone())
        });
    }
}

/// The virtual PLC's lateness that the model learned for it tolerates: half
/// the margin its guards were widened by (`learn --margin 50ms`).
const VIRTUAL_LATE_MS: f64 = 25.0;

/// One run of [`a_slow_network_gives_no_verdict_and_writes_no_flag`]: `Err`
/// when the virtual PLC fell behind real time (the run proves nothing), `Ok`
/// when it kept time and the monitor gave no verdict and no flag.
fn slow_network_run(
    plant: &Path,
    model: &Path,
    seconds: u64,
    run: usize,
    faults: Faults,
) -> Result<(), f64> {
    let share = faults.delay_share;
    // In real time: a scheduling hiccup of this machine (15 ms seen on an idle
    // one) is then 15 ms of the plant's time, not 60 as at 4×.
    let plc_time = format!("{}s", seconds + 30);
    let (mut plc, port) = virtual_plc_at(1, model, &plc_time, None);
    // The monitor joins a running plant, in the middle of a cycle.
    std::thread::sleep(Duration::from_millis(1700 + 900 * run as u64));
    let proxy = Proxy::start(([127, 0, 0, 1], port).into(), faults);
    let mut mon = monitor_at(1, plant, model, proxy.port(), &format!("{seconds}s"));
    let status = mon.child.wait().expect("the monitor ends");
    let _ = mon.wait_for("never printed", Duration::from_millis(200));
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    let stats = proxy.stats();
    assert!(stats.delayed > 0, "{stats:?}");
    let failure = if !mon.seen.is_empty() {
        Some(format!(
            "{share}: verdicts on a healthy plant: {:?}\n{err}",
            mon.seen
        ))
    } else if !err.contains("flags: none") || err.contains("flags written to the PLC: def_") {
        Some(format!("{share}: flags on a healthy plant: {err}"))
    } else {
        None
    };
    excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS)
}

/// A run's `failure`, if any: excused (`Err`, the run is made again) when
/// the PLC fell more than `limit` ms behind real time, which `late` reads.
/// A run that passes is never made again, whatever its lateness.
fn excused_if_late(
    failure: Option<String>,
    late: impl FnOnce() -> f64,
    limit: f64,
) -> Result<(), f64> {
    let Some(failure) = failure else {
        return Ok(());
    };
    let late = late();
    if late > limit {
        eprintln!("{failure}");
        return Err(late);
    }
    panic!("{failure} (the PLC kept time: {late:.1} ms late at worst)");
}

/// Stops the virtual PLC and reads, from its summary, how far behind real
/// time it fell at worst, in simulated milliseconds.
fn most_late_ms(plc: &mut Child) -> f64 {
    let summary = stop_plc(plc);
    summary["most_late_ms"].as_f64().expect("most_late_ms")
}

/// Stops the virtual PLC; its summary.
fn stop_plc(plc: &mut Child) -> serde_json::Value {
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(plc.id() as i32, libc::SIGTERM) };
    let mut out = String::new();
    let stdout = plc.stdout.as_mut().expect("stdout");
    stdout.read_to_string(&mut out).expect("the summary");
    let _ = plc.wait();
    serde_json::from_str(out.trim())
        .unwrap_or_else(|e| panic!("the virtual PLC's summary {out:?}: {e}"))
}

/// Through the same slow network, C4 stuck at 1 from 60 s: F2 is labelled and
/// `def_C4` written within 2 s of wall time after the evidence (the deadline
/// the stuck sensor misses).
#[test]
fn a_slow_network_still_flags_a_stuck_sensor_within_two_seconds() {
    let _serial = serial();
    on_time(
        "slow network, C4 stuck",
        flag_a_stuck_sensor_through_a_slow_network,
    );
}

fn flag_a_stuck_sensor_through_a_slow_network() -> Result<(), f64> {
    let (_dir, plant, model) = learned_virtual_plc();
    let (mut plc, port) = virtual_plc(model, "200s", Some("F2@60s"));
    let faults = Faults::delays(
        0.01,
        Duration::from_millis(50),
        Duration::from_millis(300),
        5,
    );
    let proxy = Proxy::start(([127, 0, 0, 1], port).into(), faults);
    let started = std::time::SystemTime::now();
    let mut mon = monitor_at_4x(plant, model, proxy.port(), "40s");
    let certain = mon.wait_for("\"labels\":[\"F2\"]", Duration::from_secs(40));
    let seen_at = std::time::SystemTime::now();
    let Some(certain) = certain else {
        let failure = Some(format!("F2 never certain: {:?}", mon.seen));
        return excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS);
    };
    assert!(certain.contains("def_C4"), "{certain}");
    // The verdict's time is on the monitor's live clock: the wall clock at its
    // start, running 4 times faster.
    let v: serde_json::Value = serde_json::from_str(&certain).expect("JSON");
    let t = v["t"].as_str().expect("an RFC 3339 time");
    let evidence = rfc3339_seconds(t);
    let start = started
        .duration_since(std::time::UNIX_EPOCH)
        .expect("epoch")
        .as_secs_f64();
    let wall_of_evidence = start + (evidence - start) / 4.0;
    let now = seen_at
        .duration_since(std::time::UNIX_EPOCH)
        .expect("epoch")
        .as_secs_f64();
    let waited = now - wall_of_evidence;
    eprintln!("F2 came {waited:.3} s after its evidence");
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    let failure = if waited >= 2.0 {
        Some(format!("F2 came {waited:.3} s after its evidence"))
    } else if mon.seen.iter().any(|l| l.contains("unknown")) {
        Some(format!("unknown on a stuck sensor: {:?}", mon.seen))
    } else {
        None
    };
    let verdict = excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS);
    let _ = plc.kill();
    let _ = plc.wait();
    verdict?;
    assert!(err.contains("flags written to the PLC: def_C4"), "{err}");
    assert!(err.contains("def_C4 raised at"), "{err}");
    Ok(())
}

/// Seconds since the epoch of an RFC 3339 UTC time (`…T05:00:00.010Z`).
fn rfc3339_seconds(t: &str) -> f64 {
    let (date, time) = t
        .trim_end_matches('Z')
        .split_once('T')
        .expect("a date and a time");
    let mut d = date.split('-').map(|x| x.parse::<i64>().expect("a number"));
    let (y, m, day) = (
        d.next().unwrap_or(0),
        d.next().unwrap_or(0),
        d.next().unwrap_or(0),
    );
    // Days from the civil date (Howard Hinnant's algorithm).
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    let mut hms = time.split(':').map(|x| x.parse::<f64>().expect("a number"));
    let (h, mi, s) = (
        hms.next().unwrap_or(0.0),
        hms.next().unwrap_or(0.0),
        hms.next().unwrap_or(0.0),
    );
    days as f64 * 86_400.0 + h * 3600.0 + mi * 60.0 + s
}

/// The sorting line without the four constraints that forbid reversing the
/// turntable away from a position (CSs8, CSs13, CSs14, CSs15), as in
/// `tests/it/probing.rs`: there, releasing A4 tells C5 stuck at 0 (the plate
/// comes back to C4) from the plate blocked in transit (it does not). Written
/// as a plant file into `dir`, for the virtual PLC and the monitor alike.
fn reversible_line(dir: &Path) -> (diagnoser::Plant, std::path::PathBuf) {
    let mut text = datasets::sorting::PLANT_TOML.to_string();
    for name in ["CSs8", "CSs13", "CSs14", "CSs15"] {
        let at = text.find(&format!("name = \"{name}\"")).expect(name);
        let start = text[..at].rfind("[[constraints]]").expect("its table");
        let end = text[at..].find("\n[").map_or(text.len(), |e| at + e + 1);
        text.replace_range(start..end, "");
    }
    let path = dir.join("reversible.toml");
    std::fs::write(&path, &text).expect("writes the plant file");
    let plant = diagnoser::Plant::from_path(&path).expect("parses");
    let shipped = datasets::sorting::plant();
    assert_eq!(plant.constraints.len(), shipped.constraints.len() - 4);
    (plant, path)
}

/// The seed of the virtual PLC's runs here (`simulate`'s default).
const SEED: u64 = 7;

/// The first time after `after` the fault-free line of [`SEED`] brings the
/// turntable back to loading, plus a scan: C5 stuck at 0 from then shows on
/// the next rotation as the ambiguity "F3, F11".
fn back_at_loading(plant: &diagnoser::Plant, after: diagnoser::Time) -> diagnoser::Time {
    let normal = runtime::closed_loop::record(plant, SEED, after + 120 * diagnoser::SECOND)
        .expect("records");
    let c4 = plant.signals.id("C4").expect("C4");
    let back = normal
        .events
        .iter()
        .find(|e| e.signal == c4 && e.value && e.t > after)
        .expect("the turntable comes back");
    back.t + 10 * diagnoser::MS
}

/// The virtual PLC at 4× on the reversible line (its plant file `plant`),
/// coupled by `def_` and `suspect_` flags, with C5 stuck at 0 from the
/// turntable's first return to loading; its port.
fn reversible_plc(plant: &diagnoser::Plant, file: &Path, model: &Path) -> (Child, u16) {
    let onset = back_at_loading(plant, 20 * diagnoser::SECOND);
    let fault = format!("F3@{}ms", onset / diagnoser::MS);
    let seed = SEED.to_string();
    let extra: [&std::ffi::OsStr; 6] = [
        "--coupling".as_ref(),
        "def+suspect".as_ref(),
        "--plant-file".as_ref(),
        file.as_os_str(),
        "--seed".as_ref(),
        seed.as_ref(),
    ];
    virtual_plc_with(4, model, "150s", Some(&fault), &extra)
}

/// `monitor --probe` beside the virtual PLC of the reversible line: the
/// turntable turns ambiguous between F3 and F11 while A4 waits for C5; the
/// monitor asks the PLC to release A4, the plate comes back to C4, and the
/// verdict line that says F3 gives the probe as its reason.
#[test]
fn with_probe_the_monitor_releases_a4_to_tell_a_stuck_c5_from_a_blocked_plate() {
    let _serial = serial();
    on_time("monitor --probe", probe_the_reversible_line);
}

fn probe_the_reversible_line() -> Result<(), f64> {
    // Under fault-free control the turntable never turns back: the hour the
    // shared model is learned from is the same on both lines.
    let (_learned, _, model) = learned_virtual_plc();
    let dir = tempfile::tempdir().expect("temporary directory");
    let (plant, file) = reversible_line(dir.path());
    let (mut plc, port) = reversible_plc(&plant, &file, model);
    let mut mon = monitor_with(4, &file, model, port, "60s", &["--probe"]);
    let Some(told) = mon.wait_for("released A4", Duration::from_secs(45)) else {
        let failure = Some(format!("no probe told: {:?}", mon.seen));
        return excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS);
    };
    let v: serde_json::Value = serde_json::from_str(&told).expect("a JSON verdict line");
    let reason = v["reason"].as_str().expect("a reason");
    assert_eq!(v["part"], "turntable", "{told}");
    // The candidates the move tells apart hold F3 and F11 (a glitch the
    // polls saw earlier may leave the plate's return among them too).
    assert!(reason.starts_with("released A4 to tell F3, F11"), "{told}");
    assert!(reason.ends_with("so F3"), "{told}");
    assert_eq!(v["labels"], serde_json::json!(["F3"]), "{told}");
    assert!(
        mon.seen
            .iter()
            .any(|l| l.contains("\"labels\":[\"F3\",\"F11\"")),
        "{:?}",
        mon.seen
    );
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(mon.child.id() as i32, libc::SIGTERM) };
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(
        err.contains("monitor: probing turntable at")
            && err.contains(
                "released A4 to tell F3, F11 apart (writing A4_PROBE_VALUE = 0, then A4_PROBE = 1)"
            ),
        "{err}"
    );
    assert!(
        err.contains("monitor: probe of turntable ended at"),
        "{err}"
    );
    // The count `/status` and `/metrics` give, in the summary at the end.
    assert!(err.contains(", 1 probing move(s); flags:"), "{err}");
    let summary = stop_plc(&mut plc);
    assert_eq!(summary["probe_requests"], 1, "{summary}");
    assert_eq!(summary["damage"], serde_json::json!([]), "{summary}");
    Ok(())
}

/// The same line and fault without `--probe`: the turntable stays
/// ambiguous, and no probe coil is ever written.
#[test]
fn without_probe_no_probe_coil_is_written_where_a_probe_would_be_made() {
    let _serial = serial();
    on_time("monitor without --probe", watch_the_reversible_line);
}

fn watch_the_reversible_line() -> Result<(), f64> {
    let (_learned, _, model) = learned_virtual_plc();
    let dir = tempfile::tempdir().expect("temporary directory");
    let (plant, file) = reversible_line(dir.path());
    let (mut plc, port) = reversible_plc(&plant, &file, model);
    let mut mon = monitor_at(4, &file, model, port, "60s");
    let ambiguous = "\"labels\":[\"F3\",\"F11\"]";
    if mon.wait_for(ambiguous, Duration::from_secs(45)).is_none() {
        let failure = Some(format!("never ambiguous: {:?}", mon.seen));
        return excused_if_late(failure, || most_late_ms(&mut plc), VIRTUAL_LATE_MS);
    }
    // Past the wait before a probe (2 s of the plant) and the answer that
    // one would have brought (3 s), at 4×.
    let after = mon.wait_for("\"part\":\"turntable\"", Duration::from_secs(3));
    assert!(
        after.is_none(),
        "the turntable's verdict changed: {after:?}"
    );
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(mon.child.id() as i32, libc::SIGTERM) };
    let status = mon.child.wait().expect("the monitor ends");
    let err = mon.stderr();
    assert!(status.success(), "{err}");
    assert!(!err.contains("probing"), "{err}");
    let summary = stop_plc(&mut plc);
    assert_eq!(summary["probe_writes"], 0, "{summary}");
    assert_eq!(summary["probe_requests"], 0, "{summary}");
    Ok(())
}
