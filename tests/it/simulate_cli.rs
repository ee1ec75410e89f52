//! End-to-end tests of `gardefou simulate`: the real binary, real files.

use std::fs;
use std::path::Path;
use std::process::Output;

use crate::support::{assert_bad_input, gardefou};
use diagnoser::{Plant, SECOND, TimeUnit};
use logs::{read_events, read_intervals_as_events};

fn simulate(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["simulate", "--out", out.to_str().expect("utf-8 path")];
    args.extend_from_slice(extra);
    gardefou(&args)
}

fn read(path: &Path) -> Vec<u8> {
    fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

const FILES: [&str; 6] = [
    "events.csv",
    "intervals.csv",
    "scans.csv",
    "truth.json",
    "damage.json",
    "plant.toml",
];

#[test]
fn same_seed_gives_byte_identical_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    let args = [
        "--duration",
        "10min",
        "--seed",
        "3",
        "--fault",
        "F2@300s",
        "--scans",
    ];
    for out in [&a, &b] {
        let o = simulate(out, &args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    for name in FILES {
        assert_eq!(
            read(&a.join(name)),
            read(&b.join(name)),
            "{name} differs between identical runs"
        );
    }
    let o = simulate(
        &c,
        &["--duration", "10min", "--seed", "4", "--fault", "F2@300s"],
    );
    assert!(o.status.success());
    assert_ne!(read(&a.join("events.csv")), read(&c.join("events.csv")));
}

#[test]
fn run_directory_is_complete_and_consistent() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    let o = simulate(
        &out,
        &[
            "--duration",
            "5min",
            "--scan-ms",
            "20",
            "--fault",
            "F5@120s",
            "--scans",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.stdout.is_empty(), "simulate prints nothing on stdout");

    let plant = Plant::from_path(&out.join("plant.toml")).expect("written plant file parses");
    assert_eq!(plant.scan_period, 20 * diagnoser::MS);
    assert_eq!(plant.faults.len(), 12);

    let truth: serde_json::Value =
        serde_json::from_slice(&read(&out.join("truth.json"))).expect("json");
    let showed = truth["faults"][0]["showed_at"].as_i64().expect("F5 shows");
    assert_eq!(
        truth,
        serde_json::json!({"faults": [{"label": "F5", "template": "blocked_at(P, C4)", "onset": 120000,
            "showed": true, "showed_at": showed}]})
    );
    // It shows where the log first differs from the same run without it.
    let normal = dir.path().join("normal");
    let o = simulate(&normal, &["--duration", "5min", "--scan-ms", "20"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows = |dir: &Path, keep: &dyn Fn(i64) -> bool| -> Vec<String> {
        String::from_utf8_lossy(&read(&dir.join("events.csv")))
            .lines()
            .skip(1)
            .filter(|l| {
                l.split(',')
                    .next()
                    .and_then(|t| t.parse().ok())
                    .is_some_and(keep)
            })
            .map(str::to_string)
            .collect()
    };
    assert!(showed >= 120_000);
    assert_eq!(rows(&out, &|t| t < showed), rows(&normal, &|t| t < showed));
    assert_ne!(
        rows(&out, &|t| t == showed),
        rows(&normal, &|t| t == showed)
    );
    let damage: serde_json::Value =
        serde_json::from_slice(&read(&out.join("damage.json"))).expect("json");
    assert_eq!(damage["scans"], 5 * 60 * 50 + 1);
    assert!(damage["damage"].is_array());

    // The long and archive forms tell the same story.
    let events = read_events(&out.join("events.csv"), &plant.signals, TimeUnit::Ms)
        .expect("events read back");
    let intervals =
        read_intervals_as_events(&out.join("intervals.csv"), &plant.signals, TimeUnit::Ms)
            .expect("intervals read back");
    // The events form ends with its end row, at the last scan.
    assert_eq!(events.end, Some(5 * 60 * SECOND));
    let events = logs::EventLog {
        end: None,
        ..events
    };
    assert_eq!(events, intervals);
    assert!(events.events.len() > 100);
    // Every event falls on a 20 ms scan.
    assert!(
        events
            .events
            .iter()
            .all(|e| e.t % (20 * diagnoser::MS) == 0)
    );
}

#[test]
fn cylinders_plant_runs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("cyl");
    let o = simulate(&out, &["--plant", "cylinders", "--duration", "10min"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plant = Plant::from_path(&out.join("plant.toml")).expect("plant file parses");
    assert_eq!(plant.name, "cylinders");
    let damage: serde_json::Value =
        serde_json::from_slice(&read(&out.join("damage.json"))).expect("json");
    assert_eq!(damage["damage"], serde_json::json!([]));
}

#[test]
fn bad_arguments_exit_2_with_the_whole_message_and_keep_earlier_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    assert!(simulate(&out, &["--duration", "2min"]).status.success());
    let before = read(&out.join("events.csv"));

    assert_bad_input(
        &simulate(&out, &["--fault", "F13@10s"]),
        "unknown fault 'F13'",
    );
    assert_bad_input(
        &simulate(&out, &["--duration", "2 fortnights"]),
        "bad duration",
    );
    assert_bad_input(&simulate(&out, &["--fault", "F2"]), "LABEL@TIME");
    assert_bad_input(&simulate(&out, &["--fault", "stuck1(C44)@1s"]), "C44");
    assert_bad_input(
        &simulate(&out, &["--duration", "1min", "--fault", "F2@2min"]),
        "after the end",
    );
    assert_bad_input(&simulate(&out, &["--scan-ms", "0"]), "--scan-ms");
    assert_bad_input(
        &gardefou(&["simulate", "--plant", "mill", "--out", "x"]),
        "mill",
    );
    // clap's own errors keep their whole message: what, the usage, a hint.
    assert_bad_input(&gardefou(&["simulate", "--bogus"]), "'--bogus'");
    assert_bad_input(
        &gardefou(&["learn", "--suggest-parts", "x.csv"]),
        "--plant <PLANT>",
    );

    assert_eq!(
        read(&out.join("events.csv")),
        before,
        "a failed run touched earlier output"
    );
    let leftovers: Vec<_> = fs::read_dir(&out)
        .expect("dir")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "staging left behind: {leftovers:?}");
}

#[test]
fn help_is_available_on_every_verb() {
    let o = gardefou(&["simulate", "--help"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    for flag in [
        "--plant",
        "--duration",
        "--seed",
        "--fault",
        "--scan-ms",
        "--out",
        "--scans",
    ] {
        assert!(text.contains(flag), "{flag} missing from help");
    }
}

/// The `label` of the first fault of `plant` whose template starts with `prefix`.
fn fault_like(plant: &Plant, prefix: &str) -> String {
    plant
        .faults
        .iter()
        .find(|f| f.template.to_string().starts_with(prefix))
        .map(|f| f.label.clone())
        .unwrap_or_else(|| panic!("{} has no {prefix} fault", plant.name))
}

#[test]
fn generated_plants_load_learn_and_keep_their_truth() {
    let dir = tempfile::tempdir().expect("temp dir");
    for (seed, size) in [("11", "small"), ("12", "medium")] {
        let normal = dir.path().join(format!("{seed}-normal"));
        let args = ["--plant", "generated", "--plant-seed", seed, "--size", size];
        let o = simulate(
            &normal,
            &[&args[..], &["--duration", "1h", "--seed", "1"]].concat(),
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let plant = Plant::from_path(&normal.join("plant.toml")).expect("the plant file loads");
        assert_eq!(plant.name, format!("generated-{seed}-{size}"));
        let damage: serde_json::Value =
            serde_json::from_slice(&read(&normal.join("damage.json"))).expect("json");
        assert_eq!(damage["damage"], serde_json::json!([]));

        // `learn` accepts the log, with the plant file as written.
        let model = dir.path().join(format!("{seed}-model.json"));
        let o = gardefou(&[
            "learn",
            "-q",
            "--plant",
            normal.join("plant.toml").to_str().expect("utf-8"),
            normal.join("events.csv").to_str().expect("utf-8"),
            "-o",
            model.to_str().expect("utf-8"),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let m: serde_json::Value = serde_json::from_slice(&read(&model)).expect("json");
        assert_eq!(m["parts"].as_array().map(Vec::len), Some(plant.parts.len()));

        // Two faults: the truth file names them, with their onsets, and says
        // when each showed.
        let (stuck, blocked) = (
            fault_like(&plant, "stuck1("),
            fault_like(&plant, "blocked_at("),
        );
        let faults = [format!("{stuck}@300s"), format!("{blocked}@400000ms")];
        let faulty = dir.path().join(format!("{seed}-faulty"));
        let run = [
            &args[..],
            &[
                "--duration",
                "20min",
                "--seed",
                "5",
                "--fault",
                &faults[0],
                "--fault",
                &faults[1],
            ],
        ]
        .concat();
        let o = simulate(&faulty, &run);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let truth: serde_json::Value =
            serde_json::from_slice(&read(&faulty.join("truth.json"))).expect("json");
        let entries = truth["faults"].as_array().expect("a list");
        assert_eq!(entries.len(), 2);
        for (e, (label, onset)) in entries.iter().zip([(&stuck, 300_000), (&blocked, 400_000)]) {
            assert_eq!(e["label"], serde_json::json!(label));
            assert_eq!(
                e["template"],
                serde_json::json!(plant.fault(label).expect("declared").template.to_string())
            );
            assert_eq!(e["onset"], serde_json::json!(onset));
            let showed = e["showed_at"].as_i64();
            assert_eq!(e["showed"], serde_json::json!(showed.is_some()));
            assert!(showed.is_none_or(|t| t >= onset), "{e}");
        }
        // The same seeds give the same files; another run seed, the same plant.
        let again = dir.path().join(format!("{seed}-again"));
        assert!(simulate(&again, &run).status.success());
        for name in ["events.csv", "truth.json", "plant.toml", "damage.json"] {
            assert_eq!(
                read(&faulty.join(name)),
                read(&again.join(name)),
                "{name} differs"
            );
        }
        assert_eq!(
            read(&faulty.join("plant.toml")),
            read(&normal.join("plant.toml"))
        );
        assert_ne!(
            read(&faulty.join("events.csv")),
            read(&normal.join("events.csv"))
        );
    }
}

#[test]
fn generated_plants_need_their_seed() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("g");
    assert_bad_input(&simulate(&out, &["--plant", "generated"]), "--plant-seed");
    assert_bad_input(&simulate(&out, &["--plant-seed", "3"]), "--plant generated");
    assert_bad_input(
        &simulate(
            &out,
            &[
                "--plant",
                "generated",
                "--plant-seed",
                "3",
                "--size",
                "huge",
            ],
        ),
        "huge",
    );
    assert_bad_input(
        &simulate(
            &out,
            &[
                "--plant",
                "generated",
                "--plant-seed",
                "3",
                "--fault",
                "F2@1s",
            ],
        ),
        "unknown fault 'F2' for plant 'generated-3-medium'",
    );
}

#[test]
fn a_run_replaces_the_whole_earlier_run_and_abandoned_staging() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    let first = simulate(&out, &["--duration", "1min", "--parquet", "--scans"]);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    assert!(out.join("intervals.parquet").exists() && out.join("scans.csv").exists());
    // A run killed before it could clean up left its staging directory (no
    // process has this id: it is above Linux's largest).
    let abandoned = out.join(".gardefou-staging-4294967");
    fs::create_dir_all(&abandoned).expect("staging");
    fs::write(abandoned.join("events.csv"), "half").expect("half a file");

    let second = simulate(&out, &["--duration", "2min"]);
    assert!(
        second.status.success(),
        "{}",
        String::from_utf8_lossy(&second.stderr)
    );
    let mut left: Vec<String> = fs::read_dir(&out)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(
        left,
        [
            "damage.json",
            "events.csv",
            "intervals.csv",
            "plant.toml",
            "truth.json"
        ],
        "files of the first run, or staging, left beside the second"
    );
}

#[cfg(unix)]
#[test]
fn an_interrupted_run_removes_its_staging_and_keeps_the_earlier_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    assert!(simulate(&out, &["--duration", "1min"]).status.success());
    let before = read(&out.join("events.csv"));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["simulate", "--duration", "2000h", "--out"])
        .arg(&out)
        .spawn()
        .expect("starts");
    let staging = out.join(format!(".gardefou-staging-{}", child.id()));
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while !staging.join("events.csv").exists() {
        assert!(std::time::Instant::now() < deadline, "no staging seen");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let status = child.wait().expect("ends");
    assert_eq!(status.code(), Some(128 + libc::SIGTERM), "{status:?}");
    assert!(!staging.exists(), "staging left behind");
    assert_eq!(
        read(&out.join("events.csv")),
        before,
        "the earlier run changed"
    );
}
