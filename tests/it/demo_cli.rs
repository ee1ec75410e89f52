//! `gardefou demo`: the closed-loop experiment of safe control, diagnosers and
//! the rewritten filter on the simulated sorting line.

use std::process::Command;

use serde_json::Value;

/// The rows of `demo --json --write-docs`, run in a scratch directory, after
/// checking that the table it writes is the repository's `docs/demo.md`.
fn demo_rows() -> Vec<Value> {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::create_dir(dir.path().join("docs")).expect("docs dir");
    let o = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["demo", "--json", "--write-docs"])
        .current_dir(dir.path())
        .output()
        .expect("gardefou runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let written = std::fs::read_to_string(dir.path().join("docs/demo.md")).expect("demo.md");
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/demo.md"))
        .expect("docs/demo.md");
    assert!(
        written == shipped,
        "docs/demo.md is not what demo gives now: run `cargo run --release -- demo --write-docs`"
    );
    serde_json::from_slice(&o.stdout).expect("a JSON array")
}

fn row<'a>(rows: &'a [Value], fault: &str, mode: &str) -> &'a Value {
    rows.iter()
        .find(|r| {
            r["mode"] == mode
                && r["scenario"]
                    .as_str()
                    .is_some_and(|s| s.split(' ').next() == Some(fault))
        })
        .unwrap_or_else(|| panic!("no row for {fault} in mode {mode}"))
}

fn ratio(r: &Value) -> f64 {
    let got = r["boxes_per_hour"].as_f64().expect("boxes_per_hour");
    let nominal = r["nominal_boxes_per_hour"].as_f64().expect("nominal");
    assert!(nominal > 250.0, "the fault-free line delivers: {r}");
    got / nominal
}

#[test]
fn coupling_keeps_production_safe_through_sensor_faults() {
    let rows = demo_rows();
    // Eight scenarios, three modes, the fields of the interface.
    assert_eq!(rows.len(), 24);
    for r in &rows {
        for field in [
            "scenario",
            "mode",
            "boxes_per_hour",
            "nominal_boxes_per_hour",
            "damage_events",
            "detection_delay_ms",
            "halted_ms",
        ] {
            assert!(r.get(field).is_some(), "{field} missing in {r}");
        }
    }
    for fault in ["F1", "F2", "F3", "F4"] {
        // (c): no damage, at least 80 % of the fault-free throughput.
        let c = row(&rows, fault, "c");
        assert_eq!(c["damage_events"], 0, "{c}");
        assert!(ratio(c) >= 0.8, "{c}");
        assert!(c["detection_delay_ms"].as_f64().is_some(), "{c}");
    }
    for fault in ["F1", "F2", "F3", "F4", "F5", "F6", "F11", "F12"] {
        // (a): the failed sensor or element shows, as damage or as a halt.
        let a = row(&rows, fault, "a");
        let damaged = a["damage_events"].as_u64().expect("count") > 0;
        let halted = a["halted_ms"].as_f64().expect("halted") > 600_000.0;
        assert!(damaged || halted, "{a}");
    }
    // (b) rescues the faults diagnosed with certainty.
    for fault in ["F2", "F4"] {
        let b = row(&rows, fault, "b");
        assert_eq!(b["damage_events"], 0, "{b}");
        assert!(ratio(b) >= 0.8, "{b}");
    }
}
