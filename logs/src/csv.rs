//! The small CSV dialect shared by the three log forms, and helpers common to
//! their readers and writers.
//!
//! Dialect: one record per line, fields separated by commas, LF or CRLF line ends,
//! an optional UTF-8 byte-order mark, blank lines ignored, whitespace around a field
//! ignored, and a field may be wrapped in double quotes (which are removed; quoted
//! fields cannot contain commas, quotes or line breaks — log values never need to).

use std::fmt::Write as _;
use std::io::{self, BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};

use vocabulary::{Located, Location, SignalTable, Time, TimeFormat};

use crate::plain;
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

/// How many bytes a reader asks its source for at once: large reads, and a
/// line end found in a block rather than a line read at a time.
const BLOCK: usize = 1 << 18;

/// The records of a CSV log, read in blocks of bytes, reusing their buffers.
pub struct CsvRecords<R> {
    reader: R,
    path: PathBuf,
    /// Bytes read ahead: `buffer[pos..filled]` are not consumed yet. It grows
    /// past [`BLOCK`] only to hold one line of up to [`LONGEST_LINE`] bytes.
    buffer: Vec<u8>,
    pos: usize,
    filled: usize,
    /// Whether the source said it has no more bytes.
    exhausted: bool,
    line: String,
    fields: Vec<Field>,
    /// A line read plainly, still in `buffer` and not split yet.
    plain: Option<(usize, usize)>,
    line_no: usize,
    first_line: bool,
}

impl<R: BufRead> CsvRecords<R> {
    /// A reader of `reader`; `path` is only used in error messages.
    pub fn new(reader: R, path: &Path) -> Self {
        CsvRecords {
            reader,
            path: path.to_path_buf(),
            buffer: Vec::new(),
            pos: 0,
            filled: 0,
            exhausted: false,
            line: String::new(),
            fields: Vec::new(),
            plain: None,
            line_no: 0,
            first_line: true,
        }
    }

    /// Reads the next non-blank record; `Ok(false)` at the end of the input.
    fn read_record(&mut self) -> Result<bool, Located> {
        self.plain = None;
        while let Some((start, end, has_end)) = self.next_line()? {
            if self.take_line(start, end, has_end)? {
                return Ok(true);
            }
        }
        self.fields.clear();
        Ok(false)
    }

    /// The next line as a range of `buffer` (without its line end) and whether
    /// it has a line end; `None` at the end of the input.
    fn next_line(&mut self) -> Result<Option<(usize, usize, bool)>, Located> {
        let mut searched = 0;
        loop {
            let unread = &self.buffer[self.pos + searched..self.filled];
            if let Some(at) = plain::find_byte(unread, b'\n') {
                let (start, end) = (self.pos, self.pos + searched + at);
                self.pos = end + 1;
                self.line_no += 1;
                self.check_length(end - start)?;
                return Ok(Some((start, end, true)));
            }
            searched = self.filled - self.pos;
            if searched > LONGEST_LINE {
                self.line_no += 1;
                return Err(self.too_long());
            }
            if self.exhausted {
                if searched == 0 {
                    return Ok(None);
                }
                let start = std::mem::replace(&mut self.pos, self.filled);
                self.line_no += 1;
                return Ok(Some((start, self.filled, false)));
            }
            self.fill()?;
        }
    }

    /// Reads more of the source after what is not consumed yet.
    fn fill(&mut self) -> Result<(), Located> {
        if self.pos > 0 {
            self.buffer.copy_within(self.pos..self.filled, 0);
            self.filled -= self.pos;
            self.pos = 0;
        }
        if self.filled == self.buffer.len() {
            // A line of up to LONGEST_LINE bytes and its line end must fit.
            let size = (2 * self.buffer.len()).clamp(BLOCK, LONGEST_LINE + BLOCK);
            self.buffer.resize(size, 0);
        }
        loop {
            match self.reader.read(&mut self.buffer[self.filled..]) {
                Ok(0) => self.exhausted = true,
                Ok(n) => self.filled += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(crate::rows::cannot_read(&self.path, self.line_no + 1, &e)),
            }
            return Ok(());
        }
    }

    fn check_length(&self, length: usize) -> Result<(), Located> {
        if length > LONGEST_LINE {
            Err(self.too_long())
        } else {
            Ok(())
        }
    }

    fn too_long(&self) -> Located {
        let location = Location::new(&self.path, self.line_no, 1);
        let message = format!(
            "line longer than {} MiB: not a log's line (a header of 10,000 signals takes 0.1 MiB)",
            LONGEST_LINE >> 20
        );
        Located::new(location, message)
    }

    /// Makes `buffer[start..end]`, the current line, the current record:
    /// `Ok(false)` if it is blank.
    fn take_line(&mut self, start: usize, end: usize, has_end: bool) -> Result<bool, Located> {
        let text = match std::str::from_utf8(&self.buffer[start..end]) {
            Ok(text) => text,
            Err(e) => {
                let location = Location::new(&self.path, self.line_no, e.valid_up_to() + 1);
                return Err(Located::new(location, "invalid UTF-8 text"));
            }
        };
        let mut text = match text.strip_suffix('\r') {
            Some(text) if has_end => text,
            _ => text,
        };
        if std::mem::take(&mut self.first_line) {
            text = text.strip_prefix('\u{feff}').unwrap_or(text);
        }
        self.line.clear();
        self.line.push_str(text);
        if self.line.trim_ascii().is_empty() {
            return Ok(false);
        }
        self.split();
        Ok(true)
    }

    fn split(&mut self) {
        self.fields.clear();
        let bytes = self.line.as_bytes();
        let mut from = 0;
        loop {
            let to = plain::find_byte(&bytes[from..], b',').map_or(bytes.len(), |p| from + p);
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

    #[inline(always)]
    fn unread(&self) -> &[u8] {
        &self.buffer[self.pos..self.filled]
    }

    #[inline(always)]
    fn read_plain(&mut self, length: usize) -> bool {
        if length > LONGEST_LINE || self.unread().get(length) != Some(&b'\n') {
            return false;
        }
        self.plain = Some((self.pos, self.pos + length));
        self.pos += length + 1;
        self.line_no += 1;
        self.first_line = false;
        true
    }

    fn settle(&mut self) {
        if let Some((start, end)) = self.plain.take() {
            // A plain line is text with no line end: it reads as it would
            // have.
            let text = String::from_utf8_lossy(&self.buffer[start..end]);
            self.line.clear();
            self.line.push_str(&text);
            self.split();
        }
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
