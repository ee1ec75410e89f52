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

use vocabulary::{Event, Located, Location, SignalId, SignalTable, Time, TimeFormat, TimeUnit};

use crate::csv::{self, CsvRecords, TimeText};
use crate::rows::{self, CellKind, Records, Rows, State, TimeParser};
use crate::{Changes, EventLog, TimeFormatChoice};

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
            return Err(csv::wrong_initial(values.len(), self.names.len()));
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
            return Err(csv::no_signal(event.signal));
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

/// The rules that tie each signal's intervals together, row after row:
/// contiguous, alternating, starting at the log's first time, only the last
/// one open. Both readers of the form apply them: [`IntervalReader`] row by
/// row, and the Parquet reader column by column.
pub(crate) struct Rules {
    /// The log's first time and the line of its first row.
    start: Option<(Time, usize)>,
    last: Vec<Option<Last>>,
}

/// How a row breaks [`Rules`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Broken {
    /// The signal's first interval starts after the log's first time, given by
    /// the row on `first_line`.
    LateFirst { log_start: Time, first_line: usize },
    /// The signal's interval on `line` is still open.
    StillOpen { line: usize },
    /// The interval does not start where the signal's previous one, on
    /// `line`, ends.
    Gap { line: usize, previous_end: Time },
    /// The interval holds the value of the signal's previous one, on `line`.
    NotMaximal { line: usize },
}

impl Rules {
    /// Rules for a log of `n` signals, before its first row.
    pub(crate) fn new(n: usize) -> Rules {
        Rules {
            start: None,
            last: vec![None; n],
        }
    }

    /// Takes the interval of the row on `line`, or says which rule it breaks.
    #[inline]
    pub(crate) fn check(&mut self, interval: &Interval, line: usize) -> Result<(), Broken> {
        let Some(slot) = self.last.get_mut(interval.signal.index()) else {
            return Ok(());
        };
        match *slot {
            None => match self.start {
                None => self.start = Some((interval.start, line)),
                Some((log_start, first_line)) if log_start != interval.start => {
                    return Err(Broken::LateFirst {
                        log_start,
                        first_line,
                    });
                }
                Some(_) => {}
            },
            Some(last) => {
                let Some(previous_end) = last.end else {
                    return Err(Broken::StillOpen { line: last.line });
                };
                if previous_end != interval.start {
                    return Err(Broken::Gap {
                        line: last.line,
                        previous_end,
                    });
                }
                if last.value == interval.value {
                    return Err(Broken::NotMaximal { line: last.line });
                }
            }
        }
        *slot = Some(Last {
            value: interval.value,
            end: interval.end,
            line,
        });
        Ok(())
    }

    /// Whether every signal has had an interval, or no row was read.
    pub(crate) fn complete(&self) -> bool {
        self.start.is_none() || self.last.iter().all(Option::is_some)
    }
}

/// Reads an intervals log row by row: an iterator of [`Interval`]s.
///
/// It checks the header, the number of fields, signal names, values and times,
/// that `t_end >= t_start`, that each signal's intervals are contiguous, alternate
/// in value and start at the log's first time, that only a signal's last interval
/// is open, and, at the end, that every signal appeared. It stops after the first
/// error. Memory grows with the number of signals, not of rows.
pub struct IntervalReader<'a, S> {
    rows: Rows<S>,
    signals: &'a SignalTable,
    /// Positions of `signal`, `value`, `t_start` and `t_end`.
    columns: [usize; 4],
    width: usize,
    time: TimeParser,
    state: State,
    /// Whether the end-of-input check is done (or moot after an error).
    end_checked: bool,
    rules: Rules,
}

impl<'a, R: BufRead> IntervalReader<'a, CsvRecords<R>> {
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

impl<'a, S: Records> IntervalReader<'a, S> {
    /// The same over the records of any container (a CSV file, a Parquet file).
    pub fn from_records(
        records: S,
        signals: &'a SignalTable,
        time: TimeFormatChoice,
    ) -> Result<Self, Located> {
        let mut rows = Rows::new(records);
        rows.read_header(HEADER)?;
        let positions = rows.map_columns(&REQUIRED, &[], HEADER)?;
        let columns = [positions[0], positions[1], positions[2], positions[3]];
        let width = rows.len();
        let mut time = TimeParser::new(time);
        let kinds = [
            CellKind::Signal,
            CellKind::Value,
            CellKind::Time,
            CellKind::Time,
        ];
        rows.check_kinds(&[0, 1, 2, 3].map(|k| (columns[k], kinds[k])), time.unit())?;
        let state = if rows.next_record()? {
            time.detect(rows.field(columns[2]));
            State::Pending
        } else {
            State::Reading
        };
        Ok(IntervalReader {
            rows,
            signals,
            columns,
            width,
            time,
            state,
            end_checked: false,
            rules: Rules::new(signals.len()),
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

    fn parse_row(&mut self) -> Result<Interval, Located> {
        let rows = &self.rows;
        let [signal_col, value_col, start_col, end_col] = self.columns;
        let line = rows.line_no();
        rows.check_width(self.width)?;
        let signal = rows.signal(signal_col, "signal", self.signals)?;
        let value = rows.value(value_col, "value")?;
        let start = self.time.parse(rows, start_col, "t_start")?;
        let end = if rows.is_blank(end_col) {
            None
        } else {
            let end = self.time.parse(rows, end_col, "t_end")?;
            if end < start {
                let message = format!(
                    "interval ends before it starts: t_end {} is before t_start {}",
                    rows.field(end_col),
                    rows.field(start_col)
                );
                return Err(rows.field_error(end_col, "t_end", message));
            }
            Some(end)
        };
        let interval = Interval {
            signal,
            value,
            start,
            end,
        };
        match self.rules.check(&interval, line) {
            Ok(()) => Ok(interval),
            Err(broken) => Err(self.broken(broken, &interval)),
        }
    }

    /// The error for the current row, which breaks a rule of the form.
    fn broken(&self, broken: Broken, interval: &Interval) -> Located {
        let rows = &self.rows;
        let [signal_col, value_col, start_col, _] = self.columns;
        let name = self.signals.name(interval.signal);
        let line = rows.line_no();
        let format = self.time.format();
        match broken {
            Broken::LateFirst {
                log_start,
                first_line,
            } => {
                let message = format!(
                    "the first interval of signal '{name}' starts at {}, not at the log's first time {} (line {first_line})",
                    rows.field(start_col),
                    format.format(log_start)
                );
                rows.field_error(start_col, "t_start", message)
            }
            Broken::StillOpen { line: open } => {
                let message = format!(
                    "signal '{name}' already has an open interval on line {open}: only its last interval may be open"
                );
                rows.field_error(signal_col, "signal", message)
            }
            Broken::Gap {
                line: previous,
                previous_end,
            } => {
                let message = format!(
                    "interval of signal '{name}' starts at {} but its previous interval (line {previous}) ends at {}",
                    rows.field(start_col),
                    format.format(previous_end)
                );
                rows.field_error(start_col, "t_start", message)
            }
            Broken::NotMaximal { line: previous } => {
                let message = format!(
                    "signal '{name}' holds {} in two consecutive intervals (lines {previous} and {line}): intervals must be maximal",
                    u8::from(interval.value),
                );
                rows.field_error(value_col, "value", message)
            }
        }
    }

    /// At the end of the input: the error naming the signals that had no interval.
    fn missing_signals(&self) -> Option<Located> {
        let missing: Vec<&str> = self
            .signals
            .iter()
            .filter(|(id, _)| self.rules.last[id.index()].is_none())
            .map(|(_, s)| s.name.as_str())
            .collect();
        if self.rules.complete() {
            return None;
        }
        let s = if missing.len() > 1 { "s" } else { "" };
        let message = format!(
            "no interval for signal{s} {}: every signal must appear",
            rows::quote_list(missing)
        );
        Some(Located::new(Location::new(self.rows.path(), 0, 0), message))
    }
}

impl<S: Records> Iterator for IntervalReader<'_, S> {
    type Item = Result<Interval, Located>;

    fn next(&mut self) -> Option<Self::Item> {
        match self.state.advance(&mut self.rows) {
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
        rows::open(path)?,
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
/// time resolution: only the value after them counts. The rows are held in
/// memory (the reader can be read only once); [`IntervalChanges`] streams a file.
pub fn read_intervals_as_events_from<R: BufRead>(
    reader: R,
    path: &Path,
    signals: &SignalTable,
    time: TimeFormatChoice,
) -> Result<EventLog, Located> {
    let mut reader = IntervalReader::new(reader, path, signals, time)?;
    let rows: Vec<Interval> = reader.by_ref().collect::<Result<_, _>>()?;
    let survey = Survey::of(rows.iter().copied().map(Ok), signals.len(), path)?;
    let (start, initial) = (survey.start, survey.initial.clone());
    let mut unfold = Unfold::new(survey);
    let mut events = Vec::new();
    for (row, interval) in rows.into_iter().enumerate() {
        unfold.feed(row as u64, interval, &mut events);
    }
    unfold.finish(&mut events);
    Ok(EventLog {
        format: reader.format(),
        start,
        initial,
        events,
        end: None,
    })
}

/// An intervals file as its initial values, then its changes scan by scan, in
/// memory that does not grow with the log when its rows come in `t_end` order
/// (as [`IntervalWriter`] writes them) or in `t_start` order; any other order
/// costs 16 bytes per change, to sort them.
///
/// The file is read twice: a first pass checks every row and finds the
/// initial values, which come last in an archive (the open intervals of the
/// signals that never change), and the order of the rows; the second emits the
/// changes, exactly as [`read_intervals_as_events_from`] rebuilds them.
pub struct IntervalChanges<'a, S> {
    rows: IntervalReader<'a, S>,
    unfold: Unfold,
    row: u64,
    format: TimeFormat,
    path: std::path::PathBuf,
}

impl<'a, S: Records> IntervalChanges<'a, S> {
    /// Reads the first pass with one reader from `open`, and keeps a second.
    pub fn open(
        mut open: impl FnMut() -> Result<IntervalReader<'a, S>, Located>,
    ) -> Result<Self, Located> {
        let first = open()?;
        let (n, format) = (first.signals.len(), first.format());
        let path = first.rows.path().to_path_buf();
        let survey = Survey::of(first, n, &path)?;
        Ok(IntervalChanges {
            rows: open()?,
            unfold: Unfold::new(survey),
            row: 0,
            format,
            path,
        })
    }
}

impl<S: Records> Changes for IntervalChanges<'_, S> {
    fn start(&self) -> Time {
        self.unfold.start()
    }

    fn initial(&self) -> &[bool] {
        self.unfold.initial()
    }

    fn format(&self) -> TimeFormat {
        self.format
    }

    fn read_scan(&mut self, out: &mut Vec<Event>) -> Result<bool, Located> {
        let from = out.len();
        while out.len() == from {
            let Some(interval) = self.rows.next() else {
                if self.unfold.finished() {
                    return Ok(false);
                }
                self.unfold.finish(out);
                return Ok(true);
            };
            if !self.unfold.feed(self.row, interval?, out) {
                let message = "the log changed while it was being read";
                return Err(Located::new(Location::new(&self.path, 0, 0), message));
            }
            self.row += 1;
        }
        Ok(true)
    }
}

/// What the first pass over an intervals log finds.
pub(crate) struct Survey {
    start: Time,
    initial: Vec<bool>,
    /// Each signal's last row.
    last_row: Vec<u64>,
    order: Order,
}

/// How the second pass reads an intervals log, by the order of its rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Order {
    /// Closed intervals in `t_end` order: each ends with a change of its signal
    /// (unless it is the signal's last), emitted as rows come.
    ByEnd,
    /// Rows in `t_start` order: each starts with a change, emitted as rows come.
    ByStart,
    /// Any other order: the changes are collected and sorted.
    Sorted,
}

impl Survey {
    /// Reads checked intervals (an [`IntervalReader`] checks every rule of the
    /// form) for the initial values, each signal's last row and the order.
    fn of(
        intervals: impl Iterator<Item = Result<Interval, Located>>,
        n: usize,
        path: &Path,
    ) -> Result<Survey, Located> {
        let mut surveyor = Surveyor::new(n);
        for interval in intervals {
            surveyor.push(&interval?);
        }
        surveyor.finish().ok_or_else(|| rows::no_data(path))
    }
}

/// A first pass under way: what it has found so far.
pub(crate) struct Surveyor {
    start: Option<Time>,
    initial: Vec<bool>,
    last_row: Vec<u64>,
    /// Rows taken so far.
    rows: u64,
    by_end: bool,
    by_start: bool,
    previous_end: Option<Time>,
    previous_start: Option<Time>,
}

impl Surveyor {
    /// Before the first row of a log of `n` signals.
    pub(crate) fn new(n: usize) -> Surveyor {
        Surveyor {
            start: None,
            initial: vec![false; n],
            last_row: vec![u64::MAX; n],
            rows: 0,
            by_end: true,
            by_start: true,
            previous_end: None,
            previous_start: None,
        }
    }

    /// Takes the next row's interval, which obeys the form's [`Rules`].
    #[inline]
    pub(crate) fn push(&mut self, interval: &Interval) {
        let &Interval {
            signal,
            value,
            start: t,
            end,
        } = interval;
        let log_start = *self.start.get_or_insert(t);
        let i = signal.index();
        if let Some(last) = self.last_row.get_mut(i) {
            *last = self.rows;
        }
        if t == log_start
            && let Some(initial) = self.initial.get_mut(i)
        {
            *initial = value;
        }
        self.rows += 1;
        self.by_start &= self.previous_start.is_none_or(|p| t >= p);
        self.previous_start = Some(t);
        if let Some(end) = end.filter(|&e| e > log_start) {
            self.by_end &= self.previous_end.is_none_or(|p| end >= p);
            self.previous_end = Some(end);
        }
    }

    /// What the pass found; `None` if it saw no row.
    pub(crate) fn finish(self) -> Option<Survey> {
        let order = match (self.by_end, self.by_start) {
            (true, _) => Order::ByEnd,
            (false, true) => Order::ByStart,
            (false, false) => Order::Sorted,
        };
        Some(Survey {
            start: self.start?,
            initial: self.initial,
            last_row: self.last_row,
            order,
        })
    }
}

/// The second pass: intervals to changes.
///
/// Every interval after the first of its signal starts with a change, at its
/// `t_start`, to its value; equivalently, every closed interval but the last of
/// its signal ends with a change, at its `t_end`, to the other value (values
/// alternate). Several changes of one signal at one time (zero-length
/// intervals) leave only the last value, and only if it differs from the value
/// before.
pub(crate) struct Unfold {
    start: Time,
    initial: Vec<bool>,
    last_row: Vec<u64>,
    order: Order,
    collapse: Collapse,
    /// [`Order::Sorted`]: the changes, until the end.
    claims: Vec<(Time, SignalId, bool)>,
    finished: bool,
}

impl Unfold {
    pub(crate) fn new(survey: Survey) -> Unfold {
        Unfold {
            start: survey.start,
            collapse: Collapse::new(survey.initial.clone()),
            initial: survey.initial,
            last_row: survey.last_row,
            order: survey.order,
            claims: Vec::new(),
            finished: false,
        }
    }

    /// The log's first time.
    pub(crate) fn start(&self) -> Time {
        self.start
    }

    /// Every signal's value at the first time.
    pub(crate) fn initial(&self) -> &[bool] {
        &self.initial
    }

    /// Whether the changes come from the rows' ends ([`Unfold::feed_end`]),
    /// not their starts ([`Unfold::feed_start`]).
    pub(crate) fn by_end(&self) -> bool {
        self.order == Order::ByEnd
    }

    /// Takes row `row`; `false` if it contradicts the first pass (the file
    /// changed in between).
    fn feed(&mut self, row: u64, interval: Interval, out: &mut Vec<Event>) -> bool {
        let Interval {
            signal,
            value,
            start,
            end,
        } = interval;
        if self.by_end() {
            self.feed_end(row, signal, value, end, out)
        } else {
            self.feed_start(signal, value, start, out)
        }
    }

    /// [`Unfold::feed`] when [`Unfold::by_end`]: only the row's signal, value
    /// and end count.
    #[inline]
    pub(crate) fn feed_end(
        &mut self,
        row: u64,
        signal: SignalId,
        value: bool,
        end: Option<Time>,
        out: &mut Vec<Event>,
    ) -> bool {
        match end {
            None => true,
            Some(_) if self.last_row.get(signal.index()) == Some(&row) => true,
            Some(end) => end <= self.start || self.collapse.claim(end, signal, !value, out),
        }
    }

    /// [`Unfold::feed`] otherwise: only the row's signal, value and start
    /// count.
    #[inline]
    pub(crate) fn feed_start(
        &mut self,
        signal: SignalId,
        value: bool,
        start: Time,
        out: &mut Vec<Event>,
    ) -> bool {
        if start <= self.start {
            return true;
        }
        if self.order == Order::Sorted {
            self.claims.push((start, signal, value));
            true
        } else {
            self.collapse.claim(start, signal, value, out)
        }
    }

    /// At the end of the rows: the changes still held.
    pub(crate) fn finish(&mut self, out: &mut Vec<Event>) {
        // Stable: the changes of one signal at one time keep their order.
        let mut claims = std::mem::take(&mut self.claims);
        claims.sort_by_key(|c| c.0);
        for (t, signal, value) in claims {
            self.collapse.claim(t, signal, value, out);
        }
        self.collapse.flush(out);
        self.finished = true;
    }

    /// Whether [`Unfold::finish`] has run.
    pub(crate) fn finished(&self) -> bool {
        self.finished
    }
}

/// Turns the value each signal takes at each time into events: for each time,
/// the last value given to each signal counts, and only if it differs from the
/// signal's current value. Times must not decrease.
struct Collapse {
    current: Vec<bool>,
    at: Option<Time>,
    slot: Vec<Option<bool>>,
    touched: Vec<SignalId>,
}

impl Collapse {
    fn new(initial: Vec<bool>) -> Collapse {
        Collapse {
            slot: vec![None; initial.len()],
            current: initial,
            at: None,
            touched: Vec::new(),
        }
    }

    /// Records that `signal` holds `value` after `t`; `false` if `t` is before the
    /// previous time.
    fn claim(&mut self, t: Time, signal: SignalId, value: bool, out: &mut Vec<Event>) -> bool {
        if self.at != Some(t) {
            if self.at.is_some_and(|at| t < at) {
                return false;
            }
            self.flush(out);
            self.at = Some(t);
        }
        if let Some(slot) = self.slot.get_mut(signal.index())
            && slot.replace(value).is_none()
        {
            self.touched.push(signal);
        }
        true
    }

    /// Emits the changes of the current time, by signal.
    fn flush(&mut self, out: &mut Vec<Event>) {
        let Some(t) = self.at else {
            return;
        };
        self.touched.sort_unstable();
        for signal in self.touched.drain(..) {
            let i = signal.index();
            if let (Some(value), Some(current)) = (
                self.slot.get_mut(i).and_then(Option::take),
                self.current.get_mut(i),
            ) && value != *current
            {
                *current = value;
                out.push(Event { t, signal, value });
            }
        }
    }
}
