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
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use crate::monitor_nats::{Server, messages, nats_server};
use crate::support::{free_port, repo as path};

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

#[test]
fn a_killed_workers_plants_are_taken_over_and_the_lines_are_those_of_one_run() {
    let Some(bin) = nats_server() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let port = free_port();
    let _server = Server::start(&bin, port, &dir.path().join("store"));
    let url = format!("nats://127.0.0.1:{port}");

    // Worker A takes plants a and b first; B takes c, and waits for the rest.
    let mut a = worker(&url, &["a", "b"], &["--worker", "A"]);
    std::thread::sleep(Duration::from_millis(700));
    let b = worker(&url, &["a", "b", "c"], &["--worker", "B"]);
    std::thread::sleep(Duration::from_millis(700));
    let monitors: Vec<Child> = PLANTS
        .iter()
        .map(|(name, run)| {
            let log = dir.path().join(format!("{name}.csv"));
            std::fs::write(&log, slice(run)).expect("writes the slice");
            let plant = path(&format!("datasets/data/sorting/{run}/plant.toml"));
            Command::new(env!("CARGO_BIN_EXE_gardefou"))
                .args(["monitor", "--plant", &plant, "--model", &path(MODEL)])
                .arg("--replay")
                .arg(&log)
                .args(["--speed", "5", "--nats", &url, "--nats-plant", name])
                .arg("--nats-outbox")
                .arg(dir.path().join(format!("{name}.outbox")))
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("a monitor starts")
        })
        .collect();

    // A is killed as soon as it has printed its first line.
    let stdout = a.stdout.take().expect("A's stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let first = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("worker A prints a line");
    a.kill().expect("kills A");
    let _ = a.wait();
    let mut printed_by_a = vec![first];
    printed_by_a.extend(rx.try_iter());
    for m in monitors {
        let out = m.wait_with_output().expect("a monitor ends");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let (by_b, err_b) = output(b);
    assert!(
        err_b.contains("taken up from the checkpoint at message"),
        "B took nothing over from a checkpoint:\n{err_b}"
    );

    let (reference, err) = output(worker(&url, &["a", "b", "c"], &["--fleet", "reference"]));
    assert_eq!(reference.len(), 3, "{err}");
    let by_a = by_plant(printed_by_a.iter().map(String::as_str));
    for (plant, want) in &reference {
        let mut got = by_a.get(plant).cloned().unwrap_or_default();
        got.extend(by_b.get(plant).cloned().unwrap_or_default());
        assert!(
            &got == want,
            "plant {plant}: the workers' lines differ from one run's\n--- A then B\n{}\n--- one run\n{}",
            got.join("\n"),
            want.join("\n")
        );
    }
    assert!(
        by_a.keys().any(|p| by_b.contains_key(p)),
        "no plant has lines from both workers: A {by_a:?}, B {by_b:?}"
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
