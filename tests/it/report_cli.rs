//! End-to-end tests of `gardefou report` without a browser: what the page says
//! about the shipped F2 run, and bad input. The page in a real browser is
//! `tests/it/report_browser.rs`.

use crate::support::{data, gardefou, learned_model as model, plant};
use std::fs;
use std::process::Command;
use std::sync::OnceLock;

/// The report of the F2 run, with the built-in layout (Graphviz has its own test).
fn f2_report() -> &'static str {
    static PAGE: OnceLock<String> = OnceLock::new();
    PAGE.get_or_init(|| {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("report.html");
        let o = gardefou(&[
            "report",
            "--plant",
            &plant(),
            "--model",
            model(),
            "--layout",
            "builtin",
            &data("sorting/F2/events.csv"),
            "-o",
            &out.display().to_string(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(o.stdout.is_empty(), "report writes nothing on stdout");
        fs::read_to_string(&out).expect("report written")
    })
}

/// The embedded timeline data.
fn data_of(page: &str) -> serde_json::Value {
    let start =
        page.find("id=\"gardefou-data\">").expect("data block") + "id=\"gardefou-data\">".len();
    let end = start + page[start..].find("</script>").expect("end of data");
    serde_json::from_str(&page[start..end].replace("<\\/", "</")).expect("data is JSON")
}

#[test]
fn the_summary_names_the_fault_and_its_meaning() {
    let page = f2_report();
    let row_start = page
        .find("<tr data-part=\"turntable\"")
        .expect("turntable row");
    let row = &page[row_start..row_start + page[row_start..].find("</tr>").expect("row end")];
    assert!(row.contains("<td class=\"labels\">F2</td>"), "{row}");
    assert!(row.contains("verdict-certain"), "{row}");
    assert!(row.contains("def_C4"), "{row}");
    assert!(
        row.contains("C4 stuck at 1: C4 (turntable at loading position) stays on"),
        "{row}"
    );
    // Every other part stayed normal.
    for part in [
        "feed",
        "intermediate",
        "rollers",
        "left_evacuation",
        "right_evacuation",
    ] {
        let at = page
            .find(&format!("<tr data-part=\"{part}\""))
            .unwrap_or_else(|| panic!("row of {part}"));
        let row = &page[at..at + page[at..].find("</tr>").expect("row end")];
        assert!(row.contains("<td class=\"labels\">N</td>"), "{row}");
    }
}

#[test]
fn each_detection_is_explained_at_four_levels() {
    let page = f2_report();
    let articles: Vec<&str> = page
        .split("<article class=\"explanation detection")
        .skip(1)
        .map(|a| &a[..a.find("</article>").expect("article end")])
        .collect();
    // N F2 F5 F7 (normal after a glitch beside them), then F2 F5, then F2
    // (`diagnose` gives the same three changes).
    assert_eq!(articles.len(), 3, "one explanation per verdict change");
    for a in &articles {
        for level in [
            "Current state",
            "State before stop",
            "Advanced state: the last changes",
            "Hypothesis",
        ] {
            assert!(a.contains(level), "level {level} missing in {a}");
        }
    }
    let last = articles.last().expect("three");
    assert!(last.contains("certain F2"), "{last}");
    assert!(last.contains("RE(C5) at 2940 ms after RE(A4)"), "{last}");
    // The deadline explanation names the expected event and its learned window.
    assert!(
        articles[0].contains("<code>FE(C4)</code> within ["),
        "{}",
        articles[0]
    );
}

#[test]
fn the_flag_rewrites_constraints_and_trips_are_explained_with_their_literals() {
    let page = f2_report();
    let rewrite = &page[page.find("<article class=\"rewrite\"").expect("a rewrite")..];
    assert!(rewrite.contains("<code>def_C4</code> raised"));
    // CSs14 read C4; raised def_C4 makes it read C4's estimate.
    assert!(rewrite.contains("<td><code>CSs14</code></td><td><code>!C4 &amp; RE(A4)</code></td>"));
    let trip = &page[page
        .find("<article class=\"explanation trip\"")
        .expect("an explained trip")..];
    let trip = &trip[..trip.find("</article>").expect("end")];
    assert!(trip.contains("<mark class=\"literal\">"), "{trip}");
    for level in [
        "Current state",
        "Projection",
        "State before stop",
        "Hypothesis",
    ] {
        assert!(trip.contains(level), "{level} missing in {trip}");
    }
    let data = data_of(page);
    let trips = data["logs"][0]["filter"]["trips"]
        .as_array()
        .expect("trips");
    assert!(!trips.is_empty());
    assert!(
        trips.iter().all(|t| t["explanation"]
            .as_str()
            .is_some_and(|id| page.contains(&format!("id=\"{id}\"")))),
        "every trip of a short log is explained: {trips:?}"
    );
}

#[test]
fn the_timeline_data_replays_to_the_logged_values() {
    let page = f2_report();
    let embedded = data_of(page);
    let log = &embedded["logs"][0];
    assert_eq!(log["tick_ns"], 1_000_000);
    let turntable = log["parts"]
        .as_array()
        .expect("parts")
        .iter()
        .find(|p| p["name"] == "turntable")
        .expect("turntable");
    let names: Vec<&str> = turntable["signals"]
        .as_array()
        .expect("signals")
        .iter()
        .filter_map(|s| s["name"].as_str())
        .collect();
    assert_eq!(names, ["A4", "C4", "C5"]);
    // Decoding C4's edges gives the log's own C4 changes.
    let c4 = &turntable["signals"][1];
    let mut t = 0i64;
    let times: Vec<i64> = c4["edges"]
        .as_array()
        .expect("edges")
        .iter()
        .map(|d| {
            t += d.as_i64().expect("integer");
            t
        })
        .collect();
    let csv = fs::read_to_string(data("sorting/F2/events.csv")).expect("log");
    let mut logged = Vec::new();
    let mut value = None;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.get(1) == Some(&"C4") {
            let v = f[2] == "1";
            if value.is_some_and(|x| x != v) {
                logged.push(f[0].parse::<f64>().expect("time") as i64);
            }
            value = Some(v);
        }
    }
    assert!(!logged.is_empty());
    assert_eq!(&times[times.len() - logged.len()..], &logged[..]);
    // The windows are the learned ones: FE(C4) is expected after RE(A4).
    let windows = turntable["windows"].as_object().expect("windows");
    assert!(
        windows
            .values()
            .flat_map(|w| w.as_array().into_iter().flatten())
            .any(|w| w["event"] == "FE(C4)" && w["lo"].as_i64() < w["hi"].as_i64()),
        "{windows:?}"
    );
}

#[test]
fn the_page_needs_no_network() {
    let page = f2_report();
    for attr in [
        "src=\"http",
        "href=\"http",
        "src='http",
        "href='http",
        "@import",
        "url(http",
    ] {
        assert!(!page.contains(attr), "the page loads {attr}…");
    }
    assert!(page.contains("<svg"), "pictures are inline SVG");
}

#[test]
fn bad_input_is_one_line_exit_2_and_keeps_the_old_report() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("report.html");
    fs::write(&out, "previous report").expect("write");
    let bad_log = dir.path().join("bad.csv");
    fs::write(&bad_log, "t,signal,value\n0,C4,1\n10,C99,1\n").expect("write");
    let out_s = out.display().to_string();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec![data("sorting/F2/missing.csv")], "missing.csv"),
        (vec![bad_log.display().to_string()], "bad.csv:3"),
    ];
    for (logs, needle) in cases {
        let mut args = vec![
            "report".to_string(),
            "--plant".to_string(),
            plant(),
            "--model".to_string(),
            model().to_string(),
            "-o".to_string(),
            out_s.clone(),
        ];
        args.extend(logs);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = gardefou(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(needle), "{err}");
        assert_eq!(
            fs::read_to_string(&out).expect("still there"),
            "previous report"
        );
    }
    // An output in a directory that does not exist.
    let o = gardefou(&[
        "report",
        "--plant",
        &plant(),
        "--model",
        model(),
        &data("sorting/F2/events.csv"),
        "-o",
        &dir.path().join("no/such/dir/r.html").display().to_string(),
        "--layout",
        "none",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no such directory"));
}

#[test]
fn summary_is_plain_in_a_pipe() {
    let o = gardefou(&[
        "diagnose",
        "--plant",
        &plant(),
        "--model",
        model(),
        "--summary",
        &data("sorting/F2/events.csv"),
    ]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        !text.contains('\x1b'),
        "no colour codes in a pipe: {text:?}"
    );
    assert!(
        text.lines()
            .any(|l| l.starts_with("turntable") && l.contains("F2"))
    );
}

#[test]
fn summary_is_coloured_on_a_terminal() {
    // `script` (util-linux) runs the command on a real pseudo-terminal.
    if Command::new("script").arg("--version").output().is_err() {
        eprintln!("skipping: `script` (util-linux) is not installed");
        return;
    }
    let command = format!(
        "{} diagnose --plant {} --model {} --summary {}",
        env!("CARGO_BIN_EXE_gardefou"),
        plant(),
        model(),
        data("sorting/F2/events.csv")
    );
    let o = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .env_remove("NO_COLOR")
        .output()
        .expect("runs script");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let turntable = text
        .lines()
        .find(|l| l.contains("turntable"))
        .unwrap_or_else(|| panic!("no turntable row: {text:?}"));
    assert!(
        turntable.starts_with("\x1b[1;31mturntable") && turntable.contains("F2"),
        "certain is red: {turntable:?}"
    );
    let feed = text
        .lines()
        .find(|l| l.contains("feed"))
        .unwrap_or_else(|| panic!("no feed row: {text:?}"));
    assert!(
        feed.starts_with("\x1b[32mfeed"),
        "normal is green: {feed:?}"
    );
}
