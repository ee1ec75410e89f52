//! `gardefou report` and `gardefou diagnose --report` on the shipped F2 run:
//! the HTML is self-contained, and, opened in a real headless Chromium
//! (tests/browser/check-report.mjs, through playwright-core), it renders without
//! errors or network requests, is not blank, names the turntable with F2, and
//! draws the turntable's C4, C5 and A4 bands.
//!
//! The browser part is skipped, with a message saying what is missing, when
//! Chromium, Node or `tests/browser/node_modules` is absent — unless
//! `GARDEFOU_REQUIRE_BROWSER=1`, which `scripts/test` sets once it has
//! installed them.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::support::{data, gardefou, learned_model as model, plant};
use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh directory under Cargo's per-target temp dir: the report and the
/// screenshot stay there after a failure, to be looked at.
fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("report_browser")
        .join(name);
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("output dir");
    dir
}

/// The `src=` / `href=` attribute values of the page that point off the machine
/// (`http:`, `https:` or protocol-relative `//`). Namespace declarations such
/// as `xmlns="http://www.w3.org/2000/svg"` are names, not resources, and are
/// not attributes of this kind.
fn remote_references(html: &str) -> Vec<String> {
    let lower = html.to_ascii_lowercase();
    let bytes = lower.as_bytes();
    let mut found = Vec::new();
    for attr in ["src", "href"] {
        let pattern = format!("{attr}=");
        let mut from = 0;
        while let Some(i) = lower[from..].find(&pattern) {
            let at = from + i;
            from = at + pattern.len();
            // An attribute starts after whitespace (or `xlink:`); `data-src=`,
            // `el.src =` and the like are something else.
            let before = at.checked_sub(1).map(|j| bytes[j]);
            if !matches!(before, Some(b' ' | b'\t' | b'\n' | b'\r' | b':')) {
                continue;
            }
            let value = lower[from..].trim_start_matches(['"', '\'', ' ']);
            if ["http:", "https:", "//"]
                .iter()
                .any(|p| value.starts_with(p))
            {
                let end = value.find(['"', '\'', ' ', '>']).unwrap_or(value.len());
                found.push(format!(
                    "{pattern}{}",
                    value[..end].chars().take(120).collect::<String>()
                ));
            }
        }
    }
    found
}

fn assert_self_contained(html: &str) {
    let remote = remote_references(html);
    assert!(
        remote.is_empty(),
        "the report must be self-contained, but it references: {remote:?}"
    );
}

#[test]
fn remote_reference_scan_tells_resources_from_namespaces() {
    let page = r##"<svg xmlns="http://www.w3.org/2000/svg"><a xlink:href="#x0-1">x</a></svg>
        <a href="#x0-3">see</a> <img src="data:image/png;base64,AAAA"> <p data-src="https://a">"##;
    assert!(remote_references(page).is_empty());
    let page = r#"<link rel="stylesheet" href="https://cdn.example/x.css">
        <script src='//cdn.example/x.js'></script> <img SRC=http://x/y.png>"#;
    assert_eq!(remote_references(page).len(), 3);
}

/// The browser and the harness, or why they cannot be used.
struct Browser {
    chromium: PathBuf,
    node: PathBuf,
}

fn on_path(name: &str) -> Option<PathBuf> {
    std::env::split_paths(&std::env::var_os("PATH")?)
        .map(|dir| dir.join(name))
        .find(|p| p.is_file())
}

fn browser() -> Result<Browser, String> {
    let chromium = Some(PathBuf::from("/usr/bin/chromium"))
        .filter(|p| p.is_file())
        .or_else(|| on_path("chromium"))
        .ok_or("Chromium is missing (install it: `apt-get install chromium`)")?;
    let node =
        on_path("node").ok_or("Node.js is missing (install it: `apt-get install nodejs npm`)")?;
    if !root()
        .join("tests/browser/node_modules/playwright-core")
        .is_dir()
    {
        return Err(
            "tests/browser/node_modules/playwright-core is missing (install it: `npm ci --prefix tests/browser`)"
                .into(),
        );
    }
    Ok(Browser { chromium, node })
}

/// The browser, or `None` after saying why the browser checks are skipped —
/// a failure instead when `GARDEFOU_REQUIRE_BROWSER=1`.
fn browser_or_skip(test: &str) -> Option<Browser> {
    match browser() {
        Ok(b) => Some(b),
        Err(why) => {
            let required = std::env::var("GARDEFOU_REQUIRE_BROWSER").is_ok_and(|v| v == "1");
            assert!(!required, "{test}: GARDEFOU_REQUIRE_BROWSER=1 but {why}");
            eprintln!("{test}: skipping the real-browser checks: {why}");
            None
        }
    }
}

/// What `check-report.mjs` saw of the page.
fn open_in_browser(b: &Browser, html: &Path, shot: &Path) -> Value {
    let o = Command::new(&b.node)
        .arg(root().join("tests/browser/check-report.mjs"))
        .arg(html)
        .arg(shot)
        .env("CHROMIUM_PATH", &b.chromium)
        .output()
        .expect("runs node");
    assert!(
        o.status.success(),
        "check-report.mjs failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: not JSON: {stdout}"))
}

fn strings(v: &Value) -> Vec<&str> {
    v.as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default()
}

#[test]
fn report_renders_in_a_real_browser() {
    let dir = out_dir("report");
    let html = dir.join("report.html");
    let o = gardefou(&[
        "report",
        "--plant",
        &plant(),
        "--model",
        model(),
        &data("sorting/F2/events.csv"),
        "-o",
        &html.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = fs::read_to_string(&html).expect("the report is written");
    assert_self_contained(&page);
    assert!(
        page.contains(r#"data-part="turntable""#),
        "no turntable row"
    );

    let Some(b) = browser_or_skip("report_renders_in_a_real_browser") else {
        return;
    };
    let shot = dir.join("shot.png");
    let seen = open_in_browser(&b, &html, &shot);
    eprintln!("{seen}");
    let ctx = format!(
        "browser saw: {seen:#}\n(report and screenshot in {})",
        dir.display()
    );

    // It rendered, cleanly and without leaving the machine.
    assert!(seen["render_error"].is_null(), "render error; {ctx}");
    assert!(
        seen["rendered_ms"].is_number(),
        "never marked rendered; {ctx}"
    );
    assert!(
        strings(&seen["console_errors"]).is_empty(),
        "console errors; {ctx}"
    );
    assert!(
        strings(&seen["page_errors"]).is_empty(),
        "uncaught exceptions; {ctx}"
    );
    assert!(
        strings(&seen["network"]).is_empty(),
        "network requests; {ctx}"
    );

    // Not blank: a real share of the page is drawn, in several colours.
    let s = &seen["screenshot"];
    let drawn = s["non_background_fraction"].as_f64().unwrap_or(0.0);
    let colours = s["distinct_colours"].as_u64().unwrap_or(0);
    assert!(drawn > 0.02 && colours >= 4, "blank page; {ctx}");

    // The turntable is named, with F2.
    let parts = seen["parts"].as_array().expect("parts");
    let turntable = parts
        .iter()
        .find(|p| p["part"] == "turntable")
        .unwrap_or_else(|| panic!("no turntable in the summary; {ctx}"));
    assert!(
        turntable["labels"].as_str().unwrap_or("").contains("F2"),
        "the turntable is not labelled F2; {ctx}"
    );

    // Its timeline draws the bands of the signals F2 is about.
    let timeline = seen["timelines"]
        .as_array()
        .expect("timelines")
        .iter()
        .find(|t| t["part"] == "turntable")
        .unwrap_or_else(|| panic!("no turntable timeline; {ctx}"));
    let bands = strings(&timeline["bands"]);
    for signal in ["C4", "C5", "A4"] {
        assert!(bands.contains(&signal), "no {signal} band; {ctx}");
        // Each band draws the signal, not only its name.
        let shapes = timeline["shapes"][signal].as_u64().unwrap_or(0);
        assert!(shapes > 0, "the {signal} band draws nothing; {ctx}");
    }
    // The timeline itself, screenshot alone against its card, is drawn.
    let t = &seen["turntable_timeline"];
    let drawn = t["non_background_fraction"].as_f64().unwrap_or(0.0);
    let colours = t["distinct_colours"].as_u64().unwrap_or(0);
    assert!(
        drawn > 0.05 && colours >= 4,
        "the turntable's timeline is blank; {ctx}"
    );
}

#[test]
fn diagnose_writes_the_report_too() {
    let dir = out_dir("diagnose");
    let html = dir.join("report.html");
    let o = gardefou(&[
        "diagnose",
        "--plant",
        &plant(),
        "--model",
        model(),
        "--report",
        &html.display().to_string(),
        &data("sorting/F2/events.csv"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = fs::read_to_string(&html).expect("diagnose --report writes the report");
    assert_self_contained(&page);
    assert!(
        page.contains(r#"data-part="turntable""#),
        "no turntable row"
    );
    assert!(page.contains("F2"), "F2 is not named");
}
