//! The text log forms read line by line: `candump -L` and VCD. Good fixtures
//! give the expected initial values and events; bad ones fail with one-line
//! errors naming file, line and column.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use logs::{IngestOptions, LogFormat, LogStream, candump, vcd};
use vocabulary::{Event, Located, MS, Plant, SECOND, SignalId, Time, TimeFormat, TimeUnit};

/// The turntable's signals, mapped into two PDOs: the sensors in TPDO1 of node
/// 1 (bits 0 and 1 of byte 0), the order in RPDO1 (bit 0 of byte 1).
const PLANT: &str = r#"
name = "turntable"
time_unit = "ms"

[signals]
C4 = { kind = "sensor", description = "turntable at loading position" }
C5 = { kind = "sensor", description = "turntable at unloading position" }
A4 = { kind = "actuator", description = "rotate turntable to unloading position" }

[can]
C4 = { cob_id = 0x181, bit = 0 }
C5 = { cob_id = 0x181, bit = 1 }
A4 = { cob_id = 0x201, bit = 8 }
"#;

const C4: SignalId = SignalId(0);
const C5: SignalId = SignalId(1);
const A4: SignalId = SignalId(2);

fn plant() -> Plant {
    Plant::parse(PLANT, Path::new("plant.toml")).expect("test plant parses")
}

fn plant_with_can(can: &str) -> Plant {
    let head = PLANT.split("[can]").next().expect("plant text");
    Plant::parse(&format!("{head}{can}"), Path::new("plant.toml")).expect("test plant parses")
}

fn fixture(form: &str, name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(form)
        .join(name)
}

fn options(batch_rows: usize) -> IngestOptions {
    IngestOptions {
        batch_rows,
        ..IngestOptions::default()
    }
}

/// Every batch, in order; the first error if any.
fn batches(log: LogStream) -> Result<Vec<Vec<Event>>, Located> {
    log.batches.collect()
}

fn events(log: LogStream) -> Result<Vec<Event>, Located> {
    Ok(batches(log)?.into_iter().flatten().collect())
}

/// The message of the first error met opening `path` or reading it through.
fn failure(
    open: fn(&Path, &Plant, &IngestOptions) -> Result<LogStream, Located>,
    path: &Path,
    plant: &Plant,
) -> String {
    match open(path, plant, &options(1)).and_then(events) {
        Ok(events) => panic!("{} read without error: {events:?}", path.display()),
        Err(e) => e.to_string(),
    }
}

fn ev(t: Time, signal: SignalId, value: bool) -> Event {
    Event { t, signal, value }
}

/// Seconds since the epoch, written with a fraction as candump does.
fn epoch(text: &str) -> Time {
    TimeUnit::S.parse(text).expect("a time")
}

fn temp_file(name: &str, text: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join(name);
    let mut file = std::fs::File::create(&path).expect("temporary file");
    file.write_all(text.as_bytes()).expect("write");
    (dir, path)
}

// ----- candump -L -----

#[test]
fn candump_good_log_gives_initial_values_and_changes() {
    let path = fixture("candump", "good.log");
    let log = candump::open(&path, &plant(), &options(1000)).expect("good log opens");
    assert_eq!(log.path, path);
    assert_eq!(log.format, LogFormat::Candump);
    assert_eq!(log.time, TimeFormat::Numeric(TimeUnit::S));
    assert_eq!(log.start, epoch("1436509052"));
    // C4 from 181#01, C5 from the same frame, A4 from 201#0000.
    assert_eq!(log.initial, vec![true, false, false]);
    assert_eq!(
        events(log).expect("good log reads"),
        vec![
            // Two frames with one timestamp: one scan, in signal order.
            ev(epoch("1436509052.3"), C4, false),
            ev(epoch("1436509052.3"), A4, true),
            // The CAN FD frame; the remote frame before it changes nothing.
            ev(epoch("1436509052.4"), C5, true),
            // A4 off and on again within one timestamp is no change; the
            // error frame and the unmapped extended frame are skipped.
            ev(epoch("1436509053.2"), A4, false),
        ]
    );
}

#[test]
fn candump_batches_never_split_a_timestamp() {
    let log = candump::open(&fixture("candump", "good.log"), &plant(), &options(1))
        .expect("good log opens");
    let batches = batches(log).expect("good log reads");
    let sizes: Vec<usize> = batches.iter().map(Vec::len).collect();
    assert_eq!(sizes, [2, 1, 1]);
}

#[test]
fn candump_frames_at_the_first_time_of_an_identifier_are_initial() {
    let (_dir, path) = temp_file(
        "fold.log",
        "(10.0) can0 181#01\n(10.0) can0 181#03\n(10.5) can0 201#0001\n(11.0) can0 181#00\n",
    );
    let log = candump::open(&path, &plant(), &options(10)).expect("log opens");
    assert_eq!(log.start, 10 * SECOND);
    assert_eq!(log.initial, vec![true, true, true]);
    assert_eq!(
        events(log).expect("log reads"),
        vec![ev(11 * SECOND, C4, false), ev(11 * SECOND, C5, false)]
    );
}

#[test]
fn candump_events_before_an_error_come_out_first() {
    let path = fixture("candump", "backwards.log");
    let log = candump::open(&path, &plant(), &options(1)).expect("the start is sound");
    let got: Vec<_> = log.batches.collect();
    assert_eq!(got.len(), 3, "{got:?}");
    assert_eq!(got[0], Ok(vec![ev(epoch("1436509052.2"), C4, false)]));
    assert_eq!(got[1], Ok(vec![ev(epoch("1436509052.3"), A4, true)]));
    assert!(got[2].is_err());
}

#[test]
fn candump_bad_logs_fail_at_file_line_and_column() {
    let plant = plant();
    let cases = [
        (
            "bad_timestamp.log",
            ":2:2: bad timestamp '1436509052.1x0000': expected seconds since the epoch, such as 1436509052.249713",
        ),
        (
            "not_candump.log",
            ":1:1: expected a timestamp in parentheses such as (1436509052.249713), found 't,signal,value': this is not a candump -L line",
        ),
        (
            "backwards.log",
            ":5:2: time goes backwards: 1436509052.25 is before 1436509052.3 on line 4",
        ),
        (
            "odd_hex.log",
            ":2:30: odd number of hex digits in the data '010': each byte takes two",
        ),
        (
            "too_long.log",
            ":2:30: 9 data bytes, more than the 8 of a classic CAN frame",
        ),
        (
            "bad_id.log",
            ":2:26: bad CAN identifier '18G': expected 3 hex digits (standard frame, at most 7FF) or 8 (extended frame)",
        ),
        (
            "short_frame.log",
            ":2:30: frame 201 has 1 data byte, but signal 'A4' is bit 8 and needs at least 2",
        ),
        (
            "never_seen.log",
            ": no frame with identifier 201 in the log, so no value for signal 'A4'",
        ),
    ];
    for (name, message) in cases {
        let path = fixture("candump", name);
        let got = failure(candump::open, &path, &plant);
        assert_eq!(got, format!("{}{message}", path.display()), "{name}");
        assert!(!got.contains('\n'), "{name}: one line");
    }
}

#[test]
fn candump_needs_a_mapping_for_every_signal() {
    let path = fixture("candump", "good.log");
    let none = plant_with_can("");
    assert_eq!(
        failure(candump::open, &path, &none),
        format!(
            "{}: the plant file has no [can] table: map every signal to a PDO bit to read candump logs, e.g. C4 = {{ cob_id = 0x181, bit = 0 }}",
            path.display()
        )
    );
    let partial = plant_with_can(
        "[can]\nC4 = { cob_id = 0x181, bit = 0 }\nC5 = { cob_id = 0x181, bit = 1 }\n",
    );
    assert_eq!(
        failure(candump::open, &path, &partial),
        format!(
            "{}: signal 'A4' has no [can] mapping in the plant file, so a candump log cannot give it a value",
            path.display()
        )
    );
}

#[test]
fn candump_is_recognised_by_its_first_line() {
    let text = std::fs::read_to_string(fixture("candump", "good.log")).expect("fixture");
    assert!(candump::looks_like(&text));
    assert!(!candump::looks_like("t,signal,value\n0,C4,1\n"));
    assert!(!vcd::looks_like(&text));
}

// ----- VCD -----

#[test]
fn vcd_good_dump_gives_initial_values_and_changes() {
    let path = fixture("vcd", "good.vcd");
    let log = vcd::open(&path, &plant(), &options(1000)).expect("good dump opens");
    assert_eq!(log.format, LogFormat::Vcd);
    assert_eq!(log.time, TimeFormat::Numeric(TimeUnit::Ms));
    assert_eq!(log.start, 0);
    assert_eq!(log.initial, vec![true, false, false]);
    assert_eq!(
        events(log).expect("good dump reads"),
        vec![
            ev(100 * MS, A4, true),
            ev(180 * MS, C4, false),
            ev(3000 * MS, C5, true),
            // A4 off and on again at #4000 is no change; `b0 #` is a 1-bit
            // value written as a vector. Vector and real variables are skipped.
            ev(4100 * MS, A4, false),
        ]
    );
}

#[test]
fn vcd_batches_never_split_a_timestamp() {
    let (_dir, path) = temp_file(
        "scan.vcd",
        "$var wire 1 ! C4 $end $var wire 1 \" C5 $end $var wire 1 # A4 $end\n\
         $enddefinitions $end\n#0 1! 0\" 0#\n#10 1# 0!\n#20 1\"\n",
    );
    let log = vcd::open(&path, &plant(), &options(1)).expect("dump opens");
    assert_eq!(
        batches(log).expect("dump reads"),
        vec![
            vec![ev(10, C4, false), ev(10, A4, true)],
            vec![ev(20, C5, true)]
        ]
    );
}

#[test]
fn vcd_timescales_become_nanoseconds() {
    let body = "$var wire 1 ! C4 $end\n$var wire 1 \" C5 $end\n$var wire 1 # A4 $end\n\
                $enddefinitions $end\n#0\n1!\n0\"\n0#\n#300\n1#\n#2501\n0#\n";
    let cases = [
        ("", TimeUnit::Ns, 300, 2501),
        (
            "$timescale 100 us $end\n",
            TimeUnit::Us,
            30 * MS,
            250_100_000,
        ),
        // 25.01 ns: truncated to the nanosecond.
        ("$timescale 10ps $end\n", TimeUnit::Ns, 3, 25),
        (
            "$timescale\n1\ns\n$end\n",
            TimeUnit::S,
            300 * SECOND,
            2501 * SECOND,
        ),
    ];
    for (timescale, unit, t1, t2) in cases {
        let (_dir, path) = temp_file("scale.vcd", &format!("{timescale}{body}"));
        let log = vcd::open(&path, &plant(), &options(10)).expect("dump opens");
        assert_eq!(log.time, TimeFormat::Numeric(unit), "{timescale:?}");
        assert_eq!(
            events(log).expect("dump reads"),
            vec![ev(t1, A4, true), ev(t2, A4, false)],
            "{timescale:?}"
        );
    }
}

#[test]
fn vcd_values_before_any_time_are_at_time_zero() {
    let (_dir, path) = temp_file(
        "early.vcd",
        "$timescale 1 ms $end\n$var wire 1 ! C4 $end\n$var wire 1 \" C5 $end\n$var wire 1 # A4 $end\n\
         $enddefinitions $end\n$dumpvars 1! 0\" 0# $end\n#5\n1#\n",
    );
    let log = vcd::open(&path, &plant(), &options(10)).expect("dump opens");
    assert_eq!((log.start, &log.initial), (0, &vec![true, false, false]));
    assert_eq!(events(log).expect("dump reads"), vec![ev(5 * MS, A4, true)]);
}

#[test]
fn vcd_bad_dumps_fail_at_file_line_and_column() {
    let plant = plant();
    let cases = [
        (
            "backwards.vcd",
            ":14:1: time goes backwards: #5 is before #10 on line 12",
        ),
        (
            "bad_time.vcd",
            ":12:1: bad time '#1a': expected # followed by a whole number of timescale units",
        ),
        (
            "x_value.vcd",
            ":13:1: value 'x' of signal 'C4' is not 0 or 1: unknown (x) and high-impedance (z) values are not supported",
        ),
        (
            "undeclared_code.vcd",
            ":13:2: identifier code '&' is not declared by any $var",
        ),
        (
            "no_initial.vcd",
            ":11:1: no initial value for signal 'C5': the dump must give every signal a value at its first time (#0)",
        ),
        (
            "unknown_signal.vcd",
            ":6:15: 'C99' is not a signal of the plant file: every 1-bit variable must be named after one",
        ),
        (
            "missing_signal.vcd",
            ":6:1: plant signal 'A4' not in the dump: no $var declares it",
        ),
        (
            "bad_timescale.vcd",
            ":1:12: bad timescale '5 ns': expected 1, 10 or 100 followed by s, ms, us, ns, ps or fs",
        ),
    ];
    for (name, message) in cases {
        let path = fixture("vcd", name);
        let got = failure(vcd::open, &path, &plant);
        assert_eq!(got, format!("{}{message}", path.display()), "{name}");
        assert!(!got.contains('\n'), "{name}: one line");
    }
}

#[test]
fn vcd_rejects_what_it_cannot_represent() {
    let head = "$var wire 1 ! C4 $end\n$var wire 1 \" C5 $end\n$var wire 1 # A4 $end\n\
                $enddefinitions $end\n#0\n1!\n0\"\n0#\n";
    let cases = [
        (
            "#10\nbz #\n",
            "10:1: value 'bz' of signal 'A4' is not 0 or 1",
        ),
        (
            "#10\nr1.5 #\n",
            "10:1: 'r1.5' is a real number, not a value of a 1-bit signal",
        ),
        ("#10\n$dumpoff\n", "10:1: $dumpoff is not supported"),
        (
            "#10\n$var wire 1 $ C4 $end\n",
            "10:1: $var after $enddefinitions",
        ),
        ("#10\n2!\n", "10:1: unexpected '2!': expected #<time>"),
        ("$comment never closed\n", "9:1: $comment has no $end"),
    ];
    for (tail, message) in cases {
        let (_dir, path) = temp_file("bad.vcd", &format!("{head}{tail}"));
        let got = failure(vcd::open, &path, &plant());
        let want = format!("{}:{message}", path.display());
        assert!(got.starts_with(&want), "{tail:?}: got {got}");
    }
    let (_dir, path) = temp_file(
        "twice.vcd",
        "$var wire 1 ! C4 $end\n$var wire 1 % C4 $end\n",
    );
    assert_eq!(
        failure(vcd::open, &path, &plant()),
        format!(
            "{}:2:15: signal 'C4' is declared twice: identifier code '!' on line 1 already carries it",
            path.display()
        )
    );
}

#[test]
fn vcd_is_recognised_by_its_first_token() {
    let text = std::fs::read_to_string(fixture("vcd", "good.vcd")).expect("fixture");
    assert!(vcd::looks_like(&text));
    assert!(!candump::looks_like(&text));
}

#[test]
fn long_logs_stream_in_bounded_batches() {
    // 100 000 frames, each toggling C4: batches of about 1000 events.
    let mut text = String::from("(0.000000) can0 201#0000\n");
    for i in 0..100_000u32 {
        text.push_str(&format!(
            "({}.{:06}) can0 181#0{}\n",
            i / 1000,
            (i % 1000) * 1000,
            i % 2
        ));
    }
    let (_dir, path) = temp_file("long.log", &text);
    let log = candump::open(&path, &plant(), &options(1000)).expect("log opens");
    let mut total = 0;
    for batch in log.batches {
        let batch = batch.expect("log reads");
        assert!(batch.len() <= 1000, "a batch of {}", batch.len());
        assert!(
            batch
                .windows(2)
                .all(|w| (w[0].t, w[0].signal) < (w[1].t, w[1].signal))
        );
        total += batch.len();
    }
    assert_eq!(total, 99_999);

    let mut text = String::from(
        "$var wire 1 ! C4 $end $var wire 1 \" C5 $end $var wire 1 # A4 $end $enddefinitions $end\n#0 0! 0\" 0#\n",
    );
    for i in 1..=100_000u32 {
        text.push_str(&format!("#{i}\n{}!\n", i % 2));
    }
    let (_dir, path) = temp_file("long.vcd", &text);
    let log = vcd::open(&path, &plant(), &options(1000)).expect("dump opens");
    let sizes: Vec<usize> = batches(log)
        .expect("dump reads")
        .iter()
        .map(Vec::len)
        .collect();
    assert_eq!(sizes.len(), 100);
    assert!(sizes.iter().all(|&n| n == 1000));
}
