//! The small CSV dialect shared by the three log forms, and helpers common to
//! their readers and writers.
//!
//! Dialect: one record per line, fields separated by commas, LF or CRLF line ends,
//! an optional UTF-8 byte-order mark, blank lines ignored, whitespace around a field
//! ignored, and a field may be wrapped in double quotes (which are removed; quoted
//! fields cannot contain commas, quotes or line breaks — log values never need to).

use std::fmt::Write as _;
use std::io::{self, BufRead, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use vocabulary::{Located, Location, SignalTable, Time, TimeFormat};

use crate::rows::Records;

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

/// The longest line a CSV log may have, in bytes: a bound on the memory a
/// file that is not a log (or has no line breaks) can take.
pub const LONGEST_LINE: usize = 1 << 20;

/// The records of a CSV log, read one line at a time, reusing their buffers.
pub struct CsvRecords<R> {
    reader: R,
    path: PathBuf,
    line: String,
    fields: Vec<Field>,
    line_no: usize,
    first_line: bool,
}

impl<R: BufRead> CsvRecords<R> {
    /// A reader of `reader`; `path` is only used in error messages.
    pub fn new(reader: R, path: &Path) -> Self {
        CsvRecords {
            reader,
            path: path.to_path_buf(),
            line: String::new(),
            fields: Vec::new(),
            line_no: 0,
            first_line: true,
        }
    }

    /// Reads the next non-blank record; `Ok(false)` at the end of the input.
    fn read_record(&mut self) -> Result<bool, Located> {
        loop {
            let mut bytes = std::mem::take(&mut self.line).into_bytes();
            bytes.clear();
            let read = self
                .reader
                .by_ref()
                .take(LONGEST_LINE as u64 + 1)
                .read_until(b'\n', &mut bytes);
            let n = match read {
                Ok(n) => n,
                Err(e) => return Err(crate::rows::cannot_read(&self.path, self.line_no + 1, &e)),
            };
            if n == 0 {
                self.fields.clear();
                return Ok(false);
            }
            self.line_no += 1;
            if n > LONGEST_LINE && bytes.last() != Some(&b'\n') {
                let location = Location::new(&self.path, self.line_no, 1);
                let message = format!(
                    "line longer than {} MiB: not a log's line (a header of 10,000 signals takes 0.1 MiB)",
                    LONGEST_LINE >> 20
                );
                return Err(Located::new(location, message));
            }
            let mut text = match String::from_utf8(bytes) {
                Ok(text) => text,
                Err(e) => {
                    let column = e.utf8_error().valid_up_to() + 1;
                    let location = Location::new(&self.path, self.line_no, column);
                    return Err(Located::new(location, "invalid UTF-8 text"));
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
}

impl<R: BufRead> Records for CsvRecords<R> {
    fn next_record(&mut self) -> Result<bool, Located> {
        self.read_record()
    }

    fn len(&self) -> usize {
        self.fields.len()
    }

    fn field(&self, i: usize) -> &str {
        self.fields
            .get(i)
            .and_then(|f| self.line.get(f.start..f.end))
            .unwrap_or("")
    }

    fn column(&self, i: usize) -> usize {
        self.fields.get(i).map_or(self.end_column(), |f| f.column)
    }

    fn end_column(&self) -> usize {
        self.line.len() + 1
    }

    fn line_no(&self) -> usize {
        self.line_no
    }

    fn path(&self) -> &Path {
        &self.path
    }
}

// ----- writing -----

/// An `InvalidInput` error: the caller broke a writer's contract.
pub(super) fn invalid_input(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

/// The error for `values` initial values given for `signals` signals.
pub(crate) fn wrong_initial(values: usize, signals: usize) -> io::Error {
    invalid_input(format!("{values} initial values for {signals} signals"))
}

/// The error for an event of a signal the table does not have.
pub(crate) fn no_signal(id: vocabulary::SignalId) -> io::Error {
    invalid_input(format!("no signal with id {}", id.0))
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
