//! The small CSV dialect shared by the three log forms, and helpers common to
//! their readers and writers.
//!
//! Dialect: one record per line, fields separated by commas, LF or CRLF line ends,
//! an optional UTF-8 byte-order mark, blank lines ignored, whitespace around a field
//! ignored, and a field may be wrapped in double quotes (which are removed; quoted
//! fields cannot contain commas, quotes or line breaks — log values never need to).

use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::TimeFormatChoice;
use crate::error::{Located, Location};
use crate::signal::{SignalId, SignalTable};
use crate::time::{Time, TimeFormat};

/// Capacity of the writers' buffers.
pub(super) const WRITE_BUFFER: usize = 1 << 16;

/// One field of the current record: a byte range of the line and the column
/// (from 1) where it starts.
#[derive(Debug, Clone, Copy)]
struct Field {
    start: usize,
    end: usize,
    column: usize,
}

/// Reads records one line at a time, reusing its buffers.
pub(super) struct CsvReader<R> {
    reader: R,
    path: PathBuf,
    line: String,
    fields: Vec<Field>,
    line_no: usize,
    first_line: bool,
}

impl<R: BufRead> CsvReader<R> {
    /// A reader of `reader`; `path` is only used in error messages.
    pub(super) fn new(reader: R, path: &Path) -> Self {
        CsvReader {
            reader,
            path: path.to_path_buf(),
            line: String::new(),
            fields: Vec::new(),
            line_no: 0,
            first_line: true,
        }
    }

    /// Reads the next non-blank record; `Ok(false)` at the end of the input.
    pub(super) fn next_record(&mut self) -> Result<bool, Located> {
        loop {
            let mut bytes = std::mem::take(&mut self.line).into_bytes();
            bytes.clear();
            let read = self.reader.read_until(b'\n', &mut bytes);
            let n = match read {
                Ok(n) => n,
                Err(e) => {
                    let location = Location::new(&self.path, self.line_no + 1, 0);
                    return Err(Located::new(location, format!("cannot read the log: {e}")));
                }
            };
            if n == 0 {
                self.fields.clear();
                return Ok(false);
            }
            self.line_no += 1;
            let mut text = match String::from_utf8(bytes) {
                Ok(text) => text,
                Err(e) => {
                    let column = e.utf8_error().valid_up_to() + 1;
                    return Err(self.error(column, None, "invalid UTF-8 text"));
                }
            };
            if text.ends_with('\n') {
                text.pop();
                if text.ends_with('\r') {
                    text.pop();
                }
            }
            if std::mem::take(&mut self.first_line) && text.starts_with('\u{feff}') {
                text.replace_range(..'\u{feff}'.len_utf8(), "");
            }
            self.line = text;
            if self.line.trim_ascii().is_empty() {
                continue;
            }
            self.split();
            return Ok(true);
        }
    }

    fn split(&mut self) {
        self.fields.clear();
        let bytes = self.line.as_bytes();
        let mut from = 0;
        loop {
            let to = bytes[from..]
                .iter()
                .position(|&b| b == b',')
                .map_or(bytes.len(), |p| from + p);
            let (mut start, mut end) = (from, to);
            while start < end && bytes[start].is_ascii_whitespace() {
                start += 1;
            }
            while end > start && bytes[end - 1].is_ascii_whitespace() {
                end -= 1;
            }
            let column = start + 1;
            if end - start >= 2 && bytes[start] == b'"' && bytes[end - 1] == b'"' {
                start += 1;
                end -= 1;
            }
            self.fields.push(Field { start, end, column });
            if to == bytes.len() {
                break;
            }
            from = to + 1;
        }
    }

    /// Reads the header record; an empty input is an error.
    pub(super) fn read_header(&mut self, expected: &str) -> Result<(), Located> {
        if self.next_record()? {
            Ok(())
        } else {
            let location = Location::new(&self.path, 1, 0);
            Err(Located::new(
                location,
                format!("empty file: expected the header {expected}"),
            ))
        }
    }

    /// Number of fields in the current record.
    pub(super) fn len(&self) -> usize {
        self.fields.len()
    }

    /// Field `i` of the current record, unquoted and trimmed (`""` if absent).
    pub(super) fn field(&self, i: usize) -> &str {
        self.fields
            .get(i)
            .and_then(|f| self.line.get(f.start..f.end))
            .unwrap_or("")
    }

    /// Column (from 1) where field `i` starts; just past the line end if absent.
    pub(super) fn column(&self, i: usize) -> usize {
        self.fields.get(i).map_or(self.line.len() + 1, |f| f.column)
    }

    /// Line (from 1) of the current record.
    pub(super) fn line_no(&self) -> usize {
        self.line_no
    }

    /// The file named in error messages.
    pub(super) fn path(&self) -> &Path {
        &self.path
    }

    /// An error at a column of the current line.
    pub(super) fn error(
        &self,
        column: usize,
        field: Option<&str>,
        message: impl Into<String>,
    ) -> Located {
        let mut location = Location::new(&self.path, self.line_no, column);
        if let Some(field) = field {
            location = location.with_field(field);
        }
        Located::new(location, message)
    }

    /// An error about field `i` of the current record, named `name`.
    pub(super) fn field_error(&self, i: usize, name: &str, message: impl Into<String>) -> Located {
        self.error(self.column(i), Some(name), message)
    }

    /// Maps the header's columns: returns the position of each `required` column;
    /// `optional` columns are accepted and ignored; anything else is an error.
    pub(super) fn map_columns(
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
                    self.column(i),
                    None,
                    format!("empty column name (expected {expected})"),
                ));
            } else {
                let message = format!("unknown column '{name}' (expected {expected})");
                return Err(self.error(self.column(i), None, message));
            };
            if duplicate {
                return Err(self.error(self.column(i), None, format!("duplicate column '{name}'")));
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

    /// Checks that the current record has `width` fields, like the header.
    pub(super) fn check_width(&self, width: usize) -> Result<(), Located> {
        let n = self.len();
        if n == width {
            return Ok(());
        }
        let column = if n > width {
            self.column(width)
        } else {
            self.line.len() + 1
        };
        Err(self.error(
            column,
            None,
            format!("expected {width} fields like the header, found {n}"),
        ))
    }

    /// Parses field `i`, named `name`, as a signal value.
    pub(super) fn value(&self, i: usize, name: &str) -> Result<bool, Located> {
        let text = self.field(i);
        parse_bool(text).ok_or_else(|| {
            self.field_error(
                i,
                name,
                format!("bad value '{text}': expected 0, 1, true or false"),
            )
        })
    }

    /// Parses field `i`, named `name`, as the name of a signal of `signals`.
    pub(super) fn signal(
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
                self.field_error(i, name, format!("unknown signal '{text}'"))
            }
        })
    }
}

/// `0`, `1`, `true` or `false` (case-insensitive).
pub(super) fn parse_bool(text: &str) -> Option<bool> {
    match text {
        "0" => Some(false),
        "1" => Some(true),
        _ if text.eq_ignore_ascii_case("false") => Some(false),
        _ if text.eq_ignore_ascii_case("true") => Some(true),
        _ => None,
    }
}

/// Parses timestamps in a given or detected representation.
pub(super) struct TimeParser {
    choice: TimeFormatChoice,
    format: TimeFormat,
    parsed_any: bool,
}

impl TimeParser {
    pub(super) fn new(choice: TimeFormatChoice) -> Self {
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

    /// Detects the representation from the first timestamp of the log, if asked to.
    pub(super) fn detect(&mut self, text: &str) {
        if let TimeFormatChoice::Detect(unit) = self.choice {
            self.format = TimeFormat::detect(text, unit);
        }
    }

    /// The representation in use.
    pub(super) fn format(&self) -> TimeFormat {
        self.format
    }

    /// Parses field `i`, named `name`, as a timestamp.
    pub(super) fn parse<R: BufRead>(
        &mut self,
        csv: &CsvReader<R>,
        i: usize,
        name: &str,
    ) -> Result<Time, Located> {
        let text = csv.field(i);
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
                    format!("bad time '{text}': expected {expected}")
                };
                Err(csv.field_error(i, name, message))
            }
        }
    }
}

/// `'A4', 'C5'`: names for a message.
pub(super) fn quote_list<'a>(names: impl IntoIterator<Item = &'a str>) -> String {
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
pub(super) fn open(path: &Path) -> Result<BufReader<File>, Located> {
    File::open(path).map(BufReader::new).map_err(|e| {
        Located::new(
            Location::new(path, 0, 0),
            format!("cannot open the log: {e}"),
        )
    })
}

/// An error for a reader that found no data row.
pub(super) fn no_data(path: &Path) -> Located {
    Located::new(
        Location::new(path, 0, 0),
        "no data rows: a log must give the initial value of every signal",
    )
}

/// Position of a stream reader: before the first data row (already read), in
/// the rows, or done (end of input or after an error).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum State {
    Pending,
    Reading,
    Done,
}

impl State {
    /// Moves `csv` to the next data record; `None` at the end of the input or
    /// once done. Errors end the reading.
    pub(super) fn advance<R: BufRead>(
        &mut self,
        csv: &mut CsvReader<R>,
    ) -> Option<Result<(), Located>> {
        match *self {
            State::Done => None,
            State::Pending => {
                *self = State::Reading;
                Some(Ok(()))
            }
            State::Reading => match csv.next_record() {
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

// ----- writing -----

/// An `InvalidInput` error: the caller broke a writer's contract.
pub(super) fn invalid_input(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

/// The names of the table's signals, checked to be writable as plain CSV fields.
pub(super) fn plain_names(signals: &SignalTable) -> io::Result<Vec<String>> {
    signals
        .iter()
        .map(|(_, s)| {
            let plain = !s.name.is_empty()
                && s.name.trim_ascii() == s.name
                && !s.name.contains([',', '"', '\n', '\r']);
            if plain {
                Ok(s.name.clone())
            } else {
                Err(invalid_input(format!(
                    "signal name {:?} cannot be written as a CSV field",
                    s.name
                )))
            }
        })
        .collect()
}

/// Flushes a writer's buffer and returns the inner writer.
pub(super) fn into_inner<W: Write>(out: BufWriter<W>) -> io::Result<W> {
    out.into_inner().map_err(|e| e.into_error())
}

/// Formats timestamps, reusing the text while the time does not change (rows of
/// one scan share their time) and without allocating for whole numbers.
pub(super) struct TimeText {
    format: TimeFormat,
    last: Option<Time>,
    text: String,
}

impl TimeText {
    pub(super) fn new(format: TimeFormat) -> Self {
        TimeText {
            format,
            last: None,
            text: String::new(),
        }
    }

    /// `t` as text.
    pub(super) fn get(&mut self, t: Time) -> &str {
        if self.last != Some(t) {
            self.text.clear();
            match self.format {
                TimeFormat::Numeric(unit) if t % unit.nanos() == 0 => {
                    // Same text as `TimeUnit::format`; writing to a String cannot fail.
                    let _ = write!(self.text, "{}", t / unit.nanos());
                }
                format => self.text.push_str(&format.format(t)),
            }
            self.last = Some(t);
        }
        &self.text
    }
}

/// `b"1"` or `b"0"`.
pub(super) fn bit(value: bool) -> &'static [u8] {
    if value { b"1" } else { b"0" }
}
