//! `gardefou demo`: the closed-loop experiment of safe control, diagnosers and
//! the rewritten filter on the simulated sorting line.

use std::process::Command;

use serde_json::Value;

/// The rows of `demo --json --write-docs`, run in a scratch directory, after
/// checking that the section it writes is the one in the repository's
/// `docs/demo.md`.
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
    let section = |text: &str| {
        let begin = "<!-- cargo run --release -- demo -->";
        let from = text.find(begin).expect("the section of `demo`");
        let to = from + text[from..].find("<!-- end -->").expect("its end");
        text[from..to].to_string()
    };
    assert!(
        section(&written) == section(&shipped),
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
    let nominal = r["nominal_work_per_hour"].as_f64().expect("nominal");
    assert!(nominal > 250.0, "the fault-free line delivers: {r}");
    r["throughput_worst_pct"]
        .as_f64()
        .expect("worst throughput")
        / 100.0
}

#[test]
fn coupling_keeps_production_safe_through_sensor_faults() {
    let rows = demo_rows();
    // The plant file's twelve faults, three modes, the fields of the interface.
    assert_eq!(rows.len(), 36);
    for r in &rows {
        for field in [
            "scenario",
            "declared",
            "mode",
            "runs",
            "work_per_hour",
            "nominal_work_per_hour",
            "throughput_mean_pct",
            "throughput_worst_pct",
            "damage_events",
            "damaged_runs",
            "detected_runs",
            "detection_median_ms",
            "detection_worst_ms",
            "halted_mean_ms",
            "halted_worst_ms",
            "probes",
            "probe_outcomes",
            "no_probe",
        ] {
            assert!(r.get(field).is_some(), "{field} missing in {r}");
        }
        assert_eq!(r["runs"], 1, "{r}");
    }
    // (c): no damage in any scenario.
    for c in rows.iter().filter(|r| r["mode"] == "c") {
        assert_eq!(c["damage_events"], 0, "{c}");
    }
    for fault in ["F2", "F4"] {
        // Certain at once: the estimate stands in, at least 80 % of the
        // fault-free throughput.
        let c = row(&rows, fault, "c");
        assert_eq!(c["declared"], "estimate", "{c}");
        assert!(ratio(c) >= 0.8, "{c}");
        assert!(c["detection_median_ms"].as_f64().is_some(), "{c}");
    }
    for (fault, forbidden) in [
        ("F1", "CSs14 (!C4 & RE(A4))"),
        ("F3", "CSs8 (C5 & C6 & !A4)"),
    ] {
        // Ambiguous with the plate blocked in transit, which the suspected
        // sensor's estimate cannot rule out: the line waits, and no move that
        // would tell them apart is safe under both.
        let c = row(&rows, fault, "c");
        assert_eq!(c["probes"], 0, "{c}");
        let reasons = c["no_probe"].as_array().expect("no_probe");
        assert!(
            reasons
                .iter()
                .any(|r| r.as_str().is_some_and(|r| r.contains(forbidden))),
            "{c}"
        );
    }
    for fault in ["F1", "F2", "F3", "F4", "F5", "F6", "F11", "F12"] {
        // (a): the failed sensor or element shows, as damage or as a halt.
        let a = row(&rows, fault, "a");
        let damaged = a["damage_events"].as_u64().expect("count") > 0;
        let halted = a["halted_worst_ms"].as_f64().expect("halted") > 600_000.0;
        assert!(damaged || halted, "{a}");
    }
    for fault in ["F5", "F6", "F11", "F12"] {
        // The plate blocked: nothing can stand in for it.
        assert_eq!(row(&rows, fault, "b")["declared"], "part stopped");
    }
    // (b) rescues the faults diagnosed with certainty.
    for fault in ["F2", "F4"] {
        let b = row(&rows, fault, "b");
        assert_eq!(b["damage_events"], 0, "{b}");
        assert!(ratio(b) >= 0.8, "{b}");
    }
}
