//! The logs shipped in `datasets/data` are what the current simulator writes, and
//! each one reads back cleanly with the ground truth it claims.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use diagnoser::{MS, Plant, TimeUnit};
use logs::{read_events, read_intervals_as_events};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/data")
}

/// Every run directory (one holding an `events.csv`), relative to `root`, sorted.
fn runs(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in fs::read_dir(&dir)
            .expect("readable directory")
            .filter_map(Result::ok)
        {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if path.file_name().is_some_and(|n| n == "events.csv") {
                out.push(dir.strip_prefix(root).expect("under root").to_path_buf());
            }
        }
    }
    out.sort();
    out
}

#[test]
fn shipped_logs_are_what_the_simulator_writes() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let out = tmp.path().join("data");
    let status = Command::new("bash")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/regenerate.sh"))
        .arg(&out)
        .env("GARDEFOU", env!("CARGO_BIN_EXE_gardefou"))
        .status()
        .expect("bash runs");
    assert!(status.success());
    let shipped = runs(&data_dir());
    assert_eq!(
        shipped,
        runs(&out),
        "the set of runs differs from datasets/regenerate.sh"
    );
    assert_eq!(shipped.len(), 16);
    for run in &shipped {
        for name in [
            "events.csv",
            "intervals.csv",
            "truth.json",
            "damage.json",
            "plant.toml",
        ] {
            let a = fs::read(data_dir().join(run).join(name)).expect("shipped file");
            let b = fs::read(out.join(run).join(name)).expect("regenerated file");
            assert!(
                a == b,
                "{}/{name} is stale: run `bash datasets/regenerate.sh`",
                run.display()
            );
        }
    }
}

#[test]
fn shipped_logs_read_back_with_their_ground_truth() {
    for run in runs(&data_dir()) {
        let dir = data_dir().join(&run);
        let plant = Plant::from_path(&dir.join("plant.toml")).expect("plant file");
        let events =
            read_events(&dir.join("events.csv"), &plant.signals, TimeUnit::Ms).expect("events");
        let intervals =
            read_intervals_as_events(&dir.join("intervals.csv"), &plant.signals, TimeUnit::Ms)
                .expect("intervals");
        // The events form also says when the run ended (its end row).
        let end = events.end.expect("the simulator writes the end row");
        assert!(
            events.events.last().is_none_or(|e| e.t <= end),
            "{}",
            run.display()
        );
        let events = logs::EventLog {
            end: None,
            ..events
        };
        assert_eq!(events, intervals, "{}", run.display());
        let truth: serde_json::Value =
            serde_json::from_slice(&fs::read(dir.join("truth.json")).expect("truth"))
                .expect("json");
        let faults = truth["faults"].as_array().expect("faults list");
        let name = run.file_name().and_then(|n| n.to_str()).expect("name");
        if name == "normal" {
            assert!(faults.is_empty());
            let damage: serde_json::Value =
                serde_json::from_slice(&fs::read(dir.join("damage.json")).expect("damage"))
                    .expect("json");
            assert_eq!(damage["damage"], serde_json::json!([]), "{}", run.display());
        } else {
            assert_eq!(faults.len(), 1, "{}", run.display());
        }
        if run.starts_with("sorting") && name != "normal" {
            assert_eq!(faults[0]["label"], name);
            assert_eq!(faults[0]["onset"], 602_000);
        }
    }
}

#[test]
fn shipped_f2_run_shows_c4_stuck_while_the_turntable_turns() {
    let dir = data_dir().join("sorting/F2");
    let plant = Plant::from_path(&dir.join("plant.toml")).expect("plant file");
    let log = read_events(&dir.join("events.csv"), &plant.signals, TimeUnit::Ms).expect("events");
    let id = |n: &str| plant.signals.id(n).expect("signal");
    let onset = 602_000 * MS;
    let rise = log
        .events
        .iter()
        .find(|e| e.signal == id("A4") && e.value && e.t >= onset)
        .expect("rotation");
    assert!(
        log.events
            .iter()
            .all(|e| !(e.signal == id("C4") && e.t >= onset)),
        "C4 changed after onset"
    );
    let c5 = log
        .events
        .iter()
        .find(|e| e.signal == id("C5") && e.value && e.t > rise.t)
        .expect("RE(C5)");
    assert!((2900..=2950).contains(&((c5.t - rise.t) / MS)));
}
