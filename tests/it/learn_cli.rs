//! End-to-end tests of `gardefou learn`: the real binary on the shipped logs,
//! with real Graphviz for the exported models.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::support::{data, gardefou};
use diagnoser::model::Model;

fn learn(out: &Path, logs: &[String], extra: &[&str]) -> (Output, PathBuf) {
    let model = out.join("model.json");
    let plant = data("sorting/normal/plant.toml");
    let mut args = vec![
        "learn",
        "--plant",
        &plant,
        "-o",
        model.to_str().expect("utf-8"),
    ];
    args.extend(logs.iter().map(String::as_str));
    args.extend_from_slice(extra);
    (gardefou(&args), model)
}

fn model(path: &Path) -> Model {
    serde_json::from_slice(&fs::read(path).expect("model written")).expect("model.json parses")
}

#[test]
fn learns_the_shipped_run_and_exports_graphviz_that_renders() {
    let dir = tempfile::tempdir().expect("temp dir");
    let dot = dir.path().join("dot");
    let (o, path) = learn(
        dir.path(),
        &[data("sorting/normal/events.csv")],
        &["--dot", dot.to_str().expect("utf-8")],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = model(&path);
    assert_eq!(m.version, diagnoser::model::MODEL_VERSION);
    assert_eq!(m.parts.len(), 6);
    let report = String::from_utf8_lossy(&o.stdout);
    assert!(
        report.contains("turntable")
            && report.contains("FE(C4)")
            && report.contains("[20, 140] ms"),
        "{report}"
    );
    assert!(
        report.contains("estimate C4 = I1 | I2 | I9 | I10"),
        "{report}"
    );
    for part in &m.parts {
        let file = dot.join(format!("{}.dot", part.name));
        let svg = Command::new("dot")
            .arg("-Tsvg")
            .arg(&file)
            .output()
            .expect("graphviz runs");
        assert!(
            svg.status.success(),
            "{}: {}",
            file.display(),
            String::from_utf8_lossy(&svg.stderr)
        );
        assert!(String::from_utf8_lossy(&svg.stdout).contains("<svg"));
    }
}

#[test]
fn several_logs_are_combined() {
    let dir = tempfile::tempdir().expect("temp dir");
    let normal = data("sorting/normal/events.csv");
    let (one, p1) = learn(
        &dir.path().join("one"),
        std::slice::from_ref(&normal),
        &["-q"],
    );
    let (two, p2) = learn(
        &dir.path().join("two"),
        &[normal.clone(), data("sorting/F3/events.csv")],
        &["-q"],
    );
    assert!(
        one.status.success() && two.status.success(),
        "{}",
        String::from_utf8_lossy(&two.stderr)
    );
    let (m1, m2) = (model(&p1), model(&p2));
    assert_eq!(m2.learned_from.logs.len(), 2);
    assert!(m2.learned_from.events > m1.learned_from.events);
    let count = |m: &Model| -> u64 {
        m.parts
            .iter()
            .find(|p| p.name == "turntable")
            .map_or(0, |p| p.transitions.iter().map(|t| t.count).sum())
    };
    assert!(
        count(&m2) > count(&m1),
        "the second log's turntable moves were not counted"
    );
}

#[test]
fn every_log_form_gives_the_same_model() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (a, pa) = learn(
        &dir.path().join("a"),
        &[data("sorting/normal/events.csv")],
        &["-q"],
    );
    let (b, pb) = learn(
        &dir.path().join("b"),
        &[data("sorting/normal/intervals.csv")],
        &["-q"],
    );
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    assert_eq!(model(&pa).parts, model(&pb).parts);
}

#[test]
fn the_parquet_archive_gives_the_same_model_as_the_csv_events() {
    let dir = tempfile::tempdir().expect("temp dir");
    let run = dir.path().join("run");
    let sim = gardefou(&[
        "simulate",
        "--duration",
        "20min",
        "--parquet",
        "--out",
        run.to_str().expect("utf-8"),
    ]);
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    let parquet = run.join("intervals.parquet");
    assert_eq!(
        fs::read(&parquet).expect("archive written").get(..4),
        Some(&b"PAR1"[..])
    );
    let (a, pa) = learn(
        &dir.path().join("a"),
        &[run.join("events.csv").display().to_string()],
        &["-q"],
    );
    let (b, pb) = learn(
        &dir.path().join("b"),
        &[parquet.display().to_string()],
        &["-q"],
    );
    assert!(
        a.status.success() && b.status.success(),
        "{}",
        String::from_utf8_lossy(&b.stderr)
    );
    assert_eq!(model(&pa).parts, model(&pb).parts);
}

#[test]
fn check_accepts_a_normal_run_and_flags_f2_right_after_the_rotation_order() {
    let dir = tempfile::tempdir().expect("temp dir");
    let other = dir.path().join("seed8");
    let sim = gardefou(&[
        "simulate",
        "--duration",
        "30min",
        "--seed",
        "8",
        "--out",
        other.to_str().expect("utf-8"),
    ]);
    assert!(sim.status.success());
    let other_log = other.join("events.csv").display().to_string();
    let f2 = data("sorting/F2/events.csv");
    let (o, _) = learn(
        dir.path(),
        &[data("sorting/normal/events.csv")],
        &["-q", "--check", &other_log, "--check", &f2],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON line"))
        .collect();
    assert!(
        lines.iter().all(|v| v["log"] == f2.as_str()),
        "violations in the normal run: {lines:?}"
    );
    let first = lines
        .iter()
        .find(|v| v["part"] == "turntable")
        .expect("a turntable violation in F2");
    let t = first["t"].as_f64().expect("t");
    // F2 starts at 602 s; the next rotation order follows within seconds and FE(C4)
    // is due at most 140 ms after it.
    assert!(
        (602_000.0..620_000.0).contains(&t),
        "first violation at {t} ms"
    );
    assert!(
        first["violation"]
            .as_str()
            .is_some_and(|m| m.contains("FE(C4)")),
        "{first}"
    );
}

#[test]
fn suggests_the_turntable_part() {
    let plant = data("sorting/normal/plant.toml");
    let log = data("sorting/normal/events.csv");
    let o = gardefou(&["learn", "--plant", &plant, "--suggest-parts", &log]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let block = text
        .split("[[parts]]")
        .find(|b| b.contains("\"A4\""))
        .expect("a part with A4");
    assert!(
        block.contains("\"C4\"") && block.contains("\"C5\""),
        "{text}"
    );
}

#[test]
fn bad_input_gives_one_line_and_exit_code_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bad = dir.path().join("bad.csv");
    fs::write(&bad, "t,signal,value\n0,C4,1\n0,C5,0\n10,C4,maybe\n").expect("write");
    let (o, model_path) = learn(dir.path(), &[bad.display().to_string()], &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("bad.csv:"), "{err}");
    assert!(!model_path.exists(), "a failed run wrote a model");
    let (o, _) = learn(
        dir.path(),
        &[dir.path().join("missing.csv").display().to_string()],
        &[],
    );
    assert_eq!(o.status.code(), Some(2));
}

#[cfg(unix)]
#[test]
fn the_model_goes_through_a_symbolic_link_and_to_standard_output() {
    let dir = tempfile::tempdir().expect("temp dir");
    let real = dir.path().join("real.json");
    fs::write(&real, "old").expect("old");
    let link = dir.path().join("model.json");
    std::os::unix::fs::symlink("real.json", &link).expect("link");
    let log = data("sorting/normal/events.csv");
    let (o, _) = learn(dir.path(), std::slice::from_ref(&log), &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        fs::symlink_metadata(&link)
            .expect("link")
            .file_type()
            .is_symlink()
    );
    let through = model(&real);
    // `-o -`: the model alone on standard output, the report on standard error.
    let plant = data("sorting/normal/plant.toml");
    let o = gardefou(&["learn", "--plant", &plant, "-o", "-", &log]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed: Model = serde_json::from_slice(&o.stdout).expect("only the model on stdout");
    assert_eq!(printed, through);
    assert!(String::from_utf8_lossy(&o.stderr).contains("learned "));
}
