//! End-to-end tests of `gardefou diagnose` and `gardefou check`: the real binary
//! on the shipped F1–F12 turntable runs, checked against a fixture file of the
//! expected verdict lines (`UPDATE_EXPECT=1` rewrites it) and against each
//! run's ground truth.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::support::{data, gardefou, learned_model as model, plant};
use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn diagnose(log: &str, extra: &[&str]) -> Output {
    let plant = plant();
    let mut args = vec!["diagnose", "--plant", &plant, "--model", model()];
    args.extend_from_slice(extra);
    args.push(log);
    gardefou(&args)
}

fn lines(o: &Output) -> Vec<Value> {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

fn labels(v: &Value) -> Vec<&str> {
    v["labels"]
        .as_array()
        .expect("labels")
        .iter()
        .filter_map(Value::as_str)
        .collect()
}

const FAULTS: [&str; 12] = [
    "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8", "F9", "F10", "F11", "F12",
];

#[test]
fn shipped_fault_runs_give_the_expected_verdicts() {
    let mut text = String::new();
    for f in FAULTS {
        let log = data(&format!("sorting/{f}/events.csv"));
        let o = diagnose(&log, &[]);
        let truth: Value = serde_json::from_str(
            &fs::read_to_string(data(&format!("sorting/{f}/truth.json"))).expect("truth"),
        )
        .expect("truth.json");
        let onset = truth["faults"][0]["onset"].as_f64().expect("onset");
        for v in lines(&o) {
            assert!(
                v["t"].as_f64().expect("t") >= onset,
                "{f}: verdict before the onset: {v}"
            );
            if v["verdict"] != "normal" {
                assert!(labels(&v).contains(&f), "{f}: true label excluded: {v}");
            }
            text.push_str(&format!("{f} {v}\n"));
        }
    }
    let fixture = root().join("tests/fixtures/diagnosis/sorting-faults.jsonl");
    if std::env::var_os("UPDATE_EXPECT").is_some() {
        fs::create_dir_all(fixture.parent().expect("parent")).expect("fixture dir");
        fs::write(&fixture, &text).expect("fixture written");
    }
    let expected = fs::read_to_string(&fixture).expect("fixture (UPDATE_EXPECT=1 writes it)");
    assert_eq!(text, expected, "verdicts differ from {}", fixture.display());
}

/// Seed 002's story of F2 (C4 stuck at 1): ambiguous with F2 and F5 once no
/// FE(C4) came within its window after RE(A4), certain F2 when RE(C5) comes.
#[test]
fn f2_turns_ambiguous_then_certain() {
    let all = lines(&diagnose(&data("sorting/F2/events.csv"), &[]));
    let turntable: Vec<&Value> = all.iter().filter(|v| v["part"] == "turntable").collect();
    let first = turntable.first().expect("a verdict");
    assert_eq!(first["verdict"], "ambiguous");
    let l = labels(first);
    assert!(l.contains(&"F2") && l.contains(&"F5"), "{first}");
    assert!(
        first["reason"]
            .as_str()
            .is_some_and(|r| r.starts_with("no FE(C4) within")),
        "{first}"
    );
    // The shipped run's RE(A4) after the onset is at 602750 ms; FE(C4)'s
    // learned window closes 140 ms later.
    assert_eq!(first["t"].as_f64(), Some(602_890.0));
    let last = turntable.last().expect("a verdict");
    assert_eq!(last["verdict"], "certain");
    assert_eq!(labels(last), ["F2"]);
    assert_eq!(last["flags"], serde_json::json!(["def_C4"]));
    assert!(
        last["reason"]
            .as_str()
            .is_some_and(|r| r.starts_with("RE(C5)")),
        "{last}"
    );
    // Normal after a glitch stands beside the faults, with no flag, until a
    // glitch would be over (100 ms).
    assert_eq!(labels(first)[0], "N", "{first}");
    assert_eq!(first["flags"], serde_json::json!([]));
    let second = &turntable[1];
    assert_eq!(labels(second), ["F2", "F5"]);
    assert_eq!(second["t"].as_f64(), Some(602_990.0));
    assert!(
        second["reason"].as_str().is_some_and(
            |r| r.ends_with("normal after a glitch at 602890 ms ruled out at 602990 ms")
        ),
        "{second}"
    );
    // The plant view agrees.
    let plant = all
        .iter()
        .rev()
        .find(|v| v["part"] == "plant")
        .expect("plant view");
    assert_eq!(labels(plant), ["F2"]);
}

#[test]
fn every_log_form_gives_the_same_verdicts() {
    let events = diagnose(&data("sorting/F2/events.csv"), &[]);
    let intervals = diagnose(&data("sorting/F2/intervals.csv"), &[]);
    assert_eq!(lines(&events), lines(&intervals));
    // A real Parquet file, written by the simulator.
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    let o = gardefou(&[
        "simulate",
        "--duration",
        "20min",
        "--fault",
        "F6@5min",
        "--parquet",
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let parquet: Vec<PathBuf> = fs::read_dir(&out)
        .expect("run dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "parquet"))
        .collect();
    assert_eq!(parquet.len(), 1, "{parquet:?}");
    let from_parquet = lines(&diagnose(parquet[0].to_str().expect("utf-8"), &[]));
    let from_csv = lines(&diagnose(
        out.join("events.csv").to_str().expect("utf-8"),
        &[],
    ));
    assert_eq!(from_parquet, from_csv);
    assert!(
        from_csv
            .iter()
            .any(|v| v["part"] == "turntable" && labels(v) == ["F6"]),
        "{from_csv:?}"
    );
}

#[test]
fn summary_is_a_table_per_part() {
    let o = diagnose(&data("sorting/F5/events.csv"), &["--summary"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let row = text
        .lines()
        .find(|l| l.starts_with("turntable"))
        .expect("a turntable row");
    let cells: Vec<&str> = row.split_whitespace().collect();
    assert_eq!(cells, ["turntable", "certain", "F5", "602890", "def_P"]);
    assert!(
        text.lines()
            .any(|l| l.starts_with("rollers ") && l.contains("normal"))
    );
}

#[test]
fn check_reports_diagnosability_sizes_and_renders_with_graphviz() {
    let dir = tempfile::tempdir().expect("temp dir");
    let dot = dir.path().join("dot");
    let plant = plant();
    let o = gardefou(&[
        "check",
        "--plant",
        &plant,
        "--model",
        model(),
        "--dot",
        dot.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let verdict = |label: &str| {
        text.lines()
            .find(|l| l.trim_start().starts_with(&format!("{label} ")))
            .unwrap_or_else(|| panic!("no line for {label} in {text}"))
            .to_string()
    };
    for f in ["F1", "F2", "F3", "F4", "F5", "F6", "F11", "F12"] {
        assert!(verdict(f).contains(": diagnosable"), "{}", verdict(f));
    }
    // A stuck position sensor and a plate blocked on its way there look the
    // same once the control waits for that sensor.
    for f in ["F1", "F3", "F11", "F12"] {
        assert!(
            verdict(f).contains("while the plant runs"),
            "{}",
            verdict(f)
        );
    }
    assert!(
        text.contains("F3 and F11 look the same once the plant stops at A4=1 C4=0 C5=0"),
        "{text}"
    );
    assert!(
        verdict("F2").contains("also if the control waits"),
        "{text}"
    );
    // An unexpected edge can hide inside the window of a normal one.
    assert!(
        verdict("F7").contains("not detectable"),
        "{}",
        verdict("F7")
    );
    assert!(text.contains("counterexample"), "{text}");
    assert!(text.contains("centralised diagnoser"), "{text}");
    let svg = Command::new("dot")
        .arg("-Tsvg")
        .arg(dot.join("turntable.diagnoser.dot"))
        .output()
        .expect("Graphviz dot runs");
    assert!(
        svg.status.success(),
        "{}",
        String::from_utf8_lossy(&svg.stderr)
    );
    assert!(String::from_utf8_lossy(&svg.stdout).contains("F2"));
}

#[test]
fn check_reads_libfaudes_generators() {
    let fx = root().join("diagnoser/tests/fixtures/faudes");
    let (generator, map) = (
        fx.join("diag_system_4.gen"),
        fx.join("diag_failure_typemap_4.txt"),
    );
    let check = |extra: &[&str]| {
        let mut args = vec!["check", "--gen", generator.to_str().expect("utf-8")];
        args.extend(["--failures", map.to_str().expect("utf-8")]);
        args.extend_from_slice(extra);
        gardefou(&args)
    };
    let o = check(&[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("F1: not diagnosable"), "{text}");
    // A verifier larger than allowed gives up in one line.
    let o = check(&["--max-states", "3"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("grew past 3 states and transitions (--max-states)"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
}

#[test]
fn check_reads_a_plant_as_its_components() {
    let dir = tempfile::tempdir().expect("temp dir");
    // A machine that may fail silently and then works on unseen; `hidden`
    // makes its start unobservable.
    let machine = |i: usize, hidden: bool| {
        let path = dir.path().join(format!("m{i}.gen"));
        let text = format!(
            "<Generator> \"m{i}\" <Alphabet> start {} go{i} done{i} f{i} +o+ </Alphabet>\n\
             <States> idle busy broken </States>\n\
             <TransRel> idle start idle idle go{i} busy busy done{i} idle idle f{i} broken broken go{i} broken </TransRel>\n\
             <InitStates> idle </InitStates> </Generator>\n",
            if hidden { "+o+" } else { "" }
        );
        fs::write(&path, text).expect("write");
        path.to_str().expect("utf-8").to_string()
    };
    let map = dir.path().join("f.txt");
    fs::write(
        &map,
        "<FailureTypes> F <FailureEvents> f0 f1 </FailureEvents> </FailureTypes>\n",
    )
    .expect("write");
    let map = map.to_str().expect("utf-8");
    let (m0, m1) = (machine(0, false), machine(1, false));
    let o = gardefou(&["check", "--gen", &m0, &m1, "--failures", map]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    // Alone, a broken machine shows `go` and never `done`: diagnosable. With
    // the other machine, it may also stop being asked.
    assert!(text.starts_with("not diagnosable"), "{text}");
    assert!(text.contains("faulty:   "), "{text}");
    let hidden = machine(2, true);
    let o = gardefou(&["check", "--gen", &m0, &hidden, "--failures", map]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(&format!(
            "{hidden}: event 'start' is unobservable here but observable in {m0}"
        )),
        "{err}"
    );
}

#[test]
fn bad_models_are_one_line_errors_with_exit_code_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let broken = dir.path().join("model.json");
    fs::write(&broken, "{\"version\": 1,\n \"plant\": 3}").expect("write");
    let plant = plant();
    let log = data("sorting/F2/events.csv");
    let o = gardefou(&[
        "diagnose",
        "--plant",
        &plant,
        "--model",
        broken.to_str().expect("utf-8"),
        &log,
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("model.json:2:"), "{err}");

    fs::write(&broken, "{\"version\": 99}").expect("write");
    let o = gardefou(&[
        "diagnose",
        "--plant",
        &plant,
        "--model",
        broken.to_str().expect("utf-8"),
        &log,
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("version 99"));

    // A model of another plant.
    let cylinders = dir.path().join("cyl.json");
    let o = gardefou(&[
        "learn",
        "-q",
        "--plant",
        &data("cylinders/normal/plant.toml"),
        "-o",
        cylinders.to_str().expect("utf-8"),
        &data("cylinders/normal/events.csv"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = gardefou(&[
        "diagnose",
        "--plant",
        &plant,
        "--model",
        cylinders.to_str().expect("utf-8"),
        &log,
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("learned for plant"), "{err}");
}

/// On the cylinder rig the control drops the order in the scan the end sensor
/// rises: that reaction's timing is learned, so a cylinder blocked on its way
/// is caught once its deadline passes (the log ends at 1 200 000 ms).
#[test]
fn a_cylinder_blocked_on_its_way_is_caught_by_the_reactions_deadline() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("cylinders.json");
    let plant = data("cylinders/normal/plant.toml");
    let o = gardefou(&[
        "learn",
        "-q",
        "--margin-rel",
        "0.1",
        "--plant",
        &plant,
        "-o",
        model.to_str().expect("utf-8"),
        &data("cylinders/normal/events.csv"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = |log: &str| {
        lines(&gardefou(&[
            "diagnose",
            "--plant",
            &plant,
            "--model",
            model.to_str().expect("utf-8"),
            "--end",
            "1200000",
            &data(log),
        ]))
    };
    assert!(run("cylinders/normal/events.csv").is_empty());
    let blocked = run("cylinders/V1-blocked-between/events.csv");
    let first = blocked
        .iter()
        .find(|v| v["part"] == "cylinder1")
        .expect("cylinder 1 leaves normal");
    assert!(
        labels(first).contains(&"V1.blocked_between.Se0.Se1"),
        "{first}"
    );
    assert!(
        first["reason"]
            .as_str()
            .is_some_and(|r| r.contains("RE(Se1)")),
        "{first}"
    );
    // The shipped log ends with its end row at 1 200 000 ms: without `--end`,
    // the deadlines up to it count all the same.
    let ended = lines(&gardefou(&[
        "diagnose",
        "--plant",
        &plant,
        "--model",
        model.to_str().expect("utf-8"),
        &data("cylinders/V1-blocked-between/events.csv"),
    ]));
    assert_eq!(ended, blocked, "the end row acts as --end");
    let text = std::fs::read_to_string(data("cylinders/V1-blocked-between/events.csv"))
        .expect("shipped log");
    assert_eq!(
        text.lines().last(),
        Some("1200000,,"),
        "the simulator writes the end row"
    );
}

#[test]
fn a_log_through_a_fifo_reads_as_the_file_does() {
    // A FIFO gives its bytes once; the intervals form is read in two passes
    // and its form is told from its first line: the log is read once.
    let dir = tempfile::tempdir().expect("temp dir");
    for form in ["events.csv", "intervals.csv"] {
        let file = data(&format!("sorting/F4/{form}"));
        let fifo = dir.path().join(format!("fifo-{form}"));
        let made = Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo runs");
        assert!(made.success());
        let (source, sink) = (PathBuf::from(&file), fifo.clone());
        let writer = std::thread::spawn(move || {
            fs::write(&sink, fs::read(&source).expect("log")).expect("writes the FIFO");
        });
        // Bounded: a reader that opened the FIFO twice would wait for ever.
        let through_fifo = Command::new("timeout")
            .args(["60", env!("CARGO_BIN_EXE_gardefou"), "diagnose", "--plant"])
            .args([plant().as_str(), "--model", model()])
            .arg(&fifo)
            .output()
            .expect("runs");
        writer.join().expect("writer");
        let direct = diagnose(&file, &[]);
        assert!(direct.status.success() && !direct.stdout.is_empty());
        assert_eq!(
            String::from_utf8_lossy(&through_fifo.stdout),
            String::from_utf8_lossy(&direct.stdout),
            "{form}: {}",
            String::from_utf8_lossy(&through_fifo.stderr)
        );
    }
}

#[test]
fn a_model_learned_with_another_plant_file_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = fs::read_to_string(plant()).expect("plant file");
    let log = data("sorting/F4/events.csv");
    let run = |edited: String, name: &str| {
        let path = dir.path().join(name);
        fs::write(&path, edited).expect("writes");
        let plant = path.to_str().expect("path").to_string();
        gardefou(&["diagnose", "--plant", &plant, "--model", model(), &log])
    };
    // A description is not what the model learned: still its plant.
    let described = text.replace("turntable at loading position", "table at loading");
    let o = run(described, "described.toml");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Two signals declared in the other order: not the plant it learned.
    let c4 = "C4 = { kind = \"sensor\", description = \"turntable at loading position\" }\n";
    let c5 = "C5 = { kind = \"sensor\", description = \"turntable at unloading position\" }\n";
    let swapped = text.replace(&format!("{c4}{c5}"), &format!("{c5}{c4}"));
    assert_ne!(swapped, text);
    let o = run(swapped, "swapped.toml");
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("learned with another plant file 'sorting'"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// Runs `gardefou ARGS` on a pseudo-terminal (util-linux's `script`), as a
/// user at a terminal would: what the terminal showed, and the exit status.
fn on_terminal(args: &[&str], stdout: &Path) -> (String, bool) {
    let quote = |a: &str| format!("'{}'", a.replace('\'', r"'\''"));
    let mut line = quote(env!("CARGO_BIN_EXE_gardefou"));
    for a in args {
        line.push(' ');
        line.push_str(&quote(a));
    }
    line.push_str(&format!(" > {}", quote(&stdout.display().to_string())));
    let o = Command::new("script")
        .args(["-qec", &line, "/dev/null"])
        .env("COLUMNS", "120")
        .output()
        .expect("util-linux's script runs");
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        o.status.success(),
    )
}

#[test]
fn several_logs_show_a_bar_over_the_logs_on_a_terminal_and_nothing_in_a_pipe() {
    let dir = tempfile::tempdir().expect("temp dir");
    let logs = dir.path().join("logs");
    fs::create_dir_all(&logs).expect("logs dir");
    for (i, run) in ["F1", "F2", "normal"].iter().enumerate() {
        let from = data(&format!("sorting/{run}/events.csv"));
        fs::copy(&from, logs.join(format!("{i}-{run}.csv"))).expect("copies a log");
    }
    let logs = logs.display().to_string();
    let plant = plant();
    let diagnose = ["diagnose", "--plant", &plant, "--model", model(), &logs];
    let piped = gardefou(&diagnose);
    assert!(
        piped.status.success(),
        "{}",
        String::from_utf8_lossy(&piped.stderr)
    );
    assert!(
        piped.stderr.is_empty(),
        "stderr in a pipe: {}",
        String::from_utf8_lossy(&piped.stderr)
    );
    let out = dir.path().join("verdicts.jsonl");
    let (terminal, ok) = on_terminal(&diagnose, &out);
    assert!(ok, "{terminal}");
    assert!(
        terminal.contains("diagnosing") && terminal.contains("/3 logs"),
        "{terminal}"
    );
    let lines = fs::read(&out).expect("the verdict lines");
    assert_eq!(
        lines, piped.stdout,
        "the same lines on a terminal as in a pipe"
    );
    assert!(!lines.is_empty());

    // A quoted pattern stands for the files it matches, in name order.
    let pattern = format!("{logs}/?-F*.csv");
    let by_pattern = gardefou(&["diagnose", "--plant", &plant, "--model", model(), &pattern]);
    let (f1, f2) = (format!("{logs}/0-F1.csv"), format!("{logs}/1-F2.csv"));
    let named = gardefou(&["diagnose", "--plant", &plant, "--model", model(), &f1, &f2]);
    assert!(
        by_pattern.status.success(),
        "{}",
        String::from_utf8_lossy(&by_pattern.stderr)
    );
    assert_eq!(by_pattern.stdout, named.stdout);
    assert!(String::from_utf8_lossy(&named.stdout).contains("1-F2.csv"));
    let none = gardefou(&[
        "diagnose",
        "--plant",
        &plant,
        "--model",
        model(),
        &format!("{logs}/*.vcd"),
    ]);
    crate::support::assert_bad_input(&none, "no file matches");

    let model_out = dir.path().join("m.json").display().to_string();
    let learn = ["learn", "-q", "--plant", &plant, "-o", &model_out, &logs];
    let piped = gardefou(&learn);
    assert!(
        piped.status.success() && piped.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&piped.stderr)
    );
    let (terminal, ok) = on_terminal(&learn, &dir.path().join("learn.out"));
    assert!(
        ok && terminal.contains("learning") && terminal.contains("/3 logs"),
        "{terminal}"
    );
}
