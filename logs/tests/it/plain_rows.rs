//! CSV logs are read in blocks, and rows written plainly straight from their
//! bytes: on any input, that reading gives what reading line by line and
//! field by field gives — the same records, events, errors and messages.
//!
//! The reference here is [`LineByLine`], CSV records read one line at a time
//! with no plain rows, as the readers read them before blocks.

use std::io::{self, BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use logs::csv::{CsvRecords, LONGEST_LINE};
use logs::{
    Changes, EventChanges, EventLog, EventReader, IntervalChanges, IntervalReader, Records,
    ScanChanges, ScanReader, TimeFormatChoice,
};
use proptest::prelude::*;
use vocabulary::{
    Event, Located, Location, Signal, SignalKind, SignalTable, Time, TimeFormat, TimeUnit,
};

// ----- the reference: one line at a time -----

/// One field of a [`LineByLine`] record.
#[derive(Debug, Clone, Copy)]
struct Field {
    start: usize,
    end: usize,
    column: usize,
}

/// CSV records read one line at a time with `read_until`, every record split
/// into fields: no block, no plain row.
struct LineByLine<R> {
    reader: R,
    path: PathBuf,
    line: String,
    fields: Vec<Field>,
    line_no: usize,
    first_line: bool,
}

impl<R: BufRead> LineByLine<R> {
    fn new(reader: R, path: &Path) -> Self {
        LineByLine {
            reader,
            path: path.to_path_buf(),
            line: String::new(),
            fields: Vec::new(),
            line_no: 0,
            first_line: true,
        }
    }

    fn split(&mut self) {
        self.fields.clear();
        let bytes = self.line.as_bytes();
        let mut from = 0;
        loop {
            let to = bytes[from..]
                .iter()
                .position(|&b| b == b',')
                .map_or(bytes.len(), |p| from + p);
            let (mut start, mut end) = (from, to);
            while start < end && bytes[start].is_ascii_whitespace() {
                start += 1;
            }
            while end > start && bytes[end - 1].is_ascii_whitespace() {
                end -= 1;
            }
            let column = start + 1;
            if end - start >= 2 && bytes[start] == b'"' && bytes[end - 1] == b'"' {
                start += 1;
                end -= 1;
            }
            self.fields.push(Field { start, end, column });
            if to == bytes.len() {
                break;
            }
            from = to + 1;
        }
    }
}

impl<R: BufRead> Records for LineByLine<R> {
    fn next_record(&mut self) -> Result<bool, Located> {
        loop {
            let mut bytes = std::mem::take(&mut self.line).into_bytes();
            bytes.clear();
            let read = (self.reader.by_ref())
                .take(LONGEST_LINE as u64 + 1)
                .read_until(b'\n', &mut bytes);
            let n = match read {
                Ok(n) => n,
                Err(e) => {
                    let location = Location::new(&self.path, self.line_no + 1, 0);
                    return Err(Located::new(location, format!("cannot read the log: {e}")));
                }
            };
            if n == 0 {
                self.fields.clear();
                return Ok(false);
            }
            self.line_no += 1;
            if n > LONGEST_LINE && bytes.last() != Some(&b'\n') {
                let location = Location::new(&self.path, self.line_no, 1);
                let message = format!(
                    "line longer than {} MiB: not a log's line (a header of 10,000 signals takes 0.1 MiB)",
                    LONGEST_LINE >> 20
                );
                return Err(Located::new(location, message));
            }
            let mut text = match String::from_utf8(bytes) {
                Ok(text) => text,
                Err(e) => {
                    let column = e.utf8_error().valid_up_to() + 1;
                    let location = Location::new(&self.path, self.line_no, column);
                    return Err(Located::new(location, "invalid UTF-8 text"));
                }
            };
            if text.ends_with('\n') {
                text.pop();
                if text.ends_with('\r') {
                    text.pop();
                }
            }
            if std::mem::take(&mut self.first_line) && text.starts_with('\u{feff}') {
                text.replace_range(..'\u{feff}'.len_utf8(), "");
            }
            self.line = text;
            if self.line.trim_ascii().is_empty() {
                continue;
            }
            self.split();
            return Ok(true);
        }
    }

    fn len(&self) -> usize {
        self.fields.len()
    }

    fn field(&self, i: usize) -> &str {
        (self.fields.get(i))
            .and_then(|f| self.line.get(f.start..f.end))
            .unwrap_or("")
    }

    fn column(&self, i: usize) -> usize {
        self.fields.get(i).map_or(self.end_column(), |f| f.column)
    }

    fn end_column(&self) -> usize {
        self.line.len() + 1
    }

    fn line_no(&self) -> usize {
        self.line_no
    }

    fn path(&self) -> &Path {
        &self.path
    }
}

// ----- sources of bytes -----

/// Bytes handed out a few at a time (`sizes`, in turn), then an error after
/// `fail_at` bytes if it is set: lines and rows cut at every place.
struct Trickle {
    data: Vec<u8>,
    at: usize,
    sizes: Vec<usize>,
    reads: usize,
    fail_at: Option<usize>,
}

impl Read for Trickle {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let end = self.fail_at.unwrap_or(self.data.len()).min(self.data.len());
        if self.at == end && self.fail_at.is_some_and(|f| f < self.data.len()) {
            return Err(io::Error::other("the disk went away"));
        }
        let size = self.sizes[self.reads % self.sizes.len()].max(1);
        self.reads += 1;
        let n = size.min(buf.len()).min(end - self.at);
        buf[..n].copy_from_slice(&self.data[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

/// How the bytes of a test reach the readers.
#[derive(Debug, Clone)]
struct Delivery {
    /// Sizes of successive reads (all at once if empty).
    sizes: Vec<usize>,
    /// Reads fail once this many bytes are read.
    fail_at: Option<usize>,
}

impl Delivery {
    fn reader(&self, data: &[u8]) -> Box<dyn BufRead> {
        if self.sizes.is_empty() && self.fail_at.is_none() {
            return Box::new(io::Cursor::new(data.to_vec()));
        }
        let trickle = Trickle {
            data: data.to_vec(),
            at: 0,
            sizes: if self.sizes.is_empty() {
                vec![usize::MAX]
            } else {
                self.sizes.clone()
            },
            reads: 0,
            fail_at: self.fail_at,
        };
        Box::new(BufReader::with_capacity(3, trickle))
    }
}

fn delivery() -> impl Strategy<Value = Delivery> {
    prop_oneof![
        2 => Just(Delivery { sizes: Vec::new(), fail_at: None }),
        1 => proptest::collection::vec(1usize..20, 1..4).prop_map(|sizes| Delivery { sizes, fail_at: None }),
        1 => (proptest::collection::vec(1usize..40, 0..3), 0usize..300)
            .prop_map(|(sizes, fail_at)| Delivery { sizes, fail_at: Some(fail_at) }),
    ]
}

// ----- what is compared -----

const PATH: &str = "plain.csv";

/// Every record as `Records` shows it: line, fields and columns, and how the
/// reading ends.
fn records(mut records: impl Records) -> (Vec<String>, Result<(), Located>) {
    let mut seen = Vec::new();
    loop {
        match records.next_record() {
            Ok(false) => return (seen, Ok(())),
            Err(e) => return (seen, Err(e)),
            Ok(true) => {}
        }
        let fields: Vec<String> = (0..records.len() + 1)
            .map(|i| format!("{}@{}", records.field(i), records.column(i)))
            .collect();
        let line = records.line_no();
        seen.push(format!(
            "{line}: {} | {}",
            fields.join(","),
            records.end_column()
        ));
    }
}

/// The events reader's rows one by one, where it stopped, and the log.
type EventsRead = (
    Vec<Result<Event, Located>>,
    usize,
    Option<Time>,
    Result<EventLog, Located>,
);

fn read_events<S: Records>(
    open: impl Fn() -> S,
    signals: &SignalTable,
    choice: TimeFormatChoice,
) -> Result<EventsRead, Located> {
    let mut reader = EventReader::from_records(open(), signals, choice)?;
    let rows: Vec<_> = reader.by_ref().collect();
    let (line, end) = (reader.line(), reader.end());
    let log = EventReader::from_records(open(), signals, choice)
        .and_then(EventChanges::open)
        .and_then(Changes::into_log);
    Ok((rows, line, end, log))
}

/// The scans reader's scans one by one, and the log.
type ScansRead = (
    Vec<Result<(Time, Vec<bool>), Located>>,
    Result<EventLog, Located>,
);

fn read_scans<S: Records>(
    open: impl Fn() -> S,
    signals: &SignalTable,
    choice: TimeFormatChoice,
) -> Result<ScansRead, Located> {
    let mut reader = ScanReader::from_records(open(), signals, choice)?;
    let mut scans = Vec::new();
    while let Some(scan) = reader.next_scan() {
        scans.push(scan.map(|(t, values)| (t, values.to_vec())));
    }
    let log = ScanReader::from_records(open(), signals, choice)
        .and_then(ScanChanges::open)
        .and_then(Changes::into_log);
    Ok((scans, log))
}

fn read_intervals<S: Records>(
    open: impl Fn() -> S,
    signals: &SignalTable,
    choice: TimeFormatChoice,
) -> Result<EventLog, Located> {
    IntervalChanges::open(|| IntervalReader::from_records(open(), signals, choice))?.into_log()
}

/// Checks that the block reading of `input` agrees with the reference in
/// every form, delivered as `delivery` says.
fn agree(input: &[u8], signals: &SignalTable, choice: TimeFormatChoice, delivery: &Delivery) {
    let path = Path::new(PATH);
    let blocks = || CsvRecords::new(delivery.reader(input), path);
    let lines = || LineByLine::new(delivery.reader(input), path);
    let text = String::from_utf8_lossy(input);
    assert_eq!(records(blocks()), records(lines()), "records of:\n{text}");
    assert_eq!(
        read_events(blocks, signals, choice),
        read_events(lines, signals, choice),
        "events form of:\n{text}"
    );
    assert_eq!(
        read_scans(blocks, signals, choice),
        read_scans(lines, signals, choice),
        "scans form of:\n{text}"
    );
    assert_eq!(
        read_intervals(blocks, signals, choice),
        read_intervals(lines, signals, choice),
        "intervals form of:\n{text}"
    );
}

// ----- inputs -----

fn table(names: &[&str]) -> SignalTable {
    let mut table = SignalTable::new();
    for name in names {
        let kind = if name.starts_with('A') {
            SignalKind::Actuator
        } else {
            SignalKind::Sensor
        };
        let signal = Signal {
            name: (*name).to_string(),
            kind,
            description: String::new(),
        };
        table.push(signal);
    }
    table
}

/// The turntable's signals, and a table whose names a field cannot hold as
/// written (spaces, quotes) or that are longer than a word.
fn signals() -> impl Strategy<Value = SignalTable> {
    prop_oneof![
        Just(table(&["C4", "C5", "A4"])),
        Just(table(&[
            "C4",
            " C5",
            "\"A4\"",
            "q\"t",
            "conveyor_running",
            "C10"
        ])),
    ]
}

fn choice() -> impl Strategy<Value = TimeFormatChoice> {
    prop_oneof![
        Just(TimeFormatChoice::Detect(TimeUnit::Ms)),
        Just(TimeFormatChoice::Detect(TimeUnit::Ns)),
        Just(TimeFormatChoice::Given(TimeFormat::Numeric(TimeUnit::S))),
        Just(TimeFormatChoice::Given(TimeFormat::Rfc3339)),
    ]
}

/// A time field at `t`: mostly plain decimals, and what a plain row must
/// leave to the fields' reading (`odd` picks which, `digits` and `junk` are
/// random text for some).
#[derive(Debug, Clone)]
struct TimeText {
    odd: usize,
    digits: String,
    junk: String,
}

impl TimeText {
    fn at(&self, t: i64) -> String {
        match self.odd {
            1 => format!("0000000000{t}"),
            2 => format!("{t}.5"),
            3 => format!("\"{t}\""),
            4 => format!(" {t}"),
            5 => format!("-{t}"),
            6 => format!("+{t}"),
            7 => String::new(),
            8 => "9223372036854775807".to_string(),
            9 => "999999999999999999".to_string(),
            10 => "2026-11-21T05:00:00.010Z".to_string(),
            11 => self.digits.clone(),
            12 => self.junk.clone(),
            _ => t.to_string(),
        }
    }
}

fn time_text() -> impl Strategy<Value = TimeText> {
    (
        prop_oneof![4 => Just(0), 1 => 1usize..13],
        "[0-9]{17,21}",
        "[ -~]{0,3}",
    )
        .prop_map(|(odd, digits, junk)| TimeText { odd, digits, junk })
}

/// A name field: the table's names as written, and others.
fn name_text(names: Vec<String>) -> BoxedStrategy<String> {
    prop_oneof![
        60 => proptest::sample::select(names.clone()),
        1 => proptest::sample::select(names.clone()).prop_map(|n| format!("\"{n}\"")),
        1 => proptest::sample::select(names).prop_map(|n| format!("{n} ")),
        1 => Just("C9".to_string()),
        1 => Just("".to_string()),
        1 => Just("t".to_string()),
        1 => "[ -~]{0,9}",
    ]
    .boxed()
}

fn value_text() -> BoxedStrategy<String> {
    prop_oneof![
        30 => Just("0".to_string()),
        30 => Just("1".to_string()),
        1 => Just("true".to_string()),
        1 => Just("FALSE".to_string()),
        1 => Just("".to_string()),
        1 => Just("2".to_string()),
        1 => Just("1 ".to_string()),
        1 => Just("\"0\"".to_string()),
        1 => Just("01".to_string()),
    ]
    .boxed()
}

/// A line's end: mostly LF, with odd ones.
fn line_end() -> BoxedStrategy<String> {
    prop_oneof![
        60 => Just("\n".to_string()),
        1 => Just("\r\n".to_string()),
        1 => Just("\n\n".to_string()),
        1 => Just("\n  \t \n".to_string()),
        1 => Just("\r\r\n".to_string()),
        1 => Just(",\n".to_string()),
        1 => Just(",,\n".to_string()),
        1 => Just("\u{feff}\n".to_string()),
        1 => Just("\u{a0}\n".to_string()),
    ]
    .boxed()
}

/// An events log: a header, then rows at times that mostly go up, a few
/// going back, written plainly or not.
fn events_text(signals: &SignalTable) -> BoxedStrategy<String> {
    let names: Vec<String> = signals.iter().map(|(_, s)| s.name.clone()).collect();
    let header = prop_oneof![
        6 => Just("t,signal,value".to_string()),
        1 => Just("\u{feff}t,signal,value".to_string()),
        1 => Just("signal,t,value".to_string()),
        1 => Just("t,signal,value,site".to_string()),
        1 => Just(" t , signal,\"value\"".to_string()),
    ];
    let step = prop_oneof![1 => Just(-1i64), 4 => Just(0), 4 => 1i64..3];
    let row = (
        step,
        time_text(),
        name_text(names),
        value_text(),
        line_end(),
    );
    (header, proptest::collection::vec(row, 0..60), any::<bool>())
        .prop_map(|(header, rows, end_row)| {
            let mut text = header + "\n";
            let mut t = 100i64;
            for (k, (step, time, name, value, end)) in rows.iter().enumerate() {
                if k > 0 {
                    t = (t + step).max(0);
                }
                text.push_str(&format!("{},{name},{value}{end}", time.at(t)));
            }
            if end_row {
                text.push_str(&format!("{},,\n", t + 5));
            }
            text
        })
        .boxed()
}

/// A scans log: `t` and the turntable's signals (in some order), then rows.
fn scans_text() -> BoxedStrategy<String> {
    let header = prop_oneof![
        4 => Just("t,C4,C5,A4".to_string()),
        1 => Just("C4,t,A4,C5".to_string()),
        1 => Just("t,C4,C5".to_string()),
    ];
    let step = prop_oneof![1 => Just(0i64), 4 => 1i64..3];
    let row = (
        step,
        time_text(),
        proptest::collection::vec(value_text(), 3),
        line_end(),
    );
    (header, proptest::collection::vec(row, 0..30))
        .prop_map(|(header, rows)| {
            let t_at = header.split(',').position(|c| c == "t").unwrap_or(0);
            let mut text = header + "\n";
            let mut t = 50i64;
            for (step, time, mut values, end) in rows {
                t += step;
                values.insert(t_at.min(values.len()), time.at(t));
                text.push_str(&values.join(","));
                text.push_str(&end);
            }
            text
        })
        .boxed()
}

/// Lines of plausible fields, for the records and the intervals form.
fn fields_text() -> BoxedStrategy<String> {
    let field = prop_oneof![
        Just("C4".to_string()),
        Just("A4".to_string()),
        Just("1".to_string()),
        Just("0".to_string()),
        Just("".to_string()),
        Just("\"".to_string()),
        Just(" 12 ".to_string()),
        "[0-9]{1,4}",
        "[ -~]{0,4}",
        any::<String>().prop_map(|s| s.chars().take(3).collect()),
    ];
    let line = (proptest::collection::vec(field, 1..5), line_end())
        .prop_map(|(fields, end)| fields.join(",") + &end);
    let header = prop_oneof![
        Just("signal,value,t_start,t_end\n".to_string()),
        Just("t,signal,value\n".to_string()),
        Just("\u{feff}\r\n".to_string()),
    ];
    (
        header,
        proptest::collection::vec(line, 0..20),
        any::<bool>(),
    )
        .prop_map(|(header, lines, cut)| {
            let text = header + &lines.concat();
            // A last line with no line end.
            if cut {
                text.trim_end_matches('\n').to_string()
            } else {
                text
            }
        })
        .boxed()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn events_read_as_line_by_line(
        (signals, text) in signals().prop_flat_map(|s| { let t = events_text(&s); (Just(s), t) }),
        choice in choice(),
        delivery in delivery(),
    ) {
        agree(text.as_bytes(), &signals, choice, &delivery);
    }

    #[test]
    fn scans_read_as_line_by_line(text in scans_text(), choice in choice(), delivery in delivery()) {
        agree(text.as_bytes(), &table(&["C4", "C5", "A4"]), choice, &delivery);
    }

    #[test]
    fn any_lines_read_as_line_by_line(
        text in fields_text(),
        signals in signals(),
        choice in choice(),
        delivery in delivery(),
    ) {
        agree(text.as_bytes(), &signals, choice, &delivery);
    }

    #[test]
    fn any_bytes_read_as_line_by_line(
        input in proptest::collection::vec(
            prop_oneof![3 => Just(b'\n'), 3 => Just(b','), 2 => Just(b'\r'), 8 => b'0'..=b'9', 4 => any::<u8>()],
            0..200,
        ),
        delivery in delivery(),
    ) {
        let mut log = b"t,signal,value\n0,C4,1\n0,C5,0\n0,A4,1\n".to_vec();
        log.extend_from_slice(&input);
        agree(&log, &table(&["C4", "C5", "A4"]), TimeFormatChoice::Detect(TimeUnit::Ms), &delivery);
    }
}

// ----- lines at the length limit -----

/// Lines just within and just past [`LONGEST_LINE`], with and without a line
/// end, read by pieces and whole.
#[test]
fn lines_at_the_length_limit_read_as_line_by_line() {
    let signals = table(&["C4", "C5", "A4"]);
    let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
    for length in [
        LONGEST_LINE - 1,
        LONGEST_LINE,
        LONGEST_LINE + 1,
        2 * LONGEST_LINE,
    ] {
        for end in ["", "\n", "\r\n"] {
            for (before, after) in [
                ("", "1,C4,0\n"),
                ("t,signal,value\n0,C4,1\n", ""),
                ("t,signal,value\n0,C4,1\n", "1,C4,0\n"),
            ] {
                let mut log = before.as_bytes().to_vec();
                log.extend(std::iter::repeat_n(b'7', length));
                log.extend_from_slice(end.as_bytes());
                log.extend_from_slice(after.as_bytes());
                for sizes in [vec![], vec![70_000, 3]] {
                    let delivery = Delivery {
                        sizes,
                        fail_at: None,
                    };
                    let path = Path::new(PATH);
                    let blocks = CsvRecords::new(delivery.reader(&log), path);
                    let lines = LineByLine::new(delivery.reader(&log), path);
                    assert_eq!(
                        records(blocks),
                        records(lines),
                        "{length} bytes, end {end:?}"
                    );
                    let blocks = || CsvRecords::new(delivery.reader(&log), path);
                    let lines = || LineByLine::new(delivery.reader(&log), path);
                    assert_eq!(
                        read_events(blocks, &signals, choice),
                        read_events(lines, &signals, choice)
                    );
                }
            }
        }
    }
}

/// A long log written plainly, read across many blocks, with one odd row
/// (quoted, spaced, going back, unknown...) at places around a block's end.
#[test]
fn odd_rows_across_blocks_read_as_line_by_line() {
    let signals = table(&["C4", "C5", "A4"]);
    let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
    let mut plain = String::from("t,signal,value\n0,C4,0\n0,C5,0\n0,A4,0\n");
    let mut value = false;
    for t in 1..28_000 {
        value = !value;
        plain.push_str(&format!(
            "{t},{},{}\n",
            ["C4", "C5", "A4"][t % 3],
            u8::from(value)
        ));
    }
    let odd_rows = [
        "\"{t}\",C4,1",
        "{t},C4 ,0",
        "{t}, C5,true",
        "{back},C5,1",
        "{t},C5,1\r",
        "{t},C7,1",
        "{t}.0,A4,0",
        "",
        "{t},,",
    ];
    for (k, odd) in odd_rows.iter().enumerate() {
        for at in [262_140, 262_144, 270_000 + k] {
            let cut = plain[..at].rfind('\n').unwrap_or(0) + 1;
            let before = plain[..cut - 1].rsplit('\n').next().unwrap_or("");
            let t: i64 = before
                .split(',')
                .next()
                .and_then(|t| t.parse().ok())
                .unwrap_or(0);
            let odd = odd
                .replace("{t}", &t.to_string())
                .replace("{back}", &(t - 1).to_string());
            let log = format!("{}{odd}\n{}", &plain[..cut], &plain[cut..]);
            for sizes in [vec![], vec![100_000, 7]] {
                let delivery = Delivery {
                    sizes,
                    fail_at: None,
                };
                let path = Path::new(PATH);
                let blocks = || CsvRecords::new(delivery.reader(log.as_bytes()), path);
                let lines = || LineByLine::new(delivery.reader(log.as_bytes()), path);
                assert_eq!(
                    read_events(blocks, &signals, choice),
                    read_events(lines, &signals, choice),
                    "{odd:?} on the line after {before:?}"
                );
            }
        }
    }
}

/// A message about a row read plainly quotes it as written.
#[test]
fn a_conflict_between_plain_rows_quotes_the_row() {
    let signals = table(&["C4", "C5", "A4"]);
    let log = "t,signal,value\n0,C4,0\n0,C5,0\n0,A4,0\n5,C4,1\n0005,C4,0\n";
    let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
    let error = logs::read_events_from(log.as_bytes(), Path::new(PATH), &signals, choice)
        .expect_err("a conflict");
    assert_eq!(
        error.to_string(),
        "plain.csv:6:9: field 'value': conflicting values for signal 'C4' at time 0005: line 5 gives the other value"
    );
}

/// A signal whose name a field holds only quoted is never read plainly.
#[test]
fn a_name_in_quotes_is_read_field_by_field() {
    let signals = table(&["C4", "\"A4\""]);
    let log = "t,signal,value\n0,C4,0\n0,\"\"A4\"\",0\n5,\"A4\",1\n";
    let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
    let error = logs::read_events_from(log.as_bytes(), Path::new(PATH), &signals, choice)
        .expect_err("an unknown signal");
    assert_eq!(
        error.to_string(),
        "plain.csv:4:3: field 'signal': unknown signal 'A4'"
    );
}
