//! Writing the archive (intervals) form as Parquet.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use super::table::{ParquetCells, ParquetColumn, ParquetLayout, TableWriter};
use crate::EventLog;
use vocabulary::{SignalTable, Time, TimeFormat, TimeUnit};

/// Rows per Parquet row group: memory holds one group's columns at a time.
const ROWS_PER_GROUP: usize = 1 << 16;

/// Writes `log` in the intervals (archive) form as a Parquet file at `path`.
///
/// Columns: `signal` (text), `value` (boolean), `t_start` and `t_end`. Times are
/// written as the log writes them ([`EventLog::format`]): for numbers in a unit,
/// `Int64` counts of that unit — a time that is not a whole number of the unit
/// is an `InvalidInput` error (write the log in a finer unit); for RFC 3339
/// logs, RFC 3339 text. `t_end` is nullable, as the form allows open intervals,
/// but this writer closes the last interval of every signal at `end`, the end of
/// the recording, which must not be before the log's last event or its start.
///
/// Rows come in `t_end` order (a row is written when its interval closes, as
/// `logs::IntervalWriter` does), which [`super::open`] reads back in
/// bounded memory; memory here is bounded by one row group. Reading the file
/// with [`super::open`] gives back `log.start`, `log.initial` and `log.events`.
pub fn write_intervals_parquet(
    log: &EventLog,
    signals: &SignalTable,
    path: &Path,
    end: Time,
) -> io::Result<()> {
    if log.initial.len() != signals.len() {
        return Err(crate::csv::wrong_initial(log.initial.len(), signals.len()));
    }
    let last = log.events.last().map_or(log.start, |e| e.t.max(log.start));
    if end < last {
        return Err(crate::csv::invalid_input(format!(
            "the end of the recording, {}, is before the log's last time {}",
            log.format.format(end),
            log.format.format(last)
        )));
    }
    let times = Times::new(log.format);
    let layout = ParquetLayout {
        group_rows: ROWS_PER_GROUP,
        ..ParquetLayout::default()
    };
    let mut out = BufWriter::new(File::create(path)?);
    let mut rows = Rows::default();
    let mut writer = TableWriter::new(&mut out, &rows.take(&times), &layout)?;
    // Each signal's open interval: value and start.
    let mut open: Vec<(bool, Time)> = log.initial.iter().map(|&v| (v, log.start)).collect();
    for event in &log.events {
        let i = event.signal.index();
        let Some(interval) = open.get_mut(i) else {
            return Err(crate::csv::no_signal(event.signal));
        };
        if interval.0 == event.value {
            continue;
        }
        if event.t < interval.1 {
            return Err(crate::csv::invalid_input(format!(
                "events out of order: signal '{}' changes at {}, before {}",
                signals.name(event.signal),
                log.format.format(event.t),
                log.format.format(interval.1)
            )));
        }
        rows.push(
            signals.name(event.signal),
            interval.0,
            interval.1,
            event.t,
            &times,
        )?;
        *interval = (event.value, event.t);
        if rows.len() >= ROWS_PER_GROUP {
            writer.write(&rows.take(&times))?;
        }
    }
    for (id, signal) in signals.iter() {
        if let Some(&(value, start)) = open.get(id.index()) {
            rows.push(&signal.name, value, start, end, &times)?;
        }
    }
    writer.write(&rows.take(&times))?;
    writer.finish()?;
    out.flush()
}

/// How times are stored: whole numbers of a unit, or RFC 3339 text.
#[derive(Debug, Clone, Copy)]
enum Times {
    Units(TimeUnit),
    Text,
}

impl Times {
    fn new(format: TimeFormat) -> Times {
        match format {
            TimeFormat::Numeric(unit) => Times::Units(unit),
            TimeFormat::Rfc3339 => Times::Text,
        }
    }
}

/// The columns of the rows not yet written.
#[derive(Default)]
struct Rows {
    signal: Vec<String>,
    value: Vec<bool>,
    start: Vec<i64>,
    end: Vec<i64>,
}

impl Rows {
    fn len(&self) -> usize {
        self.signal.len()
    }

    fn push(
        &mut self,
        signal: &str,
        value: bool,
        start: Time,
        end: Time,
        times: &Times,
    ) -> io::Result<()> {
        if let Times::Units(unit) = times {
            for t in [start, end] {
                if t % unit.nanos() != 0 {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidInput,
                        format!(
                            "time {} {unit} is not a whole number of {unit}: write the log in a finer unit",
                            unit.format(t)
                        ),
                    ));
                }
            }
        }
        self.signal.push(signal.to_string());
        self.value.push(value);
        self.start.push(start);
        self.end.push(end);
        Ok(())
    }

    /// The rows as columns, leaving none.
    fn take(&mut self, times: &Times) -> Vec<ParquetColumn> {
        let time_column = |name: &str, values: Vec<i64>| {
            let cells: ParquetCells = match times {
                Times::Units(unit) => {
                    let n = unit.nanos();
                    values.into_iter().map(|t| t / n).collect::<Vec<_>>().into()
                }
                Times::Text => (values.into_iter())
                    .map(|t| TimeFormat::Rfc3339.format(t))
                    .collect::<Vec<_>>()
                    .into(),
            };
            ParquetColumn::new(name, cells)
        };
        vec![
            ParquetColumn::new("signal", std::mem::take(&mut self.signal)),
            ParquetColumn::new("value", std::mem::take(&mut self.value)),
            time_column("t_start", std::mem::take(&mut self.start)),
            time_column("t_end", std::mem::take(&mut self.end)),
        ]
    }
}
