//! Telling a log's form from its first bytes.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use vocabulary::{Located, Location};

use crate::LogFormat;

/// The longest first line looked at: a header or a first record is far shorter,
/// and a binary file must not be read whole looking for a line end.
const MAX_LINE: u64 = 1 << 16;

/// Detects the form of the log at `path`.
///
/// - Parquet, recognised by its magic bytes `PAR1`, then by its columns: `t`,
///   `signal`, `value` (and optionally `site`, `seq`, `quality`) is the events
///   form; `signal`, `value`, `t_start`, `t_end` the intervals form; `t` and
///   signal columns the scans form.
/// - Text, by its first non-blank line: VCD if it starts with `$`; `candump -L`
///   if it reads `(<seconds>) <interface> <hex id>#<hex data>`; CSV by its
///   header: `t,signal,value…` events, `signal,value,t_start,t_end` intervals,
///   any other header with a `t` column scans.
///
/// Fails with an error naming the file when the file cannot be read or matches
/// none of these.
pub fn detect_format(path: &Path) -> Result<LogFormat, Located> {
    let file = crate::rows::open_file(path)?;
    let mut reader = BufReader::new(file);
    let head = reader.fill_buf().map_err(|e| read_error(path, &e))?;
    if head.starts_with(b"PAR1") {
        return parquet_form(path);
    }
    // The first non-blank line.
    let mut line_no = 0;
    let mut bytes = Vec::new();
    loop {
        bytes.clear();
        let n = reader
            .by_ref()
            .take(MAX_LINE)
            .read_until(b'\n', &mut bytes)
            .map_err(|e| read_error(path, &e))?;
        if n == 0 {
            return Err(Located::new(
                Location::new(path, 0, 0),
                "empty file: cannot tell the form of the log",
            ));
        }
        line_no += 1;
        if !bytes.iter().all(u8::is_ascii_whitespace) {
            break;
        }
    }
    let Ok(text) = std::str::from_utf8(&bytes) else {
        return Err(unknown(path, line_no, "it is neither text nor Parquet"));
    };
    let line = text.trim_start_matches('\u{feff}').trim();
    if line.starts_with('$') {
        return Ok(LogFormat::Vcd);
    }
    if is_candump(line) {
        return Ok(LogFormat::Candump);
    }
    let names: Vec<&str> = line.split(',').map(clean).collect();
    let has = |name: &str| names.contains(&name);
    if names.len() > 1 || has("t") {
        if has("t") && has("signal") && has("value") {
            return Ok(LogFormat::EventsCsv);
        }
        if has("signal") && has("value") && has("t_start") && has("t_end") {
            return Ok(LogFormat::IntervalsCsv);
        }
        if has("t") {
            return Ok(LogFormat::ScansCsv);
        }
    }
    Err(unknown(
        path,
        line_no,
        "its first line is not a CSV header (t,signal,value / signal,value,t_start,t_end / t,<signal>,…), a candump -L record or a VCD declaration",
    ))
}

fn read_error(path: &Path, e: &std::io::Error) -> Located {
    crate::rows::cannot_read(path, 0, e)
}

fn unknown(path: &Path, line: usize, why: &str) -> Located {
    Located::new(
        Location::new(path, line, 0),
        format!("cannot tell the form of the log: {why}; name it with --format"),
    )
}

/// The Parquet form, from the file's column names.
fn parquet_form(path: &Path) -> Result<LogFormat, Located> {
    let names = parquet_columns(path)?;
    let has = |name: &str| names.iter().any(|n| n == name);
    if has("t") && has("signal") && has("value") {
        Ok(LogFormat::EventsParquet)
    } else if has("signal") && has("value") && has("t_start") && has("t_end") {
        Ok(LogFormat::IntervalsParquet)
    } else if has("t") {
        Ok(LogFormat::ScansParquet)
    } else {
        Err(Located::new(
            Location::new(path, 0, 0),
            format!(
                "cannot tell the form of the Parquet log from its columns {}: expected t,signal,value / signal,value,t_start,t_end / t,<signal>,…",
                vocabulary::error::printable(&names.join(","))
            ),
        ))
    }
}

/// A CSV field as the readers see it: trimmed, then unquoted.
fn clean(field: &str) -> &str {
    let field = field.trim();
    field
        .strip_prefix('"')
        .and_then(|f| f.strip_suffix('"'))
        .unwrap_or(field)
}

/// Whether `line` reads `(<seconds>) <interface> <hex id>#<data>`, as
/// `candump -L` writes.
fn is_candump(line: &str) -> bool {
    let Some(rest) = line.strip_prefix('(') else {
        return false;
    };
    let Some((seconds, rest)) = rest.split_once(')') else {
        return false;
    };
    let (whole, fraction) = seconds.split_once('.').unwrap_or((seconds, ""));
    if whole.is_empty()
        || !whole
            .bytes()
            .chain(fraction.bytes())
            .all(|b| b.is_ascii_digit())
    {
        return false;
    }
    let mut words = rest.split_ascii_whitespace();
    let (Some(_interface), Some(frame), None) = (words.next(), words.next(), words.next()) else {
        return false;
    };
    let Some((id, data)) = frame.split_once('#') else {
        return false;
    };
    // Data is hex, `R` (remote frame) or `#<flags><hex>` (CAN FD).
    let data = data.strip_prefix('#').unwrap_or(data);
    !id.is_empty()
        && id.len() <= 8
        && id.bytes().all(|b| b.is_ascii_hexdigit())
        && data
            .bytes()
            .all(|b| b.is_ascii_hexdigit() || b == b'R' || b == b'r')
}

#[cfg(feature = "parquet")]
fn parquet_columns(path: &Path) -> Result<Vec<String>, Located> {
    crate::parquet::column_names(path)
}

#[cfg(not(feature = "parquet"))]
fn parquet_columns(path: &Path) -> Result<Vec<String>, Located> {
    Err(Located::new(
        Location::new(path, 0, 0),
        "a Parquet log: this build reads no Parquet (feature `parquet`)",
    ))
}

#[cfg(test)]
mod tests {
    use super::is_candump;

    #[test]
    fn recognises_candump_lines() {
        assert!(is_candump("(1436509052.249713) vcan0 044#2A366C2BBA"));
        assert!(is_candump("(0.000000) can0 181#"));
        assert!(is_candump("(12.5) can0 12345678#R"));
        assert!(!is_candump("(12.5) can0 181 2A"));
        assert!(!is_candump("t,signal,value"));
        assert!(!is_candump("(x) can0 181#00"));
    }
}
