//! `gardefou check --filter`: each part's diagnoser sized with any command, with
//! the safety filter's restriction, and with the learned control, on the model
//! learned from the shipped normal run of the sorting line.

use std::path::Path;
use std::process::Output;

use crate::support::{assert_bad_input, gardefou, plant};
use serde_json::Value;

/// The model learned from the shipped normal run (`gardefou learn` on
/// `sorting/normal/events.csv` gives this file byte for byte).
fn model() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("diagnoser/tests/fixtures/diagnosis/sorting-model.json")
        .display()
        .to_string()
}

fn check(extra: &[&str]) -> Output {
    let plant = plant();
    let model = model();
    let mut args = vec!["check", "--plant", &plant, "--model", &model];
    args.extend_from_slice(extra);
    let o = gardefou(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o
}

/// The per-part JSON objects, by part name.
fn parts(o: &Output) -> Vec<Value> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).expect("a JSON line"))
        .filter(|v| v.get("part").is_some())
        .collect()
}

fn size(v: &Value, key: &str) -> (u64, u64) {
    let s = &v["filter"][key];
    (
        s["states"].as_u64().expect("states"),
        s["transitions"].as_u64().expect("transitions"),
    )
}

#[test]
fn json_gives_the_three_sizes_and_the_turntable_shrinks() {
    let parts = parts(&check(&["--filter", "--json"]));
    assert_eq!(parts.len(), 6);
    for p in &parts {
        let name = p["part"].as_str().expect("part");
        let (any, filtered, learned) = (size(p, "any"), size(p, "filtered"), size(p, "learned"));
        assert_eq!(p["filter"]["truncated"], false, "{name}");
        // The learned control's figures are the diagnoser `check` reports.
        assert_eq!(p["filter"]["learned"], p["diagnoser"], "{name}");
        assert!(
            filtered.0 <= any.0 && filtered.1 <= any.1,
            "{name}: {filtered:?} > {any:?}"
        );
        assert!(learned.0 <= any.0, "{name}");
        let removed_by: Vec<&str> = p["filter"]["constraints"]
            .as_array()
            .expect("constraints")
            .iter()
            .filter_map(Value::as_str)
            .collect();
        if name == "turntable" {
            assert_eq!(removed_by, ["CSs14", "CSs15"]);
            assert!(
                filtered.0 < any.0 && filtered.1 < any.1,
                "{filtered:?} vs {any:?}"
            );
        } else {
            // No constraint reads only this part (and outputs): nothing removed.
            assert!(removed_by.is_empty(), "{name}: {removed_by:?}");
            assert_eq!(filtered, any, "{name}");
        }
    }
}

#[test]
fn text_gives_a_table_after_the_usual_report() {
    let plain = String::from_utf8_lossy(&check(&[]).stdout).into_owned();
    let with = String::from_utf8_lossy(&check(&["--filter"]).stdout).into_owned();
    assert!(!plain.contains("filter-based simplification"), "{plain}");
    assert!(with.starts_with(&plain), "the usual report comes first");
    let table = &with[plain.len()..];
    assert!(table.starts_with("filter-based simplification"), "{table}");
    let row = table
        .lines()
        .find(|l| l.trim_start().starts_with("turntable"))
        .expect("a turntable row");
    assert!(row.ends_with("CSs14, CSs15"), "{row}");
    assert_eq!(table.lines().count(), 2 + 6, "{table}");
}

#[test]
fn without_filter_the_json_has_no_filter_field() {
    for p in parts(&check(&["--json"])) {
        assert!(p.get("filter").is_none(), "{p}");
    }
}

#[test]
fn filter_with_a_generator_is_bad_input() {
    let o = gardefou(&["check", "--gen", "x.gen", "--failures", "y.txt", "--filter"]);
    assert_bad_input(&o, "--filter");
}
