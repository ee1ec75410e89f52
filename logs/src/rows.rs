//! The rules every tabular log form shares, whatever holds its rows.
//!
//! A form's reader sees its file as [`Records`]: a header record of column
//! names, then data records of fields, each with a line and a column for error
//! messages. A CSV file gives them line by line ([`crate::csv::CsvRecords`]); a
//! Parquet file row by row (`crate::parquet`, where line 1 holds the column
//! names and row *k* is line *k* + 1). [`Rows`] adds the checks and messages of
//! the forms on top — columns, widths, signal names, values and times — so that
//! each is written once, here, and both containers give the same errors.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use vocabulary::error::quoted;

use vocabulary::{Located, Location, SignalId, SignalTable, Time, TimeFormat};

use super::TimeFormatChoice;

/// A source of records: the header first, then the data rows.
pub trait Records {
    /// Moves to the next non-blank record; `Ok(false)` at the end of the input.
    fn next_record(&mut self) -> Result<bool, Located>;
    /// A container of lines' bytes not read yet, from the start of the next
    /// line (empty for other containers): a form's reader may read a common
    /// row's values straight from them, then [`Records::read_plain`] it.
    fn unread(&self) -> &[u8] {
        &[]
    }
    /// Reads the first `length` bytes of [`Records::unread`] as the next
    /// record, if a line feed follows them: the caller vouches that they hold
    /// exactly what the line's fields would (no quotes, spaces or carriage
    /// return). Its fields are readable after [`Records::settle`]. `false`,
    /// having read nothing, if that is not a line.
    fn read_plain(&mut self, _length: usize) -> bool {
        false
    }
    /// Splits a record [`Records::read_plain`] read into its
    /// fields, for a message about it.
    fn settle(&mut self) {}
    /// Number of fields in the current record.
    fn len(&self) -> usize;
    /// Whether the current record has no field.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Field `i` of the current record, trimmed and unquoted (`""` if absent or
    /// null).
    fn field(&self, i: usize) -> &str;
    /// Column (from 1) where field `i` starts; [`Records::end_column`] if absent.
    fn column(&self, i: usize) -> usize;
    /// The column just past the current record.
    fn end_column(&self) -> usize;
    /// Line (from 1) of the current record.
    fn line_no(&self) -> usize;
    /// The file named in error messages.
    fn path(&self) -> &Path;
    /// Field `i` as the integer the container holds, if it holds one (a
    /// Parquet integer column); `None` for text, which is parsed instead. Both
    /// mean the same: an integer cell reads as its decimal text would.
    fn integer(&self, _i: usize) -> Option<i64> {
        None
    }
    /// Field `i` as the boolean the container holds, if it holds one.
    fn boolean(&self, _i: usize) -> Option<bool> {
        None
    }
    /// Whether field `i` is empty (or null), without rendering it.
    fn is_blank(&self, i: usize) -> bool {
        self.field(i).is_empty()
    }
    /// Whether column `i` of the header can hold cells of `kind`; `Err` names
    /// the column's type otherwise. Text holds anything: CSV accepts every
    /// column, and its cells are checked one by one.
    fn holds(&self, _i: usize, _kind: CellKind) -> Result<(), String> {
        Ok(())
    }
}

/// What a column of a form holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellKind {
    /// Timestamps: numbers in a unit, or RFC 3339 text.
    Time,
    /// Signal names.
    Signal,
    /// Signal values: 0, 1, true or false.
    Value,
}

impl CellKind {
    /// What a column of this kind may hold, for messages (`unit`: the unit of
    /// numeric timestamps).
    pub fn expected(self, unit: vocabulary::TimeUnit) -> String {
        match self {
            CellKind::Time => format!("integers or floats in {unit}, or RFC 3339 text"),
            CellKind::Signal => "signal names (text)".to_string(),
            CellKind::Value => "booleans, 0 and 1, or text 0, 1, true, false".to_string(),
        }
    }
}

/// The records of a log with the checks of its form.
pub(crate) struct Rows<S> {
    records: S,
}

impl<S: Records> Rows<S> {
    pub(crate) fn new(records: S) -> Self {
        Rows { records }
    }

    /// Reads the next non-blank record; `Ok(false)` at the end of the input.
    pub(crate) fn next_record(&mut self) -> Result<bool, Located> {
        self.records.next_record()
    }

    /// What is not read yet (see [`Records::unread`]).
    #[inline(always)]
    pub(crate) fn unread(&self) -> &[u8] {
        self.records.unread()
    }

    /// Reads a plain line (see [`Records::read_plain`]).
    #[inline(always)]
    pub(crate) fn read_plain(&mut self, length: usize) -> bool {
        self.records.read_plain(length)
    }

    /// Makes the fields of a plain record readable.
    pub(crate) fn settle(&mut self) {
        self.records.settle();
    }

    /// Reads the header record; an empty input is an error.
    pub(crate) fn read_header(&mut self, expected: &str) -> Result<(), Located> {
        if self.records.next_record()? {
            Ok(())
        } else {
            let location = Location::new(self.records.path(), 1, 0);
            Err(Located::new(
                location,
                format!("empty file: expected the header {expected}"),
            ))
        }
    }

    /// Number of fields in the current record.
    pub(crate) fn len(&self) -> usize {
        self.records.len()
    }

    /// Field `i` of the current record (`""` if absent).
    pub(crate) fn field(&self, i: usize) -> &str {
        self.records.field(i)
    }

    /// Column (from 1) where field `i` starts.
    pub(crate) fn column(&self, i: usize) -> usize {
        self.records.column(i)
    }

    /// Line (from 1) of the current record.
    pub(crate) fn line_no(&self) -> usize {
        self.records.line_no()
    }

    /// The file named in error messages.
    pub(crate) fn path(&self) -> &Path {
        self.records.path()
    }

    /// An error at a column of the current line.
    pub(crate) fn error(
        &self,
        column: usize,
        field: Option<&str>,
        message: impl Into<String>,
    ) -> Located {
        let mut location = Location::new(self.records.path(), self.records.line_no(), column);
        if let Some(field) = field {
            location = location.with_field(field);
        }
        Located::new(location, message)
    }

    /// An error about field `i` of the current record, named `name`.
    pub(crate) fn field_error(&self, i: usize, name: &str, message: impl Into<String>) -> Located {
        self.error(self.records.column(i), Some(name), message)
    }

    /// Maps the header's columns: returns the position of each `required` column;
    /// `optional` columns are accepted and ignored; anything else is an error.
    pub(crate) fn map_columns(
        &self,
        required: &[&str],
        optional: &[&str],
        expected: &str,
    ) -> Result<Vec<usize>, Located> {
        let mut positions: Vec<Option<usize>> = vec![None; required.len()];
        let mut seen_optional = vec![false; optional.len()];
        for i in 0..self.len() {
            let name = self.field(i);
            let duplicate = if let Some(k) = required.iter().position(|&r| r == name) {
                positions[k].replace(i).is_some()
            } else if let Some(k) = optional.iter().position(|&o| o == name) {
                std::mem::replace(&mut seen_optional[k], true)
            } else if name.is_empty() {
                return Err(self.error(
                    self.records.column(i),
                    None,
                    format!("empty column name (expected {expected})"),
                ));
            } else {
                let message = format!("unknown column {} (expected {expected})", quoted(name));
                return Err(self.error(self.records.column(i), None, message));
            };
            if duplicate {
                let message = duplicate_column(name);
                return Err(self.error(self.records.column(i), None, message));
            }
        }
        let mut columns = Vec::with_capacity(required.len());
        for (name, position) in required.iter().zip(positions) {
            match position {
                Some(i) => columns.push(i),
                None => {
                    let message = format!("missing required column '{name}' (expected {expected})");
                    return Err(self.error(0, None, message));
                }
            }
        }
        Ok(columns)
    }

    /// Checks, on the header, that each column `(i, kind)` can hold its kind of
    /// cell (`unit`: the unit of numeric timestamps, for the message).
    pub(crate) fn check_kinds(
        &self,
        columns: &[(usize, CellKind)],
        unit: vocabulary::TimeUnit,
    ) -> Result<(), Located> {
        for &(i, kind) in columns {
            if let Err(found) = self.records.holds(i, kind) {
                let name = self.field(i);
                let message = format!(
                    "column '{name}' has type {found}: expected {}",
                    kind.expected(unit)
                );
                return Err(self.error(self.records.column(i), None, message));
            }
        }
        Ok(())
    }

    /// Checks that the current record has `width` fields, like the header.
    pub(crate) fn check_width(&self, width: usize) -> Result<(), Located> {
        let n = self.len();
        if n == width {
            return Ok(());
        }
        let column = if n > width {
            self.records.column(width)
        } else {
            self.records.end_column()
        };
        Err(self.error(
            column,
            None,
            format!("expected {width} fields like the header, found {n}"),
        ))
    }

    /// Whether field `i` is empty.
    pub(crate) fn is_blank(&self, i: usize) -> bool {
        self.records.is_blank(i)
    }

    /// Parses field `i`, named `name`, as a signal value.
    pub(crate) fn value(&self, i: usize, name: &str) -> Result<bool, Located> {
        // Typed cells first: the same values as their text, without it.
        if let Some(value) = self.records.boolean(i) {
            return Ok(value);
        }
        match self.records.integer(i) {
            Some(0) => return Ok(false),
            Some(1) => return Ok(true),
            _ => {}
        }
        let text = self.field(i);
        parse_bool(text).ok_or_else(|| {
            self.field_error(
                i,
                name,
                format!("bad value {}: expected 0, 1, true or false", quoted(text)),
            )
        })
    }

    /// Parses field `i`, named `name`, as the name of a signal of `signals`.
    pub(crate) fn signal(
        &self,
        i: usize,
        name: &str,
        signals: &SignalTable,
    ) -> Result<SignalId, Located> {
        let text = self.field(i);
        signals.id(text).ok_or_else(|| {
            if text.is_empty() {
                self.field_error(i, name, "missing signal name")
            } else {
                self.field_error(i, name, format!("unknown signal {}", quoted(text)))
            }
        })
    }
}

/// `0`, `1`, `true` or `false` (case-insensitive).
pub(crate) fn parse_bool(text: &str) -> Option<bool> {
    match text {
        "0" => Some(false),
        "1" => Some(true),
        _ if text.eq_ignore_ascii_case("false") => Some(false),
        _ if text.eq_ignore_ascii_case("true") => Some(true),
        _ => None,
    }
}

/// Parses timestamps in a given or detected representation.
pub(crate) struct TimeParser {
    choice: TimeFormatChoice,
    format: TimeFormat,
    parsed_any: bool,
}

impl TimeParser {
    pub(crate) fn new(choice: TimeFormatChoice) -> Self {
        let format = match choice {
            TimeFormatChoice::Given(format) => format,
            TimeFormatChoice::Detect(unit) => TimeFormat::Numeric(unit),
        };
        TimeParser {
            choice,
            format,
            parsed_any: false,
        }
    }

    /// The unit of numeric timestamps (for messages about a column's type).
    pub(crate) fn unit(&self) -> vocabulary::TimeUnit {
        match (self.choice, self.format) {
            (TimeFormatChoice::Detect(unit), _) | (_, TimeFormat::Numeric(unit)) => unit,
            (TimeFormatChoice::Given(_), TimeFormat::Rfc3339) => vocabulary::TimeUnit::Ms,
        }
    }

    /// Detects the representation from the first timestamp of the log, if asked to.
    pub(crate) fn detect(&mut self, text: &str) {
        if let TimeFormatChoice::Detect(unit) = self.choice {
            self.format = TimeFormat::detect(text, unit);
        }
    }

    /// The representation in use.
    pub(crate) fn format(&self) -> TimeFormat {
        self.format
    }

    /// Parses field `i`, named `name`, as a timestamp.
    pub(crate) fn parse<S: Records>(
        &mut self,
        rows: &Rows<S>,
        i: usize,
        name: &str,
    ) -> Result<Time, Located> {
        // An integer cell is read as its decimal text would be.
        if let (Some(v), TimeFormat::Numeric(unit)) = (rows.records.integer(i), self.format)
            && let Some(t) = v.checked_mul(unit.nanos())
        {
            self.parsed_any = true;
            return Ok(t);
        }
        let text = rows.field(i);
        match self.format.parse(text) {
            Some(t) => {
                self.parsed_any = true;
                Ok(t)
            }
            None => {
                let expected = match (self.choice, self.format) {
                    (TimeFormatChoice::Detect(unit), _) if !self.parsed_any => {
                        format!("a number in {unit} or RFC 3339 text")
                    }
                    (_, TimeFormat::Numeric(unit)) => format!("a number in {unit}"),
                    (_, TimeFormat::Rfc3339) => "RFC 3339 text".to_string(),
                };
                let message = if text.is_empty() {
                    format!("missing time: expected {expected}")
                } else {
                    format!("bad time {}: expected {expected}", quoted(text))
                };
                Err(rows.field_error(i, name, message))
            }
        }
    }
}

/// `'A4', 'C5'`: names for a message.
pub(crate) fn quote_list<'a>(names: impl IntoIterator<Item = &'a str>) -> String {
    let mut list = String::new();
    for name in names {
        if !list.is_empty() {
            list.push_str(", ");
        }
        list.push('\'');
        list.push_str(name);
        list.push('\'');
    }
    list
}

/// Opens a log file for reading.
pub(crate) fn open(path: &Path) -> Result<BufReader<File>, Located> {
    open_file(path).map(BufReader::new)
}

pub(crate) use crate::spool::open_file;

/// The error for a log that cannot be read past line `line`.
pub(crate) fn cannot_read(path: &Path, line: usize, e: &std::io::Error) -> Located {
    Located::new(
        Location::new(path, line, 0),
        format!("cannot read the log: {e}"),
    )
}

/// The message for a time before the previous row's (`previous`, on `line`).
pub(crate) fn backwards(t: &str, previous: &str, line: usize) -> String {
    format!("time goes backwards: {t} is before {previous} on line {line}")
}

/// The message for a column named twice.
pub(crate) fn duplicate_column(name: &str) -> String {
    format!("duplicate column {}", quoted(name))
}

/// An error about the whole file.
pub(crate) fn file_error(path: &Path, message: impl Into<String>) -> Located {
    Located::new(Location::new(path, 0, 0), message)
}

/// An error for a reader that found no data row.
pub(crate) fn no_data(path: &Path) -> Located {
    file_error(
        path,
        "no data rows: a log must give the initial value of every signal",
    )
}

/// Position of a stream reader: before the first data row (already read), in
/// the rows, or done (end of input or after an error).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum State {
    Pending,
    Reading,
    Done,
}

impl State {
    /// Moves `rows` to the next data record; `None` at the end of the input or
    /// once done. Errors end the reading.
    pub(crate) fn advance<S: Records>(
        &mut self,
        rows: &mut Rows<S>,
    ) -> Option<Result<(), Located>> {
        match *self {
            State::Done => None,
            State::Pending => {
                *self = State::Reading;
                Some(Ok(()))
            }
            State::Reading => match rows.next_record() {
                Ok(true) => Some(Ok(())),
                Ok(false) => {
                    *self = State::Done;
                    None
                }
                Err(e) => {
                    *self = State::Done;
                    Some(Err(e))
                }
            },
        }
    }
}
