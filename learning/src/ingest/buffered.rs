//! Events and scans CSV logs read line by line, for logs past the memory budget.
//!
//! polars maps a local file into memory; on a log of billions of rows the mapped
//! pages fill the resident set. This reader uses the exact streaming readers of
//! `diagnoser::log` over a `BufReader` instead, on a thread of its own that hands
//! batches over a bounded channel: resident memory stays at a few batches, and
//! parsing overlaps with learning.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use diagnoser::log::{EventReader, ScanReader, TimeFormatChoice};
use diagnoser::{Event, Located, Location, Plant, SignalId, SignalTable, Time, TimeFormat};

use super::{IngestOptions, LogEnd, LogFormat, LogStream};

enum Msg {
    Start {
        time: TimeFormat,
        start: Time,
        initial: Vec<bool>,
    },
    Batch(Vec<Event>),
    Failed(Located),
}

/// Opens an events or scans CSV log for buffered streaming.
pub(super) fn open(
    path: &Path,
    plant: &Plant,
    options: &IngestOptions,
    format: LogFormat,
) -> Result<LogStream, Located> {
    let (send, recv) = sync_channel::<Msg>(2);
    let signals = plant.signals.clone();
    let owned = path.to_path_buf();
    let choice = TimeFormatChoice::Detect(options.time_unit);
    let batch = options.batch_rows.max(1);
    let end = LogEnd::default();
    let found = end.clone();
    std::thread::Builder::new()
        .name("gardefou-read".into())
        .spawn(move || {
            let result = match format {
                LogFormat::ScansCsv => scans(&owned, &signals, choice, batch, &send),
                _ => events(&owned, &signals, choice, batch, &send, &found),
            };
            if let Err(e) = result {
                let _ = send.send(Msg::Failed(e));
            }
        })
        .map_err(|e| {
            Located::new(
                Location::new(path, 0, 0),
                format!("cannot start reading: {e}"),
            )
        })?;
    match recv.recv() {
        Ok(Msg::Start {
            time,
            start,
            initial,
        }) => Ok(LogStream {
            path: path.to_path_buf(),
            format,
            time,
            start,
            initial,
            batches: Box::new(Incoming(recv)),
            end,
        }),
        Ok(Msg::Failed(e)) => Err(e),
        Ok(Msg::Batch(_)) | Err(_) => Err(Located::new(
            Location::new(path, 0, 0),
            "the reader stopped before the first record",
        )),
    }
}

struct Incoming(Receiver<Msg>);

impl Iterator for Incoming {
    type Item = Result<Vec<Event>, Located>;
    fn next(&mut self) -> Option<Self::Item> {
        match self.0.recv().ok()? {
            Msg::Batch(b) => Some(Ok(b)),
            Msg::Failed(e) => Some(Err(e)),
            Msg::Start { .. } => None,
        }
    }
}

fn open_file(path: &Path) -> Result<BufReader<File>, Located> {
    File::open(path)
        .map(|f| BufReader::with_capacity(1 << 20, f))
        .map_err(|e| Located::new(Location::new(path, 0, 0), format!("cannot open: {e}")))
}

/// Collects one scan's changes, sorts them by signal and ships full batches.
struct Batcher<'s> {
    send: &'s SyncSender<Msg>,
    size: usize,
    batch: Vec<Event>,
    scan: Vec<Event>,
    scan_t: Option<Time>,
}

impl<'s> Batcher<'s> {
    fn new(send: &'s SyncSender<Msg>, size: usize) -> Self {
        Batcher {
            send,
            size,
            batch: Vec::with_capacity(size),
            scan: Vec::new(),
            scan_t: None,
        }
    }

    /// Returns false when the consumer is gone.
    fn push(&mut self, e: Event) -> bool {
        if self.scan_t != Some(e.t) {
            if !self.close_scan() {
                return false;
            }
            self.scan_t = Some(e.t);
        }
        self.scan.push(e);
        true
    }

    fn close_scan(&mut self) -> bool {
        self.scan.sort_unstable_by_key(|e| e.signal);
        self.batch.append(&mut self.scan);
        if self.batch.len() >= self.size {
            let full = std::mem::take(&mut self.batch);
            return self.send.send(Msg::Batch(full)).is_ok();
        }
        true
    }

    fn finish(mut self) {
        if self.close_scan() && !self.batch.is_empty() {
            let _ = self.send.send(Msg::Batch(self.batch));
        }
    }
}

fn events(
    path: &Path,
    signals: &SignalTable,
    choice: TimeFormatChoice,
    size: usize,
    send: &SyncSender<Msg>,
    end: &LogEnd,
) -> Result<(), Located> {
    let mut reader = EventReader::new(open_file(path)?, path, signals, choice)?;
    let mut values = vec![false; signals.len()];
    let mut seen = vec![false; signals.len()];
    let mut pending: Option<Event> = None;
    let mut start = None;
    // Opening rows: everything at the first timestamp.
    for row in reader.by_ref() {
        let e = row?;
        match start {
            None => start = Some(e.t),
            Some(t0) if e.t != t0 => {
                pending = Some(e);
                break;
            }
            Some(_) => {}
        }
        values[e.signal.index()] = e.value;
        seen[e.signal.index()] = true;
    }
    let Some(start) = start else {
        return Err(Located::new(Location::new(path, 2, 0), "no data rows"));
    };
    if let Some(i) = seen.iter().position(|s| !s) {
        return Err(Located::new(
            Location::new(path, 2, 0),
            format!(
                "signal '{}' has no initial value in the opening rows",
                signals.name(SignalId(i as u32))
            ),
        ));
    }
    let time = reader.format();
    if send
        .send(Msg::Start {
            time,
            start,
            initial: values.clone(),
        })
        .is_err()
    {
        return Ok(());
    }
    let mut out = Batcher::new(send, size);
    let rows = pending.into_iter().map(Ok).chain(reader.by_ref());
    for row in rows {
        let e = row?;
        let v = &mut values[e.signal.index()];
        if *v != e.value {
            *v = e.value;
            if !out.push(e) {
                return Ok(());
            }
        }
    }
    // Before the last batch goes: the consumer reads the end after it.
    if let Some(t) = reader.end() {
        end.set(t);
    }
    out.finish();
    Ok(())
}

fn scans(
    path: &Path,
    signals: &SignalTable,
    choice: TimeFormatChoice,
    size: usize,
    send: &SyncSender<Msg>,
) -> Result<(), Located> {
    let mut reader = ScanReader::new(open_file(path)?, path, signals, choice)?;
    let (start, mut values) = match reader.next_scan() {
        Some(row) => {
            let (t, v) = row?;
            (t, v.to_vec())
        }
        None => return Err(Located::new(Location::new(path, 2, 0), "no data rows")),
    };
    if send
        .send(Msg::Start {
            time: reader.format(),
            start,
            initial: values.clone(),
        })
        .is_err()
    {
        return Ok(());
    }
    let mut out = Batcher::new(send, size);
    while let Some(row) = reader.next_scan() {
        let (t, row) = row?;
        for (i, (old, &new)) in values.iter_mut().zip(row).enumerate() {
            if *old != new {
                *old = new;
                if !out.push(Event {
                    t,
                    signal: SignalId(i as u32),
                    value: new,
                }) {
                    return Ok(());
                }
            }
        }
    }
    out.finish();
    Ok(())
}
