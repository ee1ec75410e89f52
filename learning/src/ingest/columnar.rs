//! The events, intervals and scans forms, as CSV or Parquet, read with polars in
//! batches.
//!
//! # Streaming
//!
//! A polars lazy scan (`LazyCsvReader` or `LazyFrame::scan_parquet`) ends in
//! `sink_batches`, run by the streaming engine on a thread of its own. The sink's
//! callback hands each `DataFrame` of about `batch_rows` rows to the reading side
//! through a rendezvous channel, and blocks until it is taken: the engine cannot
//! run ahead of the consumer, so memory is bounded by a few batches whatever the
//! size of the log (measured: about 40 MB of heap for batches of 10 000 rows,
//! 260 MB for the default 2^20, on 10 and 20 million events alike). polars
//! memory-maps local files while a query runs: the pages it has read also count
//! in the process's resident size (clean page cache, which the kernel reclaims
//! at will). So that they stay bounded too, a Parquet log is read by one query
//! per slice of `IngestOptions::parquet_slice_rows` rows, each unmapping the
//! file when done; CSV logs past the memory budget go to the buffered reader. (polars 0.55 has no batched CSV or Parquet
//! reader any more, and its `collect_batches` needs the `async` feature; this is
//! the same mechanism on a plain thread.) Dropping the stream closes the channel,
//! which makes the callback ask the engine to stop.
//!
//! Each `DataFrame` is then decoded row by row into [`Event`]s with the exact
//! rules of `diagnoser::log`: times in the given unit or RFC 3339 text, values
//! `0`, `1`, `true`, `false`, only real changes kept, and each scan's events
//! sorted by signal. The scan at the end of a batch is held back until a later
//! time shows it is complete, so batches concatenate into one sorted stream.
//!
//! The intervals form is read twice: a first pass checks every row and finds the
//! initial values (the open intervals of signals that never change come last in
//! the archive) and the order of the rows; the second emits the changes. An
//! archive whose closed intervals are in `t_end` order (as written by
//! `diagnoser::log::IntervalWriter` and [`super::write_intervals_parquet`]) or
//! whose rows are in `t_start` order streams in bounded memory; any other order
//! costs 16 bytes per row, to sort the changes.
//!
//! # Errors
//!
//! Errors are [`Located`]. For CSV, the fast path only notices that something is
//! wrong; the file is then read again with the exact readers of
//! `diagnoser::log`, which report the first problem by line and column. For
//! Parquet, the "line" of a row is its 1-based row number plus one (as if the
//! column names were line 1) and the column is the 1-based index of the column in
//! the file's schema.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use std::thread::JoinHandle;

use diagnoser::log::{EventReader, IntervalReader, ScanReader, TimeFormatChoice};
use diagnoser::{
    Event, Located, Location, Plant, SignalId, SignalTable, Time, TimeFormat, TimeUnit,
};
use polars::prelude::{
    BooleanChunked, DataFrame, DataType, Engine, Field, Float64Chunked, IdxSize, Int64Chunked,
    LazyCsvReader, LazyFileListReader, LazyFrame, ParquetReader, PlRefPath, PlanCallback,
    PolarsResult, ScanArgsParquet, Schema, SchemaRef, SerReader, StringChunked, col,
};

use super::{IngestOptions, LogEnd, LogFormat, LogStream};

/// The three ways of writing the same information.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shape {
    Events,
    Intervals,
    Scans,
}

/// CSV or Parquet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Container {
    Csv,
    Parquet,
}

/// Required and optional columns of the events form.
const EVENT_COLUMNS: [&str; 3] = ["t", "signal", "value"];
const EVENT_OPTIONAL: [&str; 3] = ["site", "seq", "quality"];
const EVENT_EXPECTED: &str = "t,signal,value and optionally site, seq, quality";
/// Columns of the intervals form.
const INTERVAL_COLUMNS: [&str; 4] = ["signal", "value", "t_start", "t_end"];
const INTERVAL_EXPECTED: &str = "signal,value,t_start,t_end";

/// Opens a CSV or Parquet log of one of the three forms.
pub(super) fn open(
    path: &Path,
    plant: &Plant,
    options: &IngestOptions,
    format: LogFormat,
) -> Result<LogStream, Located> {
    let (shape, container) = match format {
        LogFormat::EventsCsv => (Shape::Events, Container::Csv),
        LogFormat::IntervalsCsv => (Shape::Intervals, Container::Csv),
        LogFormat::ScansCsv => (Shape::Scans, Container::Csv),
        LogFormat::EventsParquet => (Shape::Events, Container::Parquet),
        LogFormat::IntervalsParquet => (Shape::Intervals, Container::Parquet),
        LogFormat::ScansParquet => (Shape::Scans, Container::Parquet),
        LogFormat::Candump | LogFormat::Vcd => {
            return Err(file_error(
                path,
                format!("{format:?} is not a columnar log form"),
            ));
        }
    };
    let ctx = Ctx {
        path: path.to_path_buf(),
        shape,
        container,
        signals: Arc::new(plant.signals.clone()),
        unit: options.time_unit,
    };
    let batch = options.batch_rows.max(1);
    let (layout, clock) = match container {
        Container::Csv => csv_layout(&ctx)?,
        Container::Parquet => parquet_layout(&ctx)?,
    };
    let form: Box<dyn Form> = match shape {
        Shape::Events => Box::new(EventsForm::new(&ctx, layout.clone(), clock)),
        Shape::Scans => Box::new(ScansForm::new(&ctx, layout.clone(), clock)),
        Shape::Intervals => {
            // First pass: check every row, find the initial values and the order.
            let mut check = IntervalCheck::new(&ctx, layout.clone(), clock);
            let mut frames = Frames::start(
                &ctx,
                scans(&ctx, &layout, options.parquet_slice_rows)?,
                batch,
            )?;
            let mut none = Vec::new();
            loop {
                match frames.next() {
                    None => break,
                    Some(Err(message)) => return Err(ctx.polars_failure(&message)),
                    Some(Ok(df)) => check
                        .feed(&df, &mut none)
                        .map_err(|problem| ctx.locate(problem))?,
                }
            }
            check
                .finish(&mut none)
                .map_err(|problem| ctx.locate(problem))?;
            Box::new(IntervalEvents::new(&ctx, layout.clone(), check)?)
        }
    };
    let frames = Frames::start(
        &ctx,
        scans(&ctx, &layout, options.parquet_slice_rows)?,
        batch,
    )?;
    let mut reader = Reader {
        frames,
        form,
        ctx,
        batch,
        ready: VecDeque::new(),
        done: false,
        error: None,
        end: LogEnd::default(),
    };
    // Read until the initial values are known; the events read meanwhile wait in
    // `ready` for the first batch.
    while reader.form.opening().is_none() && !reader.done {
        match reader.pull() {
            Ok(more) => reader.done = !more,
            Err(e) => return Err(e),
        }
    }
    let Some((start, initial)) = reader.form.opening() else {
        return Err(no_data(path));
    };
    let initial = initial.to_vec();
    let end = reader.end.clone();
    Ok(LogStream {
        path: path.to_path_buf(),
        format,
        time: reader.form.format(),
        start,
        initial,
        batches: Box::new(reader),
        end,
    })
}

// ----- errors -----

/// What locating an error needs.
#[derive(Clone)]
struct Ctx {
    path: PathBuf,
    shape: Shape,
    container: Container,
    signals: Arc<SignalTable>,
    unit: TimeUnit,
}

/// A piece of an error message: text, or the line of a data row (known only once
/// the row is located).
#[derive(Debug, Clone)]
enum Piece {
    Text(String),
    LineOf(u64),
}

/// A problem found while decoding, before it is located in the file.
#[derive(Debug, Clone)]
struct Problem {
    /// The data row (from 0, blank lines not counted); `None` for the whole file.
    row: Option<u64>,
    /// The column's position in the file (from 0); `None` for the whole row.
    column: Option<usize>,
    field: Option<String>,
    message: Vec<Piece>,
}

impl Problem {
    fn file(message: impl Into<String>) -> Self {
        Problem {
            row: None,
            column: None,
            field: None,
            message: vec![Piece::Text(message.into())],
        }
    }

    fn row(row: u64, message: impl Into<String>) -> Self {
        Problem {
            row: Some(row),
            ..Problem::file(message)
        }
    }

    fn at(row: u64, column: usize, field: &str, message: impl Into<String>) -> Self {
        Problem {
            row: Some(row),
            column: Some(column),
            field: Some(field.to_string()),
            message: vec![Piece::Text(message.into())],
        }
    }

    /// Appends the line of data row `row` to the message.
    fn line_of(mut self, row: u64) -> Self {
        self.message.push(Piece::LineOf(row));
        self
    }

    /// Appends text to the message.
    fn then(mut self, text: impl Into<String>) -> Self {
        self.message.push(Piece::Text(text.into()));
        self
    }

    fn rows(&self) -> Vec<u64> {
        let mut rows: Vec<u64> = self.row.into_iter().collect();
        for piece in &self.message {
            if let Piece::LineOf(r) = piece {
                rows.push(*r);
            }
        }
        rows
    }

    fn render(&self, line_of: impl Fn(u64) -> usize) -> String {
        let mut text = String::new();
        for piece in &self.message {
            match piece {
                Piece::Text(s) => text.push_str(s),
                Piece::LineOf(r) => text.push_str(&line_of(*r).to_string()),
            }
        }
        text
    }
}

fn file_error(path: &Path, message: impl Into<String>) -> Located {
    Located::new(Location::new(path, 0, 0), message)
}

fn no_data(path: &Path) -> Located {
    file_error(
        path,
        "no data rows: a log must give the initial value of every signal",
    )
}

/// The first line of a polars error: its messages can span several lines of
/// advice, and our errors are one line.
fn first_line(message: &str) -> &str {
    message.lines().next().unwrap_or("").trim()
}

impl Ctx {
    /// Places a problem in the file.
    fn locate(&self, problem: Problem) -> Located {
        match self.container {
            Container::Parquet => {
                // Row r (from 0) is "line" r + 2: line 1 holds the column names.
                let line_of = |r: u64| usize::try_from(r).unwrap_or(usize::MAX).saturating_add(2);
                let (line, column) = match problem.row {
                    Some(r) => (line_of(r), problem.column.map_or(0, |c| c + 1)),
                    None => (0, 0),
                };
                let mut location = Location::new(&self.path, line, column);
                if let Some(field) = &problem.field {
                    location = location.with_field(field.clone());
                }
                Located::new(location, problem.render(line_of))
            }
            Container::Csv => {
                let rows = problem.rows();
                // The exact reader reports the first problem of the file, which
                // comes before (or is) the one the fast path found.
                let lines = match self.exact_lines(&rows, problem.row) {
                    Ok(lines) => lines,
                    Err(exact) => return exact,
                };
                let line_of = |r: u64| {
                    rows.iter()
                        .position(|&x| x == r)
                        .and_then(|k| lines.get(k).copied())
                        .unwrap_or(0)
                };
                let line = problem.row.map_or(0, line_of);
                let column = match problem.column {
                    Some(c) if line > 0 => field_column(&self.path, line, c),
                    _ => 0,
                };
                let mut location = Location::new(&self.path, line, column);
                if let Some(field) = &problem.field {
                    location = location.with_field(field.clone());
                }
                Located::new(location, problem.render(line_of))
            }
        }
    }

    /// The error for a failure of polars itself (a malformed file).
    fn polars_failure(&self, message: &str) -> Located {
        if self.container == Container::Csv {
            if let Err(exact) = self.exact_lines(&[], None) {
                return exact;
            }
            return file_error(
                &self.path,
                format!("cannot read the CSV log: {}", first_line(message)),
            );
        }
        file_error(
            &self.path,
            format!("cannot read the Parquet log: {}", first_line(message)),
        )
    }

    /// Reads the CSV file again with diagnoser's exact reader of its form, up to
    /// data row `upto` (the whole file if `None`): its first error if it finds
    /// one, else the line of each data row of `rows` (0 if not reached).
    fn exact_lines(&self, rows: &[u64], upto: Option<u64>) -> Result<Vec<usize>, Located> {
        let mut lines = vec![0; rows.len()];
        let mut note = |i: u64, line: usize| {
            for (k, &r) in rows.iter().enumerate() {
                if r == i {
                    lines[k] = line;
                }
            }
            upto == Some(i)
        };
        let reader = open_text(&self.path)?;
        let choice = TimeFormatChoice::Detect(self.unit);
        let path = self.path.as_path();
        let signals = self.signals.as_ref();
        let mut i = 0u64;
        match self.shape {
            Shape::Events => {
                let mut reader = EventReader::new(reader, path, signals, choice)?;
                while let Some(row) = reader.next() {
                    row?;
                    if note(i, reader.line()) {
                        break;
                    }
                    i += 1;
                }
            }
            Shape::Intervals => {
                let mut reader = IntervalReader::new(reader, path, signals, choice)?;
                while let Some(row) = reader.next() {
                    row?;
                    if note(i, reader.line()) {
                        break;
                    }
                    i += 1;
                }
            }
            Shape::Scans => {
                let mut reader = ScanReader::new(reader, path, signals, choice)?;
                while let Some(scan) = reader.next_scan() {
                    scan?;
                    if note(i, reader.line()) {
                        break;
                    }
                    i += 1;
                }
            }
        }
        Ok(lines)
    }
}

fn open_text(path: &Path) -> Result<BufReader<File>, Located> {
    File::open(path)
        .map(BufReader::new)
        .map_err(|e| file_error(path, format!("cannot open the log: {e}")))
}

/// The column (from 1, in bytes like diagnoser's readers) where field `index` of
/// line `line` starts, after its leading whitespace; 0 if the line is not found.
fn field_column(path: &Path, line: usize, index: usize) -> usize {
    let Ok(file) = File::open(path) else {
        return 0;
    };
    let mut text = Vec::new();
    let mut reader = BufReader::new(file);
    for _ in 0..line {
        text.clear();
        match reader.read_until(b'\n', &mut text) {
            Ok(0) | Err(_) => return 0,
            Ok(_) => {}
        }
    }
    while matches!(text.last(), Some(b'\n' | b'\r')) {
        text.pop();
    }
    let mut start = 0;
    for _ in 0..index {
        match text[start..].iter().position(|&b| b == b',') {
            Some(p) => start += p + 1,
            None => return text.len() + 1,
        }
    }
    while text
        .get(start)
        .is_some_and(|b| *b != b',' && b.is_ascii_whitespace())
    {
        start += 1;
    }
    start + 1
}

// ----- layouts: which columns to read -----

/// The columns to read: the form's columns first (in the form's order), then the
/// other columns of a CSV file (only looked at to recognise blank lines).
#[derive(Debug, Clone)]
struct Layout {
    /// Name of each column in the polars frame, and its position in the file.
    columns: Vec<(String, usize)>,
    /// For the scans form: the signal of each column after `t`.
    signals: Vec<SignalId>,
    /// CSV: blank lines come out as rows of nulls and are skipped.
    csv: bool,
    /// CSV: lines before the header (blank lines) and number of fields.
    skip_lines: usize,
    width: usize,
}

impl Layout {
    fn position(&self, k: usize) -> usize {
        self.columns.get(k).map_or(0, |c| c.1)
    }
}

/// A CSV file's header: checked by diagnoser's reader of its form, which also
/// detects how times are written from the first data row.
fn csv_layout(ctx: &Ctx) -> Result<(Layout, Clock), Located> {
    let path = ctx.path.as_path();
    let signals = ctx.signals.as_ref();
    let choice = TimeFormatChoice::Detect(ctx.unit);
    let format = match ctx.shape {
        Shape::Events => EventReader::new(open_text(path)?, path, signals, choice)?.format(),
        Shape::Intervals => IntervalReader::new(open_text(path)?, path, signals, choice)?.format(),
        Shape::Scans => ScanReader::new(open_text(path)?, path, signals, choice)?.format(),
    };
    let (header_line, names) = read_header(path)?;
    let find = |name: &str| names.iter().position(|n| n == name);
    let mut order: Vec<usize> = Vec::new();
    let mut layout_signals = Vec::new();
    match ctx.shape {
        Shape::Events | Shape::Intervals => {
            let required: &[&str] = if ctx.shape == Shape::Events {
                &EVENT_COLUMNS
            } else {
                &INTERVAL_COLUMNS
            };
            for name in required {
                match find(name) {
                    Some(i) => order.push(i),
                    None => {
                        return Err(Located::new(
                            Location::new(path, header_line, 0),
                            format!("missing required column '{name}'"),
                        ));
                    }
                }
            }
        }
        Shape::Scans => {
            let Some(t) = find("t") else {
                return Err(Located::new(
                    Location::new(path, header_line, 0),
                    "missing required column 't'",
                ));
            };
            order.push(t);
            for (i, name) in names.iter().enumerate() {
                if i == t {
                    continue;
                }
                let Some(id) = signals.id(name) else {
                    return Err(Located::new(
                        Location::new(path, header_line, 0),
                        format!("unknown column '{name}': not a signal of the plant"),
                    ));
                };
                order.push(i);
                layout_signals.push(id);
            }
        }
    }
    for i in 0..names.len() {
        if !order.contains(&i) {
            order.push(i);
        }
    }
    let layout = Layout {
        columns: order.into_iter().map(|i| (format!("c{i}"), i)).collect(),
        signals: layout_signals,
        csv: true,
        skip_lines: header_line.saturating_sub(1),
        width: names.len(),
    };
    Ok((layout, Clock::given(format, ctx.unit)))
}

/// The first non-blank line of a CSV file, split like diagnoser's readers do:
/// its line number and its trimmed, unquoted fields.
fn read_header(path: &Path) -> Result<(usize, Vec<String>), Located> {
    let mut reader = open_text(path)?;
    let mut bytes = Vec::new();
    let mut line = 0;
    loop {
        bytes.clear();
        let n = reader
            .by_ref()
            .take(1 << 20)
            .read_until(b'\n', &mut bytes)
            .map_err(|e| file_error(path, format!("cannot read the log: {e}")))?;
        if n == 0 {
            return Err(Located::new(Location::new(path, 1, 0), "empty file"));
        }
        line += 1;
        let text = String::from_utf8_lossy(&bytes);
        let text = text.trim_start_matches('\u{feff}');
        if text.trim().is_empty() {
            continue;
        }
        let names = text
            .trim_end_matches(['\n', '\r'])
            .split(',')
            .map(|f| clean(f).to_string())
            .collect();
        return Ok((line, names));
    }
}

/// A Parquet file's schema, checked against the form.
fn parquet_layout(ctx: &Ctx) -> Result<(Layout, Clock), Located> {
    let schema = parquet_schema(&ctx.path)?;
    let names: Vec<String> = schema.iter_names().map(|n| n.to_string()).collect();
    let path = ctx.path.as_path();
    let header =
        |column: usize, message: String| Located::new(Location::new(path, 1, column), message);
    let find = |name: &str| names.iter().position(|n| n == name);
    let mut order = Vec::new();
    let mut layout_signals = Vec::new();
    match ctx.shape {
        Shape::Events | Shape::Intervals => {
            let (required, optional, expected): (&[&str], &[&str], &str) =
                if ctx.shape == Shape::Events {
                    (&EVENT_COLUMNS, &EVENT_OPTIONAL, EVENT_EXPECTED)
                } else {
                    (&INTERVAL_COLUMNS, &[], INTERVAL_EXPECTED)
                };
            for (i, name) in names.iter().enumerate() {
                if !required.contains(&name.as_str()) && !optional.contains(&name.as_str()) {
                    return Err(header(
                        i + 1,
                        format!("unknown column '{name}' (expected {expected})"),
                    ));
                }
            }
            for name in required {
                match find(name) {
                    Some(i) => order.push(i),
                    None => {
                        return Err(header(
                            0,
                            format!("missing required column '{name}' (expected {expected})"),
                        ));
                    }
                }
            }
        }
        Shape::Scans => {
            let Some(t) = find("t") else {
                return Err(header(
                    0,
                    "missing required column 't' (expected t,<signal>,<signal>,…)".to_string(),
                ));
            };
            order.push(t);
            let mut seen = vec![false; ctx.signals.len()];
            for (i, name) in names.iter().enumerate() {
                if i == t {
                    continue;
                }
                let Some(id) = ctx.signals.id(name) else {
                    return Err(header(
                        i + 1,
                        format!("unknown column '{name}': not a signal of the plant"),
                    ));
                };
                seen[id.index()] = true;
                order.push(i);
                layout_signals.push(id);
            }
            let missing: Vec<&str> = ctx
                .signals
                .iter()
                .filter(|(id, _)| !seen[id.index()])
                .map(|(_, s)| s.name.as_str())
                .collect();
            if !missing.is_empty() {
                let s = if missing.len() > 1 { "s" } else { "" };
                return Err(header(
                    0,
                    format!(
                        "missing column{s} for signal{s} {}: a scans log needs every signal",
                        quote_list(&missing)
                    ),
                ));
            }
        }
    }
    // Check each column's type once, here, rather than on every batch.
    for (k, &i) in order.iter().enumerate() {
        let (name, dtype) = match schema.get_at_index(i) {
            Some((name, dtype)) => (name.as_str(), dtype),
            None => continue,
        };
        let is_time = match ctx.shape {
            Shape::Events | Shape::Scans => k == 0,
            Shape::Intervals => k >= 2,
        };
        let is_signal = ctx.shape != Shape::Scans && name == "signal";
        let ok = if is_time {
            dtype.is_integer() || dtype.is_float() || *dtype == DataType::String
        } else if is_signal {
            matches!(dtype, DataType::String | DataType::Categorical(..))
        } else {
            dtype.is_integer() || *dtype == DataType::Boolean || *dtype == DataType::String
        };
        if !ok {
            let expected = if is_time {
                format!("integers or floats in {}, or RFC 3339 text", ctx.unit)
            } else if is_signal {
                "signal names (text)".to_string()
            } else {
                "booleans, 0 and 1, or text 0, 1, true, false".to_string()
            };
            return Err(header(
                i + 1,
                format!("column '{name}' has type {dtype}: expected {expected}"),
            ));
        }
    }
    let layout = Layout {
        columns: order
            .into_iter()
            .map(|i| (names.get(i).cloned().unwrap_or_default(), i))
            .collect(),
        signals: layout_signals,
        csv: false,
        skip_lines: 0,
        width: names.len(),
    };
    Ok((layout, Clock::parquet(ctx.unit)))
}

/// The schema of a Parquet file, from its footer.
pub(super) fn parquet_schema(path: &Path) -> Result<SchemaRef, Located> {
    let failure = |e: polars::prelude::PolarsError| {
        file_error(
            path,
            format!(
                "cannot read the Parquet log: {}",
                first_line(&e.to_string())
            ),
        )
    };
    let source = PlRefPath::try_from_path(path).map_err(failure)?;
    let args = ScanArgsParquet {
        glob: false,
        ..ScanArgsParquet::default()
    };
    LazyFrame::scan_parquet(source, args)
        .and_then(|mut lf| lf.collect_schema())
        .map_err(failure)
}

/// The queries that read a layout's columns, in order: one for CSV, one per
/// slice of `slice_rows` rows for Parquet. polars maps the whole file while a
/// query runs; a query per slice maps it anew and unmaps it when done, so the
/// file's resident pages stay bounded by a slice's, whatever its size.
fn scans(ctx: &Ctx, layout: &Layout, slice_rows: usize) -> Result<Vec<LazyFrame>, Located> {
    let slice_rows = slice_rows.max(1);
    let lf = scan(ctx, layout)?;
    if ctx.container != Container::Parquet {
        return Ok(vec![lf]);
    }
    let failure = |e: polars::prelude::PolarsError| ctx.polars_failure(&e.to_string());
    let file = File::open(&ctx.path)
        .map_err(|e| file_error(&ctx.path, format!("cannot open the log: {e}")))?;
    let rows = ParquetReader::new(file).num_rows().map_err(failure)?;
    if rows <= slice_rows {
        return Ok(vec![lf]);
    }
    Ok((0..rows)
        .step_by(slice_rows)
        .map(|offset| lf.clone().slice(offset as i64, slice_rows as IdxSize))
        .collect())
}

/// The lazy scan of a layout's columns.
fn scan(ctx: &Ctx, layout: &Layout) -> Result<LazyFrame, Located> {
    let failure = |e: polars::prelude::PolarsError| ctx.polars_failure(&e.to_string());
    let source = PlRefPath::try_from_path(&ctx.path).map_err(failure)?;
    let lf = match ctx.container {
        Container::Csv => {
            // Every field as text: times and values are parsed here with the exact
            // rules of diagnoser (nanosecond-exact decimals, RFC 3339, 0/1/true/
            // false), which polars' inference would not follow. Columns are named
            // by position so that any header text works.
            let schema: Schema = (0..layout.width)
                .map(|i| Field::new(format!("c{i}").into(), DataType::String))
                .collect();
            LazyCsvReader::new(source)
                .with_has_header(true)
                .with_skip_lines(layout.skip_lines)
                .with_schema(Some(Arc::new(schema)))
                .with_missing_is_null(true)
                .with_glob(false)
                .finish()
                .map_err(failure)?
        }
        Container::Parquet => {
            let args = ScanArgsParquet {
                glob: false,
                ..ScanArgsParquet::default()
            };
            LazyFrame::scan_parquet(source, args).map_err(failure)?
        }
    };
    Ok(lf.select(
        layout
            .columns
            .iter()
            .map(|(name, _)| col(name.as_str()))
            .collect::<Vec<_>>(),
    ))
}

// ----- the polars side: frames in order, from a thread -----

/// The frames of a polars query, in order, computed on a thread of its own.
struct Frames {
    receiver: Receiver<DataFrame>,
    worker: Option<JoinHandle<PolarsResult<()>>>,
}

impl Frames {
    fn start(ctx: &Ctx, queries: Vec<LazyFrame>, rows: usize) -> Result<Frames, Located> {
        // A rendezvous channel: the callback (on polars' blocking pool) waits
        // until the consumer takes the frame, so the engine never runs more than
        // a frame ahead of it, which bounds memory. Measured on 10 million
        // events, capacity 1 instead costs a frame more at the same speed.
        let (sender, receiver) = sync_channel::<DataFrame>(0);
        let callback = PlanCallback::new(move |df: DataFrame| {
            // Stop the query once nobody reads (the stream was dropped).
            Ok(sender.send(df).is_err())
        });
        let queries = queries
            .into_iter()
            .map(|lf| {
                lf.sink_batches(callback.clone(), true, NonZeroUsize::new(rows))
                    .map_err(|e| ctx.polars_failure(&e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let worker = std::thread::Builder::new()
            .name("gardefou-ingest".to_string())
            .spawn(move || {
                // One after the other: the frames stay in order.
                for lf in queries {
                    lf.collect_with_engine(Engine::Streaming)?;
                }
                Ok(())
            })
            .map_err(|e| file_error(&ctx.path, format!("cannot start reading the log: {e}")))?;
        Ok(Frames {
            receiver,
            worker: Some(worker),
        })
    }

    /// The next frame, `None` at the end, or polars' error message.
    fn next(&mut self) -> Option<Result<DataFrame, String>> {
        if let Ok(df) = self.receiver.recv() {
            return Some(Ok(df));
        }
        // The sender is gone: the query has ended, well or not.
        let worker = self.worker.take()?;
        match worker.join() {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(Err(e.to_string())),
            Err(_) => Some(Err("the polars query stopped unexpectedly".to_string())),
        }
    }
}

// ----- reading batches -----

/// Turns frames into events.
trait Form: Send {
    /// Decodes one frame; finished scans go to `out`.
    fn feed(&mut self, df: &DataFrame, out: &mut Vec<Event>) -> Result<(), Problem>;
    /// At the end of the input: the last scan goes to `out`.
    fn finish(&mut self, out: &mut Vec<Event>) -> Result<(), Problem>;
    /// The first time and the initial values, once known.
    fn opening(&self) -> Option<(Time, &[bool])>;
    /// How times are written.
    fn format(&self) -> TimeFormat;
    /// The end the log declares, once read.
    fn end(&self) -> Option<Time> {
        None
    }
}

/// The iterator of batches of a [`LogStream`].
struct Reader {
    frames: Frames,
    form: Box<dyn Form>,
    ctx: Ctx,
    batch: usize,
    ready: VecDeque<Event>,
    done: bool,
    error: Option<Located>,
    end: LogEnd,
}

impl Reader {
    /// Decodes the next frame; `Ok(false)` at the end of the input.
    fn pull(&mut self) -> Result<bool, Located> {
        let mut out = Vec::new();
        let more = match self.frames.next() {
            None => {
                self.form
                    .finish(&mut out)
                    .map_err(|problem| self.ctx.locate(problem))?;
                if let Some(t) = self.form.end() {
                    self.end.set(t);
                }
                false
            }
            Some(Err(message)) => return Err(self.ctx.polars_failure(&message)),
            Some(Ok(df)) => {
                self.form
                    .feed(&df, &mut out)
                    .map_err(|problem| self.ctx.locate(problem))?;
                true
            }
        };
        self.ready.extend(out);
        Ok(more)
    }
}

impl Iterator for Reader {
    type Item = Result<Vec<Event>, Located>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if self.ready.len() >= self.batch || (self.done && !self.ready.is_empty()) {
                let n = self.ready.len().min(self.batch);
                return Some(Ok(self.ready.drain(..n).collect()));
            }
            // Events decoded before an error are delivered first.
            if let Some(e) = self.error.take() {
                return Some(Err(e));
            }
            if self.done {
                return None;
            }
            match self.pull() {
                Ok(more) => self.done = !more,
                Err(e) => {
                    self.done = true;
                    self.error = Some(e);
                }
            }
        }
    }
}

// ----- decoding cells -----

/// One column of a frame, by type.
enum Cells {
    Text(StringChunked),
    Int(Int64Chunked),
    Float(Float64Chunked),
    Bool(BooleanChunked),
}

impl Cells {
    fn of(df: &DataFrame, name: &str) -> Result<Cells, Problem> {
        let failure = |e: polars::prelude::PolarsError| {
            Problem::file(format!(
                "cannot decode column '{name}': {}",
                first_line(&e.to_string())
            ))
        };
        let series = df
            .column(name)
            .map_err(failure)?
            .as_materialized_series()
            .rechunk();
        let dtype = series.dtype().clone();
        Ok(match dtype {
            DataType::String => Cells::Text(series.str().map_err(failure)?.clone()),
            DataType::Boolean => Cells::Bool(series.bool().map_err(failure)?.clone()),
            DataType::Categorical(..) => {
                let text = series.cast(&DataType::String).map_err(failure)?;
                Cells::Text(text.str().map_err(failure)?.clone())
            }
            d if d.is_integer() => {
                let ints = series.cast(&DataType::Int64).map_err(failure)?;
                Cells::Int(ints.i64().map_err(failure)?.clone())
            }
            d if d.is_float() => {
                let floats = series.cast(&DataType::Float64).map_err(failure)?;
                Cells::Float(floats.f64().map_err(failure)?.clone())
            }
            other => {
                return Err(Problem::file(format!(
                    "column '{name}' has unsupported type {other}"
                )));
            }
        })
    }

    /// The cell as text, trimmed and unquoted like diagnoser's CSV fields; `None`
    /// if null or not text.
    fn text(&self, i: usize) -> Option<&str> {
        match self {
            Cells::Text(ca) => ca.get(i).map(clean),
            _ => None,
        }
    }

    /// Whether the cell is null or only whitespace.
    fn is_blank(&self, i: usize) -> bool {
        match self {
            Cells::Text(ca) => ca.get(i).is_none_or(|s| s.trim_ascii().is_empty()),
            Cells::Int(ca) => ca.get(i).is_none(),
            Cells::Float(ca) => ca.get(i).is_none(),
            Cells::Bool(ca) => ca.get(i).is_none(),
        }
    }

    /// The cell as written, for messages.
    fn shown(&self, i: usize) -> String {
        match self {
            Cells::Text(ca) => ca.get(i).map(clean).unwrap_or("").to_string(),
            Cells::Int(ca) => ca.get(i).map_or(String::new(), |v| v.to_string()),
            Cells::Float(ca) => ca.get(i).map_or(String::new(), |v| v.to_string()),
            Cells::Bool(ca) => ca.get(i).map_or(String::new(), |v| v.to_string()),
        }
    }

    /// Whether the cell is null (or empty text).
    fn is_empty(&self, i: usize) -> bool {
        match self {
            Cells::Text(ca) => ca.get(i).is_none_or(|s| clean(s).is_empty()),
            _ => self.is_blank(i),
        }
    }

    fn value(&self, i: usize) -> Result<bool, String> {
        let bad = |shown: String| format!("bad value '{shown}': expected 0, 1, true or false");
        match self {
            Cells::Bool(ca) => ca.get(i).ok_or_else(|| bad(String::new())),
            Cells::Int(ca) => match ca.get(i) {
                Some(0) => Ok(false),
                Some(1) => Ok(true),
                _ => Err(bad(self.shown(i))),
            },
            Cells::Float(ca) => match ca.get(i) {
                Some(0.0) => Ok(false),
                Some(1.0) => Ok(true),
                _ => Err(bad(self.shown(i))),
            },
            Cells::Text(_) => {
                let text = self.text(i).unwrap_or("");
                parse_bool(text).ok_or_else(|| bad(text.to_string()))
            }
        }
    }

    fn signal(&self, i: usize, signals: &SignalTable) -> Result<SignalId, String> {
        match self.text(i) {
            None | Some("") => Err("missing signal name".to_string()),
            Some(text) => signals
                .id(text)
                .ok_or_else(|| format!("unknown signal '{text}'")),
        }
    }
}

/// A field as diagnoser's CSV readers see it: trimmed, then unquoted.
fn clean(field: &str) -> &str {
    let field = field.trim_ascii();
    if field.len() >= 2 && field.starts_with('"') && field.ends_with('"') {
        &field[1..field.len() - 1]
    } else {
        field
    }
}

/// `0`, `1`, `true` or `false` (case-insensitive), as in diagnoser.
fn parse_bool(text: &str) -> Option<bool> {
    match text {
        "0" => Some(false),
        "1" => Some(true),
        _ if text.eq_ignore_ascii_case("false") => Some(false),
        _ if text.eq_ignore_ascii_case("true") => Some(true),
        _ => None,
    }
}

/// `'A4', 'C5'`: names for a message.
fn quote_list(names: &[&str]) -> String {
    names
        .iter()
        .map(|n| format!("'{n}'"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Decodes timestamps: text in the detected representation, numbers in the unit.
#[derive(Debug, Clone, Copy)]
struct Clock {
    format: TimeFormat,
    unit: TimeUnit,
    /// Whether the representation of text times is known (CSV: detected by
    /// diagnoser's reader; Parquet: from the first text time).
    decided: bool,
    /// Whether any time was parsed (for the wording of messages, as diagnoser).
    parsed_any: bool,
}

impl Clock {
    /// A clock for times written as `format`, detected with `unit`.
    fn given(format: TimeFormat, unit: TimeUnit) -> Clock {
        Clock {
            format,
            unit,
            decided: true,
            parsed_any: false,
        }
    }

    /// A clock for a Parquet file: numbers in `unit`, or text detected from the
    /// first time.
    fn parquet(unit: TimeUnit) -> Clock {
        Clock {
            format: TimeFormat::Numeric(unit),
            unit,
            decided: false,
            parsed_any: false,
        }
    }

    fn expected(&self) -> String {
        match self.format {
            _ if !self.parsed_any => format!("a number in {} or RFC 3339 text", self.unit),
            TimeFormat::Numeric(unit) => format!("a number in {unit}"),
            TimeFormat::Rfc3339 => "RFC 3339 text".to_string(),
        }
    }

    fn time(&mut self, cells: &Cells, i: usize) -> Result<Time, String> {
        let nanos = self.unit.nanos();
        let parsed = match cells {
            Cells::Text(_) => {
                let text = cells.text(i).unwrap_or("");
                if !self.decided {
                    self.format = TimeFormat::detect(text, self.unit);
                    self.decided = true;
                }
                match self.format.parse(text) {
                    Some(t) => Ok(t),
                    None if text.is_empty() => {
                        Err(format!("missing time: expected {}", self.expected()))
                    }
                    None => Err(format!("bad time '{text}': expected {}", self.expected())),
                }
            }
            Cells::Int(ca) => match ca.get(i) {
                None => Err(format!("missing time: expected {}", self.expected())),
                Some(v) => v
                    .checked_mul(nanos)
                    .ok_or_else(|| format!("time {v} {} is out of range", self.unit)),
            },
            Cells::Float(ca) => match ca.get(i) {
                None => Err(format!("missing time: expected {}", self.expected())),
                Some(v) => {
                    let t = (v * nanos as f64).round();
                    if t.is_finite() && t.abs() < 9.2e18 {
                        Ok(t as Time)
                    } else {
                        Err(format!("bad time '{v}': expected {}", self.expected()))
                    }
                }
            },
            Cells::Bool(_) => Err(format!(
                "bad time '{}': expected {}",
                cells.shown(i),
                self.expected()
            )),
        };
        if parsed.is_ok() {
            self.parsed_any = true;
        }
        parsed
    }
}

/// A frame's columns, in the layout's order.
struct Batch {
    cells: Vec<Cells>,
    height: usize,
}

impl Batch {
    fn new(df: &DataFrame, layout: &Layout) -> Result<Batch, Problem> {
        let cells = layout
            .columns
            .iter()
            .map(|(name, _)| Cells::of(df, name))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Batch {
            cells,
            height: df.height(),
        })
    }

    /// Whether row `i` is a blank line of a CSV file (polars gives it as a row of
    /// nulls). A line of only commas looks the same and is skipped too.
    fn blank(&self, layout: &Layout, i: usize) -> bool {
        layout.csv && self.cells.iter().all(|c| c.is_blank(i))
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
        if let Some(slot) = self.slot.get_mut(signal.index()) {
            if slot.replace(value).is_none() {
                self.touched.push(signal);
            }
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
            ) {
                if value != *current {
                    *current = value;
                    out.push(Event { t, signal, value });
                }
            }
        }
    }
}

// ----- the events form -----

/// The events form: `t,signal,value`, opening rows then changes.
struct EventsForm {
    signals: Arc<SignalTable>,
    layout: Layout,
    clock: Clock,
    rows: u64,
    /// First time and its first row.
    start: Option<(Time, u64)>,
    opened: bool,
    initial: Vec<Option<bool>>,
    initial_values: Vec<bool>,
    current: Vec<bool>,
    /// Each signal's last row: time, row, value.
    last: Vec<Option<(Time, u64, bool)>>,
    previous: Option<(Time, u64)>,
    /// The changes at the current time, not yet known to be complete.
    scan: Vec<Event>,
    scan_time: Option<Time>,
    /// The end row: its time and row.
    end: Option<(Time, u64)>,
}

impl EventsForm {
    fn new(ctx: &Ctx, layout: Layout, clock: Clock) -> EventsForm {
        let n = ctx.signals.len();
        EventsForm {
            signals: Arc::clone(&ctx.signals),
            layout,
            clock,
            rows: 0,
            start: None,
            opened: false,
            initial: vec![None; n],
            initial_values: Vec::new(),
            current: Vec::new(),
            last: vec![None; n],
            previous: None,
            scan: Vec::new(),
            scan_time: None,
            end: None,
        }
    }

    /// Ends the opening rows: every signal must have its initial value.
    fn open(&mut self) -> Result<(), Problem> {
        let missing: Vec<&str> = self
            .signals
            .iter()
            .filter(|(id, _)| self.initial[id.index()].is_none())
            .map(|(_, s)| s.name.as_str())
            .collect();
        let Some((start, start_row)) = self.start else {
            return Err(Problem::file(
                "no data rows: a log must give the initial value of every signal",
            ));
        };
        if !missing.is_empty() {
            let s = if missing.len() > 1 { "s" } else { "" };
            return Err(Problem::row(
                start_row,
                format!(
                    "no initial value for signal{s} {}: the log must open with one row per signal at its first time {}",
                    quote_list(&missing),
                    self.clock.format.format(start)
                ),
            ));
        }
        self.initial_values = self.initial.iter().map(|v| v.unwrap_or(false)).collect();
        self.current = self.initial_values.clone();
        self.opened = true;
        Ok(())
    }

    fn flush(&mut self, out: &mut Vec<Event>) {
        self.scan.sort_unstable_by_key(|e| e.signal);
        out.append(&mut self.scan);
    }

    fn conflict(
        &self,
        batch: &Batch,
        i: usize,
        row: u64,
        signal: SignalId,
        earlier: u64,
    ) -> Problem {
        Problem::at(
            row,
            self.layout.position(2),
            "value",
            format!(
                "conflicting values for signal '{}' at time {}: line ",
                self.signals.name(signal),
                batch.cells[0].shown(i)
            ),
        )
        .line_of(earlier)
        .then(" gives the other value")
    }

    fn row(&mut self, batch: &Batch, i: usize, out: &mut Vec<Event>) -> Result<(), Problem> {
        let row = self.rows;
        self.rows += 1;
        let (cells_t, cells_signal, cells_value) =
            (&batch.cells[0], &batch.cells[1], &batch.cells[2]);
        if let Some((_, end_row)) = self.end {
            return Err(Problem::row(row, "a row after the end row on line ")
                .line_of(end_row)
                .then(": the end row (a time with no signal and no value) must be the last"));
        }
        let t = self
            .clock
            .time(cells_t, i)
            .map_err(|m| Problem::at(row, self.layout.position(0), "t", m))?;
        if let Some((previous, previous_row)) = self.previous {
            if t < previous {
                return Err(Problem::at(
                    row,
                    self.layout.position(0),
                    "t",
                    format!(
                        "time goes backwards: {} is before {} on line ",
                        cells_t.shown(i),
                        self.clock.format.format(previous)
                    ),
                )
                .line_of(previous_row));
            }
        }
        if cells_signal.is_empty(i) && cells_value.is_empty(i) {
            if !self.opened {
                self.open()?;
            }
            self.end = Some((t, row));
            return Ok(());
        }
        let signal = cells_signal
            .signal(i, &self.signals)
            .map_err(|m| Problem::at(row, self.layout.position(1), "signal", m))?;
        let value = cells_value
            .value(i)
            .map_err(|m| Problem::at(row, self.layout.position(2), "value", m))?;
        self.previous = Some((t, row));
        let s = signal.index();
        if !self.opened {
            let (start, _) = *self.start.get_or_insert((t, row));
            if t == start {
                if self.initial[s].is_some_and(|v| v != value) {
                    let earlier = self.last[s].map_or(row, |l| l.1);
                    return Err(self.conflict(batch, i, row, signal, earlier));
                }
                self.initial[s] = Some(value);
                self.last[s] = Some((t, row, value));
                return Ok(());
            }
            self.open()?;
        }
        if self.scan_time != Some(t) {
            self.flush(out);
            self.scan_time = Some(t);
        }
        if value != self.current[s] {
            if let Some((last_t, last_row, _)) = self.last[s] {
                if last_t == t {
                    return Err(self.conflict(batch, i, row, signal, last_row));
                }
            }
            self.current[s] = value;
            self.scan.push(Event { t, signal, value });
        }
        self.last[s] = Some((t, row, value));
        Ok(())
    }
}

impl Form for EventsForm {
    fn feed(&mut self, df: &DataFrame, out: &mut Vec<Event>) -> Result<(), Problem> {
        let batch = Batch::new(df, &self.layout)?;
        for i in 0..batch.height {
            if batch.blank(&self.layout, i) {
                continue;
            }
            self.row(&batch, i, out)?;
        }
        Ok(())
    }

    fn finish(&mut self, out: &mut Vec<Event>) -> Result<(), Problem> {
        if !self.opened {
            self.open()?;
        }
        self.flush(out);
        Ok(())
    }

    fn opening(&self) -> Option<(Time, &[bool])> {
        match self.start {
            Some((start, _)) if self.opened => Some((start, &self.initial_values)),
            _ => None,
        }
    }

    fn format(&self) -> TimeFormat {
        self.clock.format
    }

    fn end(&self) -> Option<Time> {
        self.end.map(|(t, _)| t)
    }
}

// ----- the scans form -----

/// The scans form: `t,<sig1>,<sig2>,…`, one row per scan; edges are changes.
struct ScansForm {
    signals: Arc<SignalTable>,
    layout: Layout,
    clock: Clock,
    rows: u64,
    previous: Option<(Time, u64)>,
    start: Option<Time>,
    initial: Vec<bool>,
    current: Vec<bool>,
    values: Vec<bool>,
}

impl ScansForm {
    fn new(ctx: &Ctx, layout: Layout, clock: Clock) -> ScansForm {
        let n = ctx.signals.len();
        ScansForm {
            signals: Arc::clone(&ctx.signals),
            layout,
            clock,
            rows: 0,
            previous: None,
            start: None,
            initial: Vec::new(),
            current: vec![false; n],
            values: vec![false; n],
        }
    }

    fn row(&mut self, batch: &Batch, i: usize, out: &mut Vec<Event>) -> Result<(), Problem> {
        let row = self.rows;
        self.rows += 1;
        let cells_t = &batch.cells[0];
        let t = self
            .clock
            .time(cells_t, i)
            .map_err(|m| Problem::at(row, self.layout.position(0), "t", m))?;
        if let Some((previous, previous_row)) = self.previous {
            if t <= previous {
                let message = if t == previous {
                    format!(
                        "time does not increase: {} repeats the time of line ",
                        cells_t.shown(i)
                    )
                } else {
                    format!(
                        "time goes backwards: {} is before {} on line ",
                        cells_t.shown(i),
                        self.clock.format.format(previous)
                    )
                };
                let problem = Problem::at(row, self.layout.position(0), "t", message);
                return Err(problem.line_of(previous_row));
            }
        }
        for (k, &signal) in self.layout.signals.iter().enumerate() {
            let cells = &batch.cells[k + 1];
            let value = cells.value(i).map_err(|m| {
                Problem::at(
                    row,
                    self.layout.position(k + 1),
                    self.signals.name(signal),
                    m,
                )
            })?;
            self.values[signal.index()] = value;
        }
        self.previous = Some((t, row));
        if self.start.is_none() {
            self.start = Some(t);
            self.initial = self.values.clone();
            self.current = self.values.clone();
            return Ok(());
        }
        for (i, (&value, current)) in self.values.iter().zip(self.current.iter_mut()).enumerate() {
            if value != *current {
                *current = value;
                out.push(Event {
                    t,
                    signal: SignalId(i as u32),
                    value,
                });
            }
        }
        Ok(())
    }
}

impl Form for ScansForm {
    fn feed(&mut self, df: &DataFrame, out: &mut Vec<Event>) -> Result<(), Problem> {
        let batch = Batch::new(df, &self.layout)?;
        for i in 0..batch.height {
            if batch.blank(&self.layout, i) {
                continue;
            }
            self.row(&batch, i, out)?;
        }
        Ok(())
    }

    fn finish(&mut self, _out: &mut Vec<Event>) -> Result<(), Problem> {
        if self.start.is_none() {
            return Err(Problem::file(
                "no data rows: a log must give the initial value of every signal",
            ));
        }
        Ok(())
    }

    fn opening(&self) -> Option<(Time, &[bool])> {
        self.start.map(|t| (t, self.initial.as_slice()))
    }

    fn format(&self) -> TimeFormat {
        self.clock.format
    }
}

// ----- the intervals form -----

/// What the first pass remembers of a signal's last interval.
#[derive(Debug, Clone, Copy)]
struct Last {
    value: bool,
    end: Option<Time>,
    row: u64,
}

/// The first pass over an intervals log: checks every row as
/// `diagnoser::log::IntervalReader` does, and finds the initial values, each
/// signal's last row and the order of the rows.
struct IntervalCheck {
    signals: Arc<SignalTable>,
    layout: Layout,
    clock: Clock,
    rows: u64,
    /// The log's first time and its row.
    start: Option<(Time, u64)>,
    last: Vec<Option<Last>>,
    initial: Vec<bool>,
    /// Whether the closed intervals come in `t_end` order (ignoring those that
    /// end at the log's first time).
    by_end: bool,
    previous_end: Option<Time>,
    /// Whether the rows come in `t_start` order.
    by_start: bool,
    previous_start: Option<Time>,
}

impl IntervalCheck {
    fn new(ctx: &Ctx, layout: Layout, clock: Clock) -> IntervalCheck {
        let n = ctx.signals.len();
        IntervalCheck {
            signals: Arc::clone(&ctx.signals),
            layout,
            clock,
            rows: 0,
            start: None,
            last: vec![None; n],
            initial: vec![false; n],
            by_end: true,
            previous_end: None,
            by_start: true,
            previous_start: None,
        }
    }

    fn row(&mut self, batch: &Batch, i: usize) -> Result<(), Problem> {
        let row = self.rows;
        self.rows += 1;
        let layout = &self.layout;
        let [c_signal, c_value, c_start, c_end] = [0, 1, 2, 3].map(|k| &batch.cells[k]);
        let signal = c_signal
            .signal(i, &self.signals)
            .map_err(|m| Problem::at(row, layout.position(0), "signal", m))?;
        let name = self.signals.name(signal).to_string();
        let value = c_value
            .value(i)
            .map_err(|m| Problem::at(row, layout.position(1), "value", m))?;
        let start = self
            .clock
            .time(c_start, i)
            .map_err(|m| Problem::at(row, layout.position(2), "t_start", m))?;
        let end = if c_end.is_empty(i) {
            None
        } else {
            let end = self
                .clock
                .time(c_end, i)
                .map_err(|m| Problem::at(row, layout.position(3), "t_end", m))?;
            if end < start {
                return Err(Problem::at(
                    row,
                    layout.position(3),
                    "t_end",
                    format!(
                        "interval ends before it starts: t_end {} is before t_start {}",
                        c_end.shown(i),
                        c_start.shown(i)
                    ),
                ));
            }
            Some(end)
        };
        let format = self.clock.format;
        let s = signal.index();
        match self.last[s] {
            None => match self.start {
                None => self.start = Some((start, row)),
                Some((log_start, first_row)) if log_start != start => {
                    return Err(Problem::at(
                        row,
                        layout.position(2),
                        "t_start",
                        format!(
                            "the first interval of signal '{name}' starts at {}, not at the log's first time {} (line ",
                            c_start.shown(i),
                            format.format(log_start)
                        ),
                    )
                    .line_of(first_row)
                    .then(")"));
                }
                Some(_) => {}
            },
            Some(last) => {
                let Some(previous_end) = last.end else {
                    return Err(Problem::at(
                        row,
                        layout.position(0),
                        "signal",
                        format!("signal '{name}' already has an open interval on line "),
                    )
                    .line_of(last.row)
                    .then(": only its last interval may be open"));
                };
                if previous_end != start {
                    return Err(Problem::at(
                        row,
                        layout.position(2),
                        "t_start",
                        format!(
                            "interval of signal '{name}' starts at {} but its previous interval (line ",
                            c_start.shown(i)
                        ),
                    )
                    .line_of(last.row)
                    .then(format!(") ends at {}", format.format(previous_end))));
                }
                if last.value == value {
                    return Err(Problem::at(
                        row,
                        layout.position(1),
                        "value",
                        format!(
                            "signal '{name}' holds {} in two consecutive intervals (lines ",
                            u8::from(value)
                        ),
                    )
                    .line_of(last.row)
                    .then(" and ")
                    .line_of(row)
                    .then("): intervals must be maximal"));
                }
            }
        }
        self.last[s] = Some(Last { value, end, row });
        let log_start = self.start.map_or(start, |(t, _)| t);
        if start == log_start {
            self.initial[s] = value;
        }
        if self.previous_start.is_some_and(|p| start < p) {
            self.by_start = false;
        }
        self.previous_start = Some(start);
        if let Some(end) = end.filter(|&e| e > log_start) {
            if self.previous_end.is_some_and(|p| end < p) {
                self.by_end = false;
            }
            self.previous_end = Some(end);
        }
        Ok(())
    }
}

impl Form for IntervalCheck {
    fn feed(&mut self, df: &DataFrame, _out: &mut Vec<Event>) -> Result<(), Problem> {
        let batch = Batch::new(df, &self.layout)?;
        for i in 0..batch.height {
            if batch.blank(&self.layout, i) {
                continue;
            }
            self.row(&batch, i)?;
        }
        Ok(())
    }

    fn finish(&mut self, _out: &mut Vec<Event>) -> Result<(), Problem> {
        if self.start.is_none() {
            return Err(Problem::file(
                "no data rows: a log must give the initial value of every signal",
            ));
        }
        let missing: Vec<&str> = self
            .signals
            .iter()
            .filter(|(id, _)| self.last[id.index()].is_none())
            .map(|(_, s)| s.name.as_str())
            .collect();
        if !missing.is_empty() {
            let s = if missing.len() > 1 { "s" } else { "" };
            return Err(Problem::file(format!(
                "no interval for signal{s} {}: every signal must appear",
                quote_list(&missing)
            )));
        }
        Ok(())
    }

    fn opening(&self) -> Option<(Time, &[bool])> {
        self.start.map(|(t, _)| (t, self.initial.as_slice()))
    }

    fn format(&self) -> TimeFormat {
        self.clock.format
    }
}

/// How the second pass reads an intervals log, by the order of its rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Order {
    /// Closed intervals in `t_end` order: each ends with a change of its signal
    /// (unless it is the signal's last), streamed as rows come.
    ByEnd,
    /// Rows in `t_start` order: each starts with a change, streamed.
    ByStart,
    /// Any other order: the changes are collected and sorted (16 bytes each).
    Sorted,
}

/// The second pass over an intervals log: the events, exactly as
/// `diagnoser::log::read_intervals_as_events` rebuilds them.
///
/// Every interval after the first of its signal starts with a change, at its
/// `t_start`, to its value; equivalently, every closed interval but the last of
/// its signal ends with a change, at its `t_end`, to the other value (values
/// alternate). Several changes of one signal at one time (zero-length
/// intervals, glitches below the time resolution) leave only the last value,
/// and only if it differs from the value before.
struct IntervalEvents {
    signals: Arc<SignalTable>,
    layout: Layout,
    clock: Clock,
    order: Order,
    rows: u64,
    start: Time,
    initial: Vec<bool>,
    /// Each signal's last row.
    last_row: Vec<u64>,
    collapse: Collapse,
    /// `Order::Sorted`: the changes, until the end.
    claims: Vec<(Time, SignalId, bool)>,
}

impl IntervalEvents {
    fn new(ctx: &Ctx, layout: Layout, check: IntervalCheck) -> Result<IntervalEvents, Located> {
        let Some((start, _)) = check.start else {
            return Err(no_data(&ctx.path));
        };
        let order = if check.by_end {
            Order::ByEnd
        } else if check.by_start {
            Order::ByStart
        } else {
            Order::Sorted
        };
        let last_row = check
            .last
            .iter()
            .map(|l| l.map_or(u64::MAX, |l| l.row))
            .collect();
        Ok(IntervalEvents {
            signals: Arc::clone(&ctx.signals),
            layout,
            clock: check.clock,
            order,
            rows: 0,
            start,
            collapse: Collapse::new(check.initial.clone()),
            initial: check.initial,
            last_row,
            claims: Vec::new(),
        })
    }

    /// The rows were all checked by the first pass: a failure now means that
    /// the file changed in between.
    fn changed() -> Problem {
        Problem::file("the log changed while it was being read")
    }

    fn row(&mut self, batch: &Batch, i: usize, out: &mut Vec<Event>) -> Result<(), Problem> {
        let row = self.rows;
        self.rows += 1;
        let signal = batch.cells[0]
            .signal(i, &self.signals)
            .map_err(|_| Self::changed())?;
        let value = batch.cells[1].value(i).map_err(|_| Self::changed())?;
        let claimed = match self.order {
            Order::ByEnd => {
                if batch.cells[3].is_empty(i) || self.last_row.get(signal.index()) == Some(&row) {
                    return Ok(());
                }
                let end = self
                    .clock
                    .time(&batch.cells[3], i)
                    .map_err(|_| Self::changed())?;
                end <= self.start || self.collapse.claim(end, signal, !value, out)
            }
            Order::ByStart | Order::Sorted => {
                let start = self
                    .clock
                    .time(&batch.cells[2], i)
                    .map_err(|_| Self::changed())?;
                if start <= self.start {
                    true
                } else if self.order == Order::Sorted {
                    self.claims.push((start, signal, value));
                    true
                } else {
                    self.collapse.claim(start, signal, value, out)
                }
            }
        };
        if claimed {
            Ok(())
        } else {
            Err(Self::changed())
        }
    }
}

impl Form for IntervalEvents {
    fn feed(&mut self, df: &DataFrame, out: &mut Vec<Event>) -> Result<(), Problem> {
        let batch = Batch::new(df, &self.layout)?;
        for i in 0..batch.height {
            if batch.blank(&self.layout, i) {
                continue;
            }
            self.row(&batch, i, out)?;
        }
        Ok(())
    }

    fn finish(&mut self, out: &mut Vec<Event>) -> Result<(), Problem> {
        if self.order == Order::Sorted {
            // Stable: the changes of one signal at one time keep their order.
            let mut claims = std::mem::take(&mut self.claims);
            claims.sort_by_key(|c| c.0);
            for (t, signal, value) in claims {
                self.collapse.claim(t, signal, value, out);
            }
        }
        self.collapse.flush(out);
        Ok(())
    }

    fn opening(&self) -> Option<(Time, &[bool])> {
        Some((self.start, self.initial.as_slice()))
    }

    fn format(&self) -> TimeFormat {
        self.clock.format
    }
}
