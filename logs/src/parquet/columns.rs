//! The columns of an intervals archive decoded straight from their pages.
//!
//! An archive's row groups are read one at a time: each column chunk's bytes
//! (one read), its pages decompressed one by one, a dictionary page mapped
//! once (names to signal ids, times to integers), the data pages' dictionary
//! indices (or plain values) and definition levels decoded into [`Rows`].
//! Only what the writers of archives write is taken: flat columns of the
//! form's physical types, PLAIN or dictionary-encoded values, in v1 data
//! pages (which polars writes). Anything else, and anything that does not add up (a count larger
//! than its page or chunk, an index past its dictionary, a null where the
//! form needs a cell, a name that is not a signal), gives `None`, and the
//! caller leaves the file to the general reader. Every count is checked
//! against the bytes that hold it before anything is allocated for it, and
//! a row group, a chunk or a page larger than the bounds below is not taken,
//! so memory stays bounded whatever the file says.

use std::fs::File;
use std::os::unix::fs::FileExt as _;

use polars_parquet::parquet::compression::{Compression, DecompressionContext, decompress};
use polars_parquet::parquet::metadata::{ColumnChunkMetadata, FileMetadata};
use polars_parquet::parquet::schema::types::PhysicalType;
use vocabulary::{SignalId, SignalTable};

use super::clean;
use super::pages::PageHeader;

/// Rows of the largest row group taken (about 22 MB of decoded rows).
const MOST_ROWS: usize = 1 << 20;
/// Bytes of the largest column chunk, and of the largest page decompressed.
const MOST_BYTES: u64 = 1 << 25;

// Parquet encodings.
const PLAIN: i32 = 0;
const PLAIN_DICTIONARY: i32 = 2;
const RLE: i32 = 3;
const RLE_DICTIONARY: i32 = 8;

/// The form's columns, in the order of [`Layout`]'s chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Column {
    Signal,
    Value,
    Start,
    End,
}

impl Column {
    /// Every column, in the order of a row group's chunks.
    pub(super) const ALL: [Column; 4] = [Column::Signal, Column::Value, Column::Start, Column::End];

    fn name(self) -> &'static str {
        match self {
            Column::Signal => "signal",
            Column::Value => "value",
            Column::Start => "t_start",
            Column::End => "t_end",
        }
    }

    fn physical(self) -> PhysicalType {
        match self {
            Column::Signal => PhysicalType::ByteArray,
            Column::Value => PhysicalType::Boolean,
            Column::Start | Column::End => PhysicalType::Int64,
        }
    }
}

/// Where a column chunk lies in the file, and how its pages are written.
#[derive(Debug, Clone)]
struct Chunk {
    start: u64,
    end: u64,
    codec: Compression,
    /// Whether its cells may be null (definition levels precede the values).
    optional: bool,
}

/// A row group: its rows and the chunks of [`Column::ALL`].
#[derive(Debug, Clone)]
struct Group {
    rows: usize,
    chunks: Vec<Chunk>,
}

/// The row groups of an archive, as its footer lays them out.
#[derive(Debug, Clone)]
pub(super) struct Layout {
    groups: Vec<Group>,
}

impl Layout {
    /// The layout of a file of `size` bytes whose footer is `footer`;
    /// `None` unless every row group holds exactly the form's four flat
    /// columns, of the form's physical types, within the bounds above.
    pub(super) fn of(footer: &FileMetadata, size: u64) -> Option<Layout> {
        let groups = footer
            .row_groups
            .iter()
            .map(|group| {
                let columns = group.parquet_columns();
                let rows = group.num_rows();
                if columns.len() != Column::ALL.len() || rows > MOST_ROWS {
                    return None;
                }
                let chunks = Column::ALL
                    .iter()
                    .map(|&column| chunk(columns, column, rows, size))
                    .collect::<Option<Vec<_>>>()?;
                Some(Group { rows, chunks })
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Layout { groups })
    }

    /// How many row groups the file has.
    pub(super) fn len(&self) -> usize {
        self.groups.len()
    }

    /// How many rows the file has.
    pub(super) fn rows(&self) -> usize {
        self.groups.iter().map(|g| g.rows).sum()
    }
}

/// The chunk of `column` among a row group's `columns`, which holds `rows`
/// rows; `None` if it is not as the form's.
fn chunk(columns: &[ColumnChunkMetadata], column: Column, rows: usize, size: u64) -> Option<Chunk> {
    let found = columns.iter().find(|c| {
        let path = &c.descriptor().path_in_schema;
        path.len() == 1 && path[0].as_str() == column.name()
    })?;
    let descriptor = &found.descriptor().descriptor;
    let range = found.byte_range();
    let flat = descriptor.max_rep_level == 0 && (0..=1).contains(&descriptor.max_def_level);
    let fits =
        range.start <= range.end && range.end <= size && range.end - range.start <= MOST_BYTES;
    let counted = usize::try_from(found.num_values()).ok() == Some(rows);
    (flat && fits && counted && found.physical_type() == column.physical()).then(|| Chunk {
        start: range.start,
        end: range.end,
        codec: found.compression(),
        optional: descriptor.max_def_level == 1,
    })
}

/// Decoded rows of a row group: the columns a pass asked for, the others
/// left empty. Times are as written, in the log's unit.
#[derive(Debug, Default)]
pub(super) struct Rows {
    pub(super) signals: Vec<SignalId>,
    pub(super) values: Vec<bool>,
    pub(super) starts: Vec<i64>,
    pub(super) ends: Vec<i64>,
    /// Whether each row has its end (an open interval has none: its `ends`
    /// cell is 0).
    pub(super) closed: Vec<bool>,
}

impl Rows {
    fn clear(&mut self) {
        self.signals.clear();
        self.values.clear();
        self.starts.clear();
        self.ends.clear();
        self.closed.clear();
    }
}

/// Decodes the row groups of one file.
pub(super) struct Decoder {
    file: File,
    layout: Layout,
    /// The current column chunk's bytes.
    bytes: Vec<u8>,
    pages: Pages,
}

impl Decoder {
    pub(super) fn new(file: File, layout: Layout, signals: SignalTable) -> Decoder {
        Decoder {
            file,
            layout,
            bytes: Vec::new(),
            pages: Pages {
                signals,
                page: Vec::new(),
                context: DecompressionContext::Unset,
                names: Vec::new(),
                times: Vec::new(),
                indices: Vec::new(),
                defined: Vec::new(),
            },
        }
    }

    /// Decodes `columns` of row group `g` into `rows`; `None` if the file
    /// cannot be read or its pages are not as the form's.
    pub(super) fn group(&mut self, g: usize, columns: &[Column], rows: &mut Rows) -> Option<()> {
        let group = self.layout.groups.get(g)?;
        rows.clear();
        for &column in columns {
            let chunk = group.chunks.get(column as usize)?;
            let len = usize::try_from(chunk.end - chunk.start).ok()?;
            self.bytes.resize(len, 0);
            self.file.read_exact_at(&mut self.bytes, chunk.start).ok()?;
            let decoded = self
                .pages
                .chunk(&self.bytes, chunk, group.rows, column, rows)?;
            if decoded != group.rows {
                return None;
            }
        }
        Some(())
    }
}

/// What decoding pages needs, beside the chunk's bytes.
struct Pages {
    signals: SignalTable,
    /// The current page, decompressed.
    page: Vec<u8>,
    context: DecompressionContext,
    /// The chunk's dictionary: names as signal ids (`None`: not a signal),
    /// or times.
    names: Vec<Option<SignalId>>,
    times: Vec<i64>,
    /// A page's dictionary indices, and whether each of its cells is there.
    indices: Vec<u32>,
    defined: Vec<bool>,
}

/// A data page's parts: its number of cells (nulls included) and values.
struct Data<'a> {
    cells: usize,
    encoding: i32,
    values: &'a [u8],
}

impl Pages {
    /// Decodes the pages of a chunk of `column` (its `bytes`) into `rows`:
    /// how many cells they hold, at most `most`.
    fn chunk(
        &mut self,
        bytes: &[u8],
        chunk: &Chunk,
        most: usize,
        column: Column,
        rows: &mut Rows,
    ) -> Option<usize> {
        self.names.clear();
        self.times.clear();
        let (mut at, mut cells) = (0usize, 0usize);
        while at < bytes.len() {
            let header = PageHeader::read(&bytes[at..])?;
            header.check(most as i64).ok()?;
            let body = usize::try_from(header.length).ok()?.checked_add(at)?;
            let end = body.checked_add(usize::try_from(header.compressed).ok()?)?;
            let body = bytes.get(body..end)?;
            at = end;
            match header.kind {
                2 => self.dictionary(&header, body, chunk, column)?,
                0 | 3 => {
                    let left = most - cells;
                    cells += self.data(&header, body, chunk, column, left, rows)?;
                }
                // Index pages, which a reader may skip.
                _ => {}
            }
        }
        Some(cells)
    }

    /// A page's bytes, decompressed when they are.
    fn expand<'b>(
        page: &'b mut Vec<u8>,
        context: &mut DecompressionContext,
        header: &PageHeader,
        body: &'b [u8],
        codec: Compression,
    ) -> Option<&'b [u8]> {
        let size = usize::try_from(header.uncompressed).ok()?;
        if codec == Compression::Uncompressed {
            return (size == body.len()).then_some(body);
        }
        if size as u64 > MOST_BYTES {
            return None;
        }
        if page.len() < size {
            page.resize(size, 0);
        }
        let out = &mut page[..size];
        decompress(codec, body, out, context).ok()?;
        Some(out)
    }

    /// Takes a dictionary page: PLAIN names mapped to signals, or times.
    fn dictionary(
        &mut self,
        header: &PageHeader,
        body: &[u8],
        chunk: &Chunk,
        column: Column,
    ) -> Option<()> {
        if !matches!(header.encoding, PLAIN | PLAIN_DICTIONARY) {
            return None;
        }
        let count = usize::try_from(header.values?).ok()?;
        let mut page = std::mem::take(&mut self.page);
        let taken = self.take_dictionary(header, body, chunk, column, count, &mut page);
        self.page = page;
        taken
    }

    fn take_dictionary(
        &mut self,
        header: &PageHeader,
        body: &[u8],
        chunk: &Chunk,
        column: Column,
        count: usize,
        page: &mut Vec<u8>,
    ) -> Option<()> {
        let bytes = Pages::expand(page, &mut self.context, header, body, chunk.codec)?;
        match column {
            Column::Signal => {
                self.names.clear();
                let signals = &self.signals;
                plain_names(bytes, count, |name| self.names.push(signal(signals, name)))?;
            }
            Column::Start | Column::End => {
                self.times.clear();
                let times = bytes.get(..count.checked_mul(8)?)?;
                let times = times
                    .chunks_exact(8)
                    .map(|b| i64::from_le_bytes(b.try_into().unwrap_or_default()));
                self.times.extend(times);
            }
            Column::Value => return None,
        }
        Some(())
    }

    /// Takes a v1 data page of at most `most` cells into `rows`: how many
    /// it holds.
    fn data(
        &mut self,
        header: &PageHeader,
        body: &[u8],
        chunk: &Chunk,
        column: Column,
        most: usize,
        rows: &mut Rows,
    ) -> Option<usize> {
        let cells = usize::try_from(header.values?).ok()?;
        // v2 pages (kind 3) are left to the general reader.
        if cells > most || header.kind != 0 {
            return None;
        }
        let mut page = std::mem::take(&mut self.page);
        let taken = Pages::expand(&mut page, &mut self.context, header, body, chunk.codec)
            .and_then(|bytes| self.take_data(header, bytes, chunk.optional, column, rows));
        self.page = page;
        taken?;
        Some(cells)
    }

    /// A data page's decompressed `bytes` into `rows`: definition levels
    /// first if the column is `optional`, then the values.
    fn take_data(
        &mut self,
        header: &PageHeader,
        bytes: &[u8],
        optional: bool,
        column: Column,
        rows: &mut Rows,
    ) -> Option<()> {
        let cells = usize::try_from(header.values?).ok()?;
        let values = if optional {
            if header.level_encoding != RLE {
                return None;
            }
            let (len, rest) = length_prefixed(bytes)?;
            decode_levels(
                rest.get(..len)?,
                cells,
                &mut self.indices,
                &mut self.defined,
            )?;
            rest.get(len..)?
        } else {
            self.defined.clear();
            bytes
        };
        let data = Data {
            cells,
            encoding: header.encoding,
            values,
        };
        self.cells(&data, column, rows)
    }

    /// The page's cells into `rows`.
    fn cells(&mut self, data: &Data, column: Column, rows: &mut Rows) -> Option<()> {
        let nulls = self.defined.iter().filter(|&&d| !d).count();
        let present = data.cells - nulls;
        if nulls > 0 && column != Column::End {
            return None;
        }
        match column {
            Column::Signal => self.names_into(data, present, &mut rows.signals),
            Column::Value => booleans(data, present, &mut rows.values),
            Column::Start => self.times_into(data, present, &mut rows.starts),
            Column::End => {
                let from = rows.ends.len();
                self.times_into(data, present, &mut rows.ends)?;
                if nulls == 0 {
                    rows.closed.resize(rows.ends.len(), true);
                } else {
                    spread(&self.defined, from, &mut rows.ends, &mut rows.closed);
                }
                Some(())
            }
        }
    }

    /// `present` signal names, as ids.
    fn names_into(&mut self, data: &Data, present: usize, out: &mut Vec<SignalId>) -> Option<()> {
        match data.encoding {
            PLAIN => {
                let signals = &self.signals;
                let mut unknown = false;
                plain_names(data.values, present, |name| match signal(signals, name) {
                    Some(id) => out.push(id),
                    None => unknown = true,
                })?;
                (!unknown).then_some(())
            }
            PLAIN_DICTIONARY | RLE_DICTIONARY => {
                dictionary_indices(data.values, present, &mut self.indices)?;
                out.reserve(present);
                for &i in &self.indices {
                    out.push((*self.names.get(i as usize)?)?);
                }
                Some(())
            }
            _ => None,
        }
    }

    /// `present` times.
    fn times_into(&mut self, data: &Data, present: usize, out: &mut Vec<i64>) -> Option<()> {
        match data.encoding {
            PLAIN => {
                let bytes = data.values.get(..present.checked_mul(8)?)?;
                out.extend(
                    bytes
                        .chunks_exact(8)
                        .map(|b| i64::from_le_bytes(b.try_into().unwrap_or_default())),
                );
                Some(())
            }
            PLAIN_DICTIONARY | RLE_DICTIONARY => {
                dictionary_indices(data.values, present, &mut self.indices)?;
                // One check for the page, then a loop without exits.
                let largest = self.indices.iter().copied().max().unwrap_or(0);
                if largest as usize >= self.times.len() && !self.indices.is_empty() {
                    return None;
                }
                let times = &self.times;
                out.extend(self.indices.iter().map(|&i| times[i as usize]));
                Some(())
            }
            _ => None,
        }
    }
}

/// A name of the dictionary or of a PLAIN page as a signal, read as the
/// records read it (trimmed, unquoted); `None` if it is not one.
fn signal(signals: &SignalTable, name: &[u8]) -> Option<SignalId> {
    signals.id(clean(std::str::from_utf8(name).ok()?))
}

/// Hands `count` PLAIN byte arrays (a 4-byte length each, then the bytes)
/// to `each`.
fn plain_names(bytes: &[u8], count: usize, mut each: impl FnMut(&[u8])) -> Option<()> {
    let mut rest = bytes;
    for _ in 0..count {
        let (len, tail) = length_prefixed(rest)?;
        each(tail.get(..len)?);
        rest = tail.get(len..)?;
    }
    Some(())
}

/// A 4-byte little-endian length, and the bytes after it.
fn length_prefixed(bytes: &[u8]) -> Option<(usize, &[u8])> {
    let (len, rest) = bytes.split_first_chunk::<4>()?;
    Some((usize::try_from(u32::from_le_bytes(*len)).ok()?, rest))
}

/// `present` PLAIN booleans, a bit each.
fn booleans(data: &Data, present: usize, out: &mut Vec<bool>) -> Option<()> {
    if data.encoding != PLAIN {
        return None;
    }
    let bytes = data.values.get(..present.div_ceil(8))?;
    out.extend((0..present).map(|i| bytes[i / 8] >> (i % 8) & 1 == 1));
    Some(())
}

/// A page's definition levels (0 null, 1 there), `cells` of them.
fn decode_levels(
    bytes: &[u8],
    cells: usize,
    scratch: &mut Vec<u32>,
    defined: &mut Vec<bool>,
) -> Option<()> {
    hybrid(bytes, 1, cells, scratch)?;
    defined.clear();
    defined.extend(scratch.iter().map(|&level| level == 1));
    Some(())
}

/// Dictionary indices: their bit width in a byte, then `count` of them.
fn dictionary_indices(bytes: &[u8], count: usize, out: &mut Vec<u32>) -> Option<()> {
    let (&width, rest) = bytes.split_first()?;
    if width > 32 {
        return None;
    }
    hybrid(rest, u32::from(width), count, out)
}

/// Moves the values of `ends[from..]` to the cells that are there, by
/// `defined`, and marks each cell in `closed`.
fn spread(defined: &[bool], from: usize, ends: &mut Vec<i64>, closed: &mut Vec<bool>) {
    let present = ends.len() - from;
    ends.resize(from + defined.len(), 0);
    let mut next = present;
    for (k, &there) in defined.iter().enumerate().rev() {
        if there {
            next -= 1;
            ends[from + k] = ends[from + next];
        } else {
            ends[from + k] = 0;
        }
    }
    closed.extend_from_slice(defined);
}

/// `count` values of the RLE / bit-packed hybrid encoding, `width` bits
/// each, into `out`; `None` if the bytes end first.
fn hybrid(bytes: &[u8], width: u32, count: usize, out: &mut Vec<u32>) -> Option<()> {
    out.clear();
    // `count` is a page's, which the caller bounds.
    out.reserve(count);
    let mut at = 0usize;
    let size = width.div_ceil(8) as usize;
    while out.len() < count {
        let header = uleb128(bytes, &mut at)?;
        let left = count - out.len();
        if header & 1 == 0 {
            let run = usize::try_from(header >> 1).unwrap_or(usize::MAX).min(left);
            let value = bytes.get(at..at.checked_add(size)?)?;
            at += size;
            let value = value
                .iter()
                .rev()
                .fold(0u32, |v, &b| (v << 8) | u32::from(b));
            out.extend(std::iter::repeat_n(value, run));
        } else {
            let groups = usize::try_from(header >> 1).ok()?;
            let packed = groups.checked_mul(width as usize)?;
            let run = bytes.get(at..)?;
            let run = &run[..packed.min(run.len())];
            at += run.len();
            let fit = if width == 0 {
                left
            } else {
                run.len() * 8 / width as usize
            };
            let take = groups.saturating_mul(8).min(left).min(fit);
            if take == 0 {
                return None;
            }
            unpack(run, width, take, out);
        }
    }
    Some(())
}

/// An unsigned LEB128 varint at `at`, moving past it.
fn uleb128(bytes: &[u8], at: &mut usize) -> Option<u64> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *bytes.get(*at)?;
        *at += 1;
        value |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Some(value);
        }
    }
    None
}

/// `n` bit-packed values of `width` bits (least significant first) from
/// `bytes`, which hold them, into `out`.
fn unpack(bytes: &[u8], width: u32, n: usize, out: &mut Vec<u32>) {
    if width == 0 {
        out.extend(std::iter::repeat_n(0, n));
        return;
    }
    let (w, mask) = (width as usize, u64::MAX >> (64 - width));
    // A value at bit `b` is read from the eight bytes from `b / 8`: the
    // values whose eight bytes lie within `bytes` first, the rest a byte
    // at a time.
    let whole = match bytes.len().checked_sub(8) {
        Some(room) => (room * 8 / w + 1).min(n),
        None => 0,
    };
    let word = |bit: usize| {
        let bytes = bytes.get(bit / 8..).and_then(|b| b.first_chunk::<8>());
        bytes.map_or(0, |b| u64::from_le_bytes(*b))
    };
    out.extend((0..whole).map(|i| ((word(i * w) >> (i * w % 8)) & mask) as u32));
    out.extend((whole..n).map(|i| {
        let bit = i * w;
        let near = bytes.get(bit / 8..).unwrap_or_default();
        let near = near
            .iter()
            .take(8)
            .rev()
            .fold(0u64, |v, &b| (v << 8) | u64::from(b));
        ((near >> (bit % 8)) & mask) as u32
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hybrid_runs_read_as_written() {
        // An RLE run of 3 fives (width 3), then one bit-packed group of
        // 0..8 (width 3: 24 bits).
        let mut bytes = vec![3 << 1, 5];
        bytes.push(1 << 1 | 1);
        let packed: u32 = (0..8).fold(0, |acc, v| acc | (v << (3 * v)));
        bytes.extend_from_slice(&packed.to_le_bytes()[..3]);
        let mut out = Vec::new();
        assert_eq!(hybrid(&bytes, 3, 11, &mut out), Some(()));
        assert_eq!(out, [5, 5, 5, 0, 1, 2, 3, 4, 5, 6, 7]);
        // Cut short, or asked for more than it holds: refused.
        assert_eq!(hybrid(&bytes[..4], 3, 11, &mut out), None);
        assert_eq!(hybrid(&bytes, 3, 12, &mut out), None);
    }

    #[test]
    fn wide_values_unpack() {
        let values = [0xdead_beefu32, 1, 0xffff_ffff, 7, 0, 42, 9, 3];
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut out = Vec::new();
        unpack(&bytes, 32, 8, &mut out);
        assert_eq!(out, values);
        out.clear();
        unpack(&[0b1011_0110, 0b0000_0001], 3, 3, &mut out);
        assert_eq!(out, [0b110, 0b110, 0b110]);
    }

    #[test]
    fn every_width_and_length_unpacks_as_packed() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for width in 1..=32u32 {
            for n in 0..40usize {
                let values: Vec<u32> = (0..n)
                    .map(|_| {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        (state & (u64::MAX >> (64 - width))) as u32
                    })
                    .collect();
                // Packed least significant bit first, in whole bytes.
                let mut bytes = vec![0u8; (n * width as usize).div_ceil(8)];
                for (i, &v) in values.iter().enumerate() {
                    for b in 0..width as usize {
                        let bit = i * width as usize + b;
                        bytes[bit / 8] |= (((v >> b) & 1) as u8) << (bit % 8);
                    }
                }
                let mut out = Vec::new();
                unpack(&bytes, width, n, &mut out);
                assert_eq!(out, values, "width {width}, {n} values");
            }
        }
    }

    #[test]
    fn nulls_spread_to_their_cells() {
        let (mut ends, mut closed) = (vec![9, 1, 2], Vec::new());
        spread(&[false, true, false, true], 1, &mut ends, &mut closed);
        assert_eq!(ends, [9, 0, 1, 0, 2]);
        assert_eq!(closed, [false, true, false, true]);
    }
}
