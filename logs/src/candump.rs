//! `candump -L` logs: CAN frames decoded into signal changes through the plant
//! file's CiA 401 PDO bit mapping (`[can]`).
//!
//! Each line of a `candump -L` log (can-utils) is one frame:
//!
//! ```text
//! (1436509052.249713) can0 181#0102030405060708
//! (1436509052.250102) can0 12345678#DEADBEEF
//! (1436509052.251000) can0 181##1AABB
//! (1436509052.252000) can0 181#R
//! ```
//!
//! - the timestamp is in seconds since the epoch, with a fraction; it becomes
//!   nanoseconds, and the stream's [`LogStream::time`] is numeric in seconds
//!   whatever `--time-unit` says, since candump always writes seconds;
//! - the interface name is ignored: the plant file maps identifiers, not buses;
//! - the identifier has 3 hex digits (standard frame, at most `7FF`) or 8
//!   (extended frame); both match a `[can]` `cob_id` by numeric value, because a
//!   CANopen network never uses one number for both. Error frames (8 digits with
//!   `CAN_ERR_FLAG`, `0x20000000`, set) carry no process data and are skipped;
//! - `#` is followed by at most 8 data bytes (classic CAN, optionally with a
//!   `_<dlc>` suffix for DLCs above 8, and `.` between bytes as `cansend` takes),
//!   `##<flags>` by at most 64 (CAN FD), and `#R` marks a remote frame, which
//!   carries no data and is skipped;
//! - a trailing `R` or `T` (receive / transmit, written by newer candump with
//!   `-x`) is accepted and ignored. Blank lines are ignored.
//!
//! Bit `b` of a mapping is bit `b % 8` (0 = least significant) of data byte
//! `b / 8`. Frames whose identifier is not in `[can]` are skipped, and a frame
//! too short for one of its identifier's mapped bits is an error.
//!
//! Every plant signal must be mapped: a log gives every signal a value, and an
//! unmapped one would have none. A signal's initial value is its value in the
//! first frame carrying its identifier (a process image is sent whole, so that is
//! the earliest the log knows it); frames at that same timestamp still count as
//! initial. Events before every identifier has been seen are held in memory until
//! then, which in a real log is a fraction of a second (PDOs are cyclic or sent
//! on change with an inhibit time); afterwards memory does not grow with the log.
//!
//! [`PdoDecoder`] holds the decoding itself, independent of where frames come
//! from, so that the on-line runtime can feed it frames read from SocketCAN.

use std::collections::HashMap;
use std::fmt;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use vocabulary::error::quoted;

use vocabulary::{Event, Located, Location, Plant, SignalId, Time, TimeFormat, TimeUnit};

use super::{IngestOptions, LogFormat, LogStream};

/// The longest line accepted. A `candump -L` line is at most about 200 bytes
/// (a CAN FD frame with 64 data bytes); the limit stops a file that is not a log
/// at all from being read into memory as one line.
const MAX_LINE: usize = 4096;

/// `CAN_ERR_FLAG` of SocketCAN: set in the identifier of error frames.
const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Largest extended (29-bit) identifier.
const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;
/// Largest standard (11-bit) identifier.
const CAN_SFF_MASK: u32 = 0x7FF;

/// Why a plant's `[can]` table cannot decode a log into every signal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MappingError {
    /// The plant file has no `[can]` table at all.
    NoMapping,
    /// These signals (names, in declaration order) have no `[can]` entry.
    Unmapped(Vec<String>),
}

impl fmt::Display for MappingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MappingError::NoMapping => f.write_str(
                "the plant file has no [can] table: map every signal to a PDO bit to read candump logs, e.g. C4 = { cob_id = 0x181, bit = 0 }",
            ),
            MappingError::Unmapped(names) => {
                let s = if names.len() > 1 { "s" } else { "" };
                write!(
                    f,
                    "signal{s} {} ha{} no [can] mapping in the plant file, so a candump log cannot give {} a value",
                    quote_list(names.iter().map(String::as_str)),
                    if names.len() > 1 { "ve" } else { "s" },
                    if names.len() > 1 { "them" } else { "it" },
                )
            }
        }
    }
}

impl std::error::Error for MappingError {}

/// Why a frame could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameError {
    /// The frame's time is before the previous frame's.
    Backwards {
        /// The frame's time.
        t: Time,
        /// The previous frame's time.
        previous: Time,
    },
    /// The frame has too few data bytes for a bit mapped to its identifier.
    Short {
        /// The frame's identifier.
        id: u32,
        /// Its number of data bytes.
        len: usize,
        /// The signal whose bit is missing.
        signal: String,
        /// That bit.
        bit: u8,
    },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Backwards { t, previous } => write!(
                f,
                "time goes backwards: {} s is before {} s",
                TimeUnit::S.format(*t),
                TimeUnit::S.format(*previous)
            ),
            FrameError::Short {
                id,
                len,
                signal,
                bit,
            } => {
                let s = if *len == 1 { "" } else { "s" };
                write!(
                    f,
                    "frame {id:03X} has {len} data byte{s}, but signal '{signal}' is bit {bit} and needs at least {}",
                    usize::from(*bit / 8) + 1
                )
            }
        }
    }
}

impl std::error::Error for FrameError {}

/// Decodes CAN frames into signal values with a plant's `[can]` bit mapping,
/// whatever transport the frames come from (a `candump -L` file, SocketCAN).
///
/// ```
/// use std::path::Path;
/// use vocabulary::Plant;
/// use logs::candump::PdoDecoder;
///
/// let plant = Plant::parse(
///     r#"
///     name = "demo"
///     [signals]
///     C4 = { kind = "sensor" }
///     A4 = { kind = "actuator" }
///     [can]
///     C4 = { cob_id = 0x181, bit = 0 }
///     A4 = { cob_id = 0x181, bit = 9 }
///     "#,
///     Path::new("plant.toml"),
/// )
/// .unwrap();
/// let c4 = plant.signals.id("C4").unwrap();
/// let a4 = plant.signals.id("A4").unwrap();
/// let mut decoder = PdoDecoder::new(&plant).unwrap();
/// // The first frame gives both signals their first value.
/// assert_eq!(decoder.frame(0, 0x181, &[0x01, 0x00]).unwrap(), &[(c4, true), (a4, false)]);
/// // Then only changes are reported; other identifiers are ignored.
/// assert_eq!(decoder.frame(10, 0x181, &[0x01, 0x02]).unwrap(), &[(a4, true)]);
/// assert_eq!(decoder.frame(20, 0x701, &[0x05]).unwrap(), &[]);
/// ```
#[derive(Debug, Clone)]
pub struct PdoDecoder {
    /// Mapped bits by identifier, each list sorted by signal so that the changes
    /// of one frame come out in signal order.
    by_id: HashMap<u32, Vec<(SignalId, u8)>>,
    /// Signal names, for error messages.
    names: Vec<String>,
    /// The value of every signal, `None` until its identifier's first frame.
    values: Vec<Option<bool>>,
    /// Time of the last frame decoded.
    last: Option<Time>,
    /// The changes of the last frame (kept to reuse its allocation).
    changes: Vec<(SignalId, bool)>,
}

impl PdoDecoder {
    /// A decoder for `plant`'s `[can]` table. Fails unless every signal of the
    /// plant is mapped, since an unmapped signal would never get a value.
    pub fn new(plant: &Plant) -> Result<PdoDecoder, MappingError> {
        if plant.can.is_empty() {
            return Err(MappingError::NoMapping);
        }
        let n = plant.signals.len();
        let mut mapped = vec![false; n];
        let mut by_id: HashMap<u32, Vec<(SignalId, u8)>> = HashMap::new();
        for c in &plant.can {
            if let Some(m) = mapped.get_mut(c.signal.index()) {
                *m = true;
            }
            by_id.entry(c.cob_id).or_default().push((c.signal, c.bit));
        }
        let unmapped: Vec<String> = plant
            .signals
            .iter()
            .filter(|(id, _)| !mapped[id.index()])
            .map(|(_, s)| s.name.clone())
            .collect();
        if !unmapped.is_empty() {
            return Err(MappingError::Unmapped(unmapped));
        }
        for bits in by_id.values_mut() {
            bits.sort_unstable();
        }
        Ok(PdoDecoder {
            by_id,
            names: plant.signals.iter().map(|(_, s)| s.name.clone()).collect(),
            values: vec![None; n],
            last: None,
            changes: Vec::new(),
        })
    }

    /// Decodes one frame received at `t` with identifier `id` (without SocketCAN
    /// flag bits) and payload `data`.
    ///
    /// Returns the signals whose value this frame tells something new, in signal
    /// order: a first value (the identifier's first frame) or a change. Frames
    /// with an unmapped identifier return nothing. A frame earlier than the
    /// previous one, or too short for one of its identifier's bits, is an error
    /// and changes nothing.
    pub fn frame(
        &mut self,
        t: Time,
        id: u32,
        data: &[u8],
    ) -> Result<&[(SignalId, bool)], FrameError> {
        if let Some(previous) = self.last.filter(|&p| t < p) {
            return Err(FrameError::Backwards { t, previous });
        }
        self.last = Some(t);
        self.changes.clear();
        let Some(bits) = self.by_id.get(&id) else {
            return Ok(&self.changes);
        };
        // Checked before anything changes, so that an error leaves no half-decoded frame.
        if let Some(&(signal, bit)) = bits.iter().find(|(_, b)| usize::from(b / 8) >= data.len()) {
            return Err(FrameError::Short {
                id,
                len: data.len(),
                signal: self.names[signal.index()].clone(),
                bit,
            });
        }
        for &(signal, bit) in bits {
            let byte = data.get(usize::from(bit / 8)).copied().unwrap_or(0);
            let value = (byte >> (bit % 8)) & 1 == 1;
            let slot = &mut self.values[signal.index()];
            if *slot != Some(value) {
                *slot = Some(value);
                self.changes.push((signal, value));
            }
        }
        Ok(&self.changes)
    }

    /// The current value of `signal`, `None` until its identifier's first frame.
    pub fn value(&self, signal: SignalId) -> Option<bool> {
        self.values.get(signal.index()).copied().flatten()
    }

    /// Whether every signal has a value.
    pub fn is_complete(&self) -> bool {
        self.values.iter().all(Option::is_some)
    }

    /// The identifiers not seen yet and the signals they carry, sorted by
    /// identifier: what a log that ends now fails to give a value.
    pub fn unseen(&self) -> Vec<(u32, Vec<SignalId>)> {
        let mut out: Vec<(u32, Vec<SignalId>)> = self
            .by_id
            .iter()
            .filter(|(_, bits)| bits.iter().any(|(s, _)| self.value(*s).is_none()))
            .map(|(&id, bits)| (id, bits.iter().map(|&(s, _)| s).collect()))
            .collect();
        out.sort_unstable();
        out
    }
}

/// Whether `head` (the start of a file) looks like a `candump -L` log: its first
/// non-blank line parses as a frame.
pub fn looks_like(head: &str) -> bool {
    head.trim_start_matches('\u{feff}')
        .lines()
        .find(|l| !l.trim().is_empty())
        .is_some_and(|l| matches!(parse_line(l), Ok(Some(_))))
}

/// Opens a `candump -L` log and decodes it with `plant`'s `[can]` table.
///
/// Reads up to the first frame of every mapped identifier to learn the initial
/// values, then streams the rest in batches of about `options.batch_rows` events
/// (whole timestamps are never split between batches). `options.time_unit` is not
/// used: candump timestamps are always seconds.
pub fn open(path: &Path, plant: &Plant, options: &IngestOptions) -> Result<LogStream, Located> {
    let whole_file = |message: String| Located::new(Location::new(path, 0, 0), message);
    let decoder = PdoDecoder::new(plant).map_err(|e| whole_file(e.to_string()))?;
    let file = crate::rows::open_file(path)?;
    let n = plant.signals.len();
    let mut reader = Reader {
        input: BufReader::new(file),
        path: path.to_path_buf(),
        line: 0,
        buf: Vec::new(),
        decoder,
        previous: None,
        initial: vec![None; n],
        first_seen: vec![0; n],
        batcher: ScanBatcher::new(n, options.batch_rows),
        eof: false,
        failed: None,
    };

    // Opening: until every signal has a value and a later timestamp shows that
    // no more frames belong to the time of the last first value.
    let mut start = None;
    let mut opened_at: Time = Time::MIN;
    while let Some(frame) = reader.read_frame()? {
        start.get_or_insert(frame.t);
        let complete = reader.decoder.is_complete();
        reader.apply(&frame)?;
        if !complete && reader.decoder.is_complete() {
            opened_at = frame.t;
        }
        if reader.decoder.is_complete() && frame.t > opened_at {
            break;
        }
    }
    let Some(start) = start else {
        return Err(whole_file("no CAN frame in the log".into()));
    };
    let unseen = reader.decoder.unseen();
    if !unseen.is_empty() {
        let ids: Vec<String> = unseen.iter().map(|(id, _)| format!("{id:03X}")).collect();
        let names: Vec<&str> = unseen
            .iter()
            .flat_map(|(_, s)| s.iter().map(|&s| plant.signals.name(s)))
            .collect();
        let (ids_s, names_s) = (plural(ids.len()), plural(names.len()));
        return Err(whole_file(format!(
            "no frame with identifier{ids_s} {} in the log, so no value for signal{names_s} {}",
            ids.join(", "),
            quote_list(names.iter().copied())
        )));
    }
    let initial = reader.initial.iter().map(|v| v.unwrap_or(false)).collect();
    Ok(LogStream {
        path: path.to_path_buf(),
        format: LogFormat::Candump,
        time: TimeFormat::Numeric(TimeUnit::S),
        start,
        initial,
        batches: Box::new(reader),
        end: super::LogEnd::default(),
    })
}

/// One frame line, parsed.
struct Frame {
    /// Its time.
    t: Time,
    /// Column of the timestamp.
    t_column: usize,
    /// Identifier and payload, or `None` for frames without process data
    /// (remote and error frames).
    data: Option<(u32, Payload)>,
}

/// Up to 64 data bytes, with the column they start at (for messages).
struct Payload {
    bytes: [u8; 64],
    len: usize,
    column: usize,
}

/// The streaming decoder of one file; also the iterator of its batches.
struct Reader<R> {
    input: R,
    path: PathBuf,
    /// Line number of the last line read.
    line: usize,
    buf: Vec<u8>,
    decoder: PdoDecoder,
    /// Time and line of the previous frame.
    previous: Option<(Time, usize)>,
    /// Initial values; `None` until the signal's first frame.
    initial: Vec<Option<bool>>,
    /// Time of each signal's first frame.
    first_seen: Vec<Time>,
    batcher: ScanBatcher,
    eof: bool,
    /// An error to report once the events before it are out.
    failed: Option<Located>,
}

impl<R: BufRead> Reader<R> {
    fn error(&self, column: usize, message: impl Into<String>) -> Located {
        Located::new(Location::new(&self.path, self.line, column), message)
    }

    /// Reads lines up to the next frame; `None` at the end of the file.
    fn read_frame(&mut self) -> Result<Option<Frame>, Located> {
        loop {
            self.buf.clear();
            let read = (&mut self.input)
                .take(MAX_LINE as u64 + 1)
                .read_until(b'\n', &mut self.buf)
                .map_err(|e| crate::rows::cannot_read(&self.path, self.line + 1, &e))?;
            if read == 0 {
                return Ok(None);
            }
            self.line += 1;
            if self.buf.len() > MAX_LINE && self.buf.last() != Some(&b'\n') {
                return Err(self.error(
                    0,
                    format!("line longer than {MAX_LINE} bytes: this is not a candump -L log"),
                ));
            }
            let text = std::str::from_utf8(&self.buf).map_err(|e| {
                self.error(
                    e.valid_up_to() + 1,
                    "not text (invalid UTF-8): this is not a candump -L log",
                )
            })?;
            let text = if self.line == 1 {
                text.trim_start_matches('\u{feff}')
            } else {
                text
            };
            match parse_line(text.trim_end_matches(['\n', '\r'])) {
                Ok(Some(frame)) => return self.check_time(frame).map(Some),
                Ok(None) => continue,
                Err((column, message)) => return Err(self.error(column, message)),
            }
        }
    }

    fn check_time(&mut self, frame: Frame) -> Result<Frame, Located> {
        if let Some((previous, line)) = self.previous
            && frame.t < previous
        {
            return Err(self.error(
                frame.t_column,
                crate::rows::backwards(
                    &TimeUnit::S.format(frame.t),
                    &TimeUnit::S.format(previous),
                    line,
                ),
            ));
        }
        self.previous = Some((frame.t, self.line));
        Ok(frame)
    }

    /// Decodes a frame: first values, or changes for the batcher.
    fn apply(&mut self, frame: &Frame) -> Result<(), Located> {
        let Some((id, payload)) = &frame.data else {
            return Ok(());
        };
        let changes = match self
            .decoder
            .frame(frame.t, *id, &payload.bytes[..payload.len])
        {
            Ok(changes) => changes,
            Err(e) => {
                return Err(Located::new(
                    Location::new(&self.path, self.line, payload.column),
                    e.to_string(),
                ));
            }
        };
        for &(signal, value) in changes {
            let i = signal.index();
            if self.initial[i].is_none() || self.first_seen[i] == frame.t {
                // A first value, or a change at the time of the first value:
                // both describe the signal at the start of its knowledge.
                if self.initial[i].is_none() {
                    self.first_seen[i] = frame.t;
                }
                self.initial[i] = Some(value);
            } else {
                self.batcher.change(frame.t, signal, value);
            }
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
            match self.read_frame().and_then(|f| match f {
                Some(frame) => self.apply(&frame).map(|()| true),
                None => Ok(false),
            }) {
                Ok(true) => {}
                Ok(false) => self.eof = true,
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

/// Parses one line (without its line end). `Ok(None)` for a blank line; errors
/// carry the column (from 1) and the message.
fn parse_line(line: &str) -> Result<Option<Frame>, (usize, String)> {
    let mut fields = Fields { line, at: 0 };
    let Some((stamp_column, stamp)) = fields.next() else {
        return Ok(None);
    };
    let Some(inner) = stamp.strip_prefix('(').and_then(|s| s.strip_suffix(')')) else {
        return Err((
            stamp_column,
            format!(
                "expected a timestamp in parentheses such as (1436509052.249713), found {}: this is not a candump -L line",
                quoted(stamp)
            ),
        ));
    };
    let t_column = stamp_column + 1;
    let t = inner
        .starts_with(|c: char| c.is_ascii_digit())
        .then(|| TimeUnit::S.parse(inner))
        .flatten()
        .ok_or_else(|| {
            (
                t_column,
                format!(
                    "bad timestamp {}: expected seconds since the epoch, such as 1436509052.249713",
                    quoted(inner)
                ),
            )
        })?;
    if fields.next().is_none() {
        return Err((
            line.len() + 1,
            "missing interface and frame after the timestamp".into(),
        ));
    }
    let Some((frame_column, frame)) = fields.next() else {
        return Err((
            line.len() + 1,
            "missing frame after the interface, such as 181#0102".into(),
        ));
    };
    if let Some((column, extra)) = fields.next()
        && (!matches!(extra, "R" | "T") || fields.next().is_some())
    {
        return Err((
            column,
            format!("unexpected {} after the frame", quoted(extra)),
        ));
    }
    let data = parse_frame(frame, frame_column)?;
    Ok(Some(Frame { t, t_column, data }))
}

/// Parses `<id>#<data>`, `<id>##<flags><data>` or `<id>#R…` starting at `column`.
fn parse_frame(text: &str, column: usize) -> Result<Option<(u32, Payload)>, (usize, String)> {
    let Some(hash) = text.find('#') else {
        return Err((
            column,
            format!("expected a frame such as 181#0102, found {}", quoted(text)),
        ));
    };
    let id_text = &text[..hash];
    let bad_id = || {
        (
            column,
            format!(
                "bad CAN identifier {}: expected 3 hex digits (standard frame, at most 7FF) or 8 (extended frame)",
                quoted(id_text)
            ),
        )
    };
    if !id_text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(bad_id());
    }
    let id = u32::from_str_radix(id_text, 16).map_err(|_| bad_id())?;
    let error_frame = match id_text.len() {
        3 if id <= CAN_SFF_MASK => false,
        8 if id & CAN_ERR_FLAG != 0 => true,
        8 if id <= CAN_EFF_MASK => false,
        _ => return Err(bad_id()),
    };
    let rest = &text[hash + 1..];
    let rest_column = column + hash + 1;
    if rest.contains(':') {
        return Err((rest_column, "CAN XL frames are not supported".into()));
    }
    let payload = if let Some(fd) = rest.strip_prefix('#') {
        if !fd.starts_with(|c: char| c.is_ascii_hexdigit()) {
            return Err((
                rest_column + 1,
                "missing CAN FD flags: expected one hex digit after '##'".into(),
            ));
        }
        parse_data(&fd[1..], rest_column + 2, 64, "a CAN FD frame")?
    } else if rest.starts_with(['R', 'r']) {
        // A remote frame requests data and carries none.
        return Ok(None);
    } else {
        // `_<dlc>`: the DLC of a classic frame whose DLC exceeds its 8 bytes.
        let data = match rest.rsplit_once('_') {
            Some((data, dlc)) if dlc.len() == 1 && dlc.bytes().all(|b| b.is_ascii_hexdigit()) => {
                data
            }
            _ => rest,
        };
        parse_data(data, rest_column, 8, "a classic CAN frame")?
    };
    Ok((!error_frame).then_some((id, payload)))
}

/// Parses hex data bytes (optionally separated by `.`) starting at `column`.
fn parse_data(
    text: &str,
    column: usize,
    max: usize,
    kind: &str,
) -> Result<Payload, (usize, String)> {
    let mut bytes = [0u8; 64];
    let mut len = 0;
    let mut high: Option<u8> = None;
    for (i, b) in text.bytes().enumerate() {
        if b == b'.' && high.is_none() {
            continue;
        }
        let Some(digit) = (b as char).to_digit(16).filter(|_| b.is_ascii()) else {
            let c = text[i..].chars().next().unwrap_or('?');
            return Err((column + i, format!("bad hex digit '{c}' in the data")));
        };
        match high.take() {
            None => high = Some(digit as u8),
            Some(h) => {
                if let Some(slot) = bytes.get_mut(len) {
                    *slot = (h << 4) | digit as u8;
                }
                len += 1;
            }
        }
    }
    if high.is_some() {
        return Err((
            column,
            format!(
                "odd number of hex digits in the data {}: each byte takes two",
                quoted(text)
            ),
        ));
    }
    if len > max {
        return Err((
            column,
            format!("{len} data bytes, more than the {max} of {kind}"),
        ));
    }
    Ok(Payload { bytes, len, column })
}

/// The whitespace-separated fields of a line, with their columns (from 1).
struct Fields<'a> {
    line: &'a str,
    at: usize,
}

impl<'a> Iterator for Fields<'a> {
    type Item = (usize, &'a str);

    fn next(&mut self) -> Option<Self::Item> {
        let rest = &self.line[self.at..];
        let skip = rest.len() - rest.trim_start_matches([' ', '\t']).len();
        let start = self.at + skip;
        if start >= self.line.len() {
            self.at = start;
            return None;
        }
        let len = self.line[start..]
            .find([' ', '\t'])
            .unwrap_or(self.line.len() - start);
        self.at = start + len;
        Some((start + 1, &self.line[start..start + len]))
    }
}

/// `'a', 'b', 'c'`.
pub(super) fn quote_list<'a>(names: impl IntoIterator<Item = &'a str>) -> String {
    names
        .into_iter()
        .map(|n| format!("'{n}'"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// `s` when `n` calls for a plural.
pub(super) fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

/// Turns changes, arriving in time order but in any signal order within one
/// time, into batches of events sorted by `(t, signal)` with at most one event
/// per signal and time. Shared with the VCD reader.
pub(super) struct ScanBatcher {
    /// Time of the open scan.
    t: Time,
    /// The open scan's changes, with each signal's value before the scan.
    scan: Vec<(Event, bool)>,
    /// Position + 1 of each signal in `scan` (0: absent), indexed by signal.
    slot: Vec<usize>,
    /// Closed scans, ready to go out.
    ready: Vec<Event>,
    batch_rows: usize,
}

impl ScanBatcher {
    /// A batcher for `signals` signals and batches of about `batch_rows` events.
    pub(super) fn new(signals: usize, batch_rows: usize) -> Self {
        ScanBatcher {
            t: Time::MIN,
            scan: Vec::new(),
            slot: vec![0; signals],
            ready: Vec::new(),
            batch_rows: batch_rows.max(1),
        }
    }

    /// Records that `signal` changed to `value` at `t`, which must be no earlier
    /// than the previous change's time. `value` must differ from the signal's
    /// value before this change.
    pub(super) fn change(&mut self, t: Time, signal: SignalId, value: bool) {
        if t != self.t {
            self.close();
            self.t = t;
        }
        let Some(slot) = self.slot.get_mut(signal.index()) else {
            return;
        };
        if *slot > 0 {
            // A second change in one scan: the signal's value before the scan stays.
            if let Some((event, _)) = self.scan.get_mut(*slot - 1) {
                event.value = value;
                return;
            }
        }
        self.scan.push((Event { t, signal, value }, !value));
        *slot = self.scan.len();
    }

    /// Moves the open scan to the ready events, dropping signals that changed
    /// back to their value before the scan.
    fn close(&mut self) {
        for (event, _) in &self.scan {
            if let Some(slot) = self.slot.get_mut(event.signal.index()) {
                *slot = 0;
            }
        }
        self.scan.sort_unstable_by_key(|(e, _)| e.signal);
        self.ready.extend(
            self.scan
                .drain(..)
                .filter(|(e, before)| e.value != *before)
                .map(|(e, _)| e),
        );
    }

    /// The ready events, if there are enough for a batch.
    pub(super) fn take_full(&mut self) -> Option<Vec<Event>> {
        (self.ready.len() >= self.batch_rows).then(|| std::mem::take(&mut self.ready))
    }

    /// Everything left, closing the open scan; `None` if nothing is left.
    pub(super) fn finish(&mut self) -> Option<Vec<Event>> {
        self.close();
        (!self.ready.is_empty()).then(|| std::mem::take(&mut self.ready))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_frame_forms() {
        let frame = |l: &str| {
            parse_line(l)
                .map(|f| f.map(|f| (f.t, f.data.map(|(id, p)| (id, p.bytes[..p.len].to_vec())))))
        };
        assert_eq!(
            frame("(1.5) can0 181#0102"),
            Ok(Some((1_500_000_000, Some((0x181, vec![1, 2])))))
        );
        assert_eq!(
            frame("(2.000001) vcan0 12345678##3AABB R"),
            Ok(Some((2_000_001_000, Some((0x1234_5678, vec![0xAA, 0xBB])))))
        );
        assert_eq!(frame("(3) can0 181#R"), Ok(Some((3_000_000_000, None))));
        assert_eq!(frame("(3) can0 181#R5_C"), Ok(Some((3_000_000_000, None))));
        assert_eq!(
            frame("(3) can0 20000080#0000000000000000"),
            Ok(Some((3_000_000_000, None)))
        );
        assert_eq!(
            frame("(4) can0 181#01.02.03_D"),
            Ok(Some((4_000_000_000, Some((0x181, vec![1, 2, 3])))))
        );
        assert_eq!(
            frame("(4) can0 181#"),
            Ok(Some((4_000_000_000, Some((0x181, vec![])))))
        );
        assert_eq!(frame("   "), Ok(None));
    }

    #[test]
    fn reports_columns() {
        let column = |l: &str| parse_line(l).err().map(|(c, _)| c);
        assert_eq!(column("1.5 can0 181#01"), Some(1));
        assert_eq!(column("(1.x) can0 181#01"), Some(2));
        assert_eq!(column("(-1) can0 181#01"), Some(2));
        assert_eq!(column("(1) can0 18G#01"), Some(10));
        assert_eq!(column("(1) can0 800#01"), Some(10));
        assert_eq!(column("(1) can0 181#010"), Some(14));
        assert_eq!(column("(1) can0 181#01zz"), Some(16));
        assert_eq!(column("(1) can0 181#010203040506070809"), Some(14));
        assert_eq!(column("(1) can0 181##"), Some(15));
        assert_eq!(column("(1) can0 181#01 X"), Some(17));
        assert_eq!(column("(1) can0"), Some(9));
        let fd64 = format!("(1) can0 181##0{}", "00".repeat(64));
        assert_eq!(column(&fd64), None);
        let fd65 = format!("(1) can0 181##0{}", "00".repeat(65));
        assert_eq!(column(&fd65), Some(16));
    }

    #[test]
    fn batcher_drops_flips_within_a_scan_and_sorts() {
        let (a, b) = (SignalId(0), SignalId(1));
        let mut batcher = ScanBatcher::new(2, 1);
        batcher.change(5, b, true);
        batcher.change(5, a, true);
        batcher.change(5, a, false);
        assert_eq!(batcher.take_full(), None, "the scan at 5 is still open");
        batcher.change(6, a, true);
        assert_eq!(
            batcher.take_full(),
            Some(vec![Event {
                t: 5,
                signal: b,
                value: true
            }])
        );
        assert_eq!(
            batcher.finish(),
            Some(vec![Event {
                t: 6,
                signal: a,
                value: true
            }])
        );
        assert_eq!(batcher.finish(), None);
    }
}
