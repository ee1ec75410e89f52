//! The intervals form read from Parquet column by column.
//!
//! An archive as [`super::write_intervals_parquet`] writes it (`signal` text,
//! `value` booleans, `t_start` and `t_end` 64-bit integers in the time unit)
//! needs no records: its row groups are decoded from their pages
//! ([`super::columns`]) on a thread of their own, one group ahead of the
//! checks, and the rows go through the form's [`Rules`], [`Surveyor`] and
//! [`Unfold`] as they would from an [`crate::IntervalReader`]. Only the
//! columns a pass needs are decoded: the second pass skips the time it does
//! not use.
//!
//! This reader only accepts. At the first row it is not sure of (a null where
//! the form needs a cell, a name that is not a signal, a broken rule, a time
//! out of range), or at anything in the file it does not decode, it gives up,
//! and the file is read again the general way (an [`crate::IntervalReader`]
//! over [`super::ParquetRecords`]), which meets the same rows and gives the
//! form's error. Both take the same rows the same way: the property tests in
//! `tests.rs`, beside this file, hold them to it.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, Sender, SyncSender, channel, sync_channel};

use vocabulary::panics::Containment;
use vocabulary::{Event, Located, Plant, SignalId, SignalTable, Time, TimeFormat, TimeUnit};

use super::columns::{Column, Decoder, Layout, Rows};
use super::decode::{Kind, Schema};
use crate::intervals::{Interval, Rules, Survey, Surveyor, Unfold};
use crate::rows::{file_error, open_file};
use crate::{IngestOptions, LogEnd, LogFormat, LogStream};

/// The form's columns, by name.
const COLUMNS: [&str; 4] = ["signal", "value", "t_start", "t_end"];

/// Opens an intervals Parquet log column by column: the first pass before
/// this returns, the second on a thread of its own. `Ok(None)` when the
/// general reader must read it (columns of other types or encodings, or a
/// row this reader is not sure of); an error only where the general reader
/// gives the same (a file polars cannot open).
pub(crate) fn open_intervals(
    path: &Path,
    plant: &Plant,
    options: &IngestOptions,
) -> Result<Option<LogStream>, Located> {
    open_keeping(path, plant, options, KEPT_BYTES)
}

/// [`open_intervals`], the first pass keeping up to `kept_bytes` of rows
/// for the second.
pub(super) fn open_keeping(
    path: &Path,
    plant: &Plant,
    options: &IngestOptions,
    kept_bytes: usize,
) -> Result<Option<LogStream>, Located> {
    let schema = super::schema(path)?;
    if !archive_layout(&schema) {
        return Ok(None);
    }
    let Some(layout) = Layout::of(&schema.footer, schema.size) else {
        return Ok(None);
    };
    let pass = Pass {
        path: path.to_path_buf(),
        signals: plant.signals.clone(),
        unit: options.time_unit,
        batch_rows: options.batch_rows.max(1),
        layout,
        kept_bytes,
    };
    let Some((survey, kept)) = pass.survey() else {
        return Ok(None);
    };
    let unfold = Unfold::new(survey);
    let (start, initial) = (unfold.start(), unfold.initial().to_vec());
    // The rows kept serve only a second pass in `t_end` order.
    let kept = if unfold.by_end() {
        kept
    } else {
        Kept::new(0, 0, 0)
    };
    let batches = pass.unfold_on_thread(unfold, kept)?;
    Ok(Some(LogStream {
        path: path.to_path_buf(),
        format: LogFormat::IntervalsParquet,
        time: TimeFormat::Numeric(options.time_unit),
        start,
        initial,
        batches: Box::new(batches),
        end: LogEnd::default(),
    }))
}

/// Whether the file has exactly the form's columns, typed as the archive
/// writer types them.
fn archive_layout(schema: &Schema) -> bool {
    let kinds = [Kind::Text, Kind::Bool, Kind::Int, Kind::Int];
    let int64 = |name: &str| {
        schema
            .get(name)
            .is_some_and(|c| c.dtype == polars_arrow::datatypes::ArrowDataType::Int64)
    };
    schema.columns.len() == COLUMNS.len()
        && COLUMNS
            .iter()
            .zip(&kinds)
            .all(|(name, kind)| schema.get(name).is_some_and(|c| c.kind == *kind))
        && int64("t_start")
        && int64("t_end")
}

/// What both passes read.
struct Pass {
    path: PathBuf,
    signals: SignalTable,
    unit: TimeUnit,
    batch_rows: usize,
    layout: Layout,
    /// Bytes of rows the first pass may keep for the second.
    kept_bytes: usize,
}

/// Row groups decoded on threads of their own, each thread a lane that
/// decodes every other group, in order, one ahead of their reader.
struct Decoded {
    lanes: Vec<Lane>,
    /// The first group decoded.
    first: usize,
}

/// A lane's groups (`None` for one that is not as the form's, after which
/// none comes), and the way back for the groups read, to be filled again.
struct Lane {
    groups: Receiver<Option<Group>>,
    spare: Sender<Group>,
}

/// A row group decoded: its rows, and (in the first pass) the same packed
/// for [`Kept`].
#[derive(Default)]
struct Group {
    rows: Rows,
    packed: Packed,
}

impl Decoded {
    /// Row group `g`, decoded; `None` if it is not as the form's.
    fn group(&self, g: usize) -> Option<Group> {
        let lane = self
            .lanes
            .get(g.checked_sub(self.first)? % self.lanes.len())?;
        lane.groups.recv().ok()?
    }

    /// Hands group `g` back to its lane.
    fn give_back(&self, g: usize, rows: Group) {
        let lane = g.checked_sub(self.first).map(|k| k % self.lanes.len());
        if let Some(lane) = lane.and_then(|k| self.lanes.get(k)) {
            let _ = lane.spare.send(rows);
        }
    }
}

/// Lanes of decoding: two, so that decompressing and decoding a group
/// overlaps with the next and with the reader, where cores allow.
const LANES: usize = 2;

impl Pass {
    /// Starts decoding `columns` of every row group from group `first` on,
    /// each group also packed for [`Kept`] if `pack`; `None` if the file
    /// cannot be opened again or no thread started.
    fn decode(&self, first: usize, columns: &'static [Column], pack: bool) -> Option<Decoded> {
        let lanes = (0..LANES)
            .map(|lane| self.lane(first + lane, columns, pack))
            .collect::<Option<Vec<_>>>()?;
        Some(Decoded { lanes, first })
    }

    /// Starts a lane: groups `lane`, `lane + LANES`, ...
    fn lane(&self, lane: usize, columns: &'static [Column], pack: bool) -> Option<Lane> {
        let file = open_file(&self.path).ok()?;
        let mut decoder = Decoder::new(file, self.layout.clone(), self.signals.clone());
        let count = self.layout.len();
        let (send, groups) = sync_channel(0);
        let (spare, spares) = channel::<Group>();
        std::thread::Builder::new()
            .name("gardefou-decode".into())
            .spawn(move || {
                // A panic is a group not taken, not a crash.
                let _quiet = Containment::start();
                for g in (lane..count).step_by(LANES) {
                    let mut group = spares.try_recv().unwrap_or_default();
                    let decode = std::panic::AssertUnwindSafe(|| {
                        decoder.group(g, columns, &mut group.rows)?;
                        if pack {
                            group.packed.pack(&group.rows);
                        }
                        Some(())
                    });
                    let taken = std::panic::catch_unwind(decode).ok().flatten().is_some();
                    if send.send(taken.then_some(group)).is_err() || !taken {
                        return;
                    }
                }
            })
            .ok()?;
        Some(Lane { groups, spare })
    }

    /// The first pass: every row checked, the survey of the log, and the
    /// rows of the first groups kept for the second; `None` to leave the
    /// file to the general reader.
    fn survey(&self) -> Option<(Survey, Kept)> {
        let mut kept = Kept::new(self.signals.len(), self.layout.rows(), self.kept_bytes);
        let decoded = self.decode(0, &Column::ALL, !kept.full)?;
        let mut rules = Rules::new(self.signals.len());
        let mut surveyor = Surveyor::new(self.signals.len());
        let mut line = 1usize;
        for g in 0..self.layout.len() {
            let group = decoded.group(g)?;
            check(&group.rows, self.unit, &mut line, &mut rules, &mut surveyor)?;
            kept.keep(&group.packed);
            decoded.give_back(g, group);
        }
        if !rules.complete() {
            return None;
        }
        Some((surveyor.finish()?, kept))
    }

    /// Runs the second pass on a thread of its own: batches of about
    /// `batch_rows` changes over a bounded channel.
    fn unfold_on_thread(
        self,
        unfold: Unfold,
        kept: Kept,
    ) -> Result<impl Iterator<Item = Result<Vec<Event>, Located>> + Send, Located> {
        let (send, receive) = sync_channel(2);
        let path = self.path.clone();
        std::thread::Builder::new()
            .name("gardefou-read".into())
            .spawn(move || {
                let mut out = Out {
                    batch: Vec::new(),
                    size: self.batch_rows,
                    send,
                };
                if let Err(e) = self.unfold(unfold, kept, &mut out) {
                    let _ = out.send.send(Err(e));
                }
            })
            .map_err(|e| file_error(&path, format!("cannot start reading: {e}")))?;
        Ok(Incoming(receive))
    }

    /// The second pass: the changes, batch by batch, until the end or until
    /// nobody reads them: the rows `kept` first, then those of the groups
    /// after them, decoded again.
    fn unfold(&self, mut unfold: Unfold, kept: Kept, out: &mut Out) -> Result<(), Located> {
        let by_end = unfold.by_end();
        let changed = || file_error(&self.path, "the log changed while it was being read");
        if !kept
            .replay(self.unit, &mut unfold, out)
            .ok_or_else(changed)?
        {
            return Ok(());
        }
        // Only the time the changes come from is decoded.
        let columns: &'static [Column] = if by_end {
            &[Column::Signal, Column::Value, Column::End]
        } else {
            &[Column::Signal, Column::Value, Column::Start]
        };
        let decoded = self
            .decode(kept.groups, columns, false)
            .ok_or_else(changed)?;
        let mut row = kept.cells.len() as u64;
        drop(kept);
        let size = self.batch_rows;
        for g in decoded.first..self.layout.len() {
            let group = decoded.group(g).ok_or_else(changed)?;
            let rows = &group.rows;
            let height = rows.signals.len();
            for from in (0..height).step_by(size) {
                let slice = from..(from + size).min(height);
                let fed = if by_end {
                    feed_ends(rows, slice, row, self.unit, &mut unfold, &mut out.batch)
                } else {
                    feed_starts(rows, slice, self.unit, &mut unfold, &mut out.batch)
                };
                fed.ok_or_else(changed)?;
                if !out.ship() {
                    return Ok(());
                }
            }
            row += height as u64;
            decoded.give_back(g, group);
        }
        unfold.finish(&mut out.batch);
        if !out.batch.is_empty() {
            let _ = out.send.send(Ok(std::mem::take(&mut out.batch)));
        }
        Ok(())
    }
}

/// Where the second pass's changes go: a batch filling, sent once it holds
/// `size`.
struct Out {
    batch: Vec<Event>,
    size: usize,
    send: SyncSender<Result<Vec<Event>, Located>>,
}

impl Out {
    /// Sends the batch if it is full; `false` once nobody reads.
    #[inline]
    fn ship(&mut self) -> bool {
        if self.batch.len() < self.size {
            return true;
        }
        let full = std::mem::replace(&mut self.batch, Vec::with_capacity(self.size));
        self.send.send(Ok(full)).is_ok()
    }
}

/// Bytes of the rows the first pass keeps for the second, which then
/// decodes only the groups after them (a log of up to about ten million
/// rows is decoded once).
const KEPT_BYTES: usize = 40 << 20;

/// The rows of the first row groups, whole groups, as a second pass in
/// `t_end` order reads them ([`Packed`] groups one after the other).
struct Kept {
    /// How many groups are kept, and the rows of each.
    groups: usize,
    heights: Vec<usize>,
    cells: Vec<u32>,
    wide: Vec<i64>,
    /// Bytes it may take.
    budget: usize,
    /// Whether no more fits (or none could: too many signals for a cell).
    full: bool,
}

impl Kept {
    /// Nothing kept yet, for a log of `signals` signals and `rows` rows,
    /// in at most `budget` bytes.
    fn new(signals: usize, rows: usize, budget: usize) -> Kept {
        let full = signals >= 1 << 14 || rows == 0 || budget == 0;
        let rows = if full { 0 } else { rows.min(budget / 4) };
        Kept {
            groups: 0,
            heights: Vec::new(),
            cells: Vec::with_capacity(rows),
            wide: Vec::new(),
            budget,
            full,
        }
    }

    /// Keeps the next group, if it fits.
    fn keep(&mut self, packed: &Packed) {
        let cells = self.cells.len() + packed.cells.len();
        let bytes = 4 * cells + 8 * (self.wide.len() + packed.wide.len());
        self.full |= bytes > self.budget;
        if self.full {
            return;
        }
        self.cells.extend_from_slice(&packed.cells);
        self.wide.extend_from_slice(&packed.wide);
        self.heights.push(packed.cells.len());
        self.groups += 1;
    }

    /// Feeds the rows kept to `unfold`, in `t_end` order; `Some(false)`
    /// once nobody reads, `None` if they contradict the first pass.
    fn replay(&self, unit: TimeUnit, unfold: &mut Unfold, out: &mut Out) -> Option<bool> {
        let (mut row, mut wide) = (0usize, self.wide.iter());
        for &height in &self.heights {
            // Each group's ends start from 0.
            let mut end = 0i64;
            for &cell in self.cells.get(row..row + height)? {
                let signal = SignalId(cell >> 18);
                let closed = if cell & CLOSED != 0 {
                    end = match cell & WIDE {
                        WIDE => *wide.next()?,
                        near => end.wrapping_add(i64::from(near as u16 as i16)),
                    };
                    Some(nanos(end, unit)?)
                } else {
                    None
                };
                let value = cell & VALUE != 0;
                if !unfold.feed_end(row as u64, signal, value, closed, &mut out.batch) {
                    return None;
                }
                row += 1;
                if !out.ship() {
                    return Some(false);
                }
            }
        }
        Some(true)
    }
}

// A packed row: the signal in the top 14 bits, then the value, whether it
// is closed, and the end's difference to the one before as an `i16`, or
// `WIDE` for an end of its own in `Packed::wide`.
const VALUE: u32 = 1 << 17;
const CLOSED: u32 = 1 << 16;
const WIDE: u32 = 0xffff;

/// A group's rows packed for [`Kept`], a `u32` each; the ends too far from
/// the one before (the first's: from 0) in `wide`.
#[derive(Default)]
struct Packed {
    cells: Vec<u32>,
    wide: Vec<i64>,
}

impl Packed {
    /// Packs `rows`, of signals below 2^14.
    fn pack(&mut self, rows: &Rows) {
        self.cells.clear();
        self.wide.clear();
        let mut last_end = 0i64;
        let all = (rows.signals.iter().zip(&rows.values)).zip(rows.ends.iter().zip(&rows.closed));
        for ((signal, &value), (&end, &closed)) in all {
            let mut cell = (signal.0 << 18) | (u32::from(value) << 17);
            if closed {
                cell |= CLOSED;
                // -1 is the escape, `WIDE`.
                match end.checked_sub(last_end).map(i16::try_from) {
                    Some(Ok(near)) if near != -1 => cell |= u32::from(near as u16),
                    _ => {
                        cell |= WIDE;
                        self.wide.push(end);
                    }
                }
                last_end = end;
            }
            self.cells.push(cell);
        }
    }
}

/// The batches, as the second pass sends them.
struct Incoming(Receiver<Result<Vec<Event>, Located>>);

impl Iterator for Incoming {
    type Item = Result<Vec<Event>, Located>;
    fn next(&mut self) -> Option<Self::Item> {
        self.0.recv().ok()
    }
}

/// The first pass over a row group's rows, the last row before them on
/// `line`: each row's interval checked by `rules` and taken by `surveyor`;
/// `None` at the first row this reader is not sure of (a time out of range,
/// an interval that ends before it starts, a broken rule).
fn check(
    rows: &Rows,
    unit: TimeUnit,
    line: &mut usize,
    rules: &mut Rules,
    surveyor: &mut Surveyor,
) -> Option<()> {
    let ends = rows.ends.iter().zip(&rows.closed);
    let cells = (rows.signals.iter().zip(&rows.values)).zip(rows.starts.iter().zip(ends));
    for ((&signal, &value), (&start, (&end, &closed))) in cells {
        let start = nanos(start, unit)?;
        let end = if closed {
            Some(nanos(end, unit).filter(|&end| end >= start)?)
        } else {
            None
        };
        let interval = Interval {
            signal,
            value,
            start,
            end,
        };
        *line += 1;
        rules.check(&interval, *line).ok()?;
        surveyor.push(&interval);
    }
    Some(())
}

/// The second pass over the rows `slice` of a group in `t_end` order, the
/// group's first row being row `row` of the file; `None` if they
/// contradict the first pass.
fn feed_ends(
    rows: &Rows,
    slice: std::ops::Range<usize>,
    row: u64,
    unit: TimeUnit,
    unfold: &mut Unfold,
    out: &mut Vec<Event>,
) -> Option<()> {
    let first = row + slice.start as u64;
    let ends = rows
        .ends
        .get(slice.clone())?
        .iter()
        .zip(rows.closed.get(slice.clone())?);
    let cells = (rows.signals.get(slice.clone())?.iter())
        .zip(rows.values.get(slice)?)
        .zip(ends);
    for (i, ((&signal, &value), (&end, &closed))) in cells.enumerate() {
        let end = if closed {
            Some(nanos(end, unit)?)
        } else {
            None
        };
        if !unfold.feed_end(first + i as u64, signal, value, end, out) {
            return None;
        }
    }
    Some(())
}

/// The second pass over the rows `slice` of a group in any other order.
fn feed_starts(
    rows: &Rows,
    slice: std::ops::Range<usize>,
    unit: TimeUnit,
    unfold: &mut Unfold,
    out: &mut Vec<Event>,
) -> Option<()> {
    let cells = (rows.signals.get(slice.clone())?.iter())
        .zip(rows.values.get(slice.clone())?)
        .zip(rows.starts.get(slice)?);
    for ((&signal, &value), &start) in cells {
        if !unfold.feed_start(signal, value, nanos(start, unit)?, out) {
            return None;
        }
    }
    Some(())
}

/// A time in `unit` as nanoseconds, as the general reader takes an integer
/// cell; `None` out of range.
#[inline]
fn nanos(t: i64, unit: TimeUnit) -> Option<Time> {
    t.checked_mul(unit.nanos())
}
