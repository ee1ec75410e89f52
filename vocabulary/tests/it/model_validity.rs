//! A model edited or damaged in the ways that used to change verdicts is
//! refused when read, with the part, the element and the reason.

use std::path::Path;

use serde_json::{Value, json};
use vocabulary::model::Model;

/// The learned models the diagnoser's tests use, as JSON.
fn fixture(name: &str) -> Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../diagnoser/tests/fixtures/diagnosis")
        .join(name);
    serde_json::from_str(&std::fs::read_to_string(path).expect("fixture")).expect("JSON")
}

fn parse(model: &Value) -> Result<Model, String> {
    Model::parse(&model.to_string(), Path::new("model.json")).map_err(|e| e.to_string())
}

#[test]
fn every_learned_fixture_is_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../diagnoser/tests/fixtures/diagnosis");
    let mut seen = 0;
    for entry in std::fs::read_dir(dir).expect("fixtures") {
        let name = entry
            .expect("entry")
            .file_name()
            .to_string_lossy()
            .into_owned();
        if name.ends_with("-model.json") {
            parse(&fixture(&name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            seen += 1;
        }
    }
    assert!(seen >= 5, "{seen} fixtures");
}

/// What an edit is, how it is made, and what the message must say.
type Edit = (&'static str, fn(&mut Value), &'static str);

/// Each edit, and the end of the message it must give.
fn edits() -> Vec<Edit> {
    vec![
        (
            "guard bounds swapped",
            |m| {
                let g = &mut m["parts"][0]["transitions"][1]["guard"];
                let (lo, hi) = (g["lo"].clone(), g["hi"].clone());
                g["lo"] = hi;
                g["hi"] = lo;
            },
            "transition 1: guard [",
        ),
        (
            "a negative guard",
            |m| m["parts"][0]["transitions"][1]["guard"]["lo"] = json!(-5.0),
            "transition 1: guard [-5, ",
        ),
        (
            "two states alike",
            |m| {
                let first = m["parts"][0]["states"][0]["values"].clone();
                m["parts"][0]["states"][1]["values"] = first;
            },
            "state 1 has the values of an earlier state",
        ),
        (
            "a transition to nowhere",
            |m| m["parts"][0]["transitions"][0]["to"] = json!(999),
            "transition 0: joins state 999, which the part does not have",
        ),
        (
            "an event that is not a signal's edge",
            |m| m["parts"][0]["transitions"][0]["event"] = json!("RE(NOPE)"),
            "transition 0: event 'RE(NOPE)' is not the edges from state",
        ),
        (
            "a clock of no signal",
            |m| m["parts"][0]["transitions"][0]["clock"] = json!("FE(NOPE)"),
            "transition 0: clock 'FE(NOPE)' is neither 'command' nor an edge of the part's signals",
        ),
        (
            "an expected transition that does not exist",
            |m| {
                let states = m["parts"][0]["states"].as_array_mut().expect("states");
                let waiting = states
                    .iter_mut()
                    .find(|s| !s["expected"].as_array().expect("expected").is_empty())
                    .expect("a state that expects an event");
                waiting["expected"][0]["transition"] = json!(999);
            },
            "expects transition 999, which the part does not have",
        ),
        (
            "an estimate interval that ends before it starts",
            |m| {
                let intervals = &mut m["parts"][0]["estimates"][0]["intervals"];
                intervals[0]["to"] = json!(-1.0);
            },
            "is empty",
        ),
        (
            "an estimate on an interval no estimate defines",
            |m| {
                let sensor = m["parts"][0]["signals"][0].clone();
                let estimates = m["parts"][0]["sensor_estimates"]
                    .as_array_mut()
                    .expect("list");
                estimates.push(json!({"sensor": sensor, "expr": "I1 | I99", "uncertain": []}));
            },
            "uses interval 'I99', which no estimate defines",
        ),
    ]
}

#[test]
fn an_edited_model_is_refused_with_the_part_and_the_reason() {
    let model = fixture("table-model.json");
    let part = model["parts"][0]["name"]
        .as_str()
        .expect("name")
        .to_string();
    for (what, edit, reason) in edits() {
        let mut edited = model.clone();
        edit(&mut edited);
        let err = parse(&edited).expect_err(what);
        assert!(
            err.starts_with(&format!("model.json: part '{part}': ")),
            "{what}: {err}"
        );
        assert!(err.contains(reason), "{what}: {err}");
        assert_eq!(err.lines().count(), 1, "{what}: {err}");
    }
}
