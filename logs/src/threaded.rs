//! The events, intervals and scans forms, CSV or Parquet, read on a thread of
//! their own.
//!
//! The thread runs the form's reader over the container's records and hands
//! batches of changes over a bounded channel: resident memory stays at a few
//! batches, and parsing overlaps with what the caller does with the events.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use vocabulary::{Event, Located, Plant, SignalTable, Time, TimeFormat};

use crate::csv::CsvRecords;
use crate::rows::{Records, file_error, open_file};
use crate::{
    Changes, EventChanges, EventReader, IngestOptions, IntervalChanges, IntervalReader, LogEnd,
    LogFormat, LogStream, ScanChanges, ScanReader, TimeFormatChoice,
};

/// What the reading thread tells the stream.
enum Msg {
    Start {
        time: TimeFormat,
        start: Time,
        initial: Vec<bool>,
    },
    Batch(Vec<Event>),
    Failed(Located),
}

/// Opens a CSV or Parquet log of one of the three forms.
pub(crate) fn open(
    path: &Path,
    plant: &Plant,
    options: &IngestOptions,
    format: LogFormat,
) -> Result<LogStream, Located> {
    let (send, recv) = sync_channel::<Msg>(2);
    let job = Job {
        path: path.to_path_buf(),
        signals: plant.signals.clone(),
        choice: TimeFormatChoice::Detect(options.time_unit),
        options: options.clone(),
        format,
    };
    let end = LogEnd::default();
    let found = end.clone();
    std::thread::Builder::new()
        .name("gardefou-read".into())
        .spawn(move || {
            if let Err(e) = job.run(&send, &found) {
                let _ = send.send(Msg::Failed(e));
            }
        })
        .map_err(|e| file_error(path, format!("cannot start reading: {e}")))?;
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
        Ok(Msg::Batch(_)) | Err(_) => Err(file_error(
            path,
            "the reader stopped before the first record",
        )),
    }
}

/// The batches, as the thread sends them.
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

/// What the reading thread reads.
struct Job {
    path: PathBuf,
    signals: SignalTable,
    choice: TimeFormatChoice,
    options: IngestOptions,
    format: LogFormat,
}

impl Job {
    fn run(&self, send: &SyncSender<Msg>, end: &LogEnd) -> Result<(), Located> {
        match self.format {
            LogFormat::EventsCsv | LogFormat::IntervalsCsv | LogFormat::ScansCsv => {
                self.form(|| self.csv(), send, end)
            }
            #[cfg(feature = "parquet")]
            LogFormat::EventsParquet | LogFormat::IntervalsParquet | LogFormat::ScansParquet => {
                self.form(|| self.parquet(), send, end)
            }
            other => Err(file_error(
                &self.path,
                format!(
                    "{other:?} is not a form this build reads (Parquet needs the `parquet` feature)"
                ),
            )),
        }
    }

    /// Streams the form's changes over the records `open` gives (twice for
    /// the intervals form).
    fn form<S: Records>(
        &self,
        open: impl Fn() -> Result<S, Located>,
        send: &SyncSender<Msg>,
        end: &LogEnd,
    ) -> Result<(), Located> {
        let (signals, choice) = (&self.signals, self.choice);
        match self.format {
            LogFormat::EventsCsv | LogFormat::EventsParquet => {
                let reader = EventReader::from_records(open()?, signals, choice)?;
                self.stream(EventChanges::open(reader)?, send, end)
            }
            LogFormat::ScansCsv | LogFormat::ScansParquet => {
                let reader = ScanReader::from_records(open()?, signals, choice)?;
                self.stream(ScanChanges::open(reader)?, send, end)
            }
            _ => {
                let reader = || IntervalReader::from_records(open()?, signals, choice);
                self.stream(IntervalChanges::open(reader)?, send, end)
            }
        }
    }

    fn csv(&self) -> Result<CsvRecords<BufReader<File>>, Located> {
        let file = open_file(&self.path)?;
        // The records read large blocks themselves, past a small buffer.
        Ok(CsvRecords::new(BufReader::new(file), &self.path))
    }

    #[cfg(feature = "parquet")]
    fn parquet(&self) -> Result<crate::parquet::ParquetRecords, Located> {
        crate::parquet::ParquetRecords::open(&self.path, &self.options)
    }

    /// Sends the opening values, then batches of whole scans; stops quietly when
    /// the stream is dropped.
    fn stream(
        &self,
        mut changes: impl Changes,
        send: &SyncSender<Msg>,
        end: &LogEnd,
    ) -> Result<(), Located> {
        let start = Msg::Start {
            time: changes.format(),
            start: changes.start(),
            initial: changes.initial().to_vec(),
        };
        if send.send(start).is_err() {
            return Ok(());
        }
        let size = self.options.batch_rows.max(1);
        let mut batch = Vec::with_capacity(size);
        while changes.read_scan(&mut batch)? {
            if batch.len() >= size {
                let full = std::mem::replace(&mut batch, Vec::with_capacity(size));
                if send.send(Msg::Batch(full)).is_err() {
                    return Ok(());
                }
            }
        }
        // Before the last batch goes: the consumer reads the end after it.
        if let Some(t) = changes.end() {
            end.set(t);
        }
        if !batch.is_empty() {
            let _ = send.send(Msg::Batch(batch));
        }
        Ok(())
    }
}
