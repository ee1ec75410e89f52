//! The events form (long): `t,signal,value`, one row per change of one signal.
//!
//! This is the form the simulator writes and the diagnoser replays: it is as long as
//! the number of changes, not of scans, and rows can be streamed as the plant runs.
//! Rows with equal `t` belong to one PLC scan. The log opens with one row per signal
//! at its first timestamp, giving the initial values; `value` is `0`, `1`, `true`
//! or `false` (any case). Optional columns `site`, `seq` and `quality` may appear
//! anywhere in the header; their content is ignored.
//!
//! A log may say when its recording ended with a last *end row*: a time, with the
//! signal and the value left empty. Every signal kept its value until then, so
//! deadlines that passed between the last change and the end count. Without it,
//! the log ends at its last row.
//!
//! ```text
//! t,signal,value
//! 0,C4,1
//! 0,C5,0
//! 0,A4,0
//! 100,A4,1
//! 110,C4,0
//! 2000,,
//! ```

use std::io::{self, BufRead, BufWriter, Write};
use std::path::Path;

use vocabulary::{Event, Located, Location, SignalTable, Time, TimeFormat, TimeUnit};

use crate::csv::{self, CsvRecords, TimeText};
use crate::plain::{self, SignalNames};
use crate::rows::{self, CellKind, Records, Rows, State, TimeParser};
use crate::{Changes, EventLog, TimeFormatChoice};

/// The header the writer writes.
const HEADER: &str = "t,signal,value";
/// Required columns, in the order of [`EventReader::columns`].
const REQUIRED: [&str; 3] = ["t", "signal", "value"];
/// Accepted and ignored columns.
const OPTIONAL: [&str; 3] = ["site", "seq", "quality"];
/// What a header must contain, for messages.
const EXPECTED: &str = "t,signal,value and optionally site, seq, quality";

/// Writes an events log: the header, the initial values, then one row per event.
///
/// Output is buffered; call [`EventWriter::finish`] to flush it and see errors.
pub struct EventWriter<W: Write> {
    out: BufWriter<W>,
    names: Vec<String>,
    time: TimeText,
}

impl<W: Write> EventWriter<W> {
    /// Writes the header `t,signal,value` to `w`; timestamps will be written in
    /// `format`. Fails if a signal name cannot be written as a plain CSV field.
    pub fn new(w: W, signals: &SignalTable, format: TimeFormat) -> io::Result<Self> {
        let names = csv::plain_names(signals)?;
        let mut out = BufWriter::with_capacity(csv::WRITE_BUFFER, w);
        out.write_all(HEADER.as_bytes())?;
        out.write_all(b"\n")?;
        Ok(EventWriter {
            out,
            names,
            time: TimeText::new(format),
        })
    }

    /// Writes the opening rows: one per signal, in table order, all at `t`.
    /// `values` is indexed by [`SignalId::index`](crate::SignalId::index).
    pub fn write_initial(&mut self, t: Time, values: &[bool]) -> io::Result<()> {
        if values.len() != self.names.len() {
            return Err(csv::wrong_initial(values.len(), self.names.len()));
        }
        for (i, &value) in values.iter().enumerate() {
            self.row(t, i, value)?;
        }
        Ok(())
    }

    /// Writes one change. The writer does not check that the value changed or
    /// that time does not go backwards; readers do.
    pub fn write(&mut self, event: &Event) -> io::Result<()> {
        let i = event.signal.index();
        if i >= self.names.len() {
            return Err(csv::no_signal(event.signal));
        }
        self.row(event.t, i, event.value)
    }

    /// Writes the end row: the recording ended at `t`, with no change since the
    /// last row. It must be the last row written.
    pub fn write_end(&mut self, t: Time) -> io::Result<()> {
        self.out.write_all(self.time.get(t).as_bytes())?;
        self.out.write_all(b",,\n")
    }

    fn row(&mut self, t: Time, i: usize, value: bool) -> io::Result<()> {
        let name = self.names.get(i).map_or("", String::as_str);
        self.out.write_all(self.time.get(t).as_bytes())?;
        self.out.write_all(b",")?;
        self.out.write_all(name.as_bytes())?;
        self.out.write_all(b",")?;
        self.out.write_all(csv::bit(value))?;
        self.out.write_all(b"\n")
    }

    /// Flushes the output and returns the inner writer.
    pub fn finish(self) -> io::Result<W> {
        csv::into_inner(self.out)
    }
}

/// Reads an events log row by row: an iterator of the rows as [`Event`]s.
///
/// It yields every row, opening rows and repeated values included (see
/// [`read_events`] for the checked [`EventLog`]). It checks the header, the number
/// of fields, times (which must not go backwards), values and signal names, and
/// stops after the first error. Memory does not grow with the log. An end row is
/// not yielded: it ends the iteration, and [`EventReader::end`] gives its time.
pub struct EventReader<'a, S> {
    rows: Rows<S>,
    signals: &'a SignalTable,
    /// Positions of `t`, `signal` and `value`.
    columns: [usize; 3],
    width: usize,
    time: TimeParser,
    state: State,
    previous: Option<(Time, usize)>,
    end: Option<Time>,
    /// How rows written plainly read (see [`PlainEvents`]), when the header
    /// is `t,signal,value` and times are numbers.
    plain: Option<PlainEvents>,
}

/// A row written `t,signal,value` plainly: a decimal time in the log's unit,
/// a signal name as the plant spells it, `0` or `1`. Rows like this make up
/// nearly every events log, and read without their fields; any other row
/// (quotes, spaces, fractions, an end row, an unknown signal, ...) is read
/// field by field, with the messages of the form.
struct PlainEvents {
    names: SignalNames,
    nanos: Time,
}

impl PlainEvents {
    /// The event of the row at the start of `row` and the length of its line,
    /// if it is written plainly and not before `not_before`.
    #[inline(always)]
    fn read(&self, row: &[u8], not_before: Time) -> Option<(Event, usize)> {
        let (t, digits) = plain::time(row, self.nanos)?;
        let rest = row.get(digits..)?.strip_prefix(b",")?;
        let (signal, length) = self.names.prefix(rest)?;
        let value = plain::bit(&rest[length + 1..])?;
        // Time going backwards is for the fields' reading to say.
        (t >= not_before).then_some((Event { t, signal, value }, digits + length + 3))
    }
}

impl<'a, R: BufRead> EventReader<'a, CsvRecords<R>> {
    /// Reads and checks the header, then the first data row (to detect the time
    /// representation if asked to). `path` is only used in error messages.
    pub fn new(
        reader: R,
        path: &Path,
        signals: &'a SignalTable,
        time: TimeFormatChoice,
    ) -> Result<Self, Located> {
        Self::from_records(CsvRecords::new(reader, path), signals, time)
    }
}

impl<'a, S: Records> EventReader<'a, S> {
    /// The same over the records of any container (a CSV file, a Parquet file).
    pub fn from_records(
        records: S,
        signals: &'a SignalTable,
        time: TimeFormatChoice,
    ) -> Result<Self, Located> {
        let mut rows = Rows::new(records);
        rows.read_header(HEADER)?;
        let positions = rows.map_columns(&REQUIRED, &OPTIONAL, EXPECTED)?;
        let columns = [positions[0], positions[1], positions[2]];
        let width = rows.len();
        let mut time = TimeParser::new(time);
        let kinds = [CellKind::Time, CellKind::Signal, CellKind::Value];
        rows.check_kinds(&[0, 1, 2].map(|k| (columns[k], kinds[k])), time.unit())?;
        let state = if rows.next_record()? {
            time.detect(rows.field(columns[0]));
            State::Pending
        } else {
            State::Done
        };
        let plain = match time.format() {
            TimeFormat::Numeric(unit) if columns == [0, 1, 2] && width == 3 => Some(PlainEvents {
                names: SignalNames::new(signals),
                nanos: unit.nanos(),
            }),
            _ => None,
        };
        Ok(EventReader {
            rows,
            signals,
            columns,
            width,
            time,
            state,
            previous: None,
            end: None,
            plain,
        })
    }

    /// The time representation: given, or detected from the first data row
    /// (numbers in the given unit if there is none).
    pub fn format(&self) -> TimeFormat {
        self.time.format()
    }

    /// Line (from 1) of the last row read.
    pub fn line(&self) -> usize {
        self.rows.line_no()
    }

    /// The time of the log's end row, once the reader has reached it.
    pub fn end(&self) -> Option<Time> {
        self.end
    }

    /// Whether the current row is an end row (empty signal and value).
    fn at_end_row(&self) -> bool {
        let [_, signal_col, value_col] = self.columns;
        self.rows.is_blank(signal_col) && self.rows.is_blank(value_col)
    }

    /// Reads the end row's time; no row may follow it.
    fn read_end(&mut self) -> Result<(), Located> {
        let t = self.checked_time()?;
        let line = self.rows.line_no();
        if self.rows.next_record()? {
            let message = format!(
                "a row after the end row on line {line}: the end row (a time with no signal and no value) must be the last"
            );
            return Err(self.rows.error(1, None, message));
        }
        self.end = Some(t);
        Ok(())
    }

    /// The current row's time, which must not go backwards.
    fn checked_time(&mut self) -> Result<Time, Located> {
        let rows = &self.rows;
        let t_col = self.columns[0];
        rows.check_width(self.width)?;
        let t = self.time.parse(rows, t_col, "t")?;
        if let Some((previous, line)) = self.previous
            && t < previous
        {
            let message = rows::backwards(
                rows.field(t_col),
                &self.time.format().format(previous),
                line,
            );
            return Err(rows.field_error(t_col, "t", message));
        }
        Ok(t)
    }

    fn parse_row(&mut self) -> Result<Event, Located> {
        let t = self.checked_time()?;
        let rows = &self.rows;
        let [_, signal_col, value_col] = self.columns;
        let signal = rows.signal(signal_col, "signal", self.signals)?;
        let value = rows.value(value_col, "value")?;
        self.previous = Some((t, rows.line_no()));
        Ok(Event { t, signal, value })
    }

    /// The next row if it is written plainly (see [`PlainEvents`]), read
    /// straight from its line; `None`, having read nothing, otherwise.
    #[inline(always)]
    fn next_plain(&mut self) -> Option<Event> {
        let plain = self
            .plain
            .as_ref()
            .filter(|_| self.state == State::Reading)?;
        let not_before = self.previous.map_or(Time::MIN, |(t, _)| t);
        let (event, length) = plain.read(self.rows.unread(), not_before)?;
        if !self.rows.read_plain(length) {
            return None;
        }
        self.previous = Some((event.t, self.rows.line_no()));
        Some(event)
    }

    /// The error for the last row read, `event`, giving its signal another value
    /// than the row on line `earlier` at the same time.
    #[cold]
    fn conflict(&mut self, event: Event, earlier: usize) -> Located {
        self.rows.settle();
        let message = format!(
            "conflicting values for signal '{}' at time {}: line {earlier} gives the other value",
            self.signals.name(event.signal),
            self.rows.field(self.columns[0])
        );
        self.rows.field_error(self.columns[2], "value", message)
    }
}

impl<S: Records> Iterator for EventReader<'_, S> {
    type Item = Result<Event, Located>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(event) = self.next_plain() {
            return Some(Ok(event));
        }
        if let Err(e) = self.state.advance(&mut self.rows)? {
            return Some(Err(e));
        }
        if self.at_end_row() {
            self.state = State::Done;
            return self.read_end().err().map(Err);
        }
        let row = self.parse_row();
        if row.is_err() {
            self.state = State::Done;
        }
        Some(row)
    }
}

/// Reads an events log file into an [`EventLog`], detecting the time
/// representation (numbers in `unit`, or RFC 3339 text).
pub fn read_events(
    path: &Path,
    signals: &SignalTable,
    unit: TimeUnit,
) -> Result<EventLog, Located> {
    read_events_from(
        rows::open(path)?,
        path,
        signals,
        TimeFormatChoice::Detect(unit),
    )
}

/// Reads an events log from `reader` into an [`EventLog`]; `path` is only used in
/// error messages.
///
/// The opening rows (all rows at the first timestamp) must give every signal its
/// initial value. Later rows that repeat a signal's value are dropped; two rows
/// giving one signal different values at one time are an error.
pub fn read_events_from<R: BufRead>(
    reader: R,
    path: &Path,
    signals: &SignalTable,
    time: TimeFormatChoice,
) -> Result<EventLog, Located> {
    EventChanges::open(EventReader::new(reader, path, signals, time)?)?.into_log()
}

/// An events log as its initial values, then its changes scan by scan: the
/// rules of [`read_events_from`], in memory that does not grow with the log.
pub struct EventChanges<'a, S> {
    rows: EventReader<'a, S>,
    start: Time,
    initial: Vec<bool>,
    current: Vec<bool>,
    /// The time and line of each signal's last row.
    last: Vec<(Time, usize)>,
    /// The first row of the next scan, read ahead.
    next: Option<Event>,
}

impl<'a, S: Records> EventChanges<'a, S> {
    /// Reads the opening rows: every signal needs one, and no signal two values.
    pub fn open(mut rows: EventReader<'a, S>) -> Result<Self, Located> {
        let n = rows.signals.len();
        let first_line = rows.line();
        let Some(first) = rows.next().transpose()? else {
            return Err(rows::no_data(rows.rows.path()));
        };
        let start = first.t;
        let mut initial: Vec<Option<bool>> = vec![None; n];
        let mut last: Vec<(Time, usize)> = vec![(start, first_line); n];
        let mut next = Some(first);
        while let Some(event) = next.take_if(|e| e.t == start) {
            let i = event.signal.index();
            if initial[i].is_some_and(|value| value != event.value) {
                return Err(rows.conflict(event, last[i].1));
            }
            initial[i] = Some(event.value);
            last[i] = (event.t, rows.line());
            next = rows.next().transpose()?;
        }
        let missing: Vec<&str> = (rows.signals.iter())
            .filter(|(id, _)| initial[id.index()].is_none())
            .map(|(_, s)| s.name.as_str())
            .collect();
        if !missing.is_empty() {
            let s = if missing.len() > 1 { "s" } else { "" };
            let message = format!(
                "no initial value for signal{s} {}: the log must open with one row per signal at its first time {}",
                rows::quote_list(missing),
                rows.format().format(start)
            );
            let location = Location::new(rows.rows.path(), first_line, 0);
            return Err(Located::new(location, message));
        }
        let initial: Vec<bool> = initial.into_iter().map(|v| v.unwrap_or(false)).collect();
        Ok(EventChanges {
            rows,
            start,
            current: initial.clone(),
            initial,
            last,
            next,
        })
    }
}

impl<S: Records> Changes for EventChanges<'_, S> {
    fn start(&self) -> Time {
        self.start
    }

    fn initial(&self) -> &[bool] {
        &self.initial
    }

    fn format(&self) -> TimeFormat {
        self.rows.format()
    }

    fn end(&self) -> Option<Time> {
        self.rows.end()
    }

    /// Appends the changes of the next scan (its rows at one time) to `out`,
    /// sorted by signal; `Ok(false)` at the end of the log.
    fn read_scan(&mut self, out: &mut Vec<Event>) -> Result<bool, Located> {
        let first = match self.next.take() {
            Some(event) => event,
            None => match self.rows.next() {
                Some(row) => row?,
                None => return Ok(false),
            },
        };
        let from = out.len();
        self.take(first, out)?;
        loop {
            let event = match self.rows.next_plain() {
                Some(event) => event,
                None => match self.rows.next() {
                    Some(row) => row?,
                    None => break,
                },
            };
            if event.t != first.t {
                self.next = Some(event);
                break;
            }
            self.take(event, out)?;
        }
        out[from..].sort_unstable_by_key(|e| e.signal);
        Ok(true)
    }
}

impl<S: Records> EventChanges<'_, S> {
    /// Takes the last row read, `event`, into its scan: a change goes to `out`.
    #[inline(always)]
    fn take(&mut self, event: Event, out: &mut Vec<Event>) -> Result<(), Located> {
        let i = event.signal.index();
        if event.value != self.current[i] {
            if self.last[i].0 == event.t {
                return Err(self.rows.conflict(event, self.last[i].1));
            }
            self.current[i] = event.value;
            out.push(event);
        }
        self.last[i] = (event.t, self.rows.line());
        Ok(())
    }
}
