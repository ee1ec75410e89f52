//! `gardefou fleet`: workers sharing plants out of their streams on a real
//! NATS server, one killed (SIGKILL) in the middle of the plants' runs and
//! its plants taken over by the other from their checkpoints. The lines of
//! both workers, plant by plant, are then those of one uninterrupted worker,
//! byte for byte: none lost, none twice.
//!
//! The plants are slices of the shipped F2 and F5 runs of the sorting line
//! around their faults, replayed live at 5× by monitors publishing with
//! `--nats`. The server comes as in [`crate::monitor_nats`].

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use crate::monitor_nats::{Server, messages, nats_server};
use crate::support::{free_port, http_get, repo as path};

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
/// The slice of each run: the faults show from 602.9 s.
const FROM_MS: i64 = 590_000;
const TO_MS: i64 = 612_000;

/// The slice of the shipped run `run` between [`FROM_MS`] and [`TO_MS`], as
/// an events log: every signal's value at the start, the changes, the end.
fn slice(run: &str) -> String {
    let text = std::fs::read_to_string(path(&format!("datasets/data/sorting/{run}/events.csv")))
        .expect("the shipped log");
    let mut values: BTreeMap<String, String> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    let mut changes = String::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (t, signal, value) = (f[0].parse::<i64>().expect("a time"), f[1], f[2]);
        if signal.is_empty() || t > TO_MS {
            continue;
        }
        if t <= FROM_MS {
            if !values.contains_key(signal) {
                order.push(signal.to_string());
            }
            values.insert(signal.to_string(), value.to_string());
        } else {
            changes.push_str(&format!("{line}\n"));
        }
    }
    let mut out = String::from("t,signal,value\n");
    for s in &order {
        out.push_str(&format!("{FROM_MS},{s},{}\n", values[s]));
    }
    out.push_str(&changes);
    out.push_str(&format!("{TO_MS},,\n"));
    out
}

/// The plants: a name, the run it replays.
const PLANTS: [(&str, &str); 3] = [("a", "F2"), ("b", "F5"), ("c", "F2")];

fn worker(url: &str, plants: &[&str], args: &[&str]) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args(["fleet", "--nats", url]);
    for name in plants {
        let run = PLANTS.iter().find(|(n, _)| n == name).expect("a plant").1;
        cmd.args([
            "--plant",
            &path(&format!("datasets/data/sorting/{run}/plant.toml")),
        ])
        .args(["--model", &path(MODEL), "--nats-plant", name]);
    }
    cmd.args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("a worker starts")
}

/// A worker's output: its lines, by plant, in order; and its stderr.
fn output(child: Child) -> (BTreeMap<String, Vec<String>>, String) {
    let out = child.wait_with_output().expect("the worker ends");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    (by_plant(String::from_utf8_lossy(&out.stdout).lines()), err)
}

fn by_plant<'a>(lines: impl Iterator<Item = &'a str>) -> BTreeMap<String, Vec<String>> {
    let mut by: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for line in lines {
        let v: serde_json::Value = serde_json::from_str(line).expect("a JSON line");
        let plant = v["plant"].as_str().expect("a plant field").to_string();
        by.entry(plant).or_default().push(line.to_string());
    }
    by
}

/// Hands each line of `stdout` to `send`, on a thread of its own, until
/// `send` says no more.
fn forward(
    stdout: std::process::ChildStdout,
    mut send: impl FnMut(String) -> bool + Send + 'static,
) {
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if !send(line) {
                break;
            }
        }
    });
}

/// A monitor per plant, replaying its slice at 5× and publishing it.
fn monitors(dir: &Path, url: &str) -> Vec<Child> {
    PLANTS
        .iter()
        .map(|(name, run)| {
            let log = dir.join(format!("{name}.csv"));
            std::fs::write(&log, slice(run)).expect("writes the slice");
            let plant = path(&format!("datasets/data/sorting/{run}/plant.toml"));
            Command::new(env!("CARGO_BIN_EXE_gardefou"))
                .args(["monitor", "--plant", &plant, "--model", &path(MODEL)])
                .arg("--replay")
                .arg(&log)
                .args(["--speed", "5", "--nats", url, "--nats-plant", name])
                .arg("--nats-outbox")
                .arg(dir.join(format!("{name}.outbox")))
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("a monitor starts")
        })
        .collect()
}

#[test]
fn a_killed_workers_plants_are_taken_over_and_the_lines_are_those_of_one_run() {
    let Some(bin) = nats_server() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let port = free_port();
    let _server = Server::start(&bin, port, &dir.path().join("store"));
    let url = format!("nats://127.0.0.1:{port}");

    // Two workers share the plants.
    let all = ["a", "b", "c"];
    let mut workers = [
        worker(&url, &all, &["--worker", "A"]),
        worker(&url, &all, &["--worker", "B"]),
    ];
    std::thread::sleep(Duration::from_millis(1500));
    let monitors = monitors(dir.path(), &url);

    // The first worker to print a line is killed 250 ms later (1.25 s of
    // the plants' time), between two of its lines: a worker killed while it
    // publishes a line leaves that line on the stream, not on its stdout.
    let (tx, rx) = mpsc::channel();
    for (i, w) in workers.iter_mut().enumerate() {
        let stdout = w.stdout.take().expect("a worker's stdout");
        let tx = tx.clone();
        forward(stdout, move |line| tx.send((i, line)).is_ok());
    }
    let (killed, first) = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("a worker prints a line");
    std::thread::sleep(Duration::from_millis(250));
    workers[killed].kill().expect("kills the worker");
    let _ = workers[killed].wait();
    let mut printed_by_killed = vec![first];
    drop(tx);
    for m in monitors {
        let out = m.wait_with_output().expect("a monitor ends");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // Every line, until both workers' outputs close (the survivor's at its end).
    let mut by_survivor: BTreeMap<String, Vec<String>> = BTreeMap::new();
    loop {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok((i, line)) if i == killed => printed_by_killed.push(line),
            Ok((_, line)) => {
                let v: serde_json::Value = serde_json::from_str(&line).expect("a JSON line");
                let plant = v["plant"].as_str().expect("a plant field").to_string();
                by_survivor.entry(plant).or_default().push(line);
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => panic!("the surviving worker does not end"),
        }
    }
    let [w0, w1] = workers;
    let (survivor, victim) = if killed == 0 { (w1, w0) } else { (w0, w1) };
    let stderr = |c: Child| {
        String::from_utf8_lossy(&c.wait_with_output().expect("a worker ends").stderr).to_string()
    };
    let (err_killed, err_survivor) = (stderr(victim), stderr(survivor));
    // Both served plants before the kill; the survivor took the others over.
    let served = |err: &str| err.matches("served here from").count();
    assert!(
        served(&err_killed) >= 1,
        "the killed worker served nothing:\n{err_killed}"
    );
    assert!(
        err_survivor.contains("served here from the checkpoint at message"),
        "the survivor took nothing over from a checkpoint:\n{err_survivor}"
    );
    assert!(
        served(&err_killed) < 3,
        "the killed worker served every plant:\n{err_killed}"
    );

    let (reference, err) = output(worker(&url, &all, &["--fleet", "reference"]));
    assert_eq!(reference.len(), 3, "{err}");
    let by_killed = by_plant(printed_by_killed.iter().map(String::as_str));
    for (plant, want) in &reference {
        let mut got = by_killed.get(plant).cloned().unwrap_or_default();
        got.extend(by_survivor.get(plant).cloned().unwrap_or_default());
        assert!(
            &got == want,
            "plant {plant}: the workers' lines differ from one run's\n--- killed then survivor\n{}\n--- one run\n{}",
            got.join("\n"),
            want.join("\n")
        );
    }
    assert!(
        by_killed.keys().any(|p| by_survivor.contains_key(p)),
        "no plant has lines from both workers: {by_killed:?}, {by_survivor:?}"
    );
    assert!(
        reference
            .values()
            .flatten()
            .any(|l| l.contains("\"flags\":[\"def_C4\"]")),
        "{reference:?}"
    );
    // The fleet's verdict stream holds each line once.
    for (plant, want) in &reference {
        let stored = messages(
            port,
            "GARDEFOU_FLEET",
            &format!("gardefou.fleet.main.{plant}"),
        );
        assert_eq!(&stored, want, "plant {plant}: the stream's lines");
    }
}

/// `gardefou learn … --publish`: the model version it stored, from its
/// message.
fn learn_and_publish(url: &str, dir: &Path, name: &str, args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "learn",
            "--plant",
            &path("datasets/data/sorting/F2/plant.toml"),
        ])
        .arg(path("datasets/data/sorting/normal/events.csv"))
        .arg("-o")
        .arg(dir.join(format!("{name}.json")))
        .args(["--publish", url, "--nats-plant", "a"])
        .args(args)
        .output()
        .expect("learn runs");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    let version = err
        .lines()
        .find_map(|l| l.strip_prefix("published model "))
        .and_then(|l| l.split(' ').next())
        .unwrap_or_else(|| panic!("learn says what it published:\n{err}"));
    version.to_string()
}

/// The model versions `lines` name, in order, each once.
fn versions(lines: &[String]) -> Vec<String> {
    let mut seen: Vec<String> = Vec::new();
    for line in lines {
        let v: serde_json::Value = serde_json::from_str(line).expect("a JSON line");
        let model = v["model"].as_str().unwrap_or("(none)").to_string();
        if seen.last() != Some(&model) {
            seen.push(model);
        }
    }
    seen
}

#[test]
fn a_new_model_in_the_store_is_taken_up_by_a_worker_and_a_monitor_between_two_messages() {
    let Some(bin) = nats_server() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let port = free_port();
    let _server = Server::start(&bin, port, &dir.path().join("store"));
    let url = format!("nats://127.0.0.1:{port}");
    let first = learn_and_publish(&url, dir.path(), "m1", &[]);

    // A worker with no --plant serves the store's plants.
    let http = free_port();
    let mut worker = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["fleet", "--nats", &url, "--worker", "W"])
        .args(["--http", &format!("127.0.0.1:{http}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("a worker starts");
    std::thread::sleep(Duration::from_millis(1500));
    let log = dir.path().join("a.csv");
    std::fs::write(&log, slice("F2")).expect("writes the slice");
    // The monitor takes its model from the store too (no --model).
    let monitor = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args([
            "monitor",
            "--plant",
            &path("datasets/data/sorting/F2/plant.toml"),
        ])
        .arg("--replay")
        .arg(&log)
        .args(["--speed", "2", "--nats", &url, "--nats-plant", "a"])
        .arg("--follow-models")
        .arg("--nats-outbox")
        .arg(dir.path().join("a.outbox"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("a monitor starts");
    let (tx, rx) = mpsc::channel();
    let stdout = worker.stdout.take().expect("the worker's stdout");
    forward(stdout, move |line| tx.send(line).is_ok());
    let mut lines = vec![
        rx.recv_timeout(Duration::from_secs(30))
            .expect("the worker prints a line"),
    ];
    // The fleet view shows the plant served, with its model.
    let status = http_get(http, "/status");
    let body: serde_json::Value =
        serde_json::from_str(&status[status.find("\r\n\r\n").expect("a body") + 4..])
            .expect("JSON");
    assert_eq!(body["plants"][0]["plant"], "a", "{status}");
    assert_eq!(body["plants"][0]["served"], true, "{status}");
    assert_eq!(body["plants"][0]["model"], first.as_str(), "{status}");
    let metrics = http_get(http, "/metrics");
    assert!(
        metrics.contains("gardefou_fleet_plants{state=\"served\"} 1"),
        "{metrics}"
    );
    assert!(
        metrics.contains("gardefou_fleet_consumer_lag{plant=\"a\"}"),
        "{metrics}"
    );
    assert!(http_get(http, "/").contains("<table"), "the page");
    // A new version while both run.
    let second = learn_and_publish(&url, dir.path(), "m2", &["--margin-rel", "0.2"]);
    assert_ne!(first, second, "two models, two versions");
    let monitored = monitor.wait_with_output().expect("the monitor ends");
    let monitor_err = String::from_utf8_lossy(&monitored.stderr).to_string();
    assert!(monitored.status.success(), "{monitor_err}");
    // The worker's lines until it has been quiet for 3 s, then it stops.
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(3)) {
        lines.push(line);
    }
    let status = http_get(http, "/status");
    let _ = Command::new("kill")
        .args(["-TERM", &worker.id().to_string()])
        .status();
    let done = worker.wait_with_output().expect("the worker ends");
    let worker_err = String::from_utf8_lossy(&done.stderr).to_string();
    assert!(done.status.success(), "{worker_err}");

    // Each names the model it used: the first version, then the second.
    let replaced = format!("model {second} replaces {first}");
    assert_eq!(
        versions(&lines),
        [first.clone(), second.clone()],
        "{worker_err}"
    );
    assert!(worker_err.contains(&replaced), "{worker_err}");
    assert!(
        status.contains(&format!("\"model\": \"{second}\"")),
        "the view names the new model: {status}"
    );
    let monitor_lines: Vec<String> = String::from_utf8_lossy(&monitored.stdout)
        .lines()
        .map(String::from)
        .collect();
    assert_eq!(
        versions(&monitor_lines),
        [first.clone(), second.clone()],
        "{monitor_err}"
    );
    assert!(monitor_err.contains(&replaced), "{monitor_err}");
    // The worker's lines are the monitor's, with the plant.
    for line in &lines {
        let v: serde_json::Value = serde_json::from_str(line).expect("a JSON line");
        assert_eq!(v["plant"], "a", "{line}");
    }
}
