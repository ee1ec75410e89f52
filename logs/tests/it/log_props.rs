//! Property tests of the log forms: the three forms round-trip to the same
//! [`EventLog`], and no input makes a reader panic.

use std::path::Path;

use logs::{
    EventLog, EventWriter, IntervalWriter, ScanWriter, TimeFormatChoice, read_events_from,
    read_intervals_as_events_from, read_scans_as_events_from,
};
use proptest::prelude::*;
use vocabulary::{
    Event, Located, Signal, SignalId, SignalKind, SignalTable, Time, TimeFormat, TimeUnit,
};

fn table(names: &[String], actuator: &[bool]) -> SignalTable {
    let mut table = SignalTable::new();
    for (name, &actuator) in names.iter().zip(actuator) {
        let kind = if actuator {
            SignalKind::Actuator
        } else {
            SignalKind::Sensor
        };
        table.push(Signal {
            name: name.clone(),
            kind,
            description: String::new(),
        });
    }
    table
}

fn time_format() -> impl Strategy<Value = TimeFormat> {
    prop_oneof![
        Just(TimeFormat::Numeric(TimeUnit::S)),
        Just(TimeFormat::Numeric(TimeUnit::Ms)),
        Just(TimeFormat::Numeric(TimeUnit::Us)),
        Just(TimeFormat::Numeric(TimeUnit::Ns)),
        Just(TimeFormat::Rfc3339),
    ]
}

/// A signal table (1 to 6 signals with random distinct names) and a run of scans:
/// strictly increasing times and one random value per signal.
fn recording() -> impl Strategy<Value = (SignalTable, Vec<(Time, Vec<bool>)>)> {
    (
        proptest::collection::btree_set("[A-Za-z][A-Za-z0-9_]{0,5}", 1..=6),
        proptest::collection::vec(any::<bool>(), 6),
    )
        .prop_flat_map(|(names, kinds)| {
            let names: Vec<String> = names.into_iter().collect();
            let n = names.len();
            let scans = proptest::collection::vec(
                (
                    1i64..3_000_000_000,
                    proptest::collection::vec(any::<bool>(), n),
                ),
                1..40,
            );
            (
                Just(table(&names, &kinds)),
                -1_000_000_000_000i64..1_000_000_000_000,
                scans,
            )
        })
        .prop_map(|(table, start, steps)| {
            let mut t = start;
            let scans = steps
                .into_iter()
                .enumerate()
                .map(|(k, (step, values))| {
                    if k > 0 {
                        t += step;
                    }
                    (t, values)
                })
                .collect();
            (table, scans)
        })
}

/// The log the scans hold: the first scan's values, then every change.
fn source_log(format: TimeFormat, scans: &[(Time, Vec<bool>)]) -> EventLog {
    let (start, initial) = scans[0].clone();
    let mut current = initial.clone();
    let mut events = Vec::new();
    for (t, values) in &scans[1..] {
        for (i, (&value, old)) in values.iter().zip(current.iter_mut()).enumerate() {
            if value != *old {
                *old = value;
                events.push(Event {
                    t: *t,
                    signal: SignalId(i as u32),
                    value,
                });
            }
        }
    }
    EventLog {
        format,
        start,
        initial,
        events,
        end: None,
    }
}

fn unit_of(format: TimeFormat) -> TimeUnit {
    match format {
        TimeFormat::Numeric(unit) => unit,
        TimeFormat::Rfc3339 => TimeUnit::Ms,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn the_three_forms_round_trip_to_the_same_log(
        (signals, scans) in recording(),
        format in time_format(),
    ) {
        let source = source_log(format, &scans);
        let path = Path::new("mem.csv");
        let choice = TimeFormatChoice::Detect(unit_of(format));

        let mut events = EventWriter::new(Vec::new(), &signals, format).expect("writer");
        let mut intervals = IntervalWriter::new(Vec::new(), &signals, format).expect("writer");
        events.write_initial(source.start, &source.initial).expect("write");
        intervals.write_initial(source.start, &source.initial).expect("write");
        for event in &source.events {
            events.write(event).expect("write");
            intervals.write(event).expect("write");
        }
        let mut wide = ScanWriter::new(Vec::new(), &signals, format).expect("writer");
        for (t, values) in &scans {
            wide.write(*t, values).expect("write");
        }
        let events = events.finish().expect("finish");
        let intervals = intervals.finish().expect("finish");
        let wide = wide.finish().expect("finish");

        // An events log that says when it ended reads back with that end.
        let end = scans[scans.len() - 1].0;
        let mut ended = EventWriter::new(Vec::new(), &signals, format).expect("writer");
        ended.write_initial(source.start, &source.initial).expect("write");
        for event in &source.events {
            ended.write(event).expect("write");
        }
        ended.write_end(end).expect("write");
        let ended = ended.finish().expect("finish");
        let with_end = EventLog { end: Some(end), ..source.clone() };
        prop_assert_eq!(read_events_from(&ended[..], path, &signals, choice), Ok(with_end));

        let text = |bytes: &[u8]| String::from_utf8_lossy(bytes).into_owned();
        let from_events = read_events_from(&events[..], path, &signals, choice);
        prop_assert_eq!(from_events, Ok(source.clone()), "events:\n{}", text(&events));
        let from_intervals = read_intervals_as_events_from(&intervals[..], path, &signals, choice);
        prop_assert_eq!(from_intervals, Ok(source.clone()), "intervals:\n{}", text(&intervals));
        let from_scans = read_scans_as_events_from(&wide[..], path, &signals, choice);
        prop_assert_eq!(from_scans, Ok(source.clone()), "scans:\n{}", text(&wide));

        // The same with the representation given instead of detected.
        let given = TimeFormatChoice::Given(format);
        prop_assert_eq!(read_events_from(&events[..], path, &signals, given), Ok(source.clone()));
        prop_assert_eq!(read_intervals_as_events_from(&intervals[..], path, &signals, given), Ok(source.clone()));
        prop_assert_eq!(read_scans_as_events_from(&wide[..], path, &signals, given), Ok(source));
    }
}

// ----- no panic on any input -----

fn turntable() -> SignalTable {
    table(
        &["C4".to_string(), "C5".to_string(), "A4".to_string()],
        &[false, false, true],
    )
}

/// Runs every reader on `input` with several time choices; they may fail but
/// must not panic, and their messages must be one line.
fn read_all(input: &[u8]) {
    let signals = turntable();
    let path = Path::new("fuzz.csv");
    for choice in [
        TimeFormatChoice::Detect(TimeUnit::Ms),
        TimeFormatChoice::Detect(TimeUnit::Ns),
        TimeFormatChoice::Given(TimeFormat::Rfc3339),
        TimeFormatChoice::Given(TimeFormat::Numeric(TimeUnit::S)),
    ] {
        let results: [Result<EventLog, Located>; 3] = [
            read_events_from(input, path, &signals, choice),
            read_intervals_as_events_from(input, path, &signals, choice),
            read_scans_as_events_from(input, path, &signals, choice),
        ];
        for result in results {
            if let Err(e) = result {
                assert!(
                    !e.to_string().contains('\n'),
                    "message on several lines: {e}"
                );
            }
        }
    }
}

/// Fields that readers care about, and some that they must reject.
fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("t".to_string()),
        Just("signal".to_string()),
        Just("value".to_string()),
        Just("t_start".to_string()),
        Just("t_end".to_string()),
        Just("site".to_string()),
        Just("C4".to_string()),
        Just("C5".to_string()),
        Just("A4".to_string()),
        Just("\"A4\"".to_string()),
        Just("0".to_string()),
        Just("1".to_string()),
        Just("TRUE".to_string()),
        Just("".to_string()),
        Just("\"".to_string()),
        Just("-9223372036854775808".to_string()),
        Just("99999999999999999999".to_string()),
        Just("2026-11-21T05:00:00.010Z".to_string()),
        Just("\u{feff}".to_string()),
        "-?[0-9]{0,4}(\\.[0-9]{0,12})?",
        "[ -~]{0,6}",
        any::<String>().prop_map(|s| s.chars().take(4).collect()),
    ]
}

fn line() -> impl Strategy<Value = String> {
    proptest::collection::vec(token(), 0..6).prop_map(|fields| fields.join(","))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn readers_never_panic_on_arbitrary_bytes(input in proptest::collection::vec(any::<u8>(), 0..400)) {
        read_all(&input);
    }

    #[test]
    fn readers_never_panic_on_plausible_lines(
        header in prop_oneof![
            Just("t,signal,value".to_string()),
            Just("signal,value,t_start,t_end".to_string()),
            Just("t,C4,C5,A4".to_string()),
            line(),
        ],
        lines in proptest::collection::vec(line(), 0..12),
        crlf in any::<bool>(),
    ) {
        let end = if crlf { "\r\n" } else { "\n" };
        let mut input = header + end;
        for line in lines {
            input.push_str(&line);
            input.push_str(end);
        }
        read_all(input.as_bytes());
    }
}
