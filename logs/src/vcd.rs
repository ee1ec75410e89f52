//! Value change dumps (VCD, IEEE 1364 §18): the trace format of HDL simulators,
//! logic analysers and several PLC and soft-PLC tools.
//!
//! ```text
//! $timescale 1 ms $end
//! $scope module plant $end
//! $var wire 1 ! C4 $end
//! $var wire 1 " A4 $end
//! $upscope $end
//! $enddefinitions $end
//! #0
//! $dumpvars
//! 1!
//! 0"
//! $end
//! #100
//! 1"
//! #180
//! 0!
//! ```
//!
//! What is read, and the choices made where the standard leaves room:
//! - the file is a sequence of whitespace-separated tokens, so declarations may
//!   span lines (`$timescale` / `1ns` / `$end` is common);
//! - `$timescale` is 1, 10 or 100 followed by s, ms, us, ns, ps or fs, written
//!   as one token or two; without it, 1 ns. The stream's [`LogStream::time`] is
//!   numeric in the timescale's unit when that is s, ms, us or ns, else ns.
//!   Times finer than a nanosecond are truncated to it;
//! - `$scope` / `$upscope` are accepted and the hierarchy ignored: a variable is
//!   matched to a plant signal by its reference name alone;
//! - `$var <type> 1 <code> <name> $end` declares a 1-bit variable, which must be
//!   named after a plant signal. Vectors, `real`, `realtime`, `integer`,
//!   `parameter`, `event` and `string` variables cannot be plant signals and are
//!   skipped, with their value changes. Several codes for one signal are an
//!   error; one code for several signals (aliases) is accepted;
//! - every plant signal must be declared, and the dump must give each one a
//!   value at its first time (`#0` with `$dumpvars`, usually; changes before any
//!   `#` are at time 0): those are the initial values;
//! - scalar changes `0<code>` and `1<code>` (and `b0 <code>`, `b1 <code>` for a
//!   1-bit variable) are read; `x` and `z` are errors, because a PLC signal is 0
//!   or 1 and an unknown value cannot be diagnosed; `$dumpoff` (which makes
//!   every value `x`) is an error for the same reason. `$dumpvars`, `$dumpall`,
//!   `$dumpon` and `$comment` are accepted anywhere in the changes, as are
//!   unknown `$` commands up to their `$end` (vendor extensions);
//! - time must not go backwards; the same time may be repeated.
//!
//! Errors name the file, line and column of the offending token.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use vocabulary::error::quoted;

use vocabulary::{Event, Located, Location, Plant, SignalId, Time, TimeFormat, TimeUnit};

use super::candump::{ScanBatcher, plural, quote_list};
use super::{IngestOptions, LogFormat, LogStream};

/// The longest token accepted: far beyond any name or vector value, and small
/// enough that a file that is not a VCD is not read into memory as one token.
const MAX_TOKEN: usize = 1 << 16;

/// Variable types that are never a PLC's boolean signal.
const NOT_BOOLEAN: [&str; 6] = [
    "real",
    "realtime",
    "integer",
    "parameter",
    "event",
    "string",
];

/// Header commands, out of place among the value changes.
const HEADER_ONLY: [&str; 7] = [
    "$date",
    "$version",
    "$timescale",
    "$scope",
    "$upscope",
    "$var",
    "$enddefinitions",
];

/// Whether `head` (the start of a file) looks like a VCD: its first token is a
/// header command such as `$date`, `$timescale` or `$var`.
pub fn looks_like(head: &str) -> bool {
    head.trim_start_matches('\u{feff}')
        .split_ascii_whitespace()
        .next()
        .is_some_and(|t| t == "$comment" || HEADER_ONLY.contains(&t))
}

/// Opens a VCD and maps its 1-bit variables to `plant`'s signals by name.
///
/// Reads the header and the values at the first time (the initial values), then
/// streams the changes in batches of about `options.batch_rows` events (whole
/// timestamps are never split between batches). `options.time_unit` is not
/// used: the dump's `$timescale` gives the unit.
pub fn open(path: &Path, plant: &Plant, options: &IngestOptions) -> Result<LogStream, Located> {
    let file = crate::rows::open_file(path)?;
    let mut reader = Reader::new(BufReader::new(file), path, plant, options.batch_rows);
    let unit = reader.header(plant)?;

    // Opening: everything up to the first time after the first one.
    let ended_at = loop {
        match reader.step()? {
            Step::Eof => break None,
            Step::Time(t) if reader.start.is_some_and(|start| t > start) => {
                break Some((reader.tokens.tok_line, reader.tokens.tok_column));
            }
            Step::Time(_) | Step::Other => {}
        }
    };
    let missing: Vec<&str> = plant
        .signals
        .iter()
        .filter(|(id, _)| reader.values[id.index()].is_none())
        .map(|(_, s)| s.name.as_str())
        .collect();
    let start = reader.start.unwrap_or(0);
    if !missing.is_empty() {
        let (line, column) = ended_at.unwrap_or((0, 0));
        return Err(Located::new(
            Location::new(path, line, column),
            format!(
                "no initial value for signal{} {}: the dump must give every signal a value at its first time (#{})",
                plural(missing.len()),
                quote_list(missing),
                reader.first_ticks
            ),
        ));
    }
    reader.opening = false;
    let initial = reader.values.iter().map(|v| v.unwrap_or(false)).collect();
    Ok(LogStream {
        path: path.to_path_buf(),
        format: LogFormat::Vcd,
        time: TimeFormat::Numeric(unit),
        start,
        initial,
        batches: Box::new(reader),
        end: super::LogEnd::default(),
    })
}

/// The whitespace-separated tokens of a file, with where each starts.
struct Tokens<R> {
    input: R,
    path: PathBuf,
    /// Position of the next byte.
    line: usize,
    column: usize,
    /// The last token read, and where it starts.
    tok: Vec<u8>,
    tok_line: usize,
    tok_column: usize,
}

impl<R: BufRead> Tokens<R> {
    /// Reads the next token; `false` at the end of the file.
    fn next(&mut self) -> Result<bool, Located> {
        self.tok.clear();
        loop {
            let buf = match self.input.fill_buf() {
                Ok(buf) => buf,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    return Err(crate::rows::cannot_read(&self.path, self.line, &e));
                }
            };
            if buf.is_empty() {
                break;
            }
            let mut used = 0;
            let mut complete = false;
            for &b in buf {
                used += 1;
                if b.is_ascii_whitespace() {
                    if b == b'\n' {
                        self.line += 1;
                        self.column = 1;
                    } else {
                        self.column += 1;
                    }
                    if !self.tok.is_empty() {
                        complete = true;
                        break;
                    }
                } else {
                    if self.tok.is_empty() {
                        self.tok_line = self.line;
                        self.tok_column = self.column;
                    }
                    if self.tok.len() >= MAX_TOKEN {
                        return Err(self.error(format!(
                            "token longer than {MAX_TOKEN} bytes: this is not a VCD file"
                        )));
                    }
                    self.tok.push(b);
                    self.column += 1;
                }
            }
            self.input.consume(used);
            if complete {
                break;
            }
        }
        if self.tok.is_empty() {
            return Ok(false);
        }
        if let Err(e) = std::str::from_utf8(&self.tok) {
            let (line, column) = (self.tok_line, self.tok_column + e.valid_up_to());
            return Err(Located::new(
                Location::new(&self.path, line, column),
                "not text (invalid UTF-8): this is not a VCD file",
            ));
        }
        if self.tok_line == 1 && self.tok_column == 1 && self.tok.starts_with("\u{feff}".as_bytes())
        {
            // A byte-order mark before the first token.
            self.tok.drain(..3);
            if self.tok.is_empty() {
                return self.next();
            }
        }
        Ok(true)
    }

    /// The last token.
    fn text(&self) -> &str {
        // `next` checked that tokens are UTF-8.
        std::str::from_utf8(&self.tok).unwrap_or_default()
    }

    /// An error at the last token.
    fn error(&self, message: impl Into<String>) -> Located {
        self.error_at(self.tok_line, self.tok_column, message)
    }

    fn error_at(&self, line: usize, column: usize, message: impl Into<String>) -> Located {
        Located::new(Location::new(&self.path, line, column), message)
    }

    /// Reads the rest of the command opened by the last token, up to its `$end`,
    /// keeping at most `keep` tokens with their positions.
    fn until_end(&mut self, keep: usize) -> Result<Vec<(String, usize, usize)>, Located> {
        let (command, line, column) = (self.text().to_string(), self.tok_line, self.tok_column);
        let mut out = Vec::new();
        loop {
            if !self.next()? {
                return Err(self.error_at(line, column, format!("{command} has no $end")));
            }
            if self.tok == b"$end" {
                return Ok(out);
            }
            if out.len() < keep {
                out.push((self.text().to_string(), self.tok_line, self.tok_column));
            } else if keep > 0 {
                return Err(self.error(format!(
                    "unexpected {} in {command}: expected $end",
                    quoted(self.text())
                )));
            }
        }
    }
}

/// What a declared identifier code stands for.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Var {
    /// A variable that is not a plant signal (vector, real…): its changes are skipped.
    Skipped,
    /// 1-bit variable carrying these plant signals.
    Signals(Vec<SignalId>),
}

/// `$timescale` as a fraction of a nanosecond: `ticks × num / den` ns.
#[derive(Debug, Clone, Copy)]
struct Scale {
    num: i128,
    den: i128,
}

/// What one step of the changes read.
enum Step {
    Eof,
    /// A `#` time, in nanoseconds.
    Time(Time),
    Other,
}

/// The streaming reader of one file; also the iterator of its batches.
struct Reader<R> {
    tokens: Tokens<R>,
    vars: HashMap<Vec<u8>, Var>,
    names: Vec<String>,
    scale: Scale,
    /// Current time (ns), and the last `#` as written with its line.
    t: Time,
    previous: Option<(u64, usize)>,
    /// The first time, as written (for messages).
    first_ticks: u64,
    /// Time of the initial values.
    start: Option<Time>,
    /// Whether changes still set initial values.
    opening: bool,
    values: Vec<Option<bool>>,
    batcher: ScanBatcher,
    eof: bool,
    /// An error to report once the events before it are out.
    failed: Option<Located>,
}

impl<R: BufRead> Reader<R> {
    fn new(input: R, path: &Path, plant: &Plant, batch_rows: usize) -> Self {
        let n = plant.signals.len();
        Reader {
            tokens: Tokens {
                input,
                path: path.to_path_buf(),
                line: 1,
                column: 1,
                tok: Vec::new(),
                tok_line: 0,
                tok_column: 0,
            },
            vars: HashMap::new(),
            names: plant.signals.iter().map(|(_, s)| s.name.clone()).collect(),
            scale: Scale { num: 1, den: 1 },
            t: 0,
            previous: None,
            first_ticks: 0,
            start: None,
            opening: true,
            values: vec![None; n],
            batcher: ScanBatcher::new(n, batch_rows),
            eof: false,
            failed: None,
        }
    }

    /// Reads the declarations up to `$enddefinitions $end`; returns the unit of
    /// the stream's numeric timestamps.
    fn header(&mut self, plant: &Plant) -> Result<TimeUnit, Located> {
        let mut unit = TimeUnit::Ns;
        // The code and line that declared each signal.
        let mut declared: Vec<Option<(String, usize)>> = vec![None; plant.signals.len()];
        loop {
            if !self.tokens.next()? {
                return Err(self.tokens.error_at(
                    self.tokens.line,
                    0,
                    "unexpected end of file in the header: no $enddefinitions $end",
                ));
            }
            match self.tokens.text() {
                "$timescale" => unit = self.timescale()?,
                "$var" => self.var(plant, &mut declared)?,
                "$enddefinitions" => {
                    let (line, column) = (self.tokens.tok_line, self.tokens.tok_column);
                    self.tokens.until_end(0)?;
                    let missing: Vec<&str> = plant
                        .signals
                        .iter()
                        .filter(|(id, _)| declared[id.index()].is_none())
                        .map(|(_, s)| s.name.as_str())
                        .collect();
                    if !missing.is_empty() {
                        let s = plural(missing.len());
                        return Err(self.tokens.error_at(
                            line,
                            column,
                            format!(
                                "plant signal{s} {} not in the dump: no $var declares {}",
                                quote_list(missing.iter().copied()),
                                if missing.len() > 1 { "them" } else { "it" }
                            ),
                        ));
                    }
                    return Ok(unit);
                }
                t if t.starts_with('$') => {
                    // $date, $version, $comment, $scope, $upscope and vendor
                    // extensions carry nothing gardefou needs.
                    self.tokens.until_end(0)?;
                }
                t => {
                    return Err(self.tokens.error(format!(
                        "unexpected {} in the header: expected a $command such as $var, or $enddefinitions $end",
                        quoted(t)
                    )));
                }
            }
        }
    }

    /// `$timescale 1 ms $end`, or `1ms`.
    fn timescale(&mut self) -> Result<TimeUnit, Located> {
        let (line, column) = (self.tokens.tok_line, self.tokens.tok_column);
        let parts = self.tokens.until_end(2)?;
        let (line, column) = parts.first().map_or((line, column), |p| (p.1, p.2));
        let text: String = parts.iter().map(|p| p.0.as_str()).collect();
        let written: Vec<&str> = parts.iter().map(|p| p.0.as_str()).collect();
        let written = written.join(" ");
        let digits = text.len() - text.trim_start_matches(|c: char| c.is_ascii_digit()).len();
        let (number, unit) = text.split_at(digits);
        let bad = || {
            self.tokens.error_at(
                line,
                column,
                format!(
                    "bad timescale {}: expected 1, 10 or 100 followed by s, ms, us, ns, ps or fs",
                    quoted(&written)
                ),
            )
        };
        let magnitude: i128 = match number {
            "1" => 1,
            "10" => 10,
            "100" => 100,
            _ => return Err(bad()),
        };
        let (num, den, unit) = match unit {
            "s" => (1_000_000_000, 1, TimeUnit::S),
            "ms" => (1_000_000, 1, TimeUnit::Ms),
            "us" => (1_000, 1, TimeUnit::Us),
            "ns" => (1, 1, TimeUnit::Ns),
            "ps" => (1, 1_000, TimeUnit::Ns),
            "fs" => (1, 1_000_000, TimeUnit::Ns),
            _ => return Err(bad()),
        };
        self.scale = Scale {
            num: magnitude * num,
            den,
        };
        Ok(unit)
    }

    /// `$var <type> <size> <code> <name> [<bit select>] $end`.
    fn var(
        &mut self,
        plant: &Plant,
        declared: &mut [Option<(String, usize)>],
    ) -> Result<(), Located> {
        let (line, column) = (self.tokens.tok_line, self.tokens.tok_column);
        let parts = self.tokens.until_end(6)?;
        let [kind, size, code, name, select @ ..] = parts.as_slice() else {
            return Err(self.tokens.error_at(
                line,
                column,
                "incomplete $var: expected $var <type> <size> <code> <name> $end",
            ));
        };
        let width: u64 = size.0.parse().map_err(|_| {
            self.tokens.error_at(
                size.1,
                size.2,
                format!(
                    "bad size {} in $var: expected a number of bits",
                    quoted(&size.0)
                ),
            )
        })?;
        let var = if width != 1 || NOT_BOOLEAN.contains(&kind.0.as_str()) {
            Var::Skipped
        } else {
            let full: String = std::iter::once(name.0.as_str())
                .chain(select.iter().map(|s| s.0.as_str()))
                .collect();
            let id = plant.signals.id(&full).ok_or_else(|| {
                self.tokens.error_at(
                    name.1,
                    name.2,
                    format!(
                        "{} is not a signal of the plant file: every 1-bit variable must be named after one",
                        quoted(&full)
                    ),
                )
            })?;
            match &declared[id.index()] {
                Some((other, other_line)) if *other != code.0 => {
                    return Err(self.tokens.error_at(
                        name.1,
                        name.2,
                        format!(
                            "signal '{full}' is declared twice: identifier code '{other}' on line {other_line} already carries it"
                        ),
                    ));
                }
                _ => declared[id.index()] = Some((code.0.clone(), name.1)),
            }
            Var::Signals(vec![id])
        };
        let key = code.0.as_bytes().to_vec();
        match (self.vars.get_mut(&key), var) {
            (None, var) => {
                self.vars.insert(key, var);
            }
            (Some(Var::Skipped), Var::Skipped) => {}
            (Some(Var::Signals(ids)), Var::Signals(new)) => {
                // Aliases: one code carried by several names.
                for id in new {
                    if !ids.contains(&id) {
                        ids.push(id);
                    }
                }
            }
            (Some(_), _) => {
                return Err(self.tokens.error_at(
                    code.1,
                    code.2,
                    format!(
                        "identifier code {} is declared again with another size or type",
                        quoted(&code.0)
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Reads and applies one token of the changes.
    fn step(&mut self) -> Result<Step, Located> {
        if !self.tokens.next()? {
            return Ok(Step::Eof);
        }
        let Some(&first) = self.tokens.tok.first() else {
            return Ok(Step::Other);
        };
        match first {
            b'#' => self.time().map(Step::Time),
            b'0' | b'1' | b'x' | b'X' | b'z' | b'Z' => {
                let value = match first {
                    b'0' => Some(false),
                    b'1' => Some(true),
                    _ => None,
                };
                let (line, column) = (self.tokens.tok_line, self.tokens.tok_column);
                let code = self.tokens.tok[1..].to_vec();
                if code.is_empty() {
                    return Err(self
                        .tokens
                        .error(format!("missing identifier code after '{}'", first as char)));
                }
                let shown_value = (first as char).to_string();
                self.assign(
                    &code,
                    value,
                    &shown_value,
                    (line, column),
                    (line, column + 1),
                )?;
                Ok(Step::Other)
            }
            b'b' | b'B' | b'r' | b'R' => {
                let (line, column) = (self.tokens.tok_line, self.tokens.tok_column);
                let text = self.tokens.text()[1..].to_string();
                if !self.tokens.next()? {
                    return Err(self.tokens.error_at(
                        line,
                        column,
                        "missing identifier code after the value",
                    ));
                }
                let code = self.tokens.tok.clone();
                let code_column = self.tokens.tok_column;
                let code_line = self.tokens.tok_line;
                let value = if matches!(first, b'r' | b'R') {
                    Err("a real number")
                } else if !text.is_empty() && text.bytes().all(|b| b == b'0' || b == b'1') {
                    // A 1-bit value written as a vector; wider ones are left-extended.
                    Ok(Some(text.ends_with('1')))
                } else if !text.is_empty() && text.bytes().all(|b| b"01xXzZ".contains(&b)) {
                    Ok(None)
                } else {
                    Err("not a binary value")
                };
                match (self.vars.get(&code), value) {
                    (None, _) => Err(self.tokens.error_at(
                        code_line,
                        code_column,
                        undeclared(self.tokens.text()),
                    )),
                    (Some(Var::Skipped), _) => Ok(Step::Other),
                    (Some(Var::Signals(_)), Err(what)) => Err(self.tokens.error_at(
                        line,
                        column,
                        format!(
                            "{} is {what}, not a value of a 1-bit signal",
                            quoted(&format!("{}{text}", first as char))
                        ),
                    )),
                    (Some(Var::Signals(_)), Ok(value)) => {
                        let shown_value = format!("{}{text}", first as char);
                        let code_at = (code_line, code_column);
                        self.assign(&code, value, &shown_value, (line, column), code_at)?;
                        Ok(Step::Other)
                    }
                }
            }
            b'$' => {
                match self.tokens.text() {
                    "$end" | "$dumpvars" | "$dumpall" | "$dumpon" => {}
                    "$dumpoff" => {
                        return Err(self.tokens.error(
                            "$dumpoff is not supported: it makes every value unknown (x) until $dumpon, and gardefou needs every signal's value at all times",
                        ));
                    }
                    t if HEADER_ONLY.contains(&t) => {
                        return Err(self.tokens.error(format!(
                            "{t} after $enddefinitions: declarations belong in the header"
                        )));
                    }
                    _ => {
                        self.tokens.until_end(0)?;
                    }
                }
                Ok(Step::Other)
            }
            _ => Err(self.tokens.error(format!(
                "unexpected {}: expected #<time>, a value change such as 1! or a $command",
                quoted(self.tokens.text())
            ))),
        }
    }

    /// `#<time>`: moves the clock.
    fn time(&mut self) -> Result<Time, Located> {
        let text = &self.tokens.text()[1..];
        let ticks: u64 = text
            .bytes()
            .all(|b| b.is_ascii_digit())
            .then(|| text.parse().ok())
            .flatten()
            .ok_or_else(|| {
                self.tokens.error(format!(
                    "bad time {}: expected # followed by a whole number of timescale units",
                    quoted(self.tokens.text())
                ))
            })?;
        if let Some((previous, line)) = self.previous
            && ticks < previous
        {
            return Err(self.tokens.error(format!(
                "time goes backwards: #{ticks} is before #{previous} on line {line}"
            )));
        }
        let ns = i128::from(ticks) * self.scale.num / self.scale.den;
        let t = Time::try_from(ns).map_err(|_| {
            self.tokens.error(format!(
                "time #{ticks} is too large (more than 292 years in nanoseconds)"
            ))
        })?;
        if self.previous.is_none() {
            self.first_ticks = ticks;
        }
        self.previous = Some((ticks, self.tokens.tok_line));
        self.t = t;
        if self.start.is_none() {
            self.start = Some(t);
        }
        Ok(t)
    }

    /// Gives the signals of `code` `value` (`None`: x or z), written `shown_value`
    /// at line and column `value_at`, the code at `code_at`.
    fn assign(
        &mut self,
        code: &[u8],
        value: Option<bool>,
        shown_value: &str,
        value_at: (usize, usize),
        code_at: (usize, usize),
    ) -> Result<(), Located> {
        let signals = match self.vars.get(code) {
            None => {
                return Err(self.tokens.error_at(
                    code_at.0,
                    code_at.1,
                    undeclared(&String::from_utf8_lossy(code)),
                ));
            }
            Some(Var::Skipped) => return Ok(()),
            Some(Var::Signals(signals)) => signals,
        };
        let Some(value) = value else {
            let name = signals
                .first()
                .map_or("?", |s| self.names[s.index()].as_str());
            return Err(self.tokens.error_at(
                value_at.0,
                value_at.1,
                format!(
                    "value '{shown_value}' of signal '{name}' is not 0 or 1: unknown (x) and high-impedance (z) values are not supported"
                ),
            ));
        };
        if self.opening {
            // Values before any `#` are at time 0, the start of the simulation.
            self.start.get_or_insert(self.t);
        }
        for &signal in signals {
            let slot = &mut self.values[signal.index()];
            if !self.opening && *slot != Some(value) {
                self.batcher.change(self.t, signal, value);
            }
            *slot = Some(value);
        }
        Ok(())
    }
}

impl<R: BufRead> Iterator for Reader<R> {
    type Item = Result<Vec<Event>, Located>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(batch) = self.batcher.take_full() {
                return Some(Ok(batch));
            }
            if let Some(e) = self.failed.take() {
                // Reported after the events before it, which are sound.
                self.eof = true;
                return Some(Err(e));
            }
            if self.eof {
                return self.batcher.finish().map(Ok);
            }
            match self.step() {
                Ok(Step::Eof) => self.eof = true,
                Ok(Step::Time(_) | Step::Other) => {}
                Err(e) => {
                    self.failed = Some(e);
                    if let Some(batch) = self.batcher.finish() {
                        return Some(Ok(batch));
                    }
                }
            }
        }
    }
}

/// The message for a value change of an identifier code no `$var` declares.
fn undeclared(code: &str) -> String {
    format!(
        "identifier code {} is not declared by any $var",
        quoted(code)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_a_vcd_header() {
        assert!(looks_like("$date\n today\n$end\n"));
        assert!(looks_like("\u{feff}$timescale 1ns $end"));
        assert!(!looks_like("t,signal,value\n"));
        assert!(!looks_like("(1.0) can0 181#01"));
    }
}
