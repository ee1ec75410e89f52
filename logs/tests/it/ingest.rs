//! Log ingestion: every CSV and Parquet form of one simulated run reads back to
//! the same initial values and events, forms are detected, and bad files fail
//! with one-line errors naming the file, line and column.

use std::fs::File;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant as sorting_plant};
use logs::{
    EventLog, EventWriter, IntervalWriter, ScanWriter, read_events, read_intervals_as_events,
    read_scans_as_events,
};
use logs::{
    IngestOptions, LogFormat, ParquetColumn as Column, detect_format, open, write_intervals_parquet,
};
use vocabulary::{Event, Located, MS, Plant, SECOND, SignalId, Time, TimeFormat, TimeUnit};

/// A small batch size, so that every form is read in many batches.
const BATCH: usize = 200;

fn options(batch_rows: usize) -> IngestOptions {
    IngestOptions {
        format: None,
        time_unit: TimeUnit::Ms,
        batch_rows,
        parquet_slice_rows: 1 << 18,
    }
}

/// What a stream reads into, and how many batches it took.
#[derive(Debug)]
struct Read {
    format: LogFormat,
    time: TimeFormat,
    start: Time,
    initial: Vec<bool>,
    events: Vec<Event>,
    batches: usize,
    /// The end the log declared, read after the last batch.
    end: Option<Time>,
}

/// Opens and reads a whole log, checking the batch contract on the way: each
/// batch sorted by (t, signal), not empty, and times never going back.
fn read(path: &Path, plant: &Plant, options: &IngestOptions) -> Result<Read, Located> {
    let stream = open(path, plant, options)?;
    let (format, time, start, initial) = (stream.format, stream.time, stream.start, stream.initial);
    let declared = stream.end;
    let mut events: Vec<Event> = Vec::new();
    let mut batches = 0;
    for batch in stream.batches {
        let batch = batch?;
        assert!(!batch.is_empty(), "{}: empty batch", path.display());
        assert!(
            batch
                .windows(2)
                .all(|w| (w[0].t, w[0].signal) < (w[1].t, w[1].signal)),
            "{}: batch not sorted by (t, signal)",
            path.display()
        );
        if let (Some(last), Some(first)) = (events.last(), batch.first()) {
            assert!(
                (last.t, last.signal) < (first.t, first.signal),
                "{}: batches out of order",
                path.display()
            );
        }
        events.extend(batch);
        batches += 1;
    }
    Ok(Read {
        format,
        time,
        start,
        initial,
        events,
        batches,
        end: declared.get(),
    })
}

/// The first error of a log, whether at opening or in a batch.
fn first_error(path: &Path, plant: &Plant, options: &IngestOptions) -> Located {
    match read(path, plant, options) {
        Ok(_) => panic!("{} should not read", path.display()),
        Err(e) => e,
    }
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ingest")
}

fn turntable() -> Plant {
    Plant::from_path(&fixtures().join("plant.toml")).expect("fixture plant")
}

/// Ten simulated minutes of the sorting line under its default control.
fn simulated() -> (Plant, MemorySink) {
    let plant = sorting_plant();
    let mut line = SortingLine::new(SortingConfig::default());
    let mut control = SynthesisedControl::new(line.ids());
    let config = SimConfig {
        duration: 600 * SECOND,
        scan_period: 10 * MS,
        seed: 5,
        faults: Vec::new(),
    };
    let mut sink = MemorySink::default();
    run(&mut line, &mut control, &config, &mut sink, |_| {}).expect("in-memory run");
    assert!(
        sink.events.len() > 2 * BATCH,
        "a run long enough to batch: {}",
        sink.events.len()
    );
    (plant, sink)
}

fn write_parquet(path: &Path, columns: Vec<Column>) {
    logs::write_parquet_table(path, columns, &logs::ParquetLayout::default())
        .expect("write parquet");
}

/// Every scan of the run, as (time, values).
fn scans(sink: &MemorySink, end: Time) -> Vec<(Time, Vec<bool>)> {
    let mut values = sink.initial.clone();
    let mut next = sink.events.iter().peekable();
    let mut out = Vec::new();
    let mut t = sink.start;
    while t <= end {
        while let Some(e) = next.next_if(|e| e.t <= t) {
            values[e.signal.index()] = e.value;
        }
        out.push((t, values.clone()));
        t += 10 * MS;
    }
    out
}

#[test]
#[allow(clippy::too_many_lines)] // one scenario, every form in turn
fn every_form_reads_back_the_same_run() {
    let (plant, sink) = simulated();
    let signals = &plant.signals;
    let dir = tempfile::tempdir().expect("temp dir");
    let end = 600 * SECOND;
    let ms = TimeFormat::Numeric(TimeUnit::Ms);
    let log = EventLog {
        format: ms,
        start: sink.start,
        initial: sink.initial.clone(),
        events: sink.events.clone(),
        end: None,
    };
    let mut expected: Vec<(PathBuf, LogFormat)> = Vec::new();

    // CSV, with diagnoser's writers.
    let events_csv = dir.path().join("events.csv");
    let mut w =
        EventWriter::new(File::create(&events_csv).expect("create"), signals, ms).expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    w.finish().expect("finish");
    expected.push((events_csv.clone(), LogFormat::EventsCsv));

    let rfc_csv = dir.path().join("events_rfc3339.csv");
    let mut w = EventWriter::new(
        File::create(&rfc_csv).expect("create"),
        signals,
        TimeFormat::Rfc3339,
    )
    .expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    w.finish().expect("finish");
    expected.push((rfc_csv.clone(), LogFormat::EventsCsv));

    let intervals_csv = dir.path().join("intervals.csv");
    let mut w = IntervalWriter::new(File::create(&intervals_csv).expect("create"), signals, ms)
        .expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    w.finish().expect("finish");
    expected.push((intervals_csv.clone(), LogFormat::IntervalsCsv));

    let all_scans = scans(&sink, end);
    let scans_csv = dir.path().join("scans.csv");
    let mut w =
        ScanWriter::new(File::create(&scans_csv).expect("create"), signals, ms).expect("writer");
    for (t, values) in &all_scans {
        w.write(*t, values).expect("write");
    }
    w.finish().expect("finish");
    expected.push((scans_csv.clone(), LogFormat::ScansCsv));

    // Parquet: the archive with our writer, the others with polars.
    let intervals_parquet = dir.path().join("intervals.parquet");
    write_intervals_parquet(&log, signals, &intervals_parquet, end).expect("archive");
    expected.push((intervals_parquet, LogFormat::IntervalsParquet));

    let opening = sink
        .initial
        .iter()
        .enumerate()
        .map(|(i, &v)| (sink.start, SignalId(i as u32), v));
    let rows: Vec<(Time, SignalId, bool)> = opening
        .chain(sink.events.iter().map(|e| (e.t, e.signal, e.value)))
        .collect();
    let events_parquet = dir.path().join("events.parquet");
    write_parquet(
        &events_parquet,
        vec![
            Column::new("t", rows.iter().map(|r| r.0 / MS).collect::<Vec<i64>>()),
            Column::new(
                "signal",
                rows.iter()
                    .map(|r| signals.name(r.1))
                    .collect::<Vec<&str>>(),
            ),
            Column::new("value", rows.iter().map(|r| r.2).collect::<Vec<bool>>()),
            Column::new("quality", vec!["good"; rows.len()]),
        ],
    );
    expected.push((events_parquet, LogFormat::EventsParquet));

    // Text times and text values: RFC 3339 is detected from the first time.
    let rfc_parquet = dir.path().join("events_rfc3339.parquet");
    write_parquet(
        &rfc_parquet,
        vec![
            Column::new(
                "t",
                rows.iter()
                    .map(|r| TimeFormat::Rfc3339.format(r.0))
                    .collect::<Vec<String>>(),
            ),
            Column::new(
                "signal",
                rows.iter()
                    .map(|r| signals.name(r.1))
                    .collect::<Vec<&str>>(),
            ),
            Column::new(
                "value",
                rows.iter()
                    .map(|r| if r.2 { "true" } else { "0" })
                    .collect::<Vec<&str>>(),
            ),
        ],
    );
    expected.push((rfc_parquet.clone(), LogFormat::EventsParquet));

    // Float times in ms; booleans and 0/1 integers of every width as values.
    let scans_parquet = dir.path().join("scans.parquet");
    let mut columns = vec![Column::new(
        "t",
        all_scans
            .iter()
            .map(|s| s.0 as f64 / MS as f64)
            .collect::<Vec<f64>>(),
    )];
    for (id, signal) in signals.iter() {
        let i = id.index();
        // Values as booleans or as integers of every width a writer may pick.
        let name = signal.name.as_str();
        let bits = all_scans.iter().map(|s| s.1[i]);
        let column = match i % 7 {
            0 => Column::new(name, bits.collect::<Vec<bool>>()),
            1 => Column::new(name, bits.map(i8::from).collect::<Vec<i8>>()),
            2 => Column::new(name, bits.map(u8::from).collect::<Vec<u8>>()),
            3 => Column::new(name, bits.map(i16::from).collect::<Vec<i16>>()),
            4 => Column::new(name, bits.map(u16::from).collect::<Vec<u16>>()),
            5 => Column::new(name, bits.map(i32::from).collect::<Vec<i32>>()),
            _ => Column::new(name, bits.map(i64::from).collect::<Vec<i64>>()),
        };
        columns.push(column);
    }
    write_parquet(&scans_parquet, columns);
    expected.push((scans_parquet, LogFormat::ScansParquet));

    for (path, format) in &expected {
        assert_eq!(
            detect_format(path).expect("detected"),
            *format,
            "{}",
            path.display()
        );
        let got = read(path, &plant, &options(BATCH)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(got.format, *format);
        assert_eq!(got.start, sink.start, "{}", path.display());
        assert_eq!(got.initial, sink.initial, "{}", path.display());
        assert_eq!(got.events.len(), sink.events.len(), "{}", path.display());
        assert_eq!(got.events, sink.events, "{}", path.display());
        assert!(
            got.batches > 1,
            "{}: {} batch(es)",
            path.display(),
            got.batches
        );
        if path.extension().is_some_and(|x| x == "parquet") {
            // Decoded in many slices, several to a row group: the same stream.
            let sliced = IngestOptions {
                parquet_slice_rows: 97,
                ..options(BATCH)
            };
            let again = read(path, &plant, &sliced).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(
                (again.start, &again.initial, &again.events),
                (got.start, &got.initial, &got.events),
                "{} in slices",
                path.display()
            );
        }
        let text_times = *path == rfc_csv || *path == rfc_parquet;
        let time = if text_times { TimeFormat::Rfc3339 } else { ms };
        assert_eq!(got.time, time, "{}", path.display());
    }

    // The same as diagnoser's exact readers.
    let unit = TimeUnit::Ms;
    for (csv, exact) in [
        (&events_csv, read_events(&events_csv, signals, unit)),
        (
            &intervals_csv,
            read_intervals_as_events(&intervals_csv, signals, unit),
        ),
        (&scans_csv, read_scans_as_events(&scans_csv, signals, unit)),
    ] {
        let exact = exact.expect("exact reader");
        let got = read(csv, &plant, &options(BATCH)).expect("read");
        assert_eq!(
            (got.start, got.initial, got.events),
            (exact.start, exact.initial, exact.events)
        );
    }

    // A given format is not detected again; the default batch size reads in one go.
    let given = IngestOptions {
        format: Some(LogFormat::EventsCsv),
        ..IngestOptions::default()
    };
    let got = read(&events_csv, &plant, &given).expect("read");
    assert_eq!(got.events, sink.events);
    assert_eq!(got.batches, 1);
}

/// Rewrites an intervals CSV with its rows sorted by `key` (stable).
fn reorder_intervals(from: &Path, to: &Path, key: impl Fn(&[&str]) -> (String, i64)) {
    let text = std::fs::read_to_string(from).expect("read");
    let mut lines = text.lines();
    let header = lines.next().expect("header");
    let mut rows: Vec<&str> = lines.collect();
    rows.sort_by_key(|line| key(&line.split(',').collect::<Vec<_>>()));
    let mut out = File::create(to).expect("create");
    writeln!(out, "{header}").expect("write");
    for row in rows {
        writeln!(out, "{row}").expect("write");
    }
}

#[test]
fn intervals_in_any_order_give_the_same_events() {
    let (plant, sink) = simulated();
    let dir = tempfile::tempdir().expect("temp dir");
    let archive = dir.path().join("intervals.csv");
    let ms = TimeFormat::Numeric(TimeUnit::Ms);
    let mut w = IntervalWriter::new(File::create(&archive).expect("create"), &plant.signals, ms)
        .expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    w.finish().expect("finish");
    let t_start = |f: &[&str]| f.get(2).and_then(|t| t.parse::<i64>().ok()).unwrap_or(0);
    // In t_start order: streamed from the starts of intervals.
    let by_start = dir.path().join("by_start.csv");
    reorder_intervals(&archive, &by_start, |f| (String::new(), t_start(f)));
    // Grouped by signal: the changes are sorted in memory.
    let by_signal = dir.path().join("by_signal.csv");
    reorder_intervals(&archive, &by_signal, |f| (f[0].to_string(), t_start(f)));
    for path in [&archive, &by_start, &by_signal] {
        let exact = read_intervals_as_events(path, &plant.signals, TimeUnit::Ms).expect("exact");
        assert_eq!(exact.events, sink.events);
        let got = read(path, &plant, &options(BATCH)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(got.initial, sink.initial, "{}", path.display());
        assert_eq!(got.events, sink.events, "{}", path.display());
    }
}

#[test]
fn glitches_and_repeats_read_as_diagnoser_reads_them() {
    let plant = turntable();
    let dir = tempfile::tempdir().expect("temp dir");
    // Zero-length intervals (glitches below the resolution) at the start and
    // later; a repeated value in the events form; blank lines, spaces, quotes.
    let header = "signal,value,t_start,t_end\n";
    let glitches = [
        // Grouped by signal: the changes are sorted in memory.
        "C4,0,0,0\nC4,1,0,50\nC4,0,50,50\nC4,1,50,70\nC4,0,70,\n\n\
         C5,0,0,20\nC5,1,20,20\nC5,0,20,30\nC5,1,30,\nA4,0,0,100\nA4,1,100,\n",
        // In t_end order, as archives are written: streamed.
        "C4,0,0,0\nC5,0,0,20\nC5,1,20,20\nC5,0,20,30\nC4,1,0,50\nC4,0,50,50\nC4,1,50,70\n\
         A4,0,0,100\nC4,0,70,\nC5,1,30,\nA4,1,100,\n",
        // The same, with the last intervals closed at the end of the recording.
        "C4,0,0,0\nC5,0,0,20\nC5,1,20,20\nC5,0,20,30\nC4,1,0,50\nC4,0,50,50\nC4,1,50,70\n\
         A4,0,0,100\nA4,1,100,100\nC4,0,70,120\nC5,1,30,120\nA4,0,100,120\n",
        // In t_start order: streamed.
        "C4,0,0,0\nC5,0,0,20\nA4,0,0,100\nC4,1,0,50\nC5,1,20,20\nC5,0,20,30\nC5,1,30,\n\
         C4,0,50,50\nC4,1,50,70\nC4,0,70,\nA4,1,100,\n",
    ];
    let mut files = Vec::new();
    for (k, rows) in glitches.iter().enumerate() {
        let path = dir.path().join(format!("glitches{k}.csv"));
        std::fs::write(&path, format!("{header}{rows}")).expect("write");
        let exact = read_intervals_as_events(&path, &plant.signals, TimeUnit::Ms);
        files.push((path, exact));
    }
    let events = dir.path().join("repeats.csv");
    std::fs::write(
        &events,
        "\nt, signal ,value\n0,C4,1\n0,\"C5\",0\n0,A4,0\n0,A4,false\n\n100,A4,1\n100,A4,TRUE\n110, C4 ,0\n110,C5,0\n",
    )
    .expect("write");
    let exact = read_events(&events, &plant.signals, TimeUnit::Ms);
    files.push((events, exact));
    for (path, exact) in &files {
        let exact = exact.as_ref().unwrap_or_else(|e| panic!("{e}"));
        assert!(!exact.events.is_empty());
        for batch in [1, 2, 1000] {
            let got = read(path, &plant, &options(batch)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(got.start, exact.start);
            assert_eq!(got.initial, exact.initial, "{}", path.display());
            assert_eq!(
                got.events,
                exact.events,
                "{} in batches of {batch}",
                path.display()
            );
        }
    }
}

/// A bad file, how to open it, and where and what its error must be: line,
/// column, field and part of the message.
type Case<'a, P> = (P, &'a IngestOptions, usize, usize, Option<&'a str>, &'a str);

/// Checks a located error: one line, naming the file, at `line:column`.
fn assert_located(e: &Located, path: &Path, line: usize, column: usize, field: Option<&str>) {
    let text = e.to_string();
    assert!(!text.contains('\n'), "not one line: {text}");
    assert!(
        text.contains(&path.display().to_string()),
        "file not named: {text}"
    );
    assert_eq!(
        (e.location.line, e.location.column),
        (line, column),
        "wrong place: {text}"
    );
    assert_eq!(e.location.field.as_deref(), field, "wrong field: {text}");
}

#[test]
fn bad_csv_files_fail_at_the_right_line_and_column() {
    let plant = turntable();
    let events = IngestOptions {
        format: Some(LogFormat::EventsCsv),
        ..options(BATCH)
    };
    // (file, options, line, column, field, part of the message)
    let cases: [Case<&str>; 10] = [
        (
            "events_missing_column.csv",
            &events,
            1,
            0,
            None,
            "missing required column 'value'",
        ),
        (
            "events_missing_column.csv",
            &options(BATCH),
            1,
            3,
            None,
            "unknown column 'signal'",
        ),
        (
            "scans_missing_column.csv",
            &options(BATCH),
            1,
            0,
            None,
            "missing column for signal 'A4'",
        ),
        (
            "events_bad_value.csv",
            &options(BATCH),
            7,
            8,
            Some("value"),
            "bad value 'yes'",
        ),
        (
            "events_backwards.csv",
            &options(BATCH),
            6,
            1,
            Some("t"),
            "time goes backwards: 90 is before 100 on line 5",
        ),
        (
            "events_unknown_signal.csv",
            &options(BATCH),
            6,
            7,
            Some("signal"),
            "unknown signal 'B7'",
        ),
        (
            "events_bad_time.csv",
            &options(BATCH),
            6,
            1,
            Some("t"),
            "bad time '1l0'",
        ),
        (
            "intervals_backwards.csv",
            &options(BATCH),
            5,
            10,
            Some("t_end"),
            "interval ends before it starts",
        ),
        (
            "events_extra_field.csv",
            &options(BATCH),
            5,
            10,
            None,
            "expected 3 fields like the header, found 4",
        ),
        (
            "scans_bad_value.csv",
            &options(BATCH),
            4,
            6,
            Some("C5"),
            "bad value '2'",
        ),
    ];
    for (name, options, line, column, field, message) in cases {
        let path = fixtures().join(name);
        for batch in [1, options.batch_rows] {
            let options = IngestOptions {
                batch_rows: batch,
                ..options.clone()
            };
            let e = first_error(&path, &plant, &options);
            assert_located(&e, &path, line, column, field);
            assert!(e.message.contains(message), "{name}: {e}");
        }
    }
}

#[test]
fn an_error_deep_in_a_large_csv_is_located_after_the_batches_before_it() {
    let (plant, sink) = simulated();
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("events.csv");
    let ms = TimeFormat::Numeric(TimeUnit::Ms);
    let mut w = EventWriter::new(Vec::new(), &plant.signals, ms).expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    let text = String::from_utf8(w.finish().expect("finish")).expect("utf-8");
    // Line 1100 gets a value that is not boolean.
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let bad = 1100;
    let fields: Vec<&str> = lines[bad - 1].split(',').collect();
    let column = fields[0].len() + fields[1].len() + 3;
    lines[bad - 1] = format!("{},{},maybe", fields[0], fields[1]);
    std::fs::write(&path, lines.join("\n") + "\n").expect("write");

    let stream = open(&path, &plant, &options(BATCH)).expect("opens: the opening rows are fine");
    let mut delivered = 0;
    let mut error = None;
    for batch in stream.batches {
        match batch {
            Ok(batch) => delivered += batch.len(),
            Err(e) => {
                error = Some(e);
                break;
            }
        }
    }
    let e = error.expect("an error");
    assert_located(&e, &path, bad, column, Some("value"));
    assert!(
        delivered >= BATCH,
        "the batches before the error are delivered: {delivered}"
    );
}

/// The run as an events CSV, with an end row at `end` if given, and `extra`
/// rows after everything.
fn events_csv(plant: &Plant, sink: &MemorySink, end: Option<Time>, extra: &str) -> String {
    let ms = TimeFormat::Numeric(TimeUnit::Ms);
    let mut w = EventWriter::new(Vec::new(), &plant.signals, ms).expect("writer");
    w.write_initial(sink.start, &sink.initial).expect("write");
    for e in &sink.events {
        w.write(e).expect("write");
    }
    if let Some(end) = end {
        w.write_end(end).expect("write");
    }
    String::from_utf8(w.finish().expect("finish")).expect("utf-8") + extra
}

#[test]
fn an_end_row_reaches_every_reader_of_the_events_form() {
    let (plant, sink) = simulated();
    let dir = tempfile::tempdir().expect("temp dir");
    let last = sink.events.last().expect("events").t;
    let end = last + 90 * SECOND;
    let ended = dir.path().join("ended.csv");
    std::fs::write(&ended, events_csv(&plant, &sink, Some(end), "")).expect("write");
    let open_ended = dir.path().join("open_ended.csv");
    std::fs::write(&open_ended, events_csv(&plant, &sink, None, "")).expect("write");

    // The same rows as Parquet: the end row has a null signal and value.
    let names = |i: u32| plant.signals.name(SignalId(i));
    let mut rows: Vec<(Time, Option<&str>, Option<bool>)> = (0..sink.initial.len())
        .map(|i| (sink.start, Some(names(i as u32)), Some(sink.initial[i])))
        .collect();
    rows.extend(
        sink.events
            .iter()
            .map(|e| (e.t, Some(names(e.signal.0)), Some(e.value))),
    );
    rows.push((end, None, None));
    let parquet = dir.path().join("ended.parquet");
    write_parquet(
        &parquet,
        vec![
            Column::new("t", rows.iter().map(|r| r.0 / MS).collect::<Vec<i64>>()),
            Column::new("signal", rows.iter().map(|r| r.1).collect::<Vec<_>>()),
            Column::new("value", rows.iter().map(|r| r.2).collect::<Vec<_>>()),
        ],
    );

    let buffered = IngestOptions {
        batch_rows: 1,
        ..options(BATCH)
    };
    for (path, opts, declared) in [
        (&ended, options(BATCH), Some(end)),
        (&ended, buffered.clone(), Some(end)),
        (&parquet, options(BATCH), Some(end)),
        (&open_ended, options(BATCH), None),
        (&open_ended, buffered.clone(), None),
    ] {
        let what = format!("{} (batches of {})", path.display(), opts.batch_rows);
        let r = read(path, &plant, &opts).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(r.events, sink.events, "{what}: the end row adds no event");
        assert_eq!(r.end, declared, "{what}");
    }

    // Nothing may follow the end row: every reader says where.
    let after = dir.path().join("after_end.csv");
    let text = events_csv(&plant, &sink, Some(end), "");
    let end_line = text.lines().count();
    let (_, signal) = plant.signals.iter().next().expect("a signal");
    std::fs::write(
        &after,
        format!("{text}{},{},1\n", (end + SECOND) / MS, signal.name),
    )
    .expect("write");
    for opts in [options(BATCH), buffered] {
        let e = first_error(&after, &plant, &opts);
        assert_eq!(e.location.line, end_line + 1, "{e}");
        assert!(
            e.message
                .contains(&format!("after the end row on line {end_line}")),
            "{e}"
        );
    }
}

#[test]
fn bad_parquet_files_fail_clearly() {
    let plant = turntable();
    let dir = tempfile::tempdir().expect("temp dir");
    let t = |v: &[i64]| Column::new("t", v.to_vec());
    let signal = |v: &[&str]| Column::new("signal", v.to_vec());
    let value = |v: &[bool]| Column::new("value", v.to_vec());
    let good_t = [0, 0, 0, 100, 110];
    let good_signal = ["C4", "C5", "A4", "A4", "C4"];
    let good_value = [true, false, false, true, false];

    let missing = dir.path().join("missing_column.parquet");
    write_parquet(&missing, vec![t(&good_t), signal(&good_signal)]);
    let not_boolean = dir.path().join("not_boolean.parquet");
    write_parquet(
        &not_boolean,
        vec![
            t(&good_t),
            signal(&good_signal),
            Column::new("value", vec![1i64, 0, 0, 1, 2]),
        ],
    );
    let backwards = dir.path().join("backwards.parquet");
    write_parquet(
        &backwards,
        vec![
            t(&[0, 0, 0, 100, 90]),
            signal(&good_signal),
            value(&good_value),
        ],
    );
    let unknown = dir.path().join("unknown_signal.parquet");
    write_parquet(
        &unknown,
        vec![
            t(&good_t),
            signal(&["C4", "C5", "A4", "B7", "C4"]),
            value(&good_value),
        ],
    );
    let bad_time = dir.path().join("bad_time.parquet");
    write_parquet(
        &bad_time,
        vec![
            Column::new("t", vec!["0", "0", "0", "100", "1l0"]),
            signal(&good_signal),
            value(&good_value),
        ],
    );
    let backwards_intervals = dir.path().join("backwards_intervals.parquet");
    write_parquet(
        &backwards_intervals,
        vec![
            Column::new("signal", vec!["C4", "C5", "A4", "C4"]),
            Column::new("value", vec![true, false, false, false]),
            Column::new("t_start", vec![0i64, 0, 0, 100]),
            Column::new("t_end", vec![Some(100i64), None, None, Some(90)]),
        ],
    );

    let events = IngestOptions {
        format: Some(LogFormat::EventsParquet),
        ..options(2)
    };
    // Line = row number + 1 (the column names are line 1); column = position in
    // the schema, from 1.
    let cases: [Case<&Path>; 7] = [
        (
            &missing,
            &events,
            1,
            0,
            None,
            "missing required column 'value'",
        ),
        (&missing, &options(2), 1, 2, None, "unknown column 'signal'"),
        (
            &not_boolean,
            &options(2),
            6,
            3,
            Some("value"),
            "bad value '2'",
        ),
        (
            &backwards,
            &options(2),
            6,
            1,
            Some("t"),
            "time goes backwards: 90 is before 100 on line 5",
        ),
        (
            &unknown,
            &options(2),
            5,
            2,
            Some("signal"),
            "unknown signal 'B7'",
        ),
        (&bad_time, &options(2), 6, 1, Some("t"), "bad time '1l0'"),
        (
            &backwards_intervals,
            &options(2),
            5,
            4,
            Some("t_end"),
            "interval ends before it starts",
        ),
    ];
    for (path, options, line, column, field, message) in cases {
        let e = first_error(path, &plant, options);
        assert_located(&e, path, line, column, field);
        assert!(e.message.contains(message), "{}: {e}", path.display());
    }
}

#[test]
fn a_parquet_column_of_the_wrong_type_is_named_on_the_header_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let typed = dir.path().join("bool_times.parquet");
    write_parquet(
        &typed,
        vec![
            Column::new("t", vec![false, false, false, true, true]),
            Column::new("signal", vec!["C4", "C5", "A4", "A4", "C4"]),
            Column::new("value", vec![true, false, false, true, false]),
        ],
    );
    let e = first_error(&typed, &turntable(), &options(2));
    assert_located(&e, &typed, 1, 1, None);
    let expected = "column 't' has type bool: expected integers or floats in ms, or RFC 3339 text";
    assert!(e.message.contains(expected), "{e}");
}

#[test]
fn a_file_of_unknown_form_fails_clearly() {
    let plant = turntable();
    let path = fixtures().join("unknown_form.txt");
    for e in [
        detect_format(&path).expect_err("unknown"),
        open(&path, &plant, &options(BATCH)).expect_err("unknown"),
    ] {
        assert_located(&e, &path, 1, 0, None);
        assert!(e.message.contains("cannot tell the form"), "{e}");
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "").expect("write");
    let e = detect_format(&empty).expect_err("empty");
    assert!(
        e.to_string().contains("empty.csv") && e.message.contains("empty"),
        "{e}"
    );
    let parquet = dir.path().join("odd.parquet");
    write_parquet(&parquet, vec![Column::new("x", vec![1i64])]);
    let e = detect_format(&parquet).expect_err("odd columns");
    assert!(e.to_string().contains("odd.parquet"), "{e}");
    let missing = dir.path().join("missing.csv");
    let e = open(&missing, &plant, &options(BATCH)).expect_err("missing file");
    assert!(e.to_string().contains("missing.csv"), "{e}");
}

#[test]
fn text_forms_are_detected() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases = [
        (
            "a.vcd",
            "\n$date today $end\n$timescale 1ms $end\n",
            LogFormat::Vcd,
        ),
        (
            "a.log",
            "(1436509052.249713) can0 181#0102\n",
            LogFormat::Candump,
        ),
        (
            "a.csv",
            "\u{feff}t,signal,value,quality\n",
            LogFormat::EventsCsv,
        ),
        (
            "b.csv",
            "signal,value,t_start,t_end\n",
            LogFormat::IntervalsCsv,
        ),
        ("c.csv", "t,C4,C5,A4\n0,1,0,0\n", LogFormat::ScansCsv),
    ];
    for (name, text, format) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("write");
        assert_eq!(detect_format(&path).expect("detected"), format, "{name}");
    }
}

#[test]
fn the_shipped_logs_open_and_agree() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/data/sorting/normal");
    let plant = Plant::from_path(&dir.join("plant.toml")).expect("shipped plant");
    let options = IngestOptions {
        time_unit: plant.time_unit,
        ..options(BATCH)
    };
    let events = read(&dir.join("events.csv"), &plant, &options).unwrap_or_else(|e| panic!("{e}"));
    let intervals =
        read(&dir.join("intervals.csv"), &plant, &options).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(events.format, LogFormat::EventsCsv);
    assert_eq!(intervals.format, LogFormat::IntervalsCsv);
    assert_eq!(events.start, intervals.start);
    assert_eq!(events.initial, intervals.initial);
    assert_eq!(events.events, intervals.events);
    let exact =
        read_events(&dir.join("events.csv"), &plant.signals, plant.time_unit).expect("exact");
    assert_eq!(events.initial, exact.initial);
    assert_eq!(events.events, exact.events);
    assert!(!events.events.is_empty());
}

/// Peak memory on a large log: generates (once) an events CSV (an intervals CSV
/// if the file's name contains `intervals`) of
/// `GARDEFOU_LARGE_EVENTS` changes (default ten million) at
/// `GARDEFOU_LARGE_LOG` (default in the temp dir), then reads it in batches of
/// `GARDEFOU_LARGE_BATCH` rows (default: the default batch size). Run in
/// release under `/usr/bin/time -v`, a second time to measure reading alone.
#[test]
#[ignore = "large: run by hand in release under /usr/bin/time -v"]
fn a_large_events_csv_streams_in_bounded_memory() {
    let plant = sorting_plant();
    let path = std::env::var_os("GARDEFOU_LARGE_LOG").map_or_else(
        || std::env::temp_dir().join("gardefou-large-events.csv"),
        PathBuf::from,
    );
    let n: usize = std::env::var("GARDEFOU_LARGE_EVENTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000_000);
    let signals = plant.signals.len();
    if !path.exists() {
        // The intervals form if the file's name says so, else the events form.
        let ms = TimeFormat::Numeric(TimeUnit::Ms);
        let file = File::create(&path).expect("create");
        let initial = vec![false; signals];
        if path.to_string_lossy().contains("intervals") {
            let mut w = IntervalWriter::new(file, &plant.signals, ms).expect("writer");
            w.write_initial(0, &initial).expect("write");
            for event in large_events(n, signals) {
                w.write(&event).expect("write");
            }
            w.finish().expect("finish");
        } else {
            let mut w = EventWriter::new(file, &plant.signals, ms).expect("writer");
            w.write_initial(0, &initial).expect("write");
            for event in large_events(n, signals) {
                w.write(&event).expect("write");
            }
            w.finish().expect("finish");
        }
    }
    let started = std::time::Instant::now();
    let batch_rows = std::env::var("GARDEFOU_LARGE_BATCH")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(IngestOptions::default().batch_rows);
    let options = IngestOptions {
        batch_rows,
        ..IngestOptions::default()
    };
    let stream = open(&path, &plant, &options).expect("open");
    let mut count = 0;
    let mut batches = 0;
    // Peak anonymous and file-backed resident memory, sampled at each batch
    // (file-backed pages are the page cache's, and the binary's).
    let (mut anon, mut mapped) = (0, 0);
    for batch in stream.batches {
        count += batch.expect("batch").len();
        batches += 1;
        let (a, f) = resident_kib();
        anon = anon.max(a);
        mapped = mapped.max(f);
    }
    println!(
        "{count} events in {batches} batches from {} in {:.1?}; peak RssAnon {anon} KiB, RssFile {mapped} KiB",
        path.display(),
        started.elapsed()
    );
    assert_eq!(count, n);
}

/// `n` changes of `signals` signals, all false at first: three per scan of 10 ms,
/// each toggling the next signal.
fn large_events(n: usize, signals: usize) -> impl Iterator<Item = Event> {
    let mut values = vec![false; signals];
    (0..n).map(move |k| {
        let i = k % signals;
        values[i] = !values[i];
        Event {
            t: (k as i64 / 3 + 1) * 10 * MS,
            signal: SignalId(i as u32),
            value: values[i],
        }
    })
}

/// Current anonymous and file-backed resident memory (KiB), from
/// `/proc/self/status` (zeros where it does not exist).
fn resident_kib() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("RssAnon:"), field("RssFile:"))
}

#[test]
fn a_flipped_bit_in_a_parquet_footer_is_an_error_not_a_panic() {
    // Every bit of a small archive's footer, one at a time: the schema, row
    // groups and statistics that polars trusts. Each flip reads,
    // or fails in one printable line of words; polars' own panics (an Int128
    // column type from one flip) are the file's error.
    let (plant, sink) = simulated();
    let end = sink.events.last().map_or(sink.start, |e| e.t);
    let log = EventLog {
        start: sink.start,
        initial: sink.initial.clone(),
        events: sink.events.clone(),
        format: TimeFormat::Numeric(TimeUnit::Ms),
        end: None,
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let good = dir.path().join("good.parquet");
    write_intervals_parquet(&log, &plant.signals, &good, end).expect("archive");
    let bytes = std::fs::read(&good).expect("read");
    let flipped = dir.path().join("flipped.parquet");
    // The footer, its length and the magic bytes that end the file.
    let tail: [u8; 4] = bytes[bytes.len() - 8..bytes.len() - 4]
        .try_into()
        .expect("4 bytes");
    let footer = u32::from_le_bytes(tail) as usize + 8;
    let (mut read, mut refused) = (0, 0);
    for pos in bytes.len() - footer..bytes.len() {
        for bit in 0..8 {
            let mut copy = bytes.clone();
            copy[pos] ^= 1 << bit;
            std::fs::write(&flipped, &copy).expect("write");
            let outcome = std::panic::catch_unwind(|| read_all(&flipped, &plant));
            match outcome {
                Ok(Ok(())) => read += 1,
                Ok(Err(e)) => {
                    let text = e.to_string();
                    assert!(
                        !text.chars().any(char::is_control),
                        "byte {pos} bit {bit}: {text:?}"
                    );
                    // Words, not a dump of a reader's state.
                    assert!(!text.contains(" { "), "byte {pos} bit {bit}: {text:?}");
                    refused += 1;
                }
                Err(_) => panic!("byte {pos} bit {bit}: a panic escaped"),
            }
        }
    }
    assert_eq!(read + refused, 8 * footer);
    assert!(refused > 0, "no flip refused");
}

/// Opens and reads the whole log.
fn read_all(path: &Path, plant: &Plant) -> Result<(), Located> {
    let stream = open(path, plant, &options(BATCH))?;
    for batch in stream.batches {
        batch?;
    }
    Ok(())
}

/// Found by the `parquet` fuzz target, each made polars reserve more memory
/// than there is and abort the process, which no panic handler catches: a data
/// page whose header says it holds -33 values (2^61 bytes for their validity),
/// a footer whose list of row groups says it is longer than the footer (47 GB),
/// a footer field of another type than polars expects, which it read a list
/// header out of (76 GB). The footer's structure, as polars reads it, and the
/// page headers are now checked first.
#[test]
fn counts_polars_would_reserve_memory_for_are_checked_first() {
    let cases = [
        (
            "negative_page_values.parquet",
            "a damaged column chunk in row group 3: page 0 at byte 1215: a negative number of values, -33",
        ),
        (
            "list_longer_than_footer.parquet",
            "a damaged footer: cut short, or a list longer than the footer",
        ),
        (
            "footer_field_of_another_type.parquet",
            "a damaged footer: a field of another type than its own",
        ),
    ];
    for (name, message) in cases {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/parquet")
            .join(name);
        let e = first_error(&path, &turntable(), &options(BATCH));
        let expected = format!("cannot read the Parquet log: {message}");
        assert!(e.to_string().ends_with(&expected), "{name}: {e}");
    }
}
