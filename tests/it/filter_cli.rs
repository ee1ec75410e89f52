//! `gardefou filter rewrite` on the sorting line, with the model learned from the
//! shipped normal run (`diagnoser/tests/fixtures/diagnosis/sorting-model.json`).

use crate::support::{gardefou, repo as path};
use std::process::Output;

fn rewrite(extra: &[&str]) -> Output {
    let plant = path("datasets/plants/sorting.toml");
    let model = path("diagnoser/tests/fixtures/diagnosis/sorting-model.json");
    let mut args = vec!["filter", "rewrite", "--plant", &plant, "--model", &model];
    args.extend_from_slice(extra);
    gardefou(&args)
}

#[test]
fn def_c4_rewrites_the_constraints_that_read_c4_conservatively() {
    let o = rewrite(&["--flags", "def_C4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    // Seed 002 eq. 30: C4 read positively takes every interval where it may be 1.
    assert!(
        text.lines()
            .any(|l| l == "CSs6 = (!def_C4 & C4 | def_C4 & (I1 | I10 | I2 | I9)) & C6 & A2"),
        "{text}"
    );
    // Read negatively, only the intervals where C4 is certainly 1.
    assert!(
        text.lines()
            .any(|l| l == "CSs14 = !(!def_C4 & C4 | def_C4 & (I1 | I10)) & RE(A4)"),
        "{text}"
    );
    // Constraints that do not read C4 are not printed.
    assert!(!text.contains("CSs5 ="), "{text}");
}

#[test]
fn suspects_and_bad_flags() {
    let o = rewrite(&["--flags", "def_C5", "--suspects"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    // Suspected, C5 reads the union of its reading and its estimate; read
    // negatively, the smaller: the reading where C5 is certainly 1.
    assert!(
        text.lines()
            .any(|l| l
                == "CSs5 = !(!def_C5 & C5 & (!suspect_C5 | I5 | I6) | def_C5 & (I5 | I6)) & A3"),
        "{text}"
    );
    let o = rewrite(&["--flags", "def_C9"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("def_C9"), "{err}");
}

fn check(extra: &[&str]) -> Output {
    let mut args = vec!["filter", "check", "--plant"];
    let plant = path("datasets/plants/sorting.toml");
    args.push(&plant);
    args.extend_from_slice(extra);
    gardefou(&args)
}

#[test]
fn check_replays_logs_against_the_constraints() {
    // The printed control law never violates a constraint in normal operation.
    let normal = path("datasets/data/sorting/normal/events.csv");
    let o = check(&[&normal]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        o.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("0 times"));
    // With C4 stuck at 1, the control keeps rotating with "the turntable at
    // loading" and no box aboard: CSs13 holds on the recorded orders.
    let f2 = path("datasets/data/sorting/F2/events.csv");
    let o = check(&[&f2]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert_eq!(lines[0]["constraint"], "CSs13");
    assert_eq!(lines[0]["literals"], serde_json::json!(["C4", "!C6", "A4"]));
    assert!(lines[0]["t"].as_f64().is_some_and(|t| t >= 602_000.0));
}

#[test]
fn check_refuses_flags_it_cannot_use() {
    let f2 = path("datasets/data/sorting/F2/events.csv");
    let o = check(&["--flags", "def_C4", &f2]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--flags needs --model"));
}
