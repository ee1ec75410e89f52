//! The scans form (wide): `t,<sig1>,<sig2>,…`, one row per PLC scan or sample.
//!
//! This is what PLC traces, historians and spreadsheets usually export: the value
//! of every signal at every scan. Edges are extracted between consecutive rows: a
//! change between two rows is an event at the later row's time, so the sample
//! period bounds timing precision. The header holds `t` and every signal of the
//! plant once, in any order; times strictly increase.
//!
//! ```text
//! t,C4,C5,A4
//! 0,1,0,0
//! 10,1,0,1
//! 20,0,0,1
//! ```

use std::io::{self, BufRead, BufWriter, Write};
use std::path::Path;
use vocabulary::error::quoted;

use vocabulary::{Event, Located, SignalId, SignalTable, Time, TimeFormat, TimeUnit};

use crate::csv::{self, CsvRecords, TimeText};
use crate::plain;
use crate::rows::{self, CellKind, Records, Rows, State, TimeParser};
use crate::{Changes, EventLog, TimeFormatChoice};

/// Writes a scans log: the header `t` plus every signal in table order, then one
/// row per scan.
///
/// Output is buffered; call [`ScanWriter::finish`] to flush it and see errors.
pub struct ScanWriter<W: Write> {
    out: BufWriter<W>,
    signals: usize,
    time: TimeText,
    row: Vec<u8>,
}

impl<W: Write> ScanWriter<W> {
    /// Writes the header `t,<sig1>,<sig2>,…` (signals in table order) to `w`;
    /// timestamps will be written in `format`. Fails if a signal name cannot be
    /// written as a plain CSV field.
    pub fn new(w: W, signals: &SignalTable, format: TimeFormat) -> io::Result<Self> {
        let names = csv::plain_names(signals)?;
        let mut out = BufWriter::with_capacity(csv::WRITE_BUFFER, w);
        out.write_all(b"t")?;
        for name in &names {
            out.write_all(b",")?;
            out.write_all(name.as_bytes())?;
        }
        out.write_all(b"\n")?;
        Ok(ScanWriter {
            out,
            signals: names.len(),
            time: TimeText::new(format),
            row: Vec::new(),
        })
    }

    /// Writes one scan at `t`; `values` is indexed by [`SignalId::index`](crate::SignalId::index). The
    /// writer does not check that time increases; readers do.
    pub fn write(&mut self, t: Time, values: &[bool]) -> io::Result<()> {
        if values.len() != self.signals {
            return Err(csv::invalid_input(format!(
                "{} values for {} signals",
                values.len(),
                self.signals
            )));
        }
        self.row.clear();
        self.row.extend_from_slice(self.time.get(t).as_bytes());
        for &value in values {
            self.row
                .extend_from_slice(if value { b",1" } else { b",0" });
        }
        self.row.push(b'\n');
        self.out.write_all(&self.row)
    }

    /// Flushes the output and returns the inner writer.
    pub fn finish(self) -> io::Result<W> {
        csv::into_inner(self.out)
    }
}

/// Reads a scans log one scan at a time, with [`ScanReader::next_scan`].
///
/// It checks the header (`t` and every signal, once each), the number of fields,
/// times (which must strictly increase) and values, and stops after the first
/// error. Memory grows with the number of signals, not of rows.
pub struct ScanReader<'a, S> {
    rows: Rows<S>,
    signals: &'a SignalTable,
    t_column: usize,
    /// The signal of each column (`None` for `t`).
    columns: Vec<Option<SignalId>>,
    time: TimeParser,
    state: State,
    previous: Option<(Time, usize)>,
    values: Vec<bool>,
    /// Nanoseconds per unit of the log's numeric times: rows written plainly
    /// (a decimal time, `0` and `1`, nothing else) then read straight from
    /// their line, and any other row field by field.
    plain: Option<Time>,
}

impl<'a, R: BufRead> ScanReader<'a, CsvRecords<R>> {
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

impl<'a, S: Records> ScanReader<'a, S> {
    /// The same over the records of any container (a CSV file, a Parquet file).
    pub fn from_records(
        records: S,
        signals: &'a SignalTable,
        time: TimeFormatChoice,
    ) -> Result<Self, Located> {
        let mut rows = Rows::new(records);
        rows.read_header("t,<signal>,<signal>,…")?;
        let mut t_column = None;
        let mut columns = Vec::with_capacity(rows.len());
        let mut seen = vec![false; signals.len()];
        for i in 0..rows.len() {
            let name = rows.field(i);
            // The first `t` is time; another is a signal named `t`, if any.
            if name == "t" && t_column.is_none() {
                t_column = Some(i);
                columns.push(None);
                continue;
            }
            let Some(id) = signals.id(name) else {
                let message = if name == "t" {
                    "duplicate column 't'".to_string()
                } else if name.is_empty() {
                    "empty column name (expected t or a signal name)".to_string()
                } else {
                    format!("unknown column {}: not a signal of the plant", quoted(name))
                };
                return Err(rows.error(rows.column(i), None, message));
            };
            if std::mem::replace(&mut seen[id.index()], true) {
                return Err(rows.error(rows.column(i), None, rows::duplicate_column(name)));
            }
            columns.push(Some(id));
        }
        let Some(t_column) = t_column else {
            return Err(rows.error(
                0,
                None,
                "missing required column 't' (expected t,<signal>,<signal>,…)",
            ));
        };
        let missing: Vec<&str> = signals
            .iter()
            .filter(|(id, _)| !seen[id.index()])
            .map(|(_, s)| s.name.as_str())
            .collect();
        if !missing.is_empty() {
            let s = if missing.len() > 1 { "s" } else { "" };
            let message = format!(
                "missing column{s} for signal{s} {}: a scans log needs every signal",
                rows::quote_list(missing)
            );
            return Err(rows.error(0, None, message));
        }
        let mut time = TimeParser::new(time);
        let kinds: Vec<(usize, CellKind)> = (0..columns.len())
            .map(|i| {
                (
                    i,
                    if i == t_column {
                        CellKind::Time
                    } else {
                        CellKind::Value
                    },
                )
            })
            .collect();
        rows.check_kinds(&kinds, time.unit())?;
        let state = if rows.next_record()? {
            time.detect(rows.field(t_column));
            State::Pending
        } else {
            State::Done
        };
        let plain = match time.format() {
            TimeFormat::Numeric(unit) => Some(unit.nanos()),
            TimeFormat::Rfc3339 => None,
        };
        Ok(ScanReader {
            rows,
            signals,
            t_column,
            columns,
            time,
            state,
            previous: None,
            values: vec![false; signals.len()],
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

    /// The next scan: its time and the value of every signal, indexed by
    /// [`SignalId::index`](crate::SignalId::index). `None` at the end of the log or after an error.
    pub fn next_scan(&mut self) -> Option<Result<(Time, &[bool]), Located>> {
        if let Some(t) = self.next_plain() {
            return Some(Ok((t, &self.values)));
        }
        if let Err(e) = self.state.advance(&mut self.rows)? {
            return Some(Err(e));
        }
        match self.parse_row() {
            Ok(t) => Some(Ok((t, &self.values))),
            Err(e) => {
                self.state = State::Done;
                Some(Err(e))
            }
        }
    }

    /// The time of the next row if it is written plainly (see
    /// [`plain_scan`]), its values in `values`; `None`, having read nothing,
    /// otherwise.
    fn next_plain(&mut self) -> Option<Time> {
        let nanos = self.plain.filter(|_| self.state == State::Reading)?;
        let after = self.previous.map(|(t, _)| t);
        let row = self.rows.unread();
        let (t, length) = plain_scan(row, &self.columns, nanos, after, &mut self.values)?;
        if !self.rows.read_plain(length) {
            return None;
        }
        self.previous = Some((t, self.rows.line_no()));
        Some(t)
    }

    fn parse_row(&mut self) -> Result<Time, Located> {
        let rows = &self.rows;
        let t_col = self.t_column;
        rows.check_width(self.columns.len())?;
        let t = self.time.parse(rows, t_col, "t")?;
        if let Some((previous, line)) = self.previous
            && t <= previous
        {
            let message = if t == previous {
                format!(
                    "time does not increase: {} repeats the time of line {line}",
                    rows.field(t_col)
                )
            } else {
                rows::backwards(
                    rows.field(t_col),
                    &self.time.format().format(previous),
                    line,
                )
            };
            return Err(rows.field_error(t_col, "t", message));
        }
        for (i, column) in self.columns.iter().enumerate() {
            if let Some(id) = *column {
                self.values[id.index()] = rows.value(i, self.signals.name(id))?;
            }
        }
        self.previous = Some((t, rows.line_no()));
        Ok(t)
    }
}

/// Reads the scan at the start of `row` if it is written plainly: a decimal
/// time in `t`'s column, `0` or `1` in each signal's, later than `after`.
/// Gives its time and the length of its line, and sets `values` (which a row
/// that is not plain may leave half set: its reading field by field sets
/// them all, or fails).
fn plain_scan(
    row: &[u8],
    columns: &[Option<SignalId>],
    nanos: Time,
    after: Option<Time>,
    values: &mut [bool],
) -> Option<(Time, usize)> {
    let mut at = 0;
    let mut time = None;
    for (i, column) in columns.iter().enumerate() {
        if i > 0 {
            if row.get(at) != Some(&b',') {
                return None;
            }
            at += 1;
        }
        let rest = row.get(at..)?;
        match column {
            Some(id) => {
                values[id.index()] = plain::bit(rest)?;
                at += 1;
            }
            None => {
                let (t, digits) = plain::time(rest, nanos)?;
                time = Some(t);
                at += digits;
            }
        }
    }
    let t = time?;
    // Times that do not increase are for the fields' reading to say.
    after.is_none_or(|previous| t > previous).then_some((t, at))
}

/// Reads a scans log file into the [`EventLog`] the events form would give,
/// detecting the time representation (numbers in `unit`, or RFC 3339 text).
pub fn read_scans_as_events(
    path: &Path,
    signals: &SignalTable,
    unit: TimeUnit,
) -> Result<EventLog, Located> {
    read_scans_as_events_from(
        rows::open(path)?,
        path,
        signals,
        TimeFormatChoice::Detect(unit),
    )
}

/// Reads a scans log from `reader` into the [`EventLog`] the events form would give;
/// `path` is only used in error messages.
///
/// The first row gives the initial values; a value that differs from the previous
/// row's is a change at the later row's time.
pub fn read_scans_as_events_from<R: BufRead>(
    reader: R,
    path: &Path,
    signals: &SignalTable,
    time: TimeFormatChoice,
) -> Result<EventLog, Located> {
    ScanChanges::open(ScanReader::new(reader, path, signals, time)?)?.into_log()
}

/// A scans log as its initial values (its first row), then its changes row by
/// row, in memory that does not grow with the log.
pub struct ScanChanges<'a, S> {
    rows: ScanReader<'a, S>,
    start: Time,
    initial: Vec<bool>,
    current: Vec<bool>,
}

impl<'a, S: Records> ScanChanges<'a, S> {
    /// Reads the first row: the initial values.
    pub fn open(mut rows: ScanReader<'a, S>) -> Result<Self, Located> {
        let (start, initial) = match rows.next_scan() {
            None => return Err(rows::no_data(rows.rows.path())),
            Some(scan) => {
                let (t, values) = scan?;
                (t, values.to_vec())
            }
        };
        Ok(ScanChanges {
            rows,
            start,
            current: initial.clone(),
            initial,
        })
    }
}

impl<S: Records> Changes for ScanChanges<'_, S> {
    fn start(&self) -> Time {
        self.start
    }

    fn initial(&self) -> &[bool] {
        &self.initial
    }

    fn format(&self) -> TimeFormat {
        self.rows.format()
    }

    /// Appends the changes of the next row to `out`, by signal; `Ok(false)` at
    /// the end of the log.
    fn read_scan(&mut self, out: &mut Vec<Event>) -> Result<bool, Located> {
        let Some(scan) = self.rows.next_scan() else {
            return Ok(false);
        };
        let (t, values) = scan?;
        for (i, (&value, old)) in values.iter().zip(self.current.iter_mut()).enumerate() {
            if value != *old {
                *old = value;
                out.push(Event {
                    t,
                    signal: SignalId(i as u32),
                    value,
                });
            }
        }
        Ok(true)
    }
}
