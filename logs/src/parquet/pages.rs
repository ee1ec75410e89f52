//! The footer's structure and the page headers of a Parquet file, checked
//! before polars reads them.
//!
//! polars trusts a page header's counts: a data page saying it holds a
//! negative number of values makes it reserve 2^61 bytes for their validity,
//! and the process aborts ("memory allocation … failed"), which no panic
//! handler catches. [`check_chunk`] walks the pages of one column chunk (each
//! a Thrift compact-protocol `PageHeader`, then its bytes) and refuses a chunk
//! whose pages do not tile its byte range or whose counts are negative or
//! larger than the chunk's. Only the headers are read, a few bytes a page.

use std::fs::File;
use std::os::unix::fs::FileExt as _;

/// The longest page header read (statistics may hold long min and max values).
const LONGEST_HEADER: u64 = 1 << 20;

/// Nested structures in a header deeper than this are refused (the format
/// nests three deep).
const DEEPEST: u32 = 16;

/// Checks a file's footer (a Thrift `FileMetaData`) as polars reads it.
/// polars' reader reserves room for a list from the size it declares, and a
/// damaged size made it reserve 47 GB and abort; it also reads a field it
/// knows as the type it expects, whatever type the field says it has, and a
/// field of another type made it read a list header out of other bytes (76
/// GB). Every field polars reads must have the type it expects there, and
/// every list fit in the footer's bytes.
pub(super) fn check_footer(bytes: &[u8]) -> Result<(), String> {
    let mut c = Compact { bytes, at: 0 };
    match c.structure(Shape::FileMetaData, 0) {
        Ok(()) => Ok(()),
        Err(Short) => Err("cut short, or a list longer than the footer".into()),
        Err(Malformed(why)) => Err(why.into()),
    }
}

/// Checks the pages of the column chunk at bytes `start..end` of `file`,
/// which holds `values` values by its metadata.
pub(super) fn check_chunk(file: &File, start: u64, end: u64, values: i64) -> Result<(), String> {
    let mut at = start;
    let mut page = 0usize;
    while at < end {
        let header =
            read_header(file, at, end).map_err(|why| format!("page {page} at byte {at}: {why}"))?;
        header
            .check(values)
            .map_err(|why| format!("page {page} at byte {at}: {why}"))?;
        at = at
            .checked_add(header.length)
            .and_then(|a| a.checked_add(header.compressed as u64))
            .filter(|&a| a <= end)
            .ok_or_else(|| {
                format!("page {page} at byte {at} runs past its column chunk (byte {end})")
            })?;
        page += 1;
    }
    Ok(())
}

/// The header at byte `at`, read in growing slices until it parses.
fn read_header(file: &File, at: u64, end: u64) -> Result<PageHeader, String> {
    let mut want = 4096u64;
    loop {
        let len = want.min(end - at);
        let mut bytes = vec![0u8; len as usize];
        file.read_exact_at(&mut bytes, at)
            .map_err(|e| format!("cannot read its header: {e}"))?;
        match PageHeader::parse(&bytes) {
            Ok(header) => return Ok(header),
            Err(Short) if len == want && want < LONGEST_HEADER => want *= 16,
            Err(Short) => return Err("its header is cut short or too long".into()),
            Err(Malformed(why)) => return Err(format!("a malformed header ({why})")),
        }
    }
}

/// What a page header says of the page's size, counts and encodings.
#[derive(Debug, Default, PartialEq)]
pub(super) struct PageHeader {
    /// Bytes of the header itself.
    pub(super) length: u64,
    /// 0 a data page, 2 a dictionary page, 3 a v2 data page.
    pub(super) kind: i32,
    pub(super) uncompressed: i32,
    pub(super) compressed: i32,
    /// `num_values` of a data, dictionary or v2 data page.
    pub(super) values: Option<i32>,
    /// The values' encoding, and a v1 data page's definition levels'.
    pub(super) encoding: i32,
    pub(super) level_encoding: i32,
    /// v2 data pages: nulls, rows, and the levels' byte lengths.
    nulls: i32,
    rows: i32,
    levels: [i32; 2],
}

impl PageHeader {
    pub(super) fn check(&self, chunk_values: i64) -> Result<(), String> {
        let counts = [
            ("uncompressed size", self.uncompressed),
            ("compressed size", self.compressed),
            ("number of values", self.values.unwrap_or(0)),
            ("number of nulls", self.nulls),
            ("number of rows", self.rows),
            ("definition levels' length", self.levels[0]),
            ("repetition levels' length", self.levels[1]),
        ];
        if let Some((what, n)) = counts.iter().find(|(_, n)| *n < 0) {
            return Err(format!("a negative {what}, {n}"));
        }
        let data = matches!(self.kind, 0 | 3);
        let values = self.values.unwrap_or(0);
        if data && self.values.is_none() {
            return Err("a data page without its data page header".into());
        }
        if data && i64::from(values) > chunk_values {
            return Err(format!(
                "{values} values in a column chunk of {chunk_values}"
            ));
        }
        if self.nulls > values || self.rows > values {
            return Err(format!(
                "{} nulls and {} rows for {values} values",
                self.nulls, self.rows
            ));
        }
        if i64::from(self.levels[0]) + i64::from(self.levels[1]) > i64::from(self.compressed) {
            return Err("levels longer than the page".into());
        }
        Ok(())
    }

    /// The header at the start of `bytes` (Thrift compact protocol); `None`
    /// if it is cut short or malformed.
    pub(super) fn read(bytes: &[u8]) -> Option<PageHeader> {
        PageHeader::parse(bytes).ok()
    }

    /// The header at the start of `bytes` (Thrift compact protocol).
    fn parse(bytes: &[u8]) -> Result<PageHeader, Fault> {
        let mut c = Compact { bytes, at: 0 };
        let mut header = PageHeader::default();
        let mut field = 0i16;
        while let Some((id, kind)) = c.field_header(&mut field)? {
            match (id, kind) {
                (1, I32) => header.kind = c.int()?,
                (2, I32) => header.uncompressed = c.int()?,
                (3, I32) => header.compressed = c.int()?,
                (5 | 7, STRUCT) => c.data_page(&mut header)?,
                (8, STRUCT) => c.data_page_v2(&mut header)?,
                _ => c.skip(kind, 0)?,
            }
        }
        header.length = c.at as u64;
        Ok(header)
    }
}

/// Why a header did not parse.
enum Fault {
    /// The bytes ended first: read more.
    Short,
    Malformed(&'static str),
}
use Fault::{Malformed, Short};

/// A structure of the footer, as polars' reader reads it
/// (`polars-parquet`'s `handwritten_thrift/file_metadata_thrift.rs`).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Shape {
    FileMetaData,
    SchemaElement,
    RowGroup,
    ColumnChunk,
    ColumnMetaData,
    Statistics,
    KeyValue,
    SortingColumn,
    /// `ColumnOrder` and `TimeUnit`: unions of empty structures.
    EmptyUnion,
    LogicalType,
    Decimal,
    /// `TimeType` and `TimestampType`.
    TimeType,
    IntType,
    /// A structure polars reads no field of.
    Empty,
}

/// What polars reads a field as.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Field {
    /// An i16, i32 or i64 (a varint).
    Varint,
    Binary,
    Bool,
    Byte,
    Struct(Shape),
    ListOf(Element),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Element {
    Varint,
    Binary,
    Struct(Shape),
}

/// What polars reads field `id` of `shape` as; `None` for a field it skips
/// by its own type.
fn field(shape: Shape, id: i16) -> Option<Field> {
    use Field::{Binary, Bool, Byte, ListOf, Struct, Varint};
    Some(match (shape, id) {
        (Shape::FileMetaData, 1 | 3) => Varint,
        (Shape::FileMetaData, 2) => ListOf(Element::Struct(Shape::SchemaElement)),
        (Shape::FileMetaData, 4) => ListOf(Element::Struct(Shape::RowGroup)),
        (Shape::FileMetaData, 5) => ListOf(Element::Struct(Shape::KeyValue)),
        (Shape::FileMetaData, 6) => Binary,
        (Shape::FileMetaData, 7) => ListOf(Element::Struct(Shape::EmptyUnion)),
        (Shape::SchemaElement, 1..=3 | 5..=9) => Varint,
        (Shape::SchemaElement, 4) => Binary,
        (Shape::SchemaElement, 10) => Struct(Shape::LogicalType),
        (Shape::RowGroup, 1) => ListOf(Element::Struct(Shape::ColumnChunk)),
        (Shape::RowGroup, 2 | 3 | 5..=7) => Varint,
        (Shape::RowGroup, 4) => ListOf(Element::Struct(Shape::SortingColumn)),
        (Shape::ColumnChunk, 1) => Binary,
        (Shape::ColumnChunk, 2 | 4..=7) => Varint,
        (Shape::ColumnChunk, 3) => Struct(Shape::ColumnMetaData),
        (Shape::ColumnMetaData, 1 | 4..=7 | 9..=11 | 14 | 15) => Varint,
        (Shape::ColumnMetaData, 2) => ListOf(Element::Varint),
        (Shape::ColumnMetaData, 3) => ListOf(Element::Binary),
        (Shape::ColumnMetaData, 12) => Struct(Shape::Statistics),
        (Shape::Statistics, 1 | 2 | 5 | 6) => Binary,
        (Shape::Statistics, 3 | 4) => Varint,
        (Shape::Statistics, 7 | 8) => Bool,
        (Shape::KeyValue, 1 | 2) => Binary,
        (Shape::SortingColumn, 1) => Varint,
        (Shape::SortingColumn, 2 | 3) => Bool,
        (Shape::EmptyUnion, 1..=3) => Struct(Shape::Empty),
        (Shape::LogicalType, 1..=4 | 6 | 11..=15) => Struct(Shape::Empty),
        (Shape::LogicalType, 5) => Struct(Shape::Decimal),
        (Shape::LogicalType, 7 | 8) => Struct(Shape::TimeType),
        (Shape::LogicalType, 10) => Struct(Shape::IntType),
        (Shape::Decimal, 1 | 2) => Varint,
        (Shape::TimeType, 1) => Bool,
        (Shape::TimeType, 2) => Struct(Shape::EmptyUnion),
        (Shape::IntType, 1) => Byte,
        (Shape::IntType, 2) => Bool,
        _ => return None,
    })
}

/// Whether a value of Thrift type `kind` reads as `field`.
fn fits(field: Field, kind: u8) -> bool {
    match field {
        Field::Varint => matches!(kind, I16 | I32 | I64),
        Field::Binary => kind == BINARY,
        Field::Bool => matches!(kind, TRUE | FALSE),
        Field::Byte => kind == BYTE,
        Field::Struct(_) => kind == STRUCT,
        Field::ListOf(_) => matches!(kind, LIST | SET),
    }
}

// Thrift compact protocol types.
const TRUE: u8 = 1;
const FALSE: u8 = 2;
const BYTE: u8 = 3;
const I16: u8 = 4;
const I32: u8 = 5;
const I64: u8 = 6;
const DOUBLE: u8 = 7;
const BINARY: u8 = 8;
const LIST: u8 = 9;
const SET: u8 = 10;
const MAP: u8 = 11;
const STRUCT: u8 = 12;

/// A reader of the Thrift compact protocol over a header's bytes.
struct Compact<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Compact<'_> {
    fn byte(&mut self) -> Result<u8, Fault> {
        let b = *self.bytes.get(self.at).ok_or(Short)?;
        self.at += 1;
        Ok(b)
    }

    fn varint(&mut self) -> Result<u64, Fault> {
        let mut value = 0u64;
        for shift in (0..70).step_by(7) {
            let b = self.byte()?;
            if shift == 63 && b > 1 {
                return Err(Malformed("a varint past 64 bits"));
            }
            value |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(Malformed("a varint past 64 bits"))
    }

    fn zigzag(&mut self) -> Result<i64, Fault> {
        let n = self.varint()?;
        Ok((n >> 1) as i64 ^ -((n & 1) as i64))
    }

    fn int(&mut self) -> Result<i32, Fault> {
        i32::try_from(self.zigzag()?).map_err(|_| Malformed("an i32 out of range"))
    }

    /// The next field's id and type, `None` at the struct's end; `last` is
    /// the previous field's id (ids are sent as deltas).
    fn field_header(&mut self, last: &mut i16) -> Result<Option<(i16, u8)>, Fault> {
        let b = self.byte()?;
        if b == 0 {
            return Ok(None);
        }
        let (delta, kind) = (b >> 4, b & 0x0f);
        *last = if delta == 0 {
            i16::try_from(self.zigzag()?).map_err(|_| Malformed("a field id out of range"))?
        } else {
            last.checked_add(i16::from(delta))
                .ok_or(Malformed("a field id out of range"))?
        };
        Ok(Some((*last, kind)))
    }

    /// A data or dictionary page header: `num_values` (field 1, required),
    /// the encoding (field 2) and a data page's definition levels' encoding
    /// (field 3); the rest skipped.
    fn data_page(&mut self, header: &mut PageHeader) -> Result<(), Fault> {
        let (mut field, mut value) = (0i16, None);
        while let Some((id, kind)) = self.field_header(&mut field)? {
            match (id, kind) {
                (1, I32) => value = Some(self.int()?),
                (2, I32) => header.encoding = self.int()?,
                (3, I32) => header.level_encoding = self.int()?,
                _ => self.skip(kind, 1)?,
            }
        }
        let value = value.ok_or(Malformed("a page header without its number of values"))?;
        header.values = Some(value);
        Ok(())
    }

    fn data_page_v2(&mut self, header: &mut PageHeader) -> Result<(), Fault> {
        let mut field = 0i16;
        while let Some((id, kind)) = self.field_header(&mut field)? {
            match (id, kind) {
                (1, I32) => header.values = Some(self.int()?),
                (2, I32) => header.nulls = self.int()?,
                (3, I32) => header.rows = self.int()?,
                (4, I32) => header.encoding = self.int()?,
                (5, I32) => header.levels[0] = self.int()?,
                (6, I32) => header.levels[1] = self.int()?,
                _ => self.skip(kind, 1)?,
            }
        }
        Ok(())
    }

    /// A structure of `shape`, `depth` structures deep, each field polars
    /// reads of the type it expects.
    fn structure(&mut self, shape: Shape, depth: u32) -> Result<(), Fault> {
        if depth > DEEPEST {
            return Err(Malformed("structures nested too deep"));
        }
        let mut last = 0i16;
        while let Some((id, kind)) = self.field_header(&mut last)? {
            let Some(expected) = field(shape, id) else {
                self.skip(kind, depth + 1)?;
                continue;
            };
            if !fits(expected, kind) {
                return Err(Malformed("a field of another type than its own"));
            }
            match expected {
                Field::Varint => drop(self.varint()?),
                Field::Binary => {
                    let len = self.varint()?;
                    self.advance(len)?;
                }
                Field::Bool => {}
                Field::Byte => drop(self.byte()?),
                Field::Struct(inner) => self.structure(inner, depth + 1)?,
                Field::ListOf(element) => self.list(element, depth + 1)?,
            }
        }
        Ok(())
    }

    /// A list polars reads as a list of `element`s.
    fn list(&mut self, element: Element, depth: u32) -> Result<(), Fault> {
        let b = self.byte()?;
        let size = match b >> 4 {
            15 => self.varint()?,
            n => u64::from(n),
        };
        self.room_for(size)?;
        let kind = b & 0x0f;
        let fits = match element {
            Element::Varint => matches!(kind, I16 | I32 | I64),
            Element::Binary => kind == BINARY,
            Element::Struct(_) => kind == STRUCT,
        };
        if size > 0 && !fits {
            return Err(Malformed("a list of another type than its own"));
        }
        for _ in 0..size {
            match element {
                Element::Varint => drop(self.varint()?),
                Element::Binary => {
                    let len = self.varint()?;
                    self.advance(len)?;
                }
                Element::Struct(shape) => self.structure(shape, depth + 1)?,
            }
        }
        Ok(())
    }

    /// Skips a value of type `kind`, `depth` structures deep.
    fn skip(&mut self, kind: u8, depth: u32) -> Result<(), Fault> {
        if depth > DEEPEST {
            return Err(Malformed("structures nested too deep"));
        }
        match kind {
            TRUE | FALSE => {}
            BYTE => {
                self.byte()?;
            }
            I16 | I32 | I64 => {
                self.varint()?;
            }
            DOUBLE => self.advance(8)?,
            BINARY => {
                let len = self.varint()?;
                self.advance(len)?;
            }
            LIST | SET => {
                let b = self.byte()?;
                let size = match b >> 4 {
                    15 => self.varint()?,
                    n => u64::from(n),
                };
                self.room_for(size)?;
                for _ in 0..size {
                    match b & 0x0f {
                        // A boolean in a list is a byte of its own.
                        TRUE | FALSE => self.advance(1)?,
                        element => self.skip(element, depth + 1)?,
                    }
                }
            }
            MAP => {
                let size = self.varint()?;
                self.room_for(size)?;
                if size > 0 {
                    let b = self.byte()?;
                    for _ in 0..size {
                        self.skip(b >> 4, depth + 1)?;
                        self.skip(b & 0x0f, depth + 1)?;
                    }
                }
            }
            STRUCT => {
                let mut field = 0i16;
                while let Some((_, kind)) = self.field_header(&mut field)? {
                    self.skip(kind, depth + 1)?;
                }
            }
            _ => return Err(Malformed("an unknown field type")),
        }
        Ok(())
    }

    /// Whether `n` elements, a byte each at least, may follow.
    fn room_for(&self, n: u64) -> Result<(), Fault> {
        if n > (self.bytes.len() - self.at) as u64 {
            Err(Short)
        } else {
            Ok(())
        }
    }

    fn advance(&mut self, n: u64) -> Result<(), Fault> {
        let left = (self.bytes.len() - self.at) as u64;
        if n > left {
            return Err(Short);
        }
        self.at += n as usize;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A v1 data page header: DATA_PAGE, sizes 40 and 30, 16 values, PLAIN.
    fn data_page(values: i64) -> Vec<u8> {
        let zigzag = |n: i64| ((n << 1) ^ (n >> 63)) as u64;
        let varint = |mut n: u64, out: &mut Vec<u8>| loop {
            let b = (n & 0x7f) as u8;
            n >>= 7;
            if n == 0 {
                out.push(b);
                break;
            }
            out.push(b | 0x80);
        };
        let mut out = Vec::new();
        for value in [0i64, 40, 30] {
            out.push(0x15); // delta 1, i32
            varint(zigzag(value), &mut out);
        }
        out.push(0x2c); // field 5 (delta 2), struct
        out.push(0x15);
        varint(zigzag(values), &mut out);
        out.push(0x15); // encoding: PLAIN
        out.push(0);
        out.extend([0, 0]); // end of both structs
        out
    }

    #[test]
    fn a_data_page_header_reads_its_sizes_and_values() {
        let bytes = data_page(16);
        let header = PageHeader::parse(&bytes).ok().expect("parses");
        assert_eq!(
            (
                header.kind,
                header.uncompressed,
                header.compressed,
                header.values
            ),
            (0, 40, 30, Some(16))
        );
        assert_eq!(header.length, bytes.len() as u64);
        assert_eq!(header.check(16), Ok(()));
    }

    #[test]
    fn negative_or_excessive_counts_are_refused() {
        let header = PageHeader::parse(&data_page(-1)).ok().expect("parses");
        assert_eq!(
            header.check(16),
            Err("a negative number of values, -1".into())
        );
        let header = PageHeader::parse(&data_page(17)).ok().expect("parses");
        assert_eq!(
            header.check(16),
            Err("17 values in a column chunk of 16".into())
        );
    }

    #[test]
    fn a_cut_header_asks_for_more_and_garbage_never_panics() {
        let bytes = data_page(16);
        for cut in 0..bytes.len() {
            assert!(
                matches!(PageHeader::parse(&bytes[..cut]), Err(Short)),
                "cut at {cut}"
            );
        }
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..20_000 {
            let junk: Vec<u8> = (0..32)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state as u8
                })
                .collect();
            let _ = PageHeader::parse(&junk).map(|h| h.check(1 << 20));
        }
    }
}
