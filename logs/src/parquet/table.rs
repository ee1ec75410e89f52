//! Writing a table of typed columns as a Parquet file: the archive writer's
//! back end, and how tests write Parquet logs of every shape a user may bring.
//!
//! Files are written as polars writes them: data pages of version 1, strings
//! as UTF-8 views, dictionary-encoded, statistics, the Arrow schema in the
//! footer.
//!
//! ```
//! use logs::{ParquetColumn, ParquetLayout, write_parquet_table};
//!
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("events.parquet");
//! let columns = vec![
//!     ParquetColumn::new("t", vec![0i64, 10, 20]),
//!     ParquetColumn::new("signal", vec!["C4", "A4", "C4"]),
//!     ParquetColumn::new("value", vec![true, true, false]),
//! ];
//! write_parquet_table(&path, columns, &ParquetLayout::default())?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use polars_arrow::array::{Array, BooleanArray, PrimitiveArray, Utf8ViewArray};
use polars_arrow::datatypes::{ArrowDataType, ArrowSchema, Field};
use polars_arrow::record_batch::RecordBatchT;
use polars_parquet::arrow::write::{
    CompressionOptions, FileWriter, RowGroupIterator, StatisticsOptions, Version, WriteOptions,
    get_dtype_encoding,
};

/// A named column of cells.
#[derive(Debug, Clone, PartialEq)]
pub struct ParquetColumn {
    name: String,
    cells: ParquetCells,
}

impl ParquetColumn {
    /// A column named `name`; `cells` from a `Vec` of booleans, integers,
    /// floats or text, each optionally `Option` (a null cell).
    pub fn new(name: impl Into<String>, cells: impl Into<ParquetCells>) -> Self {
        ParquetColumn {
            name: name.into(),
            cells: cells.into(),
        }
    }

    /// How many cells it has.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether it has no cell.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The cells of a column, by Parquet type; `None` is a null cell.
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)]
pub enum ParquetCells {
    Bool(Vec<Option<bool>>),
    I8(Vec<Option<i8>>),
    U8(Vec<Option<u8>>),
    I16(Vec<Option<i16>>),
    U16(Vec<Option<u16>>),
    I32(Vec<Option<i32>>),
    I64(Vec<Option<i64>>),
    F64(Vec<Option<f64>>),
    Text(Vec<Option<String>>),
}

macro_rules! cells_from {
    ($variant:ident, $t:ty) => {
        impl From<Vec<$t>> for ParquetCells {
            fn from(cells: Vec<$t>) -> Self {
                ParquetCells::$variant(cells.into_iter().map(Some).collect())
            }
        }
        impl From<Vec<Option<$t>>> for ParquetCells {
            fn from(cells: Vec<Option<$t>>) -> Self {
                ParquetCells::$variant(cells)
            }
        }
    };
}

cells_from!(Bool, bool);
cells_from!(I8, i8);
cells_from!(U8, u8);
cells_from!(I16, i16);
cells_from!(U16, u16);
cells_from!(I32, i32);
cells_from!(I64, i64);
cells_from!(F64, f64);
cells_from!(Text, String);

impl From<Vec<&str>> for ParquetCells {
    fn from(cells: Vec<&str>) -> Self {
        ParquetCells::Text(cells.into_iter().map(|s| Some(s.to_string())).collect())
    }
}

impl From<Vec<Option<&str>>> for ParquetCells {
    fn from(cells: Vec<Option<&str>>) -> Self {
        ParquetCells::Text(cells.into_iter().map(|s| s.map(str::to_string)).collect())
    }
}

impl ParquetCells {
    fn len(&self) -> usize {
        match self {
            ParquetCells::Bool(v) => v.len(),
            ParquetCells::I8(v) => v.len(),
            ParquetCells::U8(v) => v.len(),
            ParquetCells::I16(v) => v.len(),
            ParquetCells::U16(v) => v.len(),
            ParquetCells::I32(v) => v.len(),
            ParquetCells::I64(v) => v.len(),
            ParquetCells::F64(v) => v.len(),
            ParquetCells::Text(v) => v.len(),
        }
    }

    fn dtype(&self) -> ArrowDataType {
        match self {
            ParquetCells::Bool(_) => ArrowDataType::Boolean,
            ParquetCells::I8(_) => ArrowDataType::Int8,
            ParquetCells::U8(_) => ArrowDataType::UInt8,
            ParquetCells::I16(_) => ArrowDataType::Int16,
            ParquetCells::U16(_) => ArrowDataType::UInt16,
            ParquetCells::I32(_) => ArrowDataType::Int32,
            ParquetCells::I64(_) => ArrowDataType::Int64,
            ParquetCells::F64(_) => ArrowDataType::Float64,
            ParquetCells::Text(_) => ArrowDataType::Utf8View,
        }
    }

    /// Rows `range` as an Arrow array.
    fn array(&self, range: std::ops::Range<usize>) -> Box<dyn Array> {
        fn primitive<T: polars_arrow::types::NativeType>(cells: &[Option<T>]) -> Box<dyn Array> {
            Box::new(PrimitiveArray::<T>::from_iter(cells.iter().copied()))
        }
        match self {
            ParquetCells::Bool(v) => Box::new(BooleanArray::from_iter(v[range].iter().copied())),
            ParquetCells::I8(v) => primitive(&v[range]),
            ParquetCells::U8(v) => primitive(&v[range]),
            ParquetCells::I16(v) => primitive(&v[range]),
            ParquetCells::U16(v) => primitive(&v[range]),
            ParquetCells::I32(v) => primitive(&v[range]),
            ParquetCells::I64(v) => primitive(&v[range]),
            ParquetCells::F64(v) => primitive(&v[range]),
            ParquetCells::Text(v) => Box::new(Utf8ViewArray::from_slice(&v[range])),
        }
    }
}

/// How pages are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[allow(missing_docs)]
pub enum ParquetCompression {
    Uncompressed,
    Snappy,
    Lz4Raw,
    Gzip,
    #[default]
    Zstd,
}

/// How a table is laid out in its file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParquetLayout {
    /// Page compression.
    pub compression: ParquetCompression,
    /// Rows per row group (at least 1).
    pub group_rows: usize,
    /// Bytes at which a data page is flushed; `None` for 1 MiB.
    pub page_bytes: Option<usize>,
}

impl Default for ParquetLayout {
    /// polars' defaults: ZSTD, row groups of 512² rows, 1 MiB pages.
    fn default() -> Self {
        ParquetLayout {
            compression: ParquetCompression::Zstd,
            group_rows: 512 * 512,
            page_bytes: None,
        }
    }
}

impl ParquetLayout {
    fn options(&self) -> WriteOptions {
        let compression = match self.compression {
            ParquetCompression::Uncompressed => CompressionOptions::Uncompressed,
            ParquetCompression::Snappy => CompressionOptions::Snappy,
            ParquetCompression::Lz4Raw => CompressionOptions::Lz4Raw,
            ParquetCompression::Gzip => CompressionOptions::Gzip(None),
            ParquetCompression::Zstd => CompressionOptions::Zstd(None),
        };
        WriteOptions {
            statistics: StatisticsOptions::default(),
            version: Version::V1,
            compression,
            data_page_size: self.page_bytes,
        }
    }
}

/// Writes `columns` as a Parquet file at `path`, in row groups of
/// `layout.group_rows` rows. Columns of different lengths, or two of one
/// name, are an `InvalidInput` error.
pub fn write_parquet_table(
    path: &Path,
    columns: Vec<ParquetColumn>,
    layout: &ParquetLayout,
) -> io::Result<()> {
    let mut out = BufWriter::new(File::create(path)?);
    let mut writer = TableWriter::new(&mut out, &columns, layout)?;
    writer.write(&columns)?;
    writer.finish()?;
    out.flush()
}

/// A Parquet file written a batch of rows at a time; each batch is cut
/// into row groups of at most `layout.group_rows` rows.
pub(crate) struct TableWriter<W: Write> {
    writer: FileWriter<W>,
    schema: ArrowSchema,
    layout: ParquetLayout,
}

impl<W: Write> TableWriter<W> {
    /// A writer of columns named and typed as `columns` (their cells are
    /// not written).
    pub(crate) fn new(
        out: W,
        columns: &[ParquetColumn],
        layout: &ParquetLayout,
    ) -> io::Result<Self> {
        let mut schema = ArrowSchema::default();
        for column in columns {
            let field = Field::new(column.name.as_str().into(), column.cells.dtype(), true);
            if schema.insert(column.name.as_str().into(), field).is_some() {
                return Err(invalid(format!("two columns are named '{}'", column.name)));
            }
        }
        let writer = FileWriter::try_new(out, schema.clone(), layout.options()).map_err(other)?;
        Ok(TableWriter {
            writer,
            schema,
            layout: *layout,
        })
    }

    /// Writes the rows of `columns`, typed as the writer's.
    pub(crate) fn write(&mut self, columns: &[ParquetColumn]) -> io::Result<()> {
        let height = columns.first().map_or(0, ParquetColumn::len);
        if let Some(c) = columns.iter().find(|c| c.len() != height) {
            return Err(invalid(format!(
                "column '{}' has {} cells, the first {height}",
                c.name,
                c.len()
            )));
        }
        let step = self.layout.group_rows.max(1);
        let batches = (0..height).step_by(step).map(|start| {
            let range = start..(start + step).min(height);
            let arrays = columns
                .iter()
                .map(|c| c.cells.array(range.clone()))
                .collect();
            RecordBatchT::try_new(range.len(), self.schema.clone().into(), arrays)
        });
        let encodings = (self.schema.iter_values())
            .map(|f| get_dtype_encoding(&f.dtype))
            .collect();
        let groups =
            RowGroupIterator::try_new(batches, &self.schema, self.layout.options(), encodings)
                .map_err(other)?;
        for group in groups {
            self.writer
                .write(u64::MAX, group.map_err(other)?)
                .map_err(other)?;
        }
        Ok(())
    }

    /// Writes the footer.
    pub(crate) fn finish(mut self) -> io::Result<()> {
        self.writer.end(None).map_err(other)?;
        Ok(())
    }
}

fn invalid(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

fn other(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}
