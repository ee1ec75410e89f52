//! A Parquet file's footer, checked, and its rows decoded slice by slice.
//!
//! Each column chunk of a row group is read into memory once (its compressed
//! bytes), then decoded by `polars-parquet` in slices of at most
//! `IngestOptions::parquet_slice_rows` rows (fewer for a wide file): the pages before a slice are
//! skipped without being decompressed, so memory holds one row group's
//! compressed columns and a slice's decoded ones. Slices are decoded on a
//! thread of their own, one ahead of their reader.

use std::fs::File;
use std::io::Cursor;
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use polars_arrow::array::{Array, BooleanArray, PrimitiveArray, Utf8ViewArray};
use polars_arrow::compute::concatenate::concatenate;
use polars_arrow::datatypes::{ArrowDataType, Field as ArrowField, TimeUnit as ArrowTimeUnit};
use polars_arrow::types::NativeType;
use polars_buffer::Buffer;
use polars_parquet::arrow::read::{
    BasicDecompressor, ColumnChunkMetadata, Filter, PageReader, column_iter_to_arrays,
    infer_schema, n_columns,
};
use polars_parquet::parquet::metadata::FileMetadata;
use polars_parquet::parquet::read::read_metadata;
use vocabulary::Located;
use vocabulary::panics::{self, Containment};

use super::{contained, failure, pages};
use crate::rows::open_file;

/// What a column's cells are, for the forms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// UTF-8 text, dictionary-encoded (categorical) or not.
    Text,
    Bool,
    /// Integers of any width, signed or not.
    Int,
    Float,
    /// Anything else (dates, binary, nested…): not a cell of any form.
    Other,
}

/// A column of the file.
#[derive(Debug, Clone)]
pub(crate) struct ColumnSpec {
    pub(crate) name: String,
    pub(crate) dtype: ArrowDataType,
    pub(crate) kind: Kind,
    /// Index of its (first) leaf among the row groups' column chunks.
    leaf: usize,
}

impl ColumnSpec {
    /// Its type, in polars' words.
    pub(crate) fn type_name(&self) -> String {
        type_name(&self.dtype)
    }
}

/// A file's footer and columns, checked.
#[derive(Debug, Clone)]
pub(crate) struct Schema {
    pub(crate) columns: Vec<ColumnSpec>,
    pub(crate) footer: FileMetadata,
    /// The file's size in bytes.
    pub(crate) size: u64,
}

impl Schema {
    /// The column named `name`.
    pub(crate) fn get(&self, name: &str) -> Option<&ColumnSpec> {
        self.columns.iter().find(|c| c.name == name)
    }
}

/// The schema of the Parquet file at `path`, from its footer, after
/// checking what the decoder trusts: the magic bytes, the footer's lists,
/// every row group and column chunk within the file, and their pages.
pub(crate) fn schema(path: &Path) -> Result<Schema, Located> {
    let size = super::check_frame(path)?;
    contained(path, || {
        let mut file = open_file(path)?;
        let footer = read_metadata(&mut file).map_err(|e| failure(path, &e.to_string()))?;
        check_footer(path, &file, &footer, size)?;
        let arrow = infer_schema(&footer).map_err(|e| failure(path, &e.to_string()))?;
        let mut columns = Vec::with_capacity(arrow.len());
        let mut leaf = 0;
        for field in arrow.iter_values() {
            columns.push(ColumnSpec {
                name: field.name.to_string(),
                dtype: field.dtype.clone(),
                kind: kind(&field.dtype),
                leaf,
            });
            leaf += n_columns(&field.dtype);
        }
        let leaves = footer.schema().columns().len();
        if leaf != leaves {
            return Err(failure(
                path,
                &format!(
                    "a damaged footer: its Arrow schema has {leaf} columns, its Parquet schema {leaves}"
                ),
            ));
        }
        Ok(Schema {
            columns,
            footer,
            size,
        })
    })
}

/// Checks the footer's byte ranges and counts, which the decoder uses
/// unchecked: every row group and column chunk within the file of `size`
/// bytes, no negative count; then the page headers of every column chunk
/// ([`pages`]), whose counts it trusts too.
fn check_footer(path: &Path, file: &File, footer: &FileMetadata, size: u64) -> Result<(), Located> {
    let fail = |why: String| Err(failure(path, &format!("a damaged footer: {why}")));
    let leaves = footer.schema().columns().len();
    for (k, group) in footer.row_groups.iter().enumerate() {
        let range = group.full_byte_range();
        if range.start > range.end || range.end > size {
            return fail(format!(
                "row group {k} spans bytes {range:?} of a file of {size}"
            ));
        }
        if group.parquet_columns().len() != leaves {
            return fail(format!(
                "row group {k} has {} column chunks for {leaves} columns",
                group.parquet_columns().len()
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
            pages::check_chunk(file, range.start, range.end, chunk.num_values()).map_err(
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
}

fn kind(dtype: &ArrowDataType) -> Kind {
    use ArrowDataType as T;
    match dtype {
        T::Utf8 | T::LargeUtf8 | T::Utf8View => Kind::Text,
        T::Dictionary(_, values, _) if kind(values) == Kind::Text => Kind::Text,
        T::Boolean => Kind::Bool,
        T::Int8 | T::Int16 | T::Int32 | T::Int64 => Kind::Int,
        T::UInt8 | T::UInt16 | T::UInt32 | T::UInt64 => Kind::Int,
        T::Float32 | T::Float64 => Kind::Float,
        _ => Kind::Other,
    }
}

/// A type as polars names it (`str`, `i64`, `datetime[μs]`…), which is how
/// users meet it in their tools.
fn type_name(dtype: &ArrowDataType) -> String {
    use ArrowDataType as T;
    let unit = |u: &ArrowTimeUnit| match u {
        ArrowTimeUnit::Second => "s",
        ArrowTimeUnit::Millisecond => "ms",
        ArrowTimeUnit::Microsecond => "μs",
        ArrowTimeUnit::Nanosecond => "ns",
    };
    let name = match dtype {
        T::Null => "null",
        T::Boolean => "bool",
        T::Int8 => "i8",
        T::Int16 => "i16",
        T::Int32 => "i32",
        T::Int64 => "i64",
        T::Int128 => "i128",
        T::UInt8 => "u8",
        T::UInt16 => "u16",
        T::UInt32 => "u32",
        T::UInt64 => "u64",
        T::Float16 => "f16",
        T::Float32 => "f32",
        T::Float64 => "f64",
        T::Utf8 | T::LargeUtf8 | T::Utf8View => "str",
        T::Dictionary(..) => "cat",
        T::Binary | T::LargeBinary | T::BinaryView | T::FixedSizeBinary(_) => "binary",
        T::Date32 | T::Date64 => "date",
        T::Time32(_) | T::Time64(_) => "time",
        T::Timestamp(u, _) => return format!("datetime[{}]", unit(u)),
        T::Duration(u) => return format!("duration[{}]", unit(u)),
        T::Decimal(p, s) => return format!("decimal[{p},{s}]"),
        T::List(f) | T::LargeList(f) | T::FixedSizeList(f, _) => {
            return format!("list[{}]", type_name(&f.dtype));
        }
        T::Struct(fields) => return format!("struct[{}]", fields.len()),
        other => return format!("{other:?}").to_lowercase(),
    };
    name.to_string()
}

/// The type a column is decoded as: text as UTF-8 views whatever its Arrow
/// annotation, the others as they are.
fn decoded_type(column: &ColumnSpec) -> ArrowDataType {
    match column.kind {
        Kind::Text => ArrowDataType::Utf8View,
        _ => column.dtype.clone(),
    }
}

/// One column of a slice, by kind.
pub(crate) enum Cells {
    Text(Utf8ViewArray),
    Int(PrimitiveArray<i64>),
    Float(PrimitiveArray<f64>),
    Bool(BooleanArray),
}

impl Cells {
    /// The decoded `array` of `column`, by its kind.
    fn of(column: &ColumnSpec, array: &dyn Array) -> Result<Cells, String> {
        let wrong = || format!("cannot decode column '{}'", column.name);
        let any = array.as_any();
        Ok(match &column.dtype {
            _ if column.kind == Kind::Text => Cells::Text(
                any.downcast_ref::<Utf8ViewArray>()
                    .ok_or_else(wrong)?
                    .clone(),
            ),
            ArrowDataType::Boolean => Cells::Bool(
                any.downcast_ref::<BooleanArray>()
                    .ok_or_else(wrong)?
                    .clone(),
            ),
            ArrowDataType::Int64 => Cells::Int(downcast::<i64>(array).ok_or_else(wrong)?.clone()),
            ArrowDataType::Int8 => Cells::Int(widen::<i8>(array).ok_or_else(wrong)?),
            ArrowDataType::Int16 => Cells::Int(widen::<i16>(array).ok_or_else(wrong)?),
            ArrowDataType::Int32 => Cells::Int(widen::<i32>(array).ok_or_else(wrong)?),
            ArrowDataType::UInt8 => Cells::Int(widen::<u8>(array).ok_or_else(wrong)?),
            ArrowDataType::UInt16 => Cells::Int(widen::<u16>(array).ok_or_else(wrong)?),
            ArrowDataType::UInt32 => Cells::Int(widen::<u32>(array).ok_or_else(wrong)?),
            ArrowDataType::UInt64 => Cells::Int(widen::<u64>(array).ok_or_else(wrong)?),
            ArrowDataType::Float64 => {
                Cells::Float(downcast::<f64>(array).ok_or_else(wrong)?.clone())
            }
            ArrowDataType::Float32 => {
                let floats = downcast::<f32>(array).ok_or_else(wrong)?;
                Cells::Float(floats.iter().map(|v| v.map(|&x| f64::from(x))).collect())
            }
            _ => return Err(unsupported(column)),
        })
    }
}

fn downcast<T: NativeType>(array: &dyn Array) -> Option<&PrimitiveArray<T>> {
    array.as_any().downcast_ref::<PrimitiveArray<T>>()
}

/// Integers of another type as `i64`; one that does not fit is null, as
/// polars' casts make it.
fn widen<T: NativeType + TryInto<i64>>(array: &dyn Array) -> Option<PrimitiveArray<i64>> {
    let ints = downcast::<T>(array)?;
    Some(
        ints.iter()
            .map(|v| v.and_then(|&x| x.try_into().ok()))
            .collect(),
    )
}

fn unsupported(column: &ColumnSpec) -> String {
    format!(
        "column '{}' has unsupported type {}",
        column.name,
        column.type_name()
    )
}

/// Rows of the file decoded: its columns, and how many rows they hold.
pub(crate) struct Slice {
    pub(crate) cells: Vec<Cells>,
    pub(crate) height: usize,
}

/// Cells decoded per slice at most: a wide file (a scans log, a column per
/// signal) is decoded in slices of fewer rows, so that memory stays at a few
/// MB per slice whatever its width.
const SLICE_CELLS: usize = 1 << 20;

/// The slices of a file, in order, decoded on a thread of their own.
pub(crate) struct Slices {
    receiver: Receiver<Result<Slice, String>>,
    worker: Option<JoinHandle<()>>,
}

impl Slices {
    /// Starts decoding the file: every column, in slices of at most
    /// `slice_rows` rows and [`SLICE_CELLS`] cells.
    pub(crate) fn start(
        path: &Path,
        schema: &Schema,
        slice_rows: usize,
    ) -> Result<Slices, Located> {
        let file = open_file(path)?;
        // One slice ahead: the decoder works while the reader reads.
        let (sender, receiver) = sync_channel(1);
        let decoder = Decoder {
            file,
            schema: schema.clone(),
            slice_rows: slice_rows
                .min(SLICE_CELLS / schema.columns.len().max(1))
                .max(1),
            sender,
        };
        let worker = std::thread::Builder::new()
            .name("gardefou-parquet".to_string())
            .spawn(move || {
                // Its panics come back through `join`, as the file's error.
                let _quiet = Containment::start();
                decoder.run();
            })
            .map_err(|e| super::file_error(path, format!("cannot start reading the log: {e}")))?;
        Ok(Slices {
            receiver,
            worker: Some(worker),
        })
    }

    /// The next slice, `None` at the end, or the decoder's error message.
    pub(crate) fn next(&mut self) -> Option<Result<Slice, String>> {
        if let Ok(slice) = self.receiver.recv() {
            return Some(slice);
        }
        // The sender is gone: the decoder has ended, well or by a panic.
        let worker = self.worker.take()?;
        match worker.join() {
            Ok(()) => None,
            Err(payload) => Some(Err(panics::message(payload.as_ref()))),
        }
    }
}

/// What the decoding thread holds.
struct Decoder {
    file: File,
    schema: Schema,
    slice_rows: usize,
    sender: SyncSender<Result<Slice, String>>,
}

impl Decoder {
    /// Decodes and sends every slice, or the first error; stops when nobody
    /// reads any more.
    fn run(self) {
        for group in &self.schema.footer.row_groups {
            let rows = group.num_rows();
            if rows == 0 {
                continue;
            }
            let chunks = group.parquet_columns();
            let bytes = match self.read_group(chunks) {
                Ok(bytes) => bytes,
                Err(message) => {
                    let _ = self.sender.send(Err(message));
                    return;
                }
            };
            for start in (0..rows).step_by(self.slice_rows) {
                let range = start..(start + self.slice_rows).min(rows);
                let slice = self.decode(chunks, &bytes, range);
                let failed = slice.is_err();
                if self.sender.send(slice).is_err() || failed {
                    return;
                }
            }
        }
    }

    /// The compressed bytes of every column chunk of a row group.
    fn read_group(&self, chunks: &[ColumnChunkMetadata]) -> Result<Vec<Buffer<u8>>, String> {
        if let Some(column) = self.schema.columns.iter().find(|c| c.kind == Kind::Other) {
            return Err(unsupported(column));
        }
        let mut read = Vec::with_capacity(self.schema.columns.len());
        for column in &self.schema.columns {
            let chunk = &chunks[column.leaf];
            let range = chunk.byte_range();
            let mut bytes = vec![0u8; (range.end - range.start) as usize];
            self.file
                .read_exact_at(&mut bytes, range.start)
                .map_err(|e| format!("cannot read column '{}': {e}", column.name))?;
            read.push(Buffer::from(bytes));
        }
        Ok(read)
    }

    /// Rows `range` of a row group, from its columns' bytes.
    fn decode(
        &self,
        chunks: &[ColumnChunkMetadata],
        bytes: &[Buffer<u8>],
        range: Range<usize>,
    ) -> Result<Slice, String> {
        let height = range.len();
        let mut cells = Vec::with_capacity(bytes.len());
        for (column, bytes) in self.schema.columns.iter().zip(bytes) {
            let chunk = &chunks[column.leaf];
            let failed = |e: &dyn std::fmt::Display| {
                format!(
                    "cannot decode column '{}': {}",
                    column.name,
                    super::first_line(&e.to_string())
                )
            };
            let pages = PageReader::new(Cursor::new(bytes.clone()), chunk, Vec::new(), usize::MAX);
            let field = ArrowField::new(column.name.as_str().into(), decoded_type(column), true);
            let types = vec![&chunk.descriptor().descriptor.primitive_type];
            let decompressor = BasicDecompressor::new(pages, Vec::new());
            let filter = Some(Filter::Range(range.clone()));
            let (arrays, _) = column_iter_to_arrays(vec![decompressor], types, field, filter)
                .map_err(|e| failed(&e))?;
            let array = match arrays.as_slice() {
                [one] => one.clone(),
                many => {
                    let many: Vec<&dyn Array> = many.iter().map(AsRef::as_ref).collect();
                    concatenate(&many).map_err(|e| failed(&e))?
                }
            };
            if array.len() != height {
                return Err(failed(&format!(
                    "{} rows where the footer says {height}",
                    array.len()
                )));
            }
            cells.push(Cells::of(column, array.as_ref())?);
        }
        Ok(Slice { cells, height })
    }
}
