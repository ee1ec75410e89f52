//! The column reader of intervals archives against the form's reader over
//! records, on generated archives, valid or damaged: the column reader
//! accepts every valid one and no other, reads the same log, and `open`
//! gives the form's errors.

use std::path::Path;

use proptest::prelude::*;
use vocabulary::{Event, Located, Plant, Time, TimeFormat, TimeUnit};

use super::ParquetRecords;
use super::intervals::{open_intervals, open_keeping};
use super::table::{
    ParquetColumn as Column, ParquetCompression, ParquetLayout as Layout, write_parquet_table,
};
use crate::rows::Records;
use crate::{Changes, IngestOptions, IntervalChanges, IntervalReader, TimeFormatChoice};

/// Three signals, one with a name too long for polars to keep inside a view.
const PLANT: &str = r#"
name = "paths"

[signals]
C4 = { kind = "sensor", description = "" }
conveyor_belt_running = { kind = "sensor", description = "" }
A4 = { kind = "actuator", description = "" }

[[parts]]
name = "p"
actuators = ["A4"]
sensors = ["C4", "conveyor_belt_running"]
element = "P"
"#;

fn plant() -> Plant {
    Plant::parse(PLANT, Path::new("paths.toml")).expect("the test plant")
}

/// One row of an archive; `None` is a null cell.
#[derive(Debug, Clone, PartialEq)]
struct Row {
    signal: Option<String>,
    value: Option<bool>,
    start: Option<i64>,
    end: Option<i64>,
}

/// A valid archive: each signal's intervals from its initial value and its
/// changes (zero-length ones included), the last one open or closed.
fn valid_rows() -> impl Strategy<Value = Vec<Row>> {
    let names = plant()
        .signals
        .iter()
        .map(|(_, s)| s.name.clone())
        .collect::<Vec<_>>();
    let signal = (
        any::<bool>(),
        prop::collection::vec(0i64..4, 0..12),
        any::<bool>(),
    );
    (-3i64..1000, prop::collection::vec(signal, 3)).prop_map(move |(t0, signals)| {
        let mut rows = Vec::new();
        for (name, (initial, steps, closed)) in names.iter().zip(signals) {
            let (mut value, mut start) = (initial, t0);
            for step in steps {
                rows.push(Row {
                    signal: Some(name.clone()),
                    value: Some(value),
                    start: Some(start),
                    end: Some(start + step),
                });
                (value, start) = (!value, start + step);
            }
            let end = closed.then_some(start + 2);
            rows.push(Row {
                signal: Some(name.clone()),
                value: Some(value),
                start: Some(start),
                end,
            });
        }
        rows
    })
}

/// Puts the rows in `t_end` order (open ones last), `t_start` order, a
/// random interleaving that keeps each signal's order, or any order.
fn arrange(rows: &mut Vec<Row>, order: u8, seed: u64) {
    let mut state = seed | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    match order {
        0 => rows.sort_by_key(|r| r.end.unwrap_or(i64::MAX)),
        1 => rows.sort_by_key(|r| r.start),
        2 => {
            let keys: Vec<u64> = rows.iter().map(|_| next() % 1000).collect();
            let mut keyed: Vec<(u64, Row)> = keys.into_iter().zip(rows.drain(..)).collect();
            // Each signal's rows keep their order: the keys of one signal
            // made non-decreasing.
            let mut last = std::collections::HashMap::new();
            for (key, row) in &mut keyed {
                let floor = last.entry(row.signal.clone()).or_insert(0);
                *key = (*key).max(*floor);
                *floor = *key;
            }
            keyed.sort_by_key(|k| k.0);
            rows.extend(keyed.into_iter().map(|k| k.1));
        }
        _ => {
            for i in (1..rows.len()).rev() {
                rows.swap(i, (next() % (i as u64 + 1)) as usize);
            }
        }
    }
}

/// A damage: which, and where (an index taken modulo the rows).
#[derive(Debug, Clone, Copy)]
struct Damage {
    kind: u8,
    at: usize,
}

/// Damages row `damage.at`; `true` if the damage leaves a valid archive the
/// column reader may still leave to the form's reader (a row of nulls).
fn damage(rows: &mut Vec<Row>, damage: Damage) -> bool {
    let at = damage.at % rows.len();
    match damage.kind {
        3 => drop(rows.remove(at)),
        4 => rows.insert(at, rows[at].clone()),
        14 => {
            let blank = Row {
                signal: None,
                value: None,
                start: None,
                end: None,
            };
            rows.insert(at, blank);
            return true;
        }
        kind => damage_cell(&mut rows[at], kind),
    }
    false
}

/// Damages a cell of `row`.
fn damage_cell(row: &mut Row, kind: u8) {
    match kind {
        0 => row.value = row.value.map(|v| !v),
        1 => row.start = row.start.map(|t| t + 1),
        2 => row.end = Some(row.end.map_or(7, |t| t - 1)),
        5 => row.signal = Some("X9".into()),
        6 => row.signal = None,
        7 => row.value = None,
        8 => row.start = None,
        9 => row.end = None,
        10 => row.end = row.start.map(|t| t - 1),
        11 => row.start = Some(i64::MAX / 2),
        12 => row.signal = row.signal.as_ref().map(|s| format!(" \"{s}\" ")),
        _ => row.signal = Some(String::new()),
    }
}

/// Row groups of 5 rows, ZSTD: a small archive has several groups.
const SMALL_GROUPS: Layout = Layout {
    compression: ParquetCompression::Zstd,
    group_rows: 5,
    page_bytes: None,
};

fn write(path: &Path, rows: &[Row]) {
    write_as(path, rows, SMALL_GROUPS);
}

fn write_as(path: &Path, rows: &[Row], layout: Layout) {
    let columns = vec![
        Column::new(
            "signal",
            rows.iter().map(|r| r.signal.clone()).collect::<Vec<_>>(),
        ),
        Column::new("value", rows.iter().map(|r| r.value).collect::<Vec<_>>()),
        Column::new("t_start", rows.iter().map(|r| r.start).collect::<Vec<_>>()),
        Column::new("t_end", rows.iter().map(|r| r.end).collect::<Vec<_>>()),
    ];
    write_parquet_table(path, columns, &layout).expect("write");
}

/// What a reading gives: the log's opening and changes, or its first error.
type Read = Result<(TimeFormat, Time, Vec<bool>, Vec<Event>), String>;

/// The form's reader over records.
fn by_records(path: &Path, plant: &Plant, options: &IngestOptions) -> Read {
    let choice = TimeFormatChoice::Detect(options.time_unit);
    let open = || {
        let records = ParquetRecords::open(path, options)?;
        IntervalReader::from_records(records, &plant.signals, choice)
    };
    let log = IntervalChanges::open(open)
        .and_then(Changes::into_log)
        .map_err(|e| e.to_string())?;
    Ok((log.format, log.start, log.initial, log.events))
}

/// The changes of an opened stream, or its first error.
fn drain(stream: Result<crate::LogStream, Located>) -> Read {
    let stream = stream.map_err(|e| e.to_string())?;
    let mut events = Vec::new();
    for batch in stream.batches {
        events.extend(batch.map_err(|e| e.to_string())?);
    }
    Ok((stream.time, stream.start, stream.initial, events))
}

fn options(unit: TimeUnit, small: bool) -> IngestOptions {
    IngestOptions {
        time_unit: unit,
        batch_rows: if small { 3 } else { 1 << 16 },
        parquet_slice_rows: if small { 4 } else { 1 << 18 },
        ..IngestOptions::default()
    }
}

/// Writes `rows` and checks that the column reader (its first pass keeping
/// up to `kept` bytes of rows) and `open` read them as the form's reader
/// over records does; `unsure`: a valid file the column reader may leave
/// to the records. The records' reading.
fn agree(
    rows: &[Row],
    unit: TimeUnit,
    small: bool,
    unsure: bool,
    kept: usize,
) -> Result<Read, TestCaseError> {
    agree_as(rows, unit, small, unsure, kept, SMALL_GROUPS)
}

fn agree_as(
    rows: &[Row],
    unit: TimeUnit,
    small: bool,
    unsure: bool,
    kept: usize,
    layout: Layout,
) -> Result<Read, TestCaseError> {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("intervals.parquet");
    write_as(&path, rows, layout);
    let plant = plant();
    let options = options(unit, small);
    let expected = by_records(&path, &plant, &options);
    match open_keeping(&path, &plant, &options, kept) {
        Ok(Some(stream)) => prop_assert_eq!(&drain(Ok(stream)), &expected),
        // Only a row of nulls makes it unsure of a valid file.
        Ok(None) => prop_assert!(expected.is_err() || unsure, "{:?}", expected),
        Err(e) => prop_assert_eq!(&Err(e.to_string()), &expected),
    }
    prop_assert_eq!(&drain(crate::open(&path, &plant, &options)), &expected);
    Ok(expected)
}

/// The codecs the tests write with.
const CODECS: [ParquetCompression; 4] = [
    ParquetCompression::Zstd,
    ParquetCompression::Uncompressed,
    ParquetCompression::Snappy,
    ParquetCompression::Lz4Raw,
];

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn the_column_reader_reads_as_the_records_do(
        mut rows in valid_rows(),
        order in 0u8..4,
        seed in any::<u64>(),
        damaged in prop::option::of((0u8..15, any::<usize>())),
        micros in any::<bool>(),
        small in any::<bool>(),
        kept in prop_oneof![0usize..120, Just(usize::MAX)],
        codec in 0usize..4,
    ) {
        arrange(&mut rows, order, seed);
        let unsure = damaged.is_some_and(|(kind, at)| damage(&mut rows, Damage { kind, at }));
        let unit = if micros { TimeUnit::Us } else { TimeUnit::Ms };
        let layout = Layout { compression: CODECS[codec], ..SMALL_GROUPS };
        let expected = agree_as(&rows, unit, small, unsure, kept, layout)?;
        // Undamaged, only any order may break the form.
        prop_assert!(damaged.is_some() || order == 3 || expected.is_ok(), "{:?}", expected);
    }
}

#[test]
fn every_damage_of_a_small_archive_reads_as_the_records_do() {
    let row = |signal: &str, value, start, end| Row {
        signal: Some(signal.into()),
        value: Some(value),
        start: Some(start),
        end,
    };
    // A zero-length interval of C4 at 30, closed last intervals, an open one.
    let archive = [
        row("C4", true, 5, Some(30)),
        row("C4", false, 30, Some(30)),
        row("A4", false, 5, Some(40)),
        row("C4", true, 30, Some(50)),
        row("conveyor_belt_running", false, 5, None),
        row("A4", true, 40, Some(60)),
    ];
    for order in 0..2 {
        for kind in 0..15 {
            for at in 0..archive.len() {
                let mut rows = archive.to_vec();
                arrange(&mut rows, order, 1);
                let unsure = damage(&mut rows, Damage { kind, at });
                let kept = [0, 40, usize::MAX][at % 3];
                let agreed = agree(&rows, TimeUnit::Ms, kind % 2 == 0, unsure, kept);
                assert!(
                    agreed.is_ok(),
                    "order {order}, damage {kind} at {at}: {agreed:?}"
                );
            }
        }
    }
}

#[test]
fn an_archive_is_read_by_columns_and_a_damaged_one_by_records() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("intervals.parquet");
    let plant = plant();
    let options = options(TimeUnit::Ms, false);
    let row = |signal: &str, value, start, end| Row {
        signal: Some(signal.into()),
        value: Some(value),
        start: Some(start),
        end,
    };
    let mut rows = vec![
        row("A4", false, 0, Some(100)),
        row("C4", true, 0, Some(110)),
        row("conveyor_belt_running", false, 0, None),
        row("C4", false, 110, None),
        row("A4", true, 100, None),
    ];
    write(&path, &rows);
    let stream = open_intervals(&path, &plant, &options).expect("readable");
    let read = drain(Ok(stream.expect("read by columns")));
    let (_, start, initial, events) = read.expect("a log");
    assert_eq!((start, initial), (0, vec![true, false, false]));
    assert_eq!(events.len(), 2);
    assert_eq!(
        read_events(&events),
        [(100_000_000, "A4"), (110_000_000, "C4")]
    );
    rows[3].start = Some(111);
    write(&path, &rows);
    assert!(matches!(open_intervals(&path, &plant, &options), Ok(None)));
    let e = drain(crate::open(&path, &plant, &options)).expect_err("a gap");
    assert!(
        e.contains(":5:3: field 't_start': interval of signal 'C4' starts at 111"),
        "{e}"
    );
}

fn read_events(events: &[Event]) -> Vec<(Time, &'static str)> {
    let names = ["C4", "conveyor_belt_running", "A4"];
    events
        .iter()
        .map(|e| (e.t, names[e.signal.index()]))
        .collect()
}

/// An archive of distinct times and names padded in many ways, which
/// polars writes PLAIN where a row group holds more than 2048 of them (not
/// worth a dictionary), in pages of a few hundred bytes, with open
/// intervals (nulls in `t_end`): read by columns, as the records read it,
/// whatever the codec and however much the first pass keeps.
#[test]
fn plain_pages_and_many_of_them_read_as_the_records_do() {
    let names = ["C4", "conveyor_belt_running", "A4"];
    let mut rows = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let steps = 1200 - 300 * k as i64;
        for i in 0..steps {
            let start = if i == 0 { 0 } else { 7 * i + k as i64 };
            let end = 7 * (i + 1) + k as i64;
            let last = i == steps - 1;
            let pad = |n: i64| " ".repeat(n as usize);
            rows.push(Row {
                signal: Some(format!("{}{name}{}", pad(i % 37), pad(i % 41))),
                value: Some(i % 2 == 1),
                start: Some(start),
                end: (!last || k != 1).then_some(end),
            });
        }
    }
    arrange(&mut rows, 0, 1);
    for (c, &compression) in CODECS[..3].iter().enumerate() {
        let layout = Layout {
            compression,
            group_rows: 3000,
            page_bytes: Some(256),
        };
        let kept = [0, 3000, usize::MAX][c];
        let read = agree_as(&rows, TimeUnit::Ms, c % 2 == 0, false, kept, layout);
        let (_, start, initial, events) = read.expect("agrees").expect("a log");
        assert_eq!((start, initial.len(), events.len()), (0, 3, 2697));
        // The column reader took it (it leaves nothing valid to the records).
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("plain.parquet");
        write_as(&path, &rows, layout);
        let options = options(TimeUnit::Ms, false);
        let stream = open_keeping(&path, &plant(), &options, kept).expect("readable");
        assert!(stream.is_some(), "{compression:?}");
    }
}

/// Bytes of an archive damaged at random: whatever the column reader makes
/// of them (an error, leaving the file to the records, or a log), it does
/// not crash, hang or allocate without bound, and a log it reads is the
/// records' reading. Uncompressed pages let a damage reach the values.
#[test]
fn damaged_bytes_read_as_the_records_do_or_not_at_all() {
    let names = ["C4", "conveyor_belt_running", "A4"];
    let rows: Vec<Row> = (0..60i64)
        .map(|i| Row {
            signal: Some(names[(i % 3) as usize].into()),
            value: Some((i / 3) % 2 == 1),
            start: Some(10 * (i / 3)),
            end: (i < 57).then_some(10 * (i / 3 + 1)),
        })
        .collect();
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("damaged.parquet");
    let plant = plant();
    let options = options(TimeUnit::Ms, true);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move |n: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as usize
    };
    for case in 0..48 {
        let compression = [ParquetCompression::Uncompressed, ParquetCompression::Zstd][case % 2];
        let layout = Layout {
            compression,
            group_rows: 12,
            page_bytes: None,
        };
        write_as(&path, &rows, layout);
        let mut bytes = std::fs::read(&path).expect("written");
        // Damage the pages, not the footer, which polars checks first.
        let pages = bytes.len().saturating_sub(600).max(8);
        for _ in 0..=next(3) {
            let at = 4 + next(pages - 4);
            bytes[at] ^= 1 << next(8);
        }
        std::fs::write(&path, &bytes).expect("damaged");
        let kept = [0, usize::MAX][case % 2];
        if let Ok(Some(stream)) = open_keeping(&path, &plant, &options, kept) {
            let read = drain(Ok(stream));
            let expected = by_records(&path, &plant, &options);
            assert_eq!(read, expected, "case {case}");
        }
    }
}

/// A cell of the round trip, as written and as its text is read back.
#[derive(Debug, Clone)]
enum Written {
    Bool(Vec<Option<bool>>),
    Small(Vec<Option<i16>>),
    Int(Vec<Option<i64>>),
    Unsigned(Vec<Option<u16>>),
    Float(Vec<Option<f64>>),
    Text(Vec<Option<String>>),
}

impl Written {
    fn column(&self, name: &str) -> Column {
        match self.clone() {
            Written::Bool(v) => Column::new(name, v),
            Written::Small(v) => Column::new(name, v),
            Written::Int(v) => Column::new(name, v),
            Written::Unsigned(v) => Column::new(name, v),
            Written::Float(v) => Column::new(name, v),
            Written::Text(v) => Column::new(name, v),
        }
    }

    /// Cell `i` as records give it: CSV's text, null as blank.
    fn text(&self, i: usize) -> String {
        let shown = |v: Option<String>| v.unwrap_or_default();
        match self {
            Written::Bool(v) => shown(v[i].map(|x| x.to_string())),
            Written::Small(v) => shown(v[i].map(|x| x.to_string())),
            Written::Int(v) => shown(v[i].map(|x| x.to_string())),
            Written::Unsigned(v) => shown(v[i].map(|x| x.to_string())),
            Written::Float(v) => shown(v[i].map(|x| x.to_string())),
            Written::Text(v) => shown(v[i].as_deref().map(|s| super::clean(s).to_string())),
        }
    }
}

fn written(rows: usize) -> impl Strategy<Value = Written> {
    use proptest::collection::vec;
    use proptest::option::weighted;
    prop_oneof![
        vec(weighted(0.8, any::<bool>()), rows).prop_map(Written::Bool),
        vec(weighted(0.8, any::<i16>()), rows).prop_map(Written::Small),
        vec(weighted(0.8, any::<i64>()), rows).prop_map(Written::Int),
        vec(weighted(0.8, any::<u16>()), rows).prop_map(Written::Unsigned),
        vec(weighted(0.8, -1e9f64..1e9), rows).prop_map(Written::Float),
        vec(weighted(0.8, "[ a-z\"é]{0,20}"), rows).prop_map(Written::Text),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Any table written is read back as records cell for cell: the header,
    /// then each row that is not all blank, at its line, whatever the row
    /// groups, pages, codec and slices.
    #[test]
    fn a_written_table_reads_back_as_its_records(
        (rows, columns) in (0usize..60).prop_flat_map(|n| {
            (Just(n), proptest::collection::vec(written(n), 1..5))
        }),
        group_rows in 1usize..40,
        page_bytes in proptest::option::of(64usize..2048),
        codec in 0usize..4,
        slice_rows in 1usize..50,
    ) {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("table.parquet");
        let names: Vec<String> = (0..columns.len()).map(|k| format!("c{k}")).collect();
        let table = columns.iter().zip(&names).map(|(c, name)| c.column(name)).collect();
        let layout = Layout { compression: CODECS[codec], group_rows, page_bytes };
        write_parquet_table(&path, table, &layout).expect("write");
        let options = IngestOptions { parquet_slice_rows: slice_rows, ..IngestOptions::default() };
        let mut records = ParquetRecords::open(&path, &options).expect("open");
        let record = |r: &ParquetRecords| (0..r.len()).map(|i| r.field(i).to_string()).collect::<Vec<_>>();
        prop_assert!(records.next_record().expect("header"));
        prop_assert_eq!(record(&records), names);
        for i in 0..rows {
            let expected: Vec<String> = columns.iter().map(|c| c.text(i)).collect();
            if expected.iter().all(String::is_empty) {
                continue;
            }
            prop_assert!(records.next_record().expect("a row"), "row {i} missing");
            prop_assert_eq!(records.line_no(), i + 2);
            prop_assert_eq!(record(&records), expected, "row {}", i);
        }
        prop_assert!(!records.next_record().expect("the end"));
    }
}
