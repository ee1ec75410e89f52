//! Reading PLC logs of every supported form as a stream of events.
//!
//! Whatever the form, a log is opened as a [`LogStream`]: the initial value of
//! every signal, then batches of [`Event`]s sorted by `(t, signal)`, with `t`
//! non-decreasing from one batch to the next. Only real changes are events.

use std::path::PathBuf;

use diagnoser::{Event, Located, Time, TimeFormat, TimeUnit};

/// The forms of log gardefou reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LogFormat {
    /// `t,signal,value` CSV (the long form).
    EventsCsv,
    /// `signal,value,t_start,t_end` CSV (the archive form).
    IntervalsCsv,
    /// `t,<sig1>,<sig2>,…` CSV (one row per scan or sample).
    ScansCsv,
    /// The events form as Parquet.
    EventsParquet,
    /// The intervals form as Parquet.
    IntervalsParquet,
    /// The scans form as Parquet.
    ScansParquet,
    /// `candump -L` output, decoded with the plant file's `[can]` bit mapping.
    Candump,
    /// Value change dump (IEEE 1364).
    Vcd,
}

/// How to open a log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IngestOptions {
    /// The form, or `None` to detect it from the file's header.
    pub format: Option<LogFormat>,
    /// Unit of numeric timestamps (`--time-unit`).
    pub time_unit: TimeUnit,
    /// Roughly how many events (or rows) to decode per batch; bounds memory.
    pub batch_rows: usize,
}

impl Default for IngestOptions {
    fn default() -> Self {
        IngestOptions { format: None, time_unit: TimeUnit::Ms, batch_rows: 1 << 20 }
    }
}

/// Batches of events, in order.
pub type Batches = Box<dyn Iterator<Item = Result<Vec<Event>, Located>> + Send>;

/// An opened log: initial values, then batches of events.
pub struct LogStream {
    /// The file.
    pub path: PathBuf,
    /// Its form.
    pub format: LogFormat,
    /// How its timestamps are written (outputs reuse it).
    pub time: TimeFormat,
    /// Time of the first record.
    pub start: Time,
    /// Initial value of every signal, indexed by [`diagnoser::SignalId::index`].
    pub initial: Vec<bool>,
    /// The changes, batch by batch.
    pub batches: Batches,
}

impl std::fmt::Debug for LogStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogStream")
            .field("path", &self.path)
            .field("format", &self.format)
            .field("time", &self.time)
            .field("start", &self.start)
            .finish_non_exhaustive()
    }
}

pub mod candump;
pub mod vcd;
