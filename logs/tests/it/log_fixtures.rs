//! Data-driven tests of the log readers: every file under `tests/fixtures/logs/<form>/`
//! is read with the reader of its form (`events`, `intervals` or `scans`).
//!
//! - A file `<name>.csv` with a `<name>.err` beside it must fail with exactly the
//!   one-line message in the `.err` file (paths are printed relative to the crate,
//!   e.g. `tests/fixtures/logs/events/missing_column.csv:1: ...`).
//! - A file whose name starts with `good` must read without error; the tests below
//!   check what it reads into.
//!
//! Run with `UPDATE_EXPECT=1` to (re)write the `.err` files from the actual
//! messages, then review the diff.

use std::fs::{self, File};
use std::io::BufReader;
use std::path::{Path, PathBuf};

use logs::{
    EventLog, TimeFormatChoice, read_events, read_events_from, read_intervals_as_events,
    read_intervals_as_events_from, read_scans_as_events, read_scans_as_events_from,
};
use vocabulary::{Event, Located, MS, Signal, SignalKind, SignalTable, TimeFormat, TimeUnit};

const FORMS: [&str; 3] = ["events", "intervals", "scans"];

/// The turntable's signals: C4, C5 (sensors) and A4 (actuator), in that order.
fn turntable() -> SignalTable {
    let mut table = SignalTable::new();
    for (name, kind) in [
        ("C4", SignalKind::Sensor),
        ("C5", SignalKind::Sensor),
        ("A4", SignalKind::Actuator),
    ] {
        table.push(Signal {
            name: name.to_string(),
            kind,
            description: String::new(),
        });
    }
    table
}

fn crate_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Reads `tests/fixtures/logs/<form>/<name>` with the reader of `form`; errors name
/// the file by its path relative to the crate, whatever the working directory.
fn read(form: &str, name: &str) -> Result<EventLog, Located> {
    let relative = PathBuf::from(format!("tests/fixtures/logs/{form}/{name}"));
    let file = File::open(crate_dir().join(&relative)).expect("fixture opens");
    let reader = BufReader::new(file);
    let signals = turntable();
    let time = TimeFormatChoice::Detect(TimeUnit::Ms);
    match form {
        "events" => read_events_from(reader, &relative, &signals, time),
        "intervals" => read_intervals_as_events_from(reader, &relative, &signals, time),
        "scans" => read_scans_as_events_from(reader, &relative, &signals, time),
        other => panic!("no reader for form {other}"),
    }
}

#[test]
fn fixtures_give_the_expected_result() {
    let update = std::env::var_os("UPDATE_EXPECT").is_some();
    let mut failures = Vec::new();
    let mut checked = 0;
    for form in FORMS {
        let dir = crate_dir().join("tests/fixtures/logs").join(form);
        let mut names: Vec<String> = fs::read_dir(&dir)
            .expect("fixture directory")
            .map(|entry| {
                entry
                    .expect("directory entry")
                    .file_name()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        names.sort();
        for name in &names {
            if let Some(stem) = name.strip_suffix(".err") {
                if !names.contains(&format!("{stem}.csv")) {
                    failures.push(format!("{form}/{name}: no {stem}.csv beside it"));
                }
                continue;
            }
            let Some(stem) = name.strip_suffix(".csv") else {
                failures.push(format!("{form}/{name}: not a .csv or .err file"));
                continue;
            };
            checked += 1;
            let err_path = dir.join(format!("{stem}.err"));
            let result = read(form, name);
            if stem.starts_with("good") {
                if let Err(e) = result {
                    failures.push(format!("{form}/{name}: expected success, got: {e}"));
                }
                if err_path.exists() {
                    failures.push(format!("{form}/{name}: a good file must have no .err"));
                }
                continue;
            }
            let actual = match result {
                Ok(log) => {
                    failures.push(format!("{form}/{name}: expected an error, read {log:?}"));
                    continue;
                }
                Err(e) => e.to_string(),
            };
            assert!(
                !actual.contains('\n'),
                "{form}/{name}: message not on one line: {actual}"
            );
            if update {
                fs::write(&err_path, format!("{actual}\n")).expect("write .err");
                continue;
            }
            match fs::read_to_string(&err_path) {
                Ok(expected) if expected.trim_end() == actual => {}
                Ok(expected) => failures.push(format!(
                    "{form}/{name}:\n  expected: {}\n  actual:   {actual}",
                    expected.trim_end()
                )),
                Err(_) => failures.push(format!(
                    "{form}/{name}: no {stem}.err (bad files need one; run with UPDATE_EXPECT=1)\n  actual:   {actual}"
                )),
            }
        }
    }
    assert!(checked >= 30, "only {checked} fixtures found");
    assert!(
        failures.is_empty(),
        "{} fixture failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

fn event(t: i64, signal: &str, value: bool) -> Event {
    let signal = turntable().id(signal).expect("known signal");
    Event {
        t: t * MS,
        signal,
        value,
    }
}

/// The recording that `events/good.csv`, `intervals/good.csv`,
/// `intervals/good_streamed.csv` and `scans/good.csv` all hold.
fn good_log() -> EventLog {
    EventLog {
        format: TimeFormat::Numeric(TimeUnit::Ms),
        start: 0,
        initial: vec![true, false, false],
        events: vec![
            event(100, "A4", true),
            event(110, "C4", false),
            event(1200, "C5", true),
            event(1210, "A4", false),
            event(2000, "C5", false),
            event(2400, "C4", true),
        ],
        end: None,
    }
}

#[test]
fn good_events_file_reads_into_its_changes() {
    let log = read("events", "good.csv").expect("good file");
    assert_eq!(log.format, TimeFormat::Numeric(TimeUnit::Ms));
    assert_eq!(log.start, 0);
    assert_eq!(log.initial, vec![true, false, false]);
    // 10 rows: 3 opening rows, 6 changes and one repeated value, dropped.
    assert_eq!(log.events.len(), 6);
    assert_eq!(log.events[0], event(100, "A4", true));
    assert_eq!(log.events[3], event(1210, "A4", false));
    assert_eq!(log, good_log());
}

#[test]
fn an_end_row_says_when_the_log_ends() {
    let log = read("events", "good_ended.csv").expect("good file");
    assert_eq!(log.end, Some(3000 * MS));
    assert_eq!(
        EventLog { end: None, ..log },
        good_log(),
        "the end row adds no event"
    );
}

#[test]
fn the_three_good_forms_hold_the_same_log() {
    for (form, name) in [
        ("intervals", "good.csv"),
        ("intervals", "good_streamed.csv"),
        ("scans", "good.csv"),
    ] {
        assert_eq!(
            read(form, name).expect("good file"),
            good_log(),
            "{form}/{name}"
        );
    }
}

#[test]
fn path_based_readers_read_the_good_files() {
    let dir = crate_dir().join("tests/fixtures/logs");
    let signals = turntable();
    let unit = TimeUnit::Ms;
    assert_eq!(
        read_events(&dir.join("events/good.csv"), &signals, unit),
        Ok(good_log())
    );
    assert_eq!(
        read_intervals_as_events(&dir.join("intervals/good.csv"), &signals, unit),
        Ok(good_log())
    );
    assert_eq!(
        read_scans_as_events(&dir.join("scans/good.csv"), &signals, unit),
        Ok(good_log())
    );
}

#[test]
fn bom_crlf_quotes_optional_columns_and_rfc3339_are_accepted() {
    let log = read("events", "good_rfc3339_bom_crlf.csv").expect("good file");
    assert_eq!(log.format, TimeFormat::Rfc3339);
    let start = vocabulary::time::parse_rfc3339("2026-11-21T05:00:00Z").expect("valid time");
    assert_eq!(log.start, start);
    assert_eq!(log.initial, vec![true, false, false]);
    assert_eq!(log.events.len(), 1);
    let a4 = turntable().id("A4").expect("known signal");
    assert_eq!(
        log.events[0],
        Event {
            t: start + 100 * MS,
            signal: a4,
            value: true
        }
    );
}

#[test]
fn zero_length_intervals_collapse() {
    let log = read("intervals", "good_glitch.csv").expect("good file");
    assert_eq!(log.start, 0);
    assert_eq!(log.initial, vec![true, false, true]);
    assert_eq!(log.events, vec![]);
}

#[test]
fn a_missing_file_is_an_error_not_a_panic() {
    let path = Path::new("tests/fixtures/logs/events/no_such_file.csv");
    let e =
        read_events(&crate_dir().join(path), &turntable(), TimeUnit::Ms).expect_err("missing file");
    assert!(e.message.starts_with("cannot open the log"), "{e}");
}

#[test]
fn a_line_longer_than_a_mib_is_refused_in_a_short_message() {
    // A file with no line breaks (or not a log at all) must not be held
    // whole, nor echoed: the reader stops at 1 MiB and says so.
    let mut text = String::from("t,signal,value\n0,");
    text.push_str(&"C4".repeat(1 << 20));
    text.push_str(",1\n");
    let err = read_events_from(
        std::io::Cursor::new(text),
        Path::new("long.csv"),
        &turntable(),
        TimeFormatChoice::Detect(TimeUnit::Ms),
    )
    .expect_err("refused");
    let message = err.to_string();
    assert!(
        message.starts_with("long.csv:2:1: line longer than 1 MiB"),
        "{message}"
    );
    assert!(message.len() < 200, "{message}");
}
