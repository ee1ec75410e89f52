//! Writers' exact output, misuse errors, and the streaming readers.

use std::io::Write as _;
use std::path::Path;

use logs::{
    EventReader, EventWriter, Interval, IntervalReader, IntervalWriter, ScanReader, ScanWriter,
    TimeFormatChoice, read_events, read_intervals_as_events, read_scans_as_events,
};
use vocabulary::{Event, MS, SECOND, Signal, SignalKind, SignalTable, TimeFormat, TimeUnit};

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

fn ev(signals: &SignalTable, t_ms: i64, name: &str, value: bool) -> Event {
    Event {
        t: t_ms * MS,
        signal: signals.id(name).expect("known signal"),
        value,
    }
}

/// The changes of the good fixtures, after initial values C4=1, C5=0, A4=0 at 0.
fn changes(signals: &SignalTable) -> Vec<Event> {
    vec![
        ev(signals, 100, "A4", true),
        ev(signals, 110, "C4", false),
        ev(signals, 1200, "C5", true),
        ev(signals, 1210, "A4", false),
        ev(signals, 2000, "C5", false),
        ev(signals, 2400, "C4", true),
    ]
}

const MS_FORMAT: TimeFormat = TimeFormat::Numeric(TimeUnit::Ms);

fn fixture(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/logs")
        .join(name);
    std::fs::read_to_string(path).expect("fixture")
}

#[test]
fn event_writer_writes_the_opening_rows_then_one_row_per_change() {
    let signals = turntable();
    let mut writer = EventWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    writer
        .write_initial(0, &[true, false, false])
        .expect("write");
    for event in changes(&signals) {
        writer.write(&event).expect("write");
    }
    let text = String::from_utf8(writer.finish().expect("finish")).expect("UTF-8");
    let expected: String = fixture("events/good.csv")
        .lines()
        .filter(|l| *l != "1210,C4,0")
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(text, expected);
}

#[test]
fn interval_writer_streams_closed_intervals_then_the_open_ones() {
    let signals = turntable();
    let mut writer = IntervalWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    writer
        .write_initial(0, &[true, false, false])
        .expect("write");
    for event in changes(&signals) {
        writer.write(&event).expect("write");
    }
    // A repeated value is not a change.
    writer
        .write(&ev(&signals, 2500, "C4", true))
        .expect("write");
    let text = String::from_utf8(writer.finish().expect("finish")).expect("UTF-8");
    assert_eq!(text, fixture("intervals/good_streamed.csv"));
}

#[test]
fn scan_writer_writes_every_signal_in_table_order() {
    let signals = turntable();
    let mut writer =
        ScanWriter::new(Vec::new(), &signals, TimeFormat::Numeric(TimeUnit::S)).expect("writer");
    writer.write(0, &[true, false, false]).expect("write");
    writer.write(10 * MS, &[true, false, true]).expect("write");
    writer.write(SECOND, &[false, false, true]).expect("write");
    let text = String::from_utf8(writer.finish().expect("finish")).expect("UTF-8");
    assert_eq!(text, "t,C4,C5,A4\n0,1,0,0\n0.01,1,0,1\n1,0,0,1\n");
}

#[test]
fn writers_use_rfc3339_when_asked() {
    let signals = turntable();
    let mut writer = EventWriter::new(Vec::new(), &signals, TimeFormat::Rfc3339).expect("writer");
    let t = vocabulary::time::parse_rfc3339("2026-11-21T05:00:00Z").expect("time");
    writer
        .write(&Event {
            t: t + 10 * MS,
            signal: signals.id("A4").expect("A4"),
            value: true,
        })
        .expect("write");
    let text = String::from_utf8(writer.finish().expect("finish")).expect("UTF-8");
    assert_eq!(text, "t,signal,value\n2026-11-21T05:00:00.010Z,A4,1\n");
}

#[test]
fn writers_reject_misuse_without_panicking() {
    let signals = turntable();
    let stranger = Event {
        t: 0,
        signal: vocabulary::SignalId(7),
        value: true,
    };

    let mut events = EventWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    assert!(events.write_initial(0, &[true]).is_err());
    assert!(events.write(&stranger).is_err());

    let mut intervals = IntervalWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    assert!(
        intervals.write(&ev(&signals, 10, "C4", true)).is_err(),
        "before write_initial"
    );
    assert!(intervals.write_initial(0, &[true, false]).is_err());
    intervals
        .write_initial(100 * MS, &[true, false, false])
        .expect("write");
    assert!(
        intervals
            .write_initial(100 * MS, &[true, false, false])
            .is_err(),
        "twice"
    );
    assert!(intervals.write(&stranger).is_err());
    assert!(
        intervals.write(&ev(&signals, 50, "C4", false)).is_err(),
        "before the open interval"
    );

    let mut scans = ScanWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    assert!(scans.write(0, &[true, false, false, true]).is_err());

    let mut odd = SignalTable::new();
    odd.push(Signal {
        name: "a,b".to_string(),
        kind: SignalKind::Sensor,
        description: String::new(),
    });
    assert!(EventWriter::new(Vec::new(), &odd, MS_FORMAT).is_err());
    assert!(IntervalWriter::new(Vec::new(), &odd, MS_FORMAT).is_err());
    assert!(ScanWriter::new(Vec::new(), &odd, MS_FORMAT).is_err());
}

#[test]
fn event_reader_yields_every_row_and_detects_the_time_format() {
    let signals = turntable();
    let text = "t,signal,value\n2026-11-21T05:00:00Z,C4,1\n2026-11-21T05:00:00Z,C4,1\n";
    let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
    let reader =
        EventReader::new(text.as_bytes(), Path::new("x.csv"), &signals, choice).expect("header");
    assert_eq!(reader.format(), TimeFormat::Rfc3339);
    let rows: Vec<Event> = reader.collect::<Result<_, _>>().expect("rows");
    assert_eq!(rows.len(), 2, "repeated rows are yielded by the row reader");

    // Numbers when the first time is a number; the reader stops after an error.
    let text = "t,signal,value\n5,C4,1\n4,C4,0\n6,C4,1\n";
    let mut reader =
        EventReader::new(text.as_bytes(), Path::new("x.csv"), &signals, choice).expect("header");
    assert_eq!(reader.format(), MS_FORMAT);
    assert!(matches!(reader.next(), Some(Ok(_))));
    assert_eq!(reader.line(), 2);
    assert!(matches!(reader.next(), Some(Err(_))));
    assert!(reader.next().is_none());
}

#[test]
fn interval_reader_yields_intervals_then_checks_every_signal_appeared() {
    let signals = turntable();
    let text = "signal,value,t_start,t_end\nC4,1,0,110\nC4,0,110,\nC5,0,0,\n";
    let choice = TimeFormatChoice::Given(MS_FORMAT);
    let mut reader =
        IntervalReader::new(text.as_bytes(), Path::new("x.csv"), &signals, choice).expect("header");
    let c4 = signals.id("C4").expect("C4");
    let first = Interval {
        signal: c4,
        value: true,
        start: 0,
        end: Some(110 * MS),
    };
    assert_eq!(reader.next(), Some(Ok(first)));
    assert_eq!(
        reader.next(),
        Some(Ok(Interval {
            signal: c4,
            value: false,
            start: 110 * MS,
            end: None
        }))
    );
    assert!(matches!(reader.next(), Some(Ok(_))));
    let missing = reader
        .next()
        .expect("an error at the end")
        .expect_err("A4 is missing");
    assert!(missing.message.contains("'A4'"), "{missing}");
    assert!(reader.next().is_none());
}

#[test]
fn scan_reader_gives_every_signal_in_table_order() {
    let signals = turntable();
    let text = "t,A4,C5,C4\n0,1,0,0\n10,0,0,1\n";
    let choice = TimeFormatChoice::Detect(TimeUnit::S);
    let mut reader =
        ScanReader::new(text.as_bytes(), Path::new("x.csv"), &signals, choice).expect("header");
    assert_eq!(reader.format(), TimeFormat::Numeric(TimeUnit::S));
    assert_eq!(
        reader.next_scan().expect("row").expect("valid"),
        (0, &[false, false, true][..])
    );
    assert_eq!(
        reader.next_scan().expect("row").expect("valid"),
        (10 * SECOND, &[true, false, false][..])
    );
    assert!(reader.next_scan().is_none());
}

#[test]
fn path_based_readers_agree_on_temporary_files() {
    let signals = turntable();
    let dir = tempfile::tempdir().expect("temporary directory");
    let write = |name: &str, bytes: &[u8]| {
        let path = dir.path().join(name);
        let mut file = std::fs::File::create(&path).expect("create");
        file.write_all(bytes).expect("write");
        path
    };

    let mut events = EventWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    let mut intervals = IntervalWriter::new(Vec::new(), &signals, MS_FORMAT).expect("writer");
    events
        .write_initial(0, &[true, false, false])
        .expect("write");
    intervals
        .write_initial(0, &[true, false, false])
        .expect("write");
    for event in changes(&signals) {
        events.write(&event).expect("write");
        intervals.write(&event).expect("write");
    }
    let events = write("events.csv", &events.finish().expect("finish"));
    let intervals = write("intervals.csv", &intervals.finish().expect("finish"));
    let scans = write("scans.csv", fixture("scans/good.csv").as_bytes());

    let from_events = read_events(&events, &signals, TimeUnit::Ms).expect("events");
    assert_eq!(from_events.events, changes(&signals));
    assert_eq!(
        read_intervals_as_events(&intervals, &signals, TimeUnit::Ms),
        Ok(from_events.clone())
    );
    assert_eq!(
        read_scans_as_events(&scans, &signals, TimeUnit::Ms),
        Ok(from_events)
    );

    let error = read_scans_as_events(&dir.path().join("absent.csv"), &signals, TimeUnit::Ms)
        .expect_err("absent");
    assert_eq!(error.location.line, 0);
}
