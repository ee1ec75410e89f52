//! Parquet logs: their rows as [`Records`], read with polars, and the archive
//! writer ([`write_intervals_parquet`]).
//!
//! A Parquet log holds the columns of its form's CSV header. Its rows are
//! handed to the form's reader as records, so every rule and message of the
//! form is the one CSV gets: the column names are the header, "line" 1, and
//! row *k* (from 1) is line *k* + 1; the column of a cell is the 1-based index
//! of its column in the file's schema. Each cell is given as the text CSV
//! would hold: integers and floats in decimal, booleans as `true`/`false`,
//! null as an empty field. A row of nulls is skipped, as CSV skips a blank
//! line.
//!
//! # Decoding
//!
//! The file's footer is checked before anything trusts it ([`pages`]), then
//! its rows are decoded by `polars-parquet`, slice by slice, on a thread of
//! their own ([`decode`]).

use std::cell::{Cell, OnceCell};
use std::path::{Path, PathBuf};

use vocabulary::Located;
use vocabulary::panics::{self, Containment};

use crate::IngestOptions;
use crate::rows::{CellKind, Records, file_error, open_file};
use decode::{Cells, Kind, Schema, Slices};
use polars_arrow::array::StaticArray;

mod archive;
mod columns;
mod decode;
mod intervals;
mod pages;
mod table;
#[cfg(test)]
mod tests;

pub use archive::write_intervals_parquet;
pub(crate) use decode::schema;
pub(crate) use intervals::open_intervals;
pub use table::{
    ParquetCells, ParquetColumn, ParquetCompression, ParquetLayout, write_parquet_table,
};

/// The first line of a polars error: its messages can span several lines of
/// advice, and our errors are one line.
fn first_line(message: &str) -> &str {
    message.lines().next().unwrap_or("").trim()
}

/// The error for a failure of polars itself (a malformed file).
fn failure(path: &Path, message: &str) -> Located {
    file_error(
        path,
        format!(
            "cannot read the Parquet log: {}",
            in_words(first_line(message))
        ),
    )
}

/// polars' message, or what it means where polars gives a dump of its
/// reader's state: the Arrow schema a Parquet footer may embed
/// (`ARROW:schema`, base64 flatbuffers) fails to decode with the flatbuffers
/// reader's error as a Rust structure (`Error { source_location: … }`), or
/// an Arrow IPC message about its fields.
fn in_words(message: &str) -> &str {
    const ARROW_SCHEMA: [&str; 3] = ["ARROW:schema", "IPC:", "source_location: ErrorLocation"];
    if ARROW_SCHEMA.iter().any(|sign| message.contains(sign)) {
        "a damaged footer: the Arrow schema it embeds (ARROW:schema) cannot be decoded"
    } else {
        message
    }
}

/// Runs a call into polars with its panics contained: a malformed file can
/// make polars panic (on this thread or on its pool's), and the user gets the
/// panic's message as the file's error, not a crash.
fn contained<T>(path: &Path, call: impl FnOnce() -> Result<T, Located>) -> Result<T, Located> {
    let _quiet = Containment::start();
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(call))
        .unwrap_or_else(|payload| Err(failure(path, &panics::message(payload.as_ref()))))
}

/// Checks what polars trusts before it decodes: the magic bytes at both ends,
/// a footer that fits in the file, and no list in it longer than the footer
/// ([`pages::check_footer`]); the file's size.
fn check_frame(path: &Path) -> Result<u64, Located> {
    use std::io::{Read, Seek, SeekFrom};
    let fail = |why: &str| failure(path, &format!("not a Parquet file: {why}"));
    let mut file = open_file(path)?;
    let size = file
        .metadata()
        .map_err(|e| failure(path, &e.to_string()))?
        .len();
    let (mut head, mut tail) = ([0u8; 4], [0u8; 8]);
    let read = file
        .read_exact(&mut head)
        .and_then(|()| file.seek(SeekFrom::End(-8)))
        .and_then(|_| file.read_exact(&mut tail));
    if size < 12 || read.is_err() {
        return Err(fail("shorter than its magic bytes and footer length"));
    }
    if &head != b"PAR1" || &tail[4..] != b"PAR1" {
        return Err(fail("it does not begin and end with PAR1"));
    }
    let footer = u64::from(u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]));
    if footer + 12 > size {
        return Err(fail(&format!(
            "its footer says it is {footer} bytes long, in a file of {size}"
        )));
    }
    let mut bytes = vec![0u8; footer as usize];
    file.seek(SeekFrom::End(-8 - footer as i64))
        .and_then(|_| file.read_exact(&mut bytes))
        .map_err(|e| failure(path, &format!("cannot read its footer: {e}")))?;
    pages::check_footer(&bytes)
        .map_err(|why| failure(path, &format!("a damaged footer: {why}")))?;
    Ok(size)
}

/// The names of a Parquet file's columns, from its footer.
pub(crate) fn column_names(path: &Path) -> Result<Vec<String>, Located> {
    Ok(schema(path)?.columns.into_iter().map(|c| c.name).collect())
}

/// The rows of a Parquet log, as records.
///
/// A record's fields are read from the decoded columns when asked for, not
/// copied out for every row: a scans log has a column per signal.
pub struct ParquetRecords {
    path: PathBuf,
    schema: Schema,
    names: Vec<String>,
    options: IngestOptions,
    /// The slices, once the header has been read.
    frames: Option<Slices>,
    /// The current slice's columns, and the next row in it.
    cells: Vec<Cells>,
    height: usize,
    next_row: usize,
    /// Rows before the current one (blank rows included).
    rows: u64,
    /// The current record.
    at: At,
    /// The text of its integer, float and boolean fields, written when asked
    /// for (in an error message, say), not for every row; `rendered_any`
    /// once one is written, until the next record.
    rendered: Vec<OnceCell<String>>,
    rendered_any: Cell<bool>,
}

/// Which record is current.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum At {
    /// None: before the header, or after the last row.
    Nothing,
    /// The header: the column names.
    Header,
    /// Row `r` of the current slice.
    Row(usize),
}

impl ParquetRecords {
    /// Opens the file and reads its schema; no row is read yet.
    pub fn open(path: &Path, options: &IngestOptions) -> Result<Self, Located> {
        let schema = schema(path)?;
        let names: Vec<String> = schema.columns.iter().map(|c| c.name.clone()).collect();
        Ok(ParquetRecords {
            path: path.to_path_buf(),
            schema,
            rendered: vec![OnceCell::new(); names.len()],
            names,
            options: options.clone(),
            frames: None,
            cells: Vec::new(),
            height: 0,
            next_row: 0,
            rows: 0,
            at: At::Nothing,
            rendered_any: Cell::new(false),
        })
    }

    /// Moves to the next slice; `Ok(false)` at the end of the file.
    fn next_frame(&mut self) -> Result<bool, Located> {
        let frames = match &mut self.frames {
            Some(frames) => frames,
            None => self.frames.insert(Slices::start(
                &self.path,
                &self.schema,
                self.options.parquet_slice_rows,
            )?),
        };
        match frames.next() {
            None => Ok(false),
            Some(Err(message)) => Err(failure(&self.path, &message)),
            Some(Ok(slice)) => {
                self.cells = slice.cells;
                self.height = slice.height;
                self.next_row = 0;
                Ok(true)
            }
        }
    }

    /// Makes `at` the current record, forgetting the text rendered for the
    /// one before.
    fn go_to(&mut self, at: At) {
        if self.rendered_any.replace(false) {
            self.rendered.iter_mut().for_each(|slot| drop(slot.take()));
        }
        self.at = at;
    }

    /// The text of field `i` of a row, written once.
    fn rendered(&self, i: usize, text: impl FnOnce() -> String) -> &str {
        self.rendered_any.set(true);
        self.rendered[i].get_or_init(text)
    }
}

impl Records for ParquetRecords {
    fn next_record(&mut self) -> Result<bool, Located> {
        if self.at == At::Nothing && self.frames.is_none() {
            self.go_to(At::Header);
            return Ok(true);
        }
        loop {
            while self.next_row < self.height {
                let r = self.next_row;
                self.next_row += 1;
                self.rows += 1;
                self.go_to(At::Row(r));
                // A row of nulls or blanks is skipped, as CSV skips a blank line.
                if (0..self.cells.len()).any(|k| !self.is_blank(k)) {
                    return Ok(true);
                }
            }
            if !self.next_frame()? {
                self.go_to(At::Nothing);
                return Ok(false);
            }
        }
    }

    fn len(&self) -> usize {
        match self.at {
            At::Nothing => 0,
            At::Header => self.names.len(),
            At::Row(_) => self.cells.len(),
        }
    }

    fn field(&self, i: usize) -> &str {
        let r = match self.at {
            At::Nothing => return "",
            At::Header => return self.names.get(i).map_or("", String::as_str),
            At::Row(r) => r,
        };
        match self.cells.get(i) {
            None => "",
            Some(Cells::Text(ca)) => ca.get(r).map_or("", clean),
            Some(Cells::Int(ca)) => ca.get(r).map_or("", |v| self.rendered(i, || v.to_string())),
            Some(Cells::Float(ca)) => ca.get(r).map_or("", |v| self.rendered(i, || v.to_string())),
            Some(Cells::Bool(ca)) => ca.get(r).map_or("", |v| self.rendered(i, || v.to_string())),
        }
    }

    fn integer(&self, i: usize) -> Option<i64> {
        match (self.at, self.cells.get(i)) {
            (At::Row(r), Some(Cells::Int(ca))) => ca.get(r),
            _ => None,
        }
    }

    fn boolean(&self, i: usize) -> Option<bool> {
        match (self.at, self.cells.get(i)) {
            (At::Row(r), Some(Cells::Bool(ca))) => ca.get(r),
            _ => None,
        }
    }

    fn is_blank(&self, i: usize) -> bool {
        let r = match self.at {
            At::Nothing => return true,
            At::Header => return self.names.get(i).is_none_or(String::is_empty),
            At::Row(r) => r,
        };
        match self.cells.get(i) {
            None => true,
            Some(Cells::Text(ca)) => ca.get(r).is_none_or(|s| clean(s).is_empty()),
            Some(Cells::Int(ca)) => ca.get(r).is_none(),
            Some(Cells::Float(ca)) => ca.get(r).is_none(),
            Some(Cells::Bool(ca)) => ca.get(r).is_none(),
        }
    }

    fn column(&self, i: usize) -> usize {
        i.min(self.names.len()) + 1
    }

    fn end_column(&self) -> usize {
        self.names.len() + 1
    }

    fn line_no(&self) -> usize {
        if self.at == At::Header {
            1
        } else {
            usize::try_from(self.rows)
                .unwrap_or(usize::MAX)
                .saturating_add(1)
        }
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn holds(&self, i: usize, kind: CellKind) -> Result<(), String> {
        let Some(column) = self.schema.columns.get(i) else {
            return Ok(());
        };
        let ok = match kind {
            CellKind::Time => matches!(column.kind, Kind::Int | Kind::Float | Kind::Text),
            CellKind::Signal => column.kind == Kind::Text,
            CellKind::Value => matches!(column.kind, Kind::Int | Kind::Bool | Kind::Text),
        };
        if ok { Ok(()) } else { Err(column.type_name()) }
    }
}

/// A field as CSV records give it: trimmed, then unquoted.
fn clean(field: &str) -> &str {
    let field = field.trim_ascii();
    if field.len() >= 2 && field.starts_with('"') && field.ends_with('"') {
        &field[1..field.len() - 1]
    } else {
        field
    }
}
