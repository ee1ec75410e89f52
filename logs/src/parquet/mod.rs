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
//! # Streaming
//!
//! A polars lazy scan (`LazyFrame::scan_parquet`) ends in `sink_batches`, run
//! by the streaming engine on a thread of its own. The sink's callback hands
//! each `DataFrame` of about `batch_rows` rows to the reading side through a
//! rendezvous channel, and blocks until it is taken: the engine cannot run
//! ahead of the consumer, so memory is bounded by a few frames whatever the
//! size of the log. polars memory-maps local files while a query runs: the
//! pages it has read also count in the process's resident size (clean page
//! cache, which the kernel reclaims at will). So that they stay bounded too, a
//! log is read by one query per slice of `IngestOptions::parquet_slice_rows`
//! rows, each unmapping the file when done. Dropping the records closes the
//! channel, which makes the callback ask the engine to stop.

use std::cell::OnceCell;
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, sync_channel};
use std::thread::JoinHandle;

use polars::prelude::{
    BooleanChunked, DataFrame, DataType, Engine, Float64Chunked, IdxSize, Int64Chunked, LazyFrame,
    ParquetReader, PlRefPath, PlanCallback, PolarsError, PolarsResult, ScanArgsParquet, SchemaRef,
    SerReader, StringChunked, col,
};
use vocabulary::Located;
use vocabulary::panics::{self, Containment};

use crate::IngestOptions;
use crate::rows::{CellKind, Records, file_error, open_file};

mod archive;
mod columns;
mod intervals;
mod pages;
#[cfg(test)]
mod tests;

pub use archive::write_intervals_parquet;
pub(crate) use intervals::open_intervals;

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

/// Checks the footer's byte ranges and counts, which polars' streaming reader
/// uses unchecked: every row group and column chunk within the file of `size`
/// bytes, no negative count; then the page headers of every column chunk
/// ([`pages`]), whose counts polars trusts too.
fn check_footer(path: &Path, size: u64) -> Result<(), Located> {
    contained(path, || {
        let file = open_file(path)?;
        let copy = file
            .try_clone()
            .map_err(|e| failure(path, &e.to_string()))?;
        let mut reader = ParquetReader::new(copy);
        let footer = reader
            .get_metadata()
            .map_err(|e| failure(path, &e.to_string()))?;
        let fail = |why: String| Err(failure(path, &format!("a damaged footer: {why}")));
        for (k, group) in footer.row_groups.iter().enumerate() {
            let range = group.full_byte_range();
            if range.start > range.end || range.end > size {
                return fail(format!(
                    "row group {k} spans bytes {range:?} of a file of {size}"
                ));
            }
            for chunk in group.parquet_columns() {
                let range = chunk.byte_range();
                let counts = chunk.num_values() >= 0 && chunk.compressed_size() >= 0;
                if range.start > range.end || range.end > size || !counts {
                    return fail(format!(
                        "a column chunk of row group {k} spans bytes {range:?} of a file of {size}"
                    ));
                }
                pages::check_chunk(&file, range.start, range.end, chunk.num_values()).map_err(
                    |why| {
                        failure(
                            path,
                            &format!("a damaged column chunk in row group {k}: {why}"),
                        )
                    },
                )?;
            }
        }
        Ok(())
    })
}

/// The schema of a Parquet file, from its footer.
pub(crate) fn schema(path: &Path) -> Result<SchemaRef, Located> {
    let size = check_frame(path)?;
    check_footer(path, size)?;
    contained(path, || {
        let failed = |e: PolarsError| failure(path, &e.to_string());
        let source = PlRefPath::try_from_path(&crate::spool::readable(path)).map_err(failed)?;
        LazyFrame::scan_parquet(source, scan_args())
            .and_then(|mut lf| lf.collect_schema())
            .map_err(failed)
    })
}

/// The names of a Parquet file's columns, from its footer.
pub(crate) fn column_names(path: &Path) -> Result<Vec<String>, Located> {
    Ok(schema(path)?.iter_names().map(|n| n.to_string()).collect())
}

fn scan_args() -> ScanArgsParquet {
    ScanArgsParquet {
        glob: false,
        ..ScanArgsParquet::default()
    }
}

/// The rows of a Parquet log, as records.
pub struct ParquetRecords {
    path: PathBuf,
    schema: SchemaRef,
    names: Vec<String>,
    options: IngestOptions,
    /// The frames, once the header has been read.
    frames: Option<Frames>,
    /// The current frame's columns, and the next row in it.
    cells: Vec<Cells>,
    height: usize,
    next_row: usize,
    /// Rows before the current one (blank rows included).
    rows: u64,
    header: bool,
    /// The current record's text cells, one after the other.
    text: String,
    /// The current record's fields.
    fields: Vec<Field>,
    /// The text of its integer, float and boolean fields, written when asked
    /// for (in an error message, say), not for every row.
    rendered: Vec<OnceCell<String>>,
}

/// A field of the current record.
#[derive(Debug, Clone, Copy)]
enum Field {
    /// Text, trimmed and unquoted: a range of `ParquetRecords::text`.
    Text(usize, usize),
    Int(i64),
    Float(f64),
    Bool(bool),
    Null,
}

impl ParquetRecords {
    /// Opens the file and reads its schema; no row is read yet.
    pub fn open(path: &Path, options: &IngestOptions) -> Result<Self, Located> {
        let schema = schema(path)?;
        let names = schema.iter_names().map(|n| n.to_string()).collect();
        Ok(ParquetRecords {
            path: path.to_path_buf(),
            schema,
            names,
            options: options.clone(),
            frames: None,
            cells: Vec::new(),
            height: 0,
            next_row: 0,
            rows: 0,
            header: false,
            text: String::new(),
            fields: Vec::new(),
            rendered: Vec::new(),
        })
    }

    /// The header record: the column names.
    fn read_header(&mut self) {
        self.header = true;
        self.text.clear();
        self.fields.clear();
        for name in &self.names {
            let start = self.text.len();
            self.text.push_str(name);
            self.fields.push(Field::Text(start, self.text.len()));
        }
        self.rendered = vec![OnceCell::new(); self.names.len()];
    }

    /// Moves to the next frame; `Ok(false)` at the end of the file.
    fn next_frame(&mut self) -> Result<bool, Located> {
        let frames = match &mut self.frames {
            Some(frames) => frames,
            None => self
                .frames
                .insert(Frames::start(&self.path, &self.options, None)?),
        };
        match frames.next() {
            None => Ok(false),
            Some(Err(message)) => Err(failure(&self.path, &message)),
            Some(Ok(df)) => {
                let cells = || {
                    (self.names.iter())
                        .map(|name| Cells::of(&df, name))
                        .collect::<Result<_, _>>()
                        .map_err(|message| failure(&self.path, &message))
                };
                self.cells = contained(&self.path, cells)?;
                self.height = df.height();
                self.next_row = 0;
                Ok(true)
            }
        }
    }

    /// Takes row `i` of the current frame; `false` if all its cells are null
    /// or blank.
    fn take_row(&mut self, i: usize) -> bool {
        self.text.clear();
        self.fields.clear();
        for slot in &mut self.rendered {
            slot.take();
        }
        for cells in &self.cells {
            let field = cells.field(i, &mut self.text);
            self.fields.push(field);
        }
        (0..self.fields.len()).any(|k| !self.is_blank(k))
    }
}

impl Records for ParquetRecords {
    fn next_record(&mut self) -> Result<bool, Located> {
        if !self.header && self.frames.is_none() {
            self.read_header();
            return Ok(true);
        }
        self.header = false;
        loop {
            while self.next_row < self.height {
                let i = self.next_row;
                self.next_row += 1;
                self.rows += 1;
                if self.take_row(i) {
                    return Ok(true);
                }
            }
            if !self.next_frame()? {
                self.fields.clear();
                return Ok(false);
            }
        }
    }

    fn len(&self) -> usize {
        self.fields.len()
    }

    fn field(&self, i: usize) -> &str {
        let Some(&field) = self.fields.get(i) else {
            return "";
        };
        match field {
            Field::Text(a, b) => &self.text[a..b],
            Field::Null => "",
            Field::Int(v) => self.rendered[i].get_or_init(|| v.to_string()),
            Field::Float(v) => self.rendered[i].get_or_init(|| v.to_string()),
            Field::Bool(v) => self.rendered[i].get_or_init(|| v.to_string()),
        }
    }

    fn integer(&self, i: usize) -> Option<i64> {
        match self.fields.get(i) {
            Some(Field::Int(v)) => Some(*v),
            _ => None,
        }
    }

    fn boolean(&self, i: usize) -> Option<bool> {
        match self.fields.get(i) {
            Some(Field::Bool(v)) => Some(*v),
            _ => None,
        }
    }

    fn is_blank(&self, i: usize) -> bool {
        match self.fields.get(i) {
            None | Some(Field::Null) => true,
            Some(Field::Text(a, b)) => a == b,
            Some(_) => false,
        }
    }

    fn column(&self, i: usize) -> usize {
        i.min(self.names.len()) + 1
    }

    fn end_column(&self) -> usize {
        self.names.len() + 1
    }

    fn line_no(&self) -> usize {
        if self.header {
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
        let Some((_, dtype)) = self.schema.get_at_index(i) else {
            return Ok(());
        };
        let text = matches!(dtype, DataType::String);
        let ok = match kind {
            CellKind::Time => dtype.is_integer() || dtype.is_float() || text,
            CellKind::Signal => text || matches!(dtype, DataType::Categorical(..)),
            CellKind::Value => dtype.is_integer() || *dtype == DataType::Boolean || text,
        };
        if ok { Ok(()) } else { Err(dtype.to_string()) }
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

/// One column of a frame, by type.
enum Cells {
    Text(StringChunked),
    Int(Int64Chunked),
    Float(Float64Chunked),
    Bool(BooleanChunked),
}

impl Cells {
    fn of(df: &DataFrame, name: &str) -> Result<Cells, String> {
        let failed = |e: PolarsError| {
            format!(
                "cannot decode column '{name}': {}",
                first_line(&e.to_string())
            )
        };
        let series = df
            .column(name)
            .map_err(failed)?
            .as_materialized_series()
            .rechunk();
        Ok(match series.dtype() {
            DataType::String => Cells::Text(series.str().map_err(failed)?.clone()),
            DataType::Boolean => Cells::Bool(series.bool().map_err(failed)?.clone()),
            DataType::Categorical(..) => {
                let text = series.cast(&DataType::String).map_err(failed)?;
                Cells::Text(text.str().map_err(failed)?.clone())
            }
            d if d.is_integer() => {
                let ints = series.cast(&DataType::Int64).map_err(failed)?;
                Cells::Int(ints.i64().map_err(failed)?.clone())
            }
            d if d.is_float() => {
                let floats = series.cast(&DataType::Float64).map_err(failed)?;
                Cells::Float(floats.f64().map_err(failed)?.clone())
            }
            other => return Err(format!("column '{name}' has unsupported type {other}")),
        })
    }

    /// Cell `i`, its text (trimmed and unquoted) appended to `text`.
    fn field(&self, i: usize, text: &mut String) -> Field {
        match self {
            Cells::Text(ca) => match ca.get(i) {
                None => Field::Null,
                Some(s) => {
                    let start = text.len();
                    text.push_str(clean(s));
                    Field::Text(start, text.len())
                }
            },
            Cells::Int(ca) => ca.get(i).map_or(Field::Null, Field::Int),
            Cells::Float(ca) => ca.get(i).map_or(Field::Null, Field::Float),
            Cells::Bool(ca) => ca.get(i).map_or(Field::Null, Field::Bool),
        }
    }
}

/// The frames of the queries that read a file, in order, computed on a thread
/// of its own.
pub(crate) struct Frames {
    receiver: Receiver<DataFrame>,
    worker: Option<JoinHandle<PolarsResult<()>>>,
}

impl Frames {
    /// Starts reading the file: every column, or only `columns` (in that
    /// order), which polars then does not decode.
    pub(crate) fn start(
        path: &Path,
        options: &IngestOptions,
        columns: Option<&[&str]>,
    ) -> Result<Frames, Located> {
        contained(path, || Frames::start_uncontained(path, options, columns))
    }

    fn start_uncontained(
        path: &Path,
        options: &IngestOptions,
        columns: Option<&[&str]>,
    ) -> Result<Frames, Located> {
        let failed = |e: PolarsError| failure(path, &e.to_string());
        let queries = slices(path, options.parquet_slice_rows, columns)?;
        // A rendezvous channel: the callback (on polars' blocking pool) waits
        // until the consumer takes the frame, so the engine never runs more than
        // a frame ahead of it, which bounds memory.
        let (sender, receiver) = sync_channel::<DataFrame>(0);
        let callback = PlanCallback::new(move |df: DataFrame| {
            // Stop the query once nobody reads (the records were dropped).
            Ok(sender.send(df).is_err())
        });
        let rows = NonZeroUsize::new(options.batch_rows.max(1));
        let queries = queries
            .into_iter()
            .map(|lf| {
                lf.sink_batches(callback.clone(), true, rows)
                    .map_err(failed)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let worker = std::thread::Builder::new()
            .name("gardefou-parquet".to_string())
            .spawn(move || {
                // Its panics come back through `join`, as the file's error.
                let _quiet = Containment::start();
                // One after the other: the frames stay in order.
                for lf in queries {
                    lf.collect_with_engine(Engine::Streaming)?;
                }
                Ok(())
            })
            .map_err(|e| file_error(path, format!("cannot start reading the log: {e}")))?;
        Ok(Frames {
            receiver,
            worker: Some(worker),
        })
    }

    /// The next frame, `None` at the end, or polars' error message.
    pub(crate) fn next(&mut self) -> Option<Result<DataFrame, String>> {
        if let Ok(df) = self.receiver.recv() {
            return Some(Ok(df));
        }
        // The sender is gone: the query has ended, well or not.
        let worker = self.worker.take()?;
        match worker.join() {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(Err(e.to_string())),
            Err(payload) => Some(Err(panics::message(payload.as_ref()))),
        }
    }
}

/// The queries that read a file, one per slice of `slice_rows` rows: polars
/// maps the whole file while a query runs; a query per slice maps it anew and
/// unmaps it when done, so the file's resident pages stay bounded by a slice's.
fn slices(
    path: &Path,
    slice_rows: usize,
    columns: Option<&[&str]>,
) -> Result<Vec<LazyFrame>, Located> {
    contained(path, || slices_uncontained(path, slice_rows, columns))
}

fn slices_uncontained(
    path: &Path,
    slice_rows: usize,
    columns: Option<&[&str]>,
) -> Result<Vec<LazyFrame>, Located> {
    let failed = |e: PolarsError| failure(path, &e.to_string());
    let slice_rows = slice_rows.max(1);
    let source = PlRefPath::try_from_path(&crate::spool::readable(path)).map_err(failed)?;
    let mut lf = LazyFrame::scan_parquet(source, scan_args()).map_err(failed)?;
    if let Some(columns) = columns {
        lf = lf.select(columns.iter().map(|&name| col(name)).collect::<Vec<_>>());
    }
    let file = open_file(path)?;
    let rows = ParquetReader::new(file).num_rows().map_err(failed)?;
    if rows <= slice_rows {
        return Ok(vec![lf]);
    }
    Ok((0..rows)
        .step_by(slice_rows)
        .map(|offset| lf.clone().slice(offset as i64, slice_rows as IdxSize))
        .collect())
}
