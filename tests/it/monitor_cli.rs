//! `gardefou monitor`: online diagnosis from a replayed log or from JSON events
//! on standard input, with deadlines fired by timers.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::support;
use crate::support::repo as path;

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

/// A replay of every log form (events, intervals and scans CSV, Parquet) of
/// one simulated run with a fault gives exactly the verdicts of `diagnose` on
/// the same file.
#[test]
fn a_replay_of_every_log_form_gives_the_offline_verdicts() {
    let bin = env!("CARGO_BIN_EXE_gardefou");
    let dir = tempfile::tempdir().expect("a temp dir");
    let run = dir.path().join("run");
    let o = Command::new(bin)
        .args([
            "simulate",
            "--duration",
            "12min",
            "--fault",
            "F2@300s",
            "--seed",
            "3",
        ])
        .args(["--scans", "--parquet", "--out"])
        .arg(&run)
        .output()
        .expect("simulate runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plant = run.join("plant.toml");
    let model = path(MODEL);
    let mut flagged = 0;
    for form in [
        "events.csv",
        "intervals.csv",
        "scans.csv",
        "intervals.parquet",
    ] {
        let log = run.join(form);
        assert!(log.exists(), "{form} was not written");
        let offline = Command::new(bin)
            .args(["diagnose", "--model", &model, "--plant"])
            .arg(&plant)
            .arg(&log)
            .output()
            .expect("runs");
        assert!(
            offline.status.success(),
            "{form}: {}",
            String::from_utf8_lossy(&offline.stderr)
        );
        let online = Command::new(bin)
            .args(["monitor", "--model", &model, "--speed", "5000", "--plant"])
            .arg(&plant)
            .arg("--replay")
            .arg(&log)
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&online.stderr);
        assert!(online.status.success(), "{form}: {err}");
        assert!(!err.contains("panicked"), "{form}: {err}");
        let text = String::from_utf8_lossy(&online.stdout);
        assert_eq!(
            text,
            String::from_utf8_lossy(&offline.stdout),
            "{form}: {err}"
        );
        flagged += usize::from(text.contains("def_C4"));
    }
    assert_eq!(flagged, 4, "F2 is flagged from every form");
}

fn line(t: u64, signal: &str, value: u8) -> String {
    format!("{{\"t\": {t}, \"signal\": \"{signal}\", \"value\": {value}}}\n")
}

/// The shipped run of the sorting line's turntable sensor C4 stuck at 1 (F2).
const F2_PLANT: &str = "datasets/data/sorting/F2/plant.toml";
const F2_EVENTS: &str = "datasets/data/sorting/F2/events.csv";

/// `{"t": T}`: nothing else happened up to T.
fn watermark(t: u64) -> String {
    format!("{{\"t\": {t}}}")
}

/// The F2 run as JSON lines.
fn f2_lines() -> Vec<String> {
    let csv = std::fs::read_to_string(path(F2_EVENTS)).expect("log");
    support::feeder::json_lines(&csv)
}

/// `diagnose` on a log of the F2 plant: the verdicts the monitor must give.
fn offline(log: &Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "diagnose",
            "--plant",
            &path(F2_PLANT),
            "--model",
            &path(MODEL),
        ])
        .arg(log)
        .output()
        .expect("runs");
    assert!(o.status.success());
    String::from_utf8(o.stdout).expect("text")
}

/// `diagnose` on the F2 run.
fn f2_offline() -> String {
    offline(Path::new(&path(F2_EVENTS)))
}

/// A whole number from the environment, or `default`.
fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// `monitor --stdin` on the F2 plant, with pipes.
fn stdin_monitor(extra: &[&str]) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "monitor",
            "--plant",
            &path(F2_PLANT),
            "--model",
            &path(MODEL),
        ])
        .arg("--stdin")
        .args(extra)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts")
}

/// Feeds `bytes` (lines) at `pace`, closes standard input, and returns the
/// monitor's stdout and stderr.
fn fed(lines: &[String], pace: &support::feeder::Pace, extra: &[&str]) -> (String, String) {
    let mut child = stdin_monitor(extra);
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = {
        let lines = lines.to_vec();
        let pace = pace.clone();
        std::thread::spawn(move || support::feeder::feed(&mut stdin, &lines, &pace))
    };
    // A monitor that locks up fails the test instead of hanging it.
    let pid = child.id().to_string();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    let Ok(out) = rx.recv_timeout(Duration::from_secs(120)) else {
        let _ = Command::new("kill").args(["-KILL", &pid]).status();
        panic!("{pace:?}: the monitor did not end within 120 s of its input");
    };
    let out = out.expect("waits");
    writer.join().expect("feeds").expect("writes");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    (String::from_utf8_lossy(&out.stdout).into_owned(), err)
}

/// Sends SIGTERM and returns how long the monitor took to exit, and its output.
fn terminate(child: std::process::Child) -> (Duration, std::process::Output) {
    let pid = child.id().to_string();
    let sent = Instant::now();
    let killed = Command::new("kill").args(["-TERM", &pid]).status();
    assert!(killed.expect("kill runs").success());
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    let out = rx
        .recv_timeout(Duration::from_secs(10))
        .expect("exits after SIGTERM")
        .expect("waits");
    (sent.elapsed(), out)
}

/// Deadlines fire on the source's watermarks, never on the wall clock: with
/// standard input open and silent, the deadline after RE(A4) waits; a
/// watermark line past it fires it at its own time. A line behind the
/// watermark is a warning.
#[test]
fn a_deadline_fires_on_a_watermark_not_on_the_wall_clock() {
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
    // The rotation order, then silence up to 1100: C4 has not fallen yet,
    // and its deadline (140 ms after the order) has not passed.
    text.push_str(&line(1000, "A4", 1));
    text.push_str(&format!("{}\n", watermark(1100)));
    stdin.write_all(text.as_bytes()).expect("writes");
    stdin.flush().expect("flushes");
    // Half a second of wall time is not evidence: no verdict.
    assert!(rx.recv_timeout(Duration::from_millis(500)).is_err());
    stdin
        .write_all(format!("{}\n", watermark(1200)).as_bytes())
        .expect("writes");
    stdin.flush().expect("flushes");
    let sent = Instant::now();
    let (at, verdict) = rx
        .recv_timeout(Duration::from_secs(5))
        .expect("a verdict once the watermark passes the deadline");
    assert!(verdict.contains("\"part\":\"turntable\""), "{verdict}");
    assert!(verdict.contains("no FE(C4) within"), "{verdict}");
    assert!(verdict.contains("\"t\":1140"), "{verdict}");
    assert!(at - sent < Duration::from_millis(500), "{:?}", at - sent);
    // Behind the watermark: a warning, not a crash.
    stdin
        .write_all(line(500, "A4", 0).as_bytes())
        .expect("writes");
    drop(stdin);
    let out = child.wait_with_output().expect("exits");
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 19: not JSON"), "{err}");
    assert!(
        err.contains("time 500 is behind the watermark 1200,"),
        "{err}"
    );
    assert!(err.contains("2 warnings"), "{err}");
}

/// However the producer paces its lines (a scan split across pauses, pauses
/// of 0.5 s and 3 s just before the fault shows, random jitter), the verdicts
/// are the offline ones: a pause delays them and changes none.
#[test]
fn a_paced_producer_gives_the_offline_verdicts() {
    use support::feeder::Pace;
    let lines = f2_lines();
    let offline = f2_offline();
    assert!(offline.contains("\"labels\":[\"F2\"]"), "{offline}");
    // The first line at or after the fault's evidence (602.78 s).
    let evidence = lines
        .iter()
        .position(|l| l.contains("\"t\": 6027") || l.contains("\"t\": 6028"))
        .unwrap_or(lines.len() / 2);
    let lock_up = Pace::Pauses(vec![
        (73, Duration::from_millis(10)),
        (74, Duration::from_millis(10)),
    ]);
    for pace in [
        lock_up,
        Pace::Pauses(vec![(evidence, Duration::from_millis(500))]),
        Pace::Pauses(vec![(evidence, Duration::from_secs(3))]),
        Pace::Jitter {
            seed: 7,
            max: Duration::from_micros(300),
        },
    ] {
        let (online, err) = fed(&lines, &pace, &[]);
        assert_eq!(online, offline, "{pace:?}\n{err}");
        assert!(err.contains("flags: def_C4"), "{pace:?}: {err}");
    }
}

/// A far-future time, bytes that are not UTF-8, an over-long line and a line
/// behind the watermark are warnings: the verdicts are those of the log
/// without them.
#[test]
fn bad_lines_are_warnings_and_change_no_verdict() {
    let mut lines = f2_lines();
    let offline = f2_offline();
    lines.insert(
        300,
        r#"{"t": 9999999999, "signal": "C4", "value": 0}"#.into(),
    );
    lines.insert(
        400,
        String::from_utf8_lossy(b"{\"t\": 1, \xff\xfe}").into_owned(),
    );
    lines.insert(500, "x".repeat(100_000));
    lines.insert(600, r#"{"t": 5, "signal": "C4", "value": 1}"#.into());
    // Bytes that are not UTF-8 at all, written raw.
    let mut raw: Vec<u8> = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        if i == 700 {
            raw.extend_from_slice(b"\xc3\x28\xa0\xa1\n");
        }
        raw.extend_from_slice(l.as_bytes());
        raw.push(b'\n');
    }
    let mut child = stdin_monitor(&[]);
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || stdin.write_all(&raw));
    let out = child.wait_with_output().expect("exits");
    writer.join().expect("feeds").expect("writes");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert_eq!(String::from_utf8_lossy(&out.stdout), offline, "{err}");
    assert!(err.contains("far ahead of the stream"), "{err}");
    assert!(err.contains("not UTF-8"), "{err}");
    assert!(err.contains("100000 bytes"), "{err}");
    assert!(err.contains("behind the watermark"), "{err}");
}

/// A flood at full speed, many times over: every run gives the offline
/// verdicts (no timer splits a scan). `GARDEFOU_FLOOD_LINES` sets the flood's
/// length (the F2 run repeated, shifted in time), `GARDEFOU_FLOOD_RUNS` the
/// runs.
#[test]
fn a_flood_gives_the_offline_verdicts_every_time() {
    use support::feeder::Pace;
    let want = env_or("GARDEFOU_FLOOD_LINES", 100_000);
    let runs = env_or("GARDEFOU_FLOOD_RUNS", 3);
    let csv = std::fs::read_to_string(path(F2_EVENTS)).expect("log");
    let (flood, log) = repeated(&csv, want);
    let dir = tempfile::tempdir().expect("a temp dir");
    let file = dir.path().join("flood.csv");
    std::fs::write(&file, &log).expect("writes");
    let offline = offline(&file);
    for run in 0..runs {
        let (online, err) = fed(&flood, &Pace::AllAtOnce, &[]);
        assert!(online == offline, "run {run}: verdicts differ\n{err}");
    }
}

/// The F2 run's events repeated, each copy shifted past the previous, until
/// `want` lines: the JSON lines and the same events as a CSV log.
fn repeated(csv: &str, want: usize) -> (Vec<String>, String) {
    let rows: Vec<(u64, &str, &str)> = csv
        .lines()
        .skip(1)
        .filter_map(|r| {
            let mut f = r.split(',');
            let (t, s, v) = (f.next()?, f.next()?, f.next()?);
            (!s.is_empty())
                .then(|| (t.parse().ok(), s, v))
                .and_then(|(t, s, v)| Some((t?, s, v)))
        })
        .collect();
    let span = rows.last().map_or(1, |r| r.0) + 10_000;
    let mut lines = Vec::new();
    let mut log = String::from("t,signal,value\n");
    let mut copy = 0u64;
    while lines.len() < want {
        // Every copy after the first starts from the first's values again.
        for &(t, s, v) in &rows {
            let t = t + copy * span;
            lines.push(format!(
                "{{\"t\": {t}, \"signal\": \"{s}\", \"value\": {v}}}"
            ));
            log.push_str(&format!("{t},{s},{v}\n"));
        }
        copy += 1;
    }
    (lines, log)
}

/// SIGTERM ends the monitor within a second whatever standard input does:
/// a flood in progress, the pacing that once locked it up, a long pause.
#[test]
fn sigterm_ends_the_monitor_within_a_second() {
    let lines = f2_lines();
    let csv = std::fs::read_to_string(path(F2_EVENTS)).expect("log");
    let (flood, _) = repeated(&csv, 300_000);
    for (what, lines, pause) in [
        ("flood", flood, None),
        (
            "pacing",
            lines[..77].to_vec(),
            Some(Duration::from_millis(10)),
        ),
        ("pause", lines[..500].to_vec(), None),
    ] {
        let mut child = stdin_monitor(&[]);
        let mut stdin = child.stdin.take().expect("stdin");
        let (done_tx, done_rx) = mpsc::channel();
        std::thread::spawn(move || {
            for (i, l) in lines.iter().enumerate() {
                if stdin.write_all(format!("{l}\n").as_bytes()).is_err() {
                    break;
                }
                if let Some(p) = pause
                    && i >= 73
                {
                    let _ = stdin.flush();
                    std::thread::sleep(p);
                }
            }
            let _ = stdin.flush();
            let _ = done_tx.send(());
            // Standard input stays open until the monitor is gone.
            std::thread::sleep(Duration::from_secs(30));
            drop(stdin);
        });
        if what != "flood" {
            done_rx.recv_timeout(Duration::from_secs(10)).expect("fed");
        }
        std::thread::sleep(Duration::from_millis(300));
        let (took, out) = terminate(child);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{what}: {err}");
        assert!(took < Duration::from_secs(1), "{what}: {took:?}");
        assert!(err.contains("monitor terminated"), "{what}: {err}");
    }
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

/// Probing moves are written to a PLC's probe coils: `--probe` with a source
/// that cannot write is refused in one line.
#[test]
fn probe_needs_modbus() {
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path("datasets/plants/sorting.toml")])
        .args(["--model", &path(MODEL), "--stdin", "--probe"])
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("--probe needs --modbus"), "{err}");
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
    assert_eq!(err.matches("behind the watermark").count(), 3, "{err}");
    assert!(err.contains("monitor terminated"), "{err}");
    assert!(err.contains("flags: def_C4"), "{err}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("\"labels\":[\"F2\"]"), "{text}");
}
