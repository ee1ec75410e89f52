//! The intervals form: `signal,value,t_start,t_end`, one row per maximal interval
//! during which a signal held a value.
//!
//! This is the archive form: a signal that rarely changes costs a row per change,
//! whatever the scan rate, and a file can be cut at any point without losing what
//! the signals were doing. `t_end` empty means the interval is still open (the
//! recording ended, or is still running). Each signal's intervals are contiguous
//! (an interval starts where the previous one ends), alternate in value, start at
//! the log's first time, and only the last one may be open. Rows of different
//! signals may interleave in any way, but each signal's rows come in time order.
//!
//! ```text
//! signal,value,t_start,t_end
//! A4,0,0,100
//! C4,1,0,110
//! C5,0,0,
//! C4,0,110,
//! A4,1,100,
//! ```

use std::io::{self, BufRead, BufWriter, Write};
use std::path::Path;

use super::csv::{self, CsvReader, State, TimeParser, TimeText};
use super::{EventLog, TimeFormatChoice};
use crate::error::{Located, Location};
use crate::signal::{Event, SignalId, SignalTable};
use crate::time::{Time, TimeFormat, TimeUnit};

/// The header the writer writes.
const HEADER: &str = "signal,value,t_start,t_end";
/// Required columns, in the order of [`IntervalReader::columns`].
const REQUIRED: [&str; 4] = ["signal", "value", "t_start", "t_end"];

/// One maximal interval of constant value of one signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Interval {
    /// The signal.
    pub signal: SignalId,
    /// The value it held.
    pub value: bool,
    /// When the interval started (a change, or the start of the log).
    pub start: Time,
    /// When it ended (the next change, or the end of the recording); `None` while
    /// open.
    pub end: Option<Time>,
}

/// Writes an intervals log as the changes stream in: a row each time a signal's
/// interval closes, and the still-open intervals at the end.
///
/// Memory does not grow with the number of events (one open interval per
/// signal). Output is buffered; call [`IntervalWriter::finish`] to write the open
/// intervals, flush and see errors.
pub struct IntervalWriter<W: Write> {
    out: BufWriter<W>,
    names: Vec<String>,
    /// Each signal's open interval: value and start.
    open: Vec<Option<(bool, Time)>>,
    start_text: TimeText,
    end_text: TimeText,
}

impl<W: Write> IntervalWriter<W> {
    /// Writes the header `signal,value,t_start,t_end` to `w`; timestamps will be
    /// written in `format`. Fails if a signal name cannot be written as a plain CSV
    /// field.
    pub fn new(w: W, signals: &SignalTable, format: TimeFormat) -> io::Result<Self> {
        let names = csv::plain_names(signals)?;
        let mut out = BufWriter::with_capacity(csv::WRITE_BUFFER, w);
        out.write_all(HEADER.as_bytes())?;
        out.write_all(b"\n")?;
        Ok(IntervalWriter {
            out,
            open: vec![None; names.len()],
            names,
            start_text: TimeText::new(format),
            end_text: TimeText::new(format),
        })
    }

    /// Opens one interval per signal at `t` with its initial value. `values` is
    /// indexed by [`SignalId::index`](crate::SignalId::index). Writes nothing yet.
    pub fn write_initial(&mut self, t: Time, values: &[bool]) -> io::Result<()> {
        if values.len() != self.names.len() {
            return Err(csv::invalid_input(format!(
                "{} initial values for {} signals",
                values.len(),
                self.names.len()
            )));
        }
        if self.open.iter().any(Option::is_some) {
            return Err(csv::invalid_input(
                "initial values already written".to_string(),
            ));
        }
        for (open, &value) in self.open.iter_mut().zip(values) {
            *open = Some((value, t));
        }
        Ok(())
    }

    /// Records a change: writes the row of the signal's open interval, closed at
    /// `event.t`, and opens a new one. An event that repeats the signal's value
    /// changes nothing. Fails on an unknown signal, before
    /// [`IntervalWriter::write_initial`], or if `event.t` is before the start of
    /// the open interval.
    pub fn write(&mut self, event: &Event) -> io::Result<()> {
        let i = event.signal.index();
        let Some(open) = self.open.get_mut(i) else {
            return Err(csv::invalid_input(format!(
                "no signal with id {}",
                event.signal.0
            )));
        };
        let Some((value, start)) = *open else {
            return Err(csv::invalid_input(
                "event written before the initial values".to_string(),
            ));
        };
        if value == event.value {
            return Ok(());
        }
        if event.t < start {
            return Err(csv::invalid_input(format!(
                "event at {} before the start {start} of the open interval",
                event.t
            )));
        }
        *open = Some((event.value, event.t));
        self.row(i, value, start, Some(event.t))
    }

    fn row(&mut self, i: usize, value: bool, start: Time, end: Option<Time>) -> io::Result<()> {
        let name = self.names.get(i).map_or("", String::as_str);
        self.out.write_all(name.as_bytes())?;
        self.out.write_all(b",")?;
        self.out.write_all(csv::bit(value))?;
        self.out.write_all(b",")?;
        self.out.write_all(self.start_text.get(start).as_bytes())?;
        self.out.write_all(b",")?;
        if let Some(end) = end {
            self.out.write_all(self.end_text.get(end).as_bytes())?;
        }
        self.out.write_all(b"\n")
    }

    /// Writes the still-open intervals (empty `t_end`) in signal-table order,
    /// flushes the output and returns the inner writer.
    pub fn finish(mut self) -> io::Result<W> {
        for i in 0..self.open.len() {
            if let Some((value, start)) = self.open[i] {
                self.row(i, value, start, None)?;
            }
        }
        csv::into_inner(self.out)
    }
}

/// What a reader remembers of a signal's last interval.
#[derive(Debug, Clone, Copy)]
struct Last {
    value: bool,
    end: Option<Time>,
    line: usize,
}

/// Reads an intervals log row by row: an iterator of [`Interval`]s.
///
/// It checks the header, the number of fields, signal names, values and times,
/// that `t_end >= t_start`, that each signal's intervals are contiguous, alternate
/// in value and start at the log's first time, that only a signal's last interval
/// is open, and, at the end, that every signal appeared. It stops after the first
/// error. Memory grows with the number of signals, not of rows.
pub struct IntervalReader<'a, R> {
    csv: CsvReader<R>,
    signals: &'a SignalTable,
    /// Positions of `signal`, `value`, `t_start` and `t_end`.
    columns: [usize; 4],
    width: usize,
    time: TimeParser,
    state: State,
    /// Whether the end-of-input check is done (or moot after an error).
    end_checked: bool,
    /// The log's first time and the line of its first row.
    start: Option<(Time, usize)>,
    last: Vec<Option<Last>>,
}

impl<'a, R: BufRead> IntervalReader<'a, R> {
    /// Reads and checks the header, then the first data row (to detect the time
    /// representation if asked to). `path` is only used in error messages.
    pub fn new(
        reader: R,
        path: &Path,
        signals: &'a SignalTable,
        time: TimeFormatChoice,
    ) -> Result<Self, Located> {
        let mut csv = CsvReader::new(reader, path);
        csv.read_header(HEADER)?;
        let positions = csv.map_columns(&REQUIRED, &[], HEADER)?;
        let columns = [positions[0], positions[1], positions[2], positions[3]];
        let width = csv.len();
        let mut time = TimeParser::new(time);
        let state = if csv.next_record()? {
            time.detect(csv.field(columns[2]));
            State::Pending
        } else {
            State::Reading
        };
        Ok(IntervalReader {
            csv,
            signals,
            columns,
            width,
            time,
            state,
            end_checked: false,
            start: None,
            last: vec![None; signals.len()],
        })
    }

    /// The time representation: given, or detected from the first data row
    /// (numbers in the given unit if there is none).
    pub fn format(&self) -> TimeFormat {
        self.time.format()
    }

    /// Line (from 1) of the last row read.
    pub fn line(&self) -> usize {
        self.csv.line_no()
    }

    fn parse_row(&mut self) -> Result<Interval, Located> {
        let csv = &self.csv;
        let [signal_col, value_col, start_col, end_col] = self.columns;
        let line = csv.line_no();
        csv.check_width(self.width)?;
        let signal = csv.signal(signal_col, "signal", self.signals)?;
        let name = self.signals.name(signal);
        let value = csv.value(value_col, "value")?;
        let start = self.time.parse(csv, start_col, "t_start")?;
        let end = if csv.field(end_col).is_empty() {
            None
        } else {
            let end = self.time.parse(csv, end_col, "t_end")?;
            if end < start {
                let message = format!(
                    "interval ends before it starts: t_end {} is before t_start {}",
                    csv.field(end_col),
                    csv.field(start_col)
                );
                return Err(csv.field_error(end_col, "t_end", message));
            }
            Some(end)
        };
        let format = self.time.format();
        let slot = &mut self.last[signal.index()];
        match *slot {
            None => match self.start {
                None => self.start = Some((start, line)),
                Some((log_start, first_line)) if log_start != start => {
                    let message = format!(
                        "the first interval of signal '{name}' starts at {}, not at the log's first time {} (line {first_line})",
                        csv.field(start_col),
                        format.format(log_start)
                    );
                    return Err(csv.field_error(start_col, "t_start", message));
                }
                Some(_) => {}
            },
            Some(last) => {
                let Some(previous_end) = last.end else {
                    let message = format!(
                        "signal '{name}' already has an open interval on line {}: only its last interval may be open",
                        last.line
                    );
                    return Err(csv.field_error(signal_col, "signal", message));
                };
                if previous_end != start {
                    let message = format!(
                        "interval of signal '{name}' starts at {} but its previous interval (line {}) ends at {}",
                        csv.field(start_col),
                        last.line,
                        format.format(previous_end)
                    );
                    return Err(csv.field_error(start_col, "t_start", message));
                }
                if last.value == value {
                    let message = format!(
                        "signal '{name}' holds {} in two consecutive intervals (lines {} and {line}): intervals must be maximal",
                        u8::from(value),
                        last.line
                    );
                    return Err(csv.field_error(value_col, "value", message));
                }
            }
        }
        *slot = Some(Last { value, end, line });
        Ok(Interval {
            signal,
            value,
            start,
            end,
        })
    }

    /// At the end of the input: the error naming the signals that had no interval.
    fn missing_signals(&self) -> Option<Located> {
        let missing: Vec<&str> = self
            .signals
            .iter()
            .filter(|(id, _)| self.last[id.index()].is_none())
            .map(|(_, s)| s.name.as_str())
            .collect();
        if missing.is_empty() || self.start.is_none() {
            return None;
        }
        let s = if missing.len() > 1 { "s" } else { "" };
        let message = format!(
            "no interval for signal{s} {}: every signal must appear",
            csv::quote_list(missing)
        );
        Some(Located::new(Location::new(self.csv.path(), 0, 0), message))
    }
}

impl<R: BufRead> Iterator for IntervalReader<'_, R> {
    type Item = Result<Interval, Located>;

    fn next(&mut self) -> Option<Self::Item> {
        match self.state.advance(&mut self.csv) {
            None => {
                if std::mem::replace(&mut self.end_checked, true) {
                    None
                } else {
                    self.missing_signals().map(Err)
                }
            }
            Some(Err(e)) => {
                self.end_checked = true;
                Some(Err(e))
            }
            Some(Ok(())) => {
                let row = self.parse_row();
                if row.is_err() {
                    self.state = State::Done;
                    self.end_checked = true;
                }
                Some(row)
            }
        }
    }
}

/// Reads an intervals log file into the [`EventLog`] the events form would give,
/// detecting the time representation (numbers in `unit`, or RFC 3339 text).
pub fn read_intervals_as_events(
    path: &Path,
    signals: &SignalTable,
    unit: TimeUnit,
) -> Result<EventLog, Located> {
    read_intervals_as_events_from(
        csv::open(path)?,
        path,
        signals,
        TimeFormatChoice::Detect(unit),
    )
}

/// Reads an intervals log from `reader` into the [`EventLog`] the events form would
/// give; `path` is only used in error messages.
///
/// Initial values are the values of each signal's first interval; every later
/// interval start is a change. Zero-length intervals are glitches shorter than the
/// time resolution: only the value after them counts.
pub fn read_intervals_as_events_from<R: BufRead>(
    reader: R,
    path: &Path,
    signals: &SignalTable,
    time: TimeFormatChoice,
) -> Result<EventLog, Located> {
    let mut reader = IntervalReader::new(reader, path, signals, time)?;
    let n = signals.len();
    let mut start = None;
    let mut initial: Vec<Option<bool>> = vec![None; n];
    // Each signal's value as of its last emitted change, and the change not yet
    // emitted because a zero-length interval may still cancel it.
    let mut current = vec![false; n];
    let mut pending: Vec<Option<(Time, bool)>> = vec![None; n];
    let mut events = Vec::new();
    for interval in &mut reader {
        let Interval {
            signal,
            value,
            start: t,
            ..
        } = interval?;
        let i = signal.index();
        let log_start = *start.get_or_insert(t);
        if initial[i].is_none() || t == log_start {
            initial[i] = Some(value);
            current[i] = value;
            continue;
        }
        match pending[i] {
            Some((at, _)) if at == t => {}
            Some((at, v)) => {
                events.push(Event {
                    t: at,
                    signal,
                    value: v,
                });
                current[i] = v;
            }
            None => {}
        }
        pending[i] = (value != current[i]).then_some((t, value));
    }
    let Some(start) = start else {
        return Err(csv::no_data(path));
    };
    for (i, change) in pending.iter().enumerate() {
        if let Some((t, value)) = *change {
            events.push(Event {
                t,
                signal: SignalId(i as u32),
                value,
            });
        }
    }
    events.sort_unstable_by_key(|e| (e.t, e.signal));
    let Some(initial) = initial.into_iter().collect::<Option<Vec<bool>>>() else {
        // The reader already reported missing signals; this is only a safeguard.
        return Err(csv::no_data(path));
    };
    Ok(EventLog {
        format: reader.format(),
        start,
        initial,
        events,
        end: None,
    })
}
