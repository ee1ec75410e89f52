//! Every log form gardefou reads and writes, in one place.
//!
//! A recording is the value of every signal at its start and every later
//! change. Logs write it in three tabular forms (SPEC §3), as CSV or Parquet:
//! - [`events`] (long form, `t,signal,value`): one row per change, the form the
//!   simulator writes and the diagnoser replays;
//! - [`intervals`] (`signal,value,t_start,t_end`): one row per maximal interval
//!   of constant value, the compact archive form;
//! - [`scans`] (wide form, `t,<sig1>,<sig2>,…`): one row per PLC scan or
//!   sample, the form PLC traces and historians usually export;
//!
//! and in two forms of the wire: [`candump`] (`candump -L`, CANopen PDOs
//! decoded with the plant file's `[can]` mapping) and [`vcd`] (value change
//! dump).
//!
//! Each tabular form's rules and messages are written once, in its reader
//! ([`EventReader`], [`IntervalReader`], [`ScanReader`]), which reads
//! [`Records`] from either container: [`csv::CsvRecords`] line by line, or
//! `parquet::ParquetRecords` row by row (feature `parquet`, which brings
//! polars). [`open`] reads any form as a [`LogStream`]: the initial values,
//! then batches of events, in memory that does not grow with the log. The
//! `read_*` functions build a whole [`EventLog`] in memory; the writers stream.
//!
//! Timestamps are numbers in a unit or RFC 3339 text ([`TimeFormat`]); readers
//! take it as given or detect it from the first data row ([`TimeFormatChoice`]).
//! The CSV dialect is deliberately small: comma-separated fields, LF or CRLF
//! line ends, an optional UTF-8 byte-order mark, blank lines ignored,
//! whitespace around fields ignored, and fields optionally wrapped in double
//! quotes (with no comma or quote inside). Readers stop at the first problem
//! and report it as a one-line [`Located`](vocabulary::Located) error
//! (`file:line:column: field 'x': message`); they never panic.
//!
//! It is not for: what the events mean (the diagnosers, the learner), or
//! talking to a live PLC (the runtime).
//!
//! ```
//! use std::path::Path;
//! use logs::{EventWriter, TimeFormatChoice, read_events_from};
//! use vocabulary::{Event, Signal, SignalKind, SignalTable, TimeFormat, TimeUnit, MS};
//!
//! let mut signals = SignalTable::new();
//! for name in ["C4", "A4"] {
//!     let kind = if name.starts_with('A') { SignalKind::Actuator } else { SignalKind::Sensor };
//!     signals.push(Signal { name: name.into(), kind, description: String::new() });
//! }
//! let a4 = signals.id("A4").unwrap();
//!
//! let format = TimeFormat::Numeric(TimeUnit::Ms);
//! let mut writer = EventWriter::new(Vec::new(), &signals, format).unwrap();
//! writer.write_initial(0, &[true, false]).unwrap();
//! writer.write(&Event { t: 100 * MS, signal: a4, value: true }).unwrap();
//! let csv = writer.finish().unwrap();
//! assert_eq!(csv, b"t,signal,value\n0,C4,1\n0,A4,0\n100,A4,1\n");
//!
//! let choice = TimeFormatChoice::Detect(TimeUnit::Ms);
//! let log = read_events_from(&csv[..], Path::new("mem.csv"), &signals, choice).unwrap();
//! assert_eq!(log.initial, vec![true, false]);
//! assert_eq!(log.events, vec![Event { t: 100 * MS, signal: a4, value: true }]);
//! ```

pub mod candump;
pub mod csv;
mod detect;
pub mod events;
pub mod intervals;
mod many;
#[cfg(feature = "parquet")]
pub mod parquet;
mod plain;
mod rows;
pub mod scans;
mod spool;
mod stream;
mod threaded;
pub mod vcd;

pub use detect::detect_format;
pub use events::{EventChanges, EventReader, EventWriter, read_events, read_events_from};
pub use intervals::{
    Interval, IntervalChanges, IntervalReader, IntervalWriter, read_intervals_as_events,
    read_intervals_as_events_from,
};
pub use many::{LOG_ENDINGS, OpenAhead, expand_dirs, open_ahead};
#[cfg(feature = "parquet")]
pub use parquet::{
    ParquetCells, ParquetColumn, ParquetCompression, ParquetLayout, write_intervals_parquet,
    write_parquet_table,
};
pub use rows::{CellKind, Records};
pub use scans::{
    ScanChanges, ScanReader, ScanWriter, read_scans_as_events, read_scans_as_events_from,
};
pub use stream::{Batches, IngestOptions, LogEnd, LogFormat, LogStream, open};

use vocabulary::{Event, Located, Time, TimeFormat, TimeUnit};

/// How a reader learns the representation of a log's timestamps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeFormatChoice {
    /// Use this representation.
    Given(TimeFormat),
    /// Detect it from the first data row with [`TimeFormat::detect`]: RFC 3339 if
    /// the first timestamp is RFC 3339 text, numbers in this unit otherwise.
    Detect(TimeUnit),
}

/// A tabular log read as its opening values, then its changes scan by scan,
/// in memory that does not grow with the log ([`EventChanges`],
/// [`IntervalChanges`], [`ScanChanges`]).
pub trait Changes {
    /// The log's first time.
    fn start(&self) -> Time;
    /// Every signal's value at the first time.
    fn initial(&self) -> &[bool];
    /// How the log writes its times.
    fn format(&self) -> TimeFormat;
    /// Appends the changes of at least one more time to `out`, sorted by time
    /// then signal; `Ok(false)` at the end of the log.
    fn read_scan(&mut self, out: &mut Vec<Event>) -> Result<bool, Located>;
    /// The end the log declares, once its last scan is read.
    fn end(&self) -> Option<Time> {
        None
    }

    /// Every change, in memory: the whole log.
    fn into_log(mut self) -> Result<EventLog, Located>
    where
        Self: Sized,
    {
        let mut events = Vec::new();
        while self.read_scan(&mut events)? {}
        Ok(EventLog {
            format: self.format(),
            start: self.start(),
            initial: self.initial().to_vec(),
            events,
            end: self.end(),
        })
    }
}

/// A whole log, whatever its form: initial values and the changes that follow.
///
/// Reading the same recording from any of the three forms gives the same value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EventLog {
    /// How the log wrote its timestamps (outputs reuse it).
    pub format: TimeFormat,
    /// The first timestamp: the time of the initial values.
    pub start: Time,
    /// Value of every signal at `start`, indexed by [`SignalId::index`](crate::SignalId::index).
    pub initial: Vec<bool>,
    /// The changes after `start`: only real changes (a signal's value differs from
    /// its previous one), sorted by time then signal id, at most one per signal and
    /// time.
    pub events: Vec<Event>,
    /// When the recording ended, if the log says so (the events form's end row):
    /// no change between the last event and then.
    pub end: Option<Time>,
}
