//! Reading PLC logs of every supported form as a stream of events.
//!
//! Whatever the form, a log is opened as a [`LogStream`]: the initial value of
//! every signal, then batches of [`Event`]s sorted by `(t, signal)`, with `t`
//! non-decreasing from one batch to the next. Only real changes are events.
//!
//! [`open`] detects the form ([`detect_format`]) unless it is given, then reads
//! the events, intervals and scans forms, CSV or Parquet, with the form's reader
//! on a thread of its own, batch by batch (memory does not grow with the log),
//! and hands `candump -L` and VCD logs to [`candump`] and [`vcd`]. Every form
//! of the same recording gives the same initial values and the same events.
//!
//! Errors are one-line [`Located`] errors naming the file, line, column and
//! field. In a Parquet file, the "line" of a row is its 1-based row number plus
//! one (as if the column names were line 1), and the column is the 1-based index
//! of the column in the file's schema.

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use vocabulary::{Event, Located, Plant, Time, TimeFormat, TimeUnit};

use crate::detect::detect_format;
use crate::spool::Spool;
use crate::{candump, threaded, vcd};

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

impl LogFormat {
    /// Every form with its command-line name.
    pub const NAMES: [(&'static str, LogFormat); 8] = [
        ("events-csv", LogFormat::EventsCsv),
        ("intervals-csv", LogFormat::IntervalsCsv),
        ("scans-csv", LogFormat::ScansCsv),
        ("events-parquet", LogFormat::EventsParquet),
        ("intervals-parquet", LogFormat::IntervalsParquet),
        ("scans-parquet", LogFormat::ScansParquet),
        ("candump", LogFormat::Candump),
        ("vcd", LogFormat::Vcd),
    ];
}

impl std::str::FromStr for LogFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        LogFormat::NAMES
            .iter()
            .find(|(n, _)| *n == s)
            .map(|&(_, f)| f)
            .ok_or_else(|| {
                let names: Vec<&str> = LogFormat::NAMES.iter().map(|(n, _)| *n).collect();
                format!("unknown log form '{s}' (expected {})", names.join(", "))
            })
    }
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
    /// Parquet rows are decoded in slices of at most this many rows: memory
    /// holds a row group's compressed columns and about two slices decoded.
    pub parquet_slice_rows: usize,
}

impl Default for IngestOptions {
    fn default() -> Self {
        IngestOptions {
            format: None,
            time_unit: TimeUnit::Ms,
            batch_rows: 1 << 16,
            parquet_slice_rows: 1 << 18,
        }
    }
}

/// When a log says its recording ended (the events form's end row, see
/// `logs::events`). The readers stream, and the end row comes last:
/// it is known once every batch has been read, and shared with the reader that
/// finds it.
#[derive(Debug, Clone, Default)]
pub struct LogEnd(Arc<OnceLock<Time>>);

impl LogEnd {
    /// The declared end, once the batches are exhausted; `None` before, or when
    /// the log does not say.
    pub fn get(&self) -> Option<Time> {
        self.0.get().copied()
    }

    /// Records the end a reader found (the first one counts).
    pub(crate) fn set(&self, t: Time) {
        let _ = self.0.set(t);
    }

    /// The time deadlines run to at the end of a replay: the last event, or the
    /// declared end or `extra` (`--end`) when later.
    pub fn extend(&self, last: Time, extra: Option<Time>) -> Time {
        last.max(self.get().unwrap_or(last))
            .max(extra.unwrap_or(last))
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
    /// Initial value of every signal, indexed by [`vocabulary::SignalId::index`].
    pub initial: Vec<bool>,
    /// The changes, batch by batch.
    pub batches: Batches,
    /// When the recording ended, if the log says so; known after the batches.
    pub end: LogEnd,
}

impl LogStream {
    /// A log already in memory (e.g. a simulated run), as an events log named
    /// `name`, its times written as `time`.
    pub fn from_events(
        name: &str,
        time: TimeFormat,
        start: Time,
        initial: Vec<bool>,
        events: Vec<Event>,
    ) -> LogStream {
        LogStream {
            path: PathBuf::from(name),
            format: LogFormat::EventsCsv,
            time,
            start,
            initial,
            batches: Box::new(std::iter::once(Ok(events))),
            end: LogEnd::default(),
        }
    }
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

/// Opens the log at `path`, of the form `options.format` or else the detected
/// one ([`detect_format`]), for the signals of `plant`. A pipe, FIFO or
/// character device is read once, into a temporary file that is deleted when
/// the stream is dropped, since reading a log may open it more than once.
///
/// CSV and Parquet logs of the three forms are read by the form's reader
/// ([`crate::EventReader`], [`crate::IntervalReader`], [`crate::ScanReader`]) on
/// a thread of its own, which hands batches of about `options.batch_rows`
/// events over a bounded channel: memory stays at a few batches whatever the
/// size of the log, and reading overlaps with what the caller does. Parquet
/// rows come from `polars-parquet` (feature `parquet`), CSV lines from
/// [`crate::csv::CsvRecords`]; both go through the same rules (an intervals
/// archive as the Parquet writer writes it is read column by column, by the
/// same rules, and falls back to its records at the first row it doubts).
/// The initial values are read before this returns. An intervals log is
/// read twice (see [`crate::IntervalChanges`]). `candump -L` and VCD logs are
/// read by [`candump::open`] and [`vcd::open`].
///
/// Numeric timestamps are in `options.time_unit`; text timestamps may be RFC
/// 3339 (detected from the first one, as [`TimeFormat::detect`] does). Parquet
/// time columns may hold integers or floats in the unit, or text; value columns
/// booleans, integers 0 and 1, or text `0`, `1`, `true`, `false`.
///
/// Errors, before or during the batches, are one line naming the file, line,
/// column and field: a missing column, a value that is not boolean, time going
/// backwards, an unknown signal, a time that cannot be parsed, a missing initial
/// value... In a Parquet file, the "line" of a row is its 1-based row number
/// plus one (as if the column names were line 1), and the column is the
/// 1-based index of the column in the file's schema.
pub fn open(path: &Path, plant: &Plant, options: &IngestOptions) -> Result<LogStream, Located> {
    let Some(spool) = Spool::of(path)? else {
        return open_regular(path, plant, options);
    };
    let mut log = open_regular(path, plant, options)?;
    let batches = log.batches;
    // The copy lives as long as the batches are read.
    log.batches = Box::new(batches.inspect(move |_| {
        let _ = &spool;
    }));
    Ok(log)
}

/// [`open`] on a file that can be opened more than once.
fn open_regular(path: &Path, plant: &Plant, options: &IngestOptions) -> Result<LogStream, Located> {
    let format = match options.format {
        Some(format) => format,
        None => detect_format(path)?,
    };
    // An archive is read column by column; a file that reader is not sure
    // of, by the form's reader, which gives the form's errors.
    #[cfg(feature = "parquet")]
    if format == LogFormat::IntervalsParquet
        && let Some(log) = crate::parquet::open_intervals(path, plant, options)?
    {
        return Ok(log);
    }
    match format {
        LogFormat::Candump => candump::open(path, plant, options),
        LogFormat::Vcd => vcd::open(path, plant, options),
        LogFormat::EventsCsv
        | LogFormat::IntervalsCsv
        | LogFormat::ScansCsv
        | LogFormat::EventsParquet
        | LogFormat::IntervalsParquet
        | LogFormat::ScansParquet => threaded::open(path, plant, options, format),
    }
}
