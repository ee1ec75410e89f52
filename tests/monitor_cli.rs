//! `gardefou monitor`: online diagnosis from a replayed log or from JSON events
//! on standard input, with deadlines fired by timers.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

fn path(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";

/// A replay, even accelerated 2000 times, gives exactly the offline verdicts:
/// every deadline fires at its own time, between the right scans.
#[test]
fn accelerated_replay_gives_the_offline_verdicts() {
    let plant = path("datasets/data/sorting/F2/plant.toml");
    let log = path("datasets/data/sorting/F2/events.csv");
    let model = path(MODEL);
    let offline = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["diagnose", "--plant", &plant, "--model", &model, &log])
        .output()
        .expect("runs");
    assert!(offline.status.success());
    let online = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &plant, "--model", &model])
        .args(["--replay", &log, "--speed", "2000"])
        .output()
        .expect("runs");
    assert!(
        online.status.success(),
        "{}",
        String::from_utf8_lossy(&online.stderr)
    );
    let text = String::from_utf8_lossy(&online.stdout);
    assert_eq!(text, String::from_utf8_lossy(&offline.stdout));
    assert!(text.contains("\"flags\":[\"def_C4\"]"), "{text}");
    let err = String::from_utf8_lossy(&online.stderr);
    assert!(err.contains("flags: def_C4"), "{err}");
}

fn line(t: u64, signal: &str, value: u8) -> String {
    format!("{{\"t\": {t}, \"signal\": \"{signal}\", \"value\": {value}}}\n")
}

/// With standard input still open and nothing more coming, the deadline after
/// RE(A4) fires from a timer, on time; bad lines and time going backwards are
/// warnings.
#[test]
fn a_deadline_fires_on_time_with_no_new_event() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path("datasets/plants/sorting.toml")])
        .args(["--model", &path(MODEL), "--stdin"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts");
    let mut stdin = child.stdin.take().expect("stdin");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel::<(Instant, String)>();
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send((Instant::now(), l)).is_err() {
                break;
            }
        }
    });
    // Initial values: the turntable at loading, conveyors running.
    let mut text = String::new();
    for (s, v) in [
        ("C0", 0),
        ("C1", 0),
        ("C2", 0),
        ("C3", 0),
        ("C4", 1),
        ("C5", 0),
        ("C6", 0),
        ("C7", 0),
        ("C8", 0),
        ("C9", 0),
        ("C10", 0),
        ("A0", 1),
        ("A1", 1),
        ("A2", 0),
        ("A3", 0),
        ("A4", 0),
        ("A5", 1),
        ("A6", 1),
    ] {
        text.push_str(&line(0, s, v));
    }
    text.push_str("this is not JSON\n");
    stdin.write_all(text.as_bytes()).expect("writes");
    stdin.flush().expect("flushes");
    std::thread::sleep(Duration::from_millis(200));
    // The rotation order, and then silence: C4 never falls.
    stdin
        .write_all(line(1000, "A4", 1).as_bytes())
        .expect("writes");
    stdin.flush().expect("flushes");
    let sent = Instant::now();
    let (at, verdict) = rx
        .recv_timeout(Duration::from_secs(5))
        .expect("a verdict while standard input is still open");
    let waited = at - sent;
    assert!(verdict.contains("\"part\":\"turntable\""), "{verdict}");
    assert!(verdict.contains("no FE(C4) within"), "{verdict}");
    assert!(verdict.contains("\"t\":1140"), "{verdict}");
    // The deadline is 140 ms after RE(A4): not before, and not much after.
    assert!(waited >= Duration::from_millis(100), "{waited:?}");
    assert!(waited < Duration::from_millis(1500), "{waited:?}");
    // Time going backwards: a warning, not a crash.
    stdin
        .write_all(line(500, "A4", 0).as_bytes())
        .expect("writes");
    drop(stdin);
    let out = child.wait_with_output().expect("exits");
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 19: not JSON"), "{err}");
    assert!(err.contains("time went backwards"), "{err}");
    assert!(err.contains("2 warnings"), "{err}");
}

#[test]
fn a_source_is_required() {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path("datasets/plants/sorting.toml")])
        .args(["--model", &path(MODEL)])
        .output()
        .expect("runs");
    assert_eq!(o.status.code(), Some(2));
}

/// The shipped F2 run fed as JSON lines, with stale lines (timestamps going
/// backwards) slipped in after the detection: each is a warning, and `def_C4`
/// stays raised to the end. SIGTERM then ends the monitor cleanly, with its
/// summary.
#[test]
fn out_of_order_events_lose_no_flag_and_sigterm_ends_cleanly() {
    let log = std::fs::read_to_string(path("datasets/data/sorting/F2/events.csv")).expect("log");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "monitor",
            "--plant",
            &path("datasets/data/sorting/F2/plant.toml"),
        ])
        .args(["--model", &path(MODEL), "--stdin"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts");
    let mut stdin = child.stdin.take().expect("stdin");
    let mut text = String::new();
    let mut stale = 0;
    for row in log.lines().skip(1) {
        let mut f = row.split(',');
        let (Some(t), Some(s), Some(v)) = (f.next(), f.next(), f.next()) else {
            continue;
        };
        let t: u64 = t.parse().expect("a time");
        // Up to 610 s: F2 begins at 602 s and is certain by 606 s.
        if t > 610_000 {
            break;
        }
        text.push_str(&line(t, s, v.parse().expect("0 or 1")));
        if t > 607_000 && stale < 3 {
            text.push_str(&line(t - 5_000, "C4", 0));
            stale += 1;
        }
    }
    assert_eq!(stale, 3);
    stdin.write_all(text.as_bytes()).expect("writes");
    stdin.flush().expect("flushes");
    // Standard input stays open: only the signal ends the monitor.
    std::thread::sleep(Duration::from_millis(1500));
    let pid = child.id().to_string();
    let killed = Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill runs");
    assert!(killed.success());
    let out = child.wait_with_output().expect("exits");
    drop(stdin);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert_eq!(err.matches("time went backwards").count(), 3, "{err}");
    assert!(err.contains("monitor terminated"), "{err}");
    assert!(err.contains("flags: def_C4"), "{err}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("\"labels\":[\"F2\"]"), "{text}");
}
