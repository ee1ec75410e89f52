//! A log read as a stream, batch by batch, gives exactly what the whole-file
//! readers give.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use logs::{IngestOptions, ScanWriter, open, read_events, read_scans_as_events};
use vocabulary::{Event, MS, SECOND, TimeFormat, TimeUnit};

fn read_all(path: &Path) -> (Vec<bool>, i64, Vec<Event>) {
    let options = IngestOptions {
        batch_rows: 500,
        ..IngestOptions::default()
    };
    let log = open(path, &plant(), &options).expect("opens");
    let (initial, start) = (log.initial.clone(), log.start);
    let mut events = Vec::new();
    for batch in log.batches {
        events.extend(batch.expect("reads"));
    }
    (initial, start, events)
}

fn shipped(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../datasets/data")
        .join(rel)
}

#[test]
fn streamed_events_match_the_whole_file_reader() {
    let path = shipped("sorting/normal/events.csv");
    let whole = read_events(&path, &plant().signals, TimeUnit::Ms).expect("reads");
    let streamed = read_all(&path);
    assert!(streamed.2.len() > 1000);
    assert_eq!(streamed, (whole.initial, whole.start, whole.events));
}

#[test]
fn streamed_scans_match_the_whole_file_reader_and_the_run() {
    let mut line = SortingLine::new(SortingConfig::default());
    let mut ctl = SynthesisedControl::new(line.ids());
    let cfg = SimConfig {
        duration: 300 * SECOND,
        scan_period: 10 * MS,
        seed: 3,
        faults: vec![],
    };
    let mut sink = MemorySink::default();
    run(&mut line, &mut ctl, &cfg, &mut sink, |_| {}).expect("runs");
    // Rebuild every scan from the changes and write the wide form.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("scans.csv");
    let signals = plant().signals;
    let mut w = ScanWriter::new(
        BufWriter::new(File::create(&path).expect("create")),
        &signals,
        TimeFormat::Numeric(TimeUnit::Ms),
    )
    .expect("writer");
    let mut values = sink.initial.clone();
    let mut events = sink.events.iter().peekable();
    let mut t = sink.start;
    while t <= cfg.duration {
        while let Some(e) = events.next_if(|e| e.t == t) {
            values[e.signal.index()] = e.value;
        }
        w.write(t, &values).expect("row");
        t += 10 * MS;
    }
    w.finish().expect("flush");
    let whole = read_scans_as_events(&path, &signals, TimeUnit::Ms).expect("reads");
    let streamed = read_all(&path);
    assert_eq!(streamed, (whole.initial, whole.start, whole.events));
    assert_eq!(streamed.2, sink.events);
    assert_eq!(streamed.0, sink.initial);
}

#[test]
fn a_streamed_log_reports_bad_rows_with_their_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bad.csv");
    let mut text = String::from("t,signal,value\n");
    for (i, (_, s)) in plant().signals.iter().enumerate() {
        text.push_str(&format!("0,{},{}\n", s.name, i % 2));
    }
    text.push_str("10,C4,1\n20,C4,perhaps\n");
    std::fs::write(&path, text).expect("write");
    let log = open(&path, &plant(), &IngestOptions::default()).expect("opening rows are fine");
    let err = log
        .batches
        .filter_map(Result::err)
        .next()
        .expect("an error");
    let msg = err.to_string();
    assert!(msg.contains("bad.csv:21:"), "{msg}");
}
