//! Logs past the memory budget are read by the buffered reader; it must give
//! exactly what the polars path gives.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use diagnoser::log::ScanWriter;
use diagnoser::{Event, MS, SECOND, TimeFormat, TimeUnit};
use learning::ingest::{IngestOptions, open};

fn read_all(path: &Path, budget: u64) -> (Vec<bool>, i64, Vec<Event>) {
    let options = IngestOptions {
        memory_budget: budget,
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
fn buffered_events_reader_matches_polars() {
    let path = shipped("sorting/normal/events.csv");
    let fast = read_all(&path, u64::MAX);
    let buffered = read_all(&path, 0);
    assert!(fast.2.len() > 1000);
    assert_eq!(fast, buffered);
}

#[test]
fn buffered_scans_reader_matches_polars() {
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
    let fast = read_all(&path, u64::MAX);
    let buffered = read_all(&path, 0);
    assert_eq!(fast, buffered);
    assert_eq!(buffered.2, sink.events);
    assert_eq!(buffered.0, sink.initial);
}

#[test]
fn buffered_reader_reports_bad_rows_with_their_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bad.csv");
    let mut text = String::from("t,signal,value\n");
    for (i, (_, s)) in plant().signals.iter().enumerate() {
        text.push_str(&format!("0,{},{}\n", s.name, i % 2));
    }
    text.push_str("10,C4,1\n20,C4,perhaps\n");
    std::fs::write(&path, text).expect("write");
    let options = IngestOptions {
        memory_budget: 0,
        ..IngestOptions::default()
    };
    let log = open(&path, &plant(), &options).expect("opening rows are fine");
    let err = log
        .batches
        .filter_map(Result::err)
        .next()
        .expect("an error");
    let msg = err.to_string();
    assert!(msg.contains("bad.csv:21:"), "{msg}");
}
