//! `--can IFACE`: CANopen (CiA 401) digital-I/O PDOs read from a CAN bus.
//!
//! TPDOs carry the PLC's inputs and RPDOs its outputs; the plant file's `[can]`
//! table says which bit of which identifier carries which signal, and
//! [`PdoDecoder`] (shared with `candump -L` logs) turns frames into values.
//! Two transports feed it the same bytes:
//!
//! - `IFACE` (`can0`, `vcan0`): a SocketCAN raw socket; every read gives one
//!   16-byte `struct can_frame`;
//! - `udp:HOST:PORT`: a UDP socket bound there; every datagram holds one or
//!   more such 16-byte records, as a raw socket would have delivered them (a
//!   bridge from another machine's bus, or a test).
//!
//! Both go through [`decode_can_frame`]. A PLC scan puts several frames on
//! the bus (its inputs' TPDO, then the RPDO of the outputs it computed from
//! them), where the PLC's own log has one scan: the source gathers the frames
//! arriving within half a scan period (over `--speed`) of a first one, or
//! until every mapped identifier has come, and their changes form one scan,
//! stamped on the source's [`LiveClock`] when the first arrived. The cost is
//! that a scan reaches the diagnosers up to half a scan period late. The
//! first frame of each identifier gives
//! its signals' first values, and once every signal has one they go out as
//! [`Item::Start`]; after that, changes go out as [`Item::Scan`]. Remote and
//! error frames and unmapped identifiers are skipped; frames too short for a
//! mapped bit, malformed records and datagrams are warnings, and decoding goes
//! on. CAN is only read here: the flags are not written back.
//!
//! CAN frames carry no timestamp: the source reads a local bus (or a bridge
//! delivering in order), so its watermark, sent whenever the bus stays quiet
//! for half a scan, is the read clock less that half scan.
//!
//! If the socket fails (the interface goes down or away), the source reports
//! [`Item::Lost`], reopens the interface every [`REOPEN_EVERY`], and starts
//! again from first values, since what happened in between is unknown.

use std::net::{SocketAddr, ToSocketAddrs};
use std::time::Duration;

use diagnoser::{Event, Failure, Plant, SignalId, Time, TimeFormat};
use logs::candump::PdoDecoder;
use tokio::sync::mpsc;

use super::source::{Item, Link, LiveClock, Source};
/// Size of SocketCAN's `struct can_frame` (`CAN_MTU`).
pub const CAN_FRAME_SIZE: usize = 16;
/// `CAN_EFF_FLAG`: the identifier is extended (29 bits).
const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// `CAN_RTR_FLAG`: a remote frame, which carries no data.
const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// `CAN_ERR_FLAG`: an error frame, which carries no process data.
const CAN_ERR_FLAG: u32 = 0x2000_0000;
const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;
const CAN_SFF_MASK: u32 = 0x7FF;

/// Wait between attempts to reopen a CAN interface that failed.
pub const REOPEN_EVERY: Duration = Duration::from_secs(1);
/// How long the source waits for every identifier before saying which ones it
/// still waits for (a PDO sent only on change may never come on its own).
const WAITING_NOTE_AFTER: Duration = Duration::from_secs(5);
/// Largest UDP payload.
const MAX_DATAGRAM: usize = 65_536;

/// A classic CAN data frame: identifier (without flag bits) and payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataFrame {
    /// The identifier, 11 or 29 bits.
    pub id: u32,
    /// Whether the identifier is extended (29 bits).
    pub extended: bool,
    len: u8,
    bytes: [u8; 8],
}

impl DataFrame {
    /// The payload.
    pub fn data(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }
}

/// Decodes one SocketCAN `struct can_frame`: `can_id` (`u32`, little-endian,
/// with the EFF / RTR / ERR flag bits), `len` (`u8`), three bytes of padding
/// and eight data bytes. Remote and error frames give `None`, as they carry no
/// process data; a length above 8 is an error.
pub fn decode_can_frame(bytes: &[u8; CAN_FRAME_SIZE]) -> Result<Option<DataFrame>, String> {
    let raw = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    let len = bytes[4];
    if raw & (CAN_RTR_FLAG | CAN_ERR_FLAG) != 0 {
        return Ok(None);
    }
    let extended = raw & CAN_EFF_FLAG != 0;
    let id = raw & if extended { CAN_EFF_MASK } else { CAN_SFF_MASK };
    if len > 8 {
        return Err(format!(
            "frame {id:03X} has length {len}, more than the 8 bytes of a classic CAN frame"
        ));
    }
    let mut data = [0u8; 8];
    data.copy_from_slice(&bytes[8..16]);
    Ok(Some(DataFrame {
        id,
        extended,
        len,
        bytes: data,
    }))
}

/// Where the frames come from.
enum Transport {
    Udp(std::net::UdpSocket),
    #[cfg(target_os = "linux")]
    Socket {
        iface: String,
        socket: socketcan::tokio::CanSocket,
    },
}

/// PDOs read from a CAN interface, or from UDP datagrams of raw frames.
pub struct CanSource {
    transport: Transport,
    pdos: Pdos,
    speed: f64,
    /// Longest wall time from a scan's first frame to its last.
    gather: Duration,
}

impl CanSource {
    /// Opens `iface` (a SocketCAN interface such as `can0`, or `udp:HOST:PORT`)
    /// and prepares `plant`'s `[can]` decoding; the source's clock runs `speed`
    /// times faster than the wall clock. Fails if the plant file does not map
    /// every signal or the interface cannot be opened; on success, says on
    /// standard error where it reads from.
    pub fn new(iface: &str, plant: &Plant, speed: f64) -> Result<CanSource, Failure> {
        let decoder =
            PdoDecoder::new(plant).map_err(|e| Failure::BadInput(format!("--can {iface}: {e}")))?;
        let (transport, name) = match iface.strip_prefix("udp:") {
            Some(addr) => {
                let socket = bind_udp(iface, addr)?;
                let name = socket
                    .local_addr()
                    .map_or_else(|_| iface.to_string(), |a| format!("udp:{a}"));
                (Transport::Udp(socket), name)
            }
            None => (open_interface(iface)?, iface.to_string()),
        };
        eprintln!("monitor: reading CAN frames from {name}");
        // Half a scan period: the outputs a PLC computed from a TPDO go out
        // within its scan, and the next scan's frames come a period later.
        let gather = Duration::from_nanos((plant.scan_period.max(0) as f64 / 2.0 / speed) as u64);
        Ok(CanSource {
            transport,
            pdos: Pdos::new(name, decoder, plant),
            speed,
            gather,
        })
    }
}

fn bind_udp(iface: &str, addr: &str) -> Result<std::net::UdpSocket, Failure> {
    let addrs: Vec<SocketAddr> = addr
        .to_socket_addrs()
        .map_err(|e| {
            Failure::BadInput(format!(
                "--can {iface}: expected udp:HOST:PORT, e.g. udp:127.0.0.1:5000 ({e})"
            ))
        })?
        .collect();
    let socket = std::net::UdpSocket::bind(&addrs[..])
        .map_err(|e| Failure::Io(format!("--can {iface}: cannot bind a UDP socket: {e}")))?;
    // tokio takes the socket over in `spawn`, and needs it non-blocking.
    socket
        .set_nonblocking(true)
        .map_err(|e| Failure::Io(format!("--can {iface}: {e}")))?;
    Ok(socket)
}

#[cfg(target_os = "linux")]
fn open_interface(iface: &str) -> Result<Transport, Failure> {
    // The socket registers with the runtime's reactor, which only exists
    // inside the runtime: outside, opening would panic.
    if tokio::runtime::Handle::try_current().is_err() {
        return Err(Failure::Io(format!(
            "--can {iface}: a SocketCAN interface can only be opened inside the monitor's runtime"
        )));
    }
    let socket = open_socket(iface).map_err(|e| match e {
        OpenError::NoSuchInterface(e) => {
            Failure::BadInput(format!("--can {iface}: no network interface named '{iface}' ({e})"))
        }
        OpenError::NoCanSupport(e) => Failure::BadInput(format!(
            "--can {iface}: this kernel has no SocketCAN support ({e}); udp:HOST:PORT reads frames from UDP instead"
        )),
        OpenError::NotCan(e) => Failure::BadInput(format!(
            "--can {iface}: '{iface}' is not a CAN interface ({e})"
        )),
        OpenError::Other(e) => Failure::Io(format!("--can {iface}: cannot open a CAN socket: {e}")),
    })?;
    Ok(Transport::Socket {
        iface: iface.to_string(),
        socket,
    })
}

#[cfg(not(target_os = "linux"))]
fn open_interface(iface: &str) -> Result<Transport, Failure> {
    Err(Failure::BadInput(format!(
        "--can {iface}: SocketCAN needs Linux; udp:HOST:PORT reads frames from UDP instead"
    )))
}

/// Why a CAN interface could not be opened.
#[cfg(target_os = "linux")]
enum OpenError {
    NoSuchInterface(std::io::Error),
    NoCanSupport(std::io::Error),
    NotCan(std::io::Error),
    Other(std::io::Error),
}

/// Opens a raw CAN socket on `iface`. The name is looked up first, so that a
/// missing interface and a kernel without CAN give different messages (both
/// are `ENODEV` or `EAFNOSUPPORT` otherwise).
#[cfg(target_os = "linux")]
fn open_socket(iface: &str) -> Result<socketcan::tokio::CanSocket, OpenError> {
    let addr = socketcan::CanAddr::from_iface(iface).map_err(OpenError::NoSuchInterface)?;
    socketcan::tokio::CanSocket::open_addr(&addr).map_err(|e| match e.raw_os_error() {
        // EAFNOSUPPORT (97), EPROTONOSUPPORT (93): no `can` / `can-raw` module.
        Some(97 | 93) => OpenError::NoCanSupport(e),
        // ENODEV (19) from bind: the interface exists but is not CAN.
        Some(19) => OpenError::NotCan(e),
        _ => OpenError::Other(e),
    })
}

impl Source for CanSource {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Rfc3339
    }

    fn spawn(self: Box<Self>, link: Link) {
        let CanSource {
            transport,
            pdos,
            speed,
            gather,
        } = *self;
        // The flags are not written to the bus: `link.flags` is dropped.
        tokio::spawn(run(
            transport,
            pdos,
            LiveClock::new(speed),
            gather,
            link.items,
        ));
    }
}

/// Sends `items`; false if the monitor has gone.
async fn send_all(tx: &mpsc::Sender<Item>, items: &mut Vec<Item>) -> bool {
    for item in items.drain(..) {
        if tx.send(item).await.is_err() {
            return false;
        }
    }
    true
}

/// A transport on the runtime.
enum Reader {
    Udp(tokio::net::UdpSocket),
    #[cfg(target_os = "linux")]
    Socket {
        iface: String,
        socket: socketcan::tokio::CanSocket,
    },
}

impl Reader {
    /// Reads one datagram, or one frame, into `buf`.
    async fn recv(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Reader::Udp(socket) => socket.recv_from(buf).await.map(|(n, _)| n),
            #[cfg(target_os = "linux")]
            Reader::Socket { socket, .. } => {
                use tokio::io::AsyncReadExt;
                let n = socket.read(buf).await?;
                // The kernel writes `can_id` in the host's byte order.
                if cfg!(target_endian = "big") && n >= 4 {
                    buf[..4].reverse();
                }
                Ok(n)
            }
        }
    }
}

/// Reads frames until the monitor goes: gathers each scan's frames, decodes
/// them, and sends what comes out.
async fn run(
    transport: Transport,
    mut pdos: Pdos,
    clock: LiveClock,
    gather: Duration,
    tx: mpsc::Sender<Item>,
) {
    let mut reader = match transport {
        Transport::Udp(socket) => match tokio::net::UdpSocket::from_std(socket) {
            Ok(s) => Reader::Udp(s),
            Err(e) => {
                let m = format!("can {}: {e}", pdos.name);
                let _ = tx.send(Item::Fatal(Failure::Io(m))).await;
                return;
            }
        },
        #[cfg(target_os = "linux")]
        Transport::Socket { iface, socket } => Reader::Socket { iface, socket },
    };
    let mut buf = vec![0u8; MAX_DATAGRAM];
    let mut batch: Vec<u8> = Vec::new();
    let mut items = Vec::new();
    let mut note_at = tokio::time::Instant::now() + WAITING_NOTE_AFTER;
    let tick = gather.max(Duration::from_millis(1));
    loop {
        let first = match tokio::time::timeout(tick, reader.recv(&mut buf)).await {
            Ok(r) => r,
            Err(_) => {
                // A quiet bus: nothing changed up to the read clock, less
                // the time a scan's frames take to gather.
                if pdos.started {
                    let lag = gather.as_nanos() as Time;
                    items.push(Item::Watermark(clock.now() - lag));
                } else if tokio::time::Instant::now() >= note_at {
                    pdos.waiting_note(&mut items);
                }
                if !send_all(&tx, &mut items).await {
                    return;
                }
                continue;
            }
        };
        let mut failed = None;
        match first {
            Ok(n) => {
                let t = clock.now();
                batch.clear();
                pdos.append(&buf[..n], &mut batch, &mut items);
                // The rest of the scan: what arrives within `gather` of its
                // first frame, unless every identifier is already there.
                let close = tokio::time::Instant::now() + gather;
                while !pdos.has_every_identifier(&batch) {
                    match tokio::time::timeout_at(close, reader.recv(&mut buf)).await {
                        Err(_) => break,
                        Ok(Ok(n)) => pdos.append(&buf[..n], &mut batch, &mut items),
                        Ok(Err(e)) => {
                            failed = Some(e);
                            break;
                        }
                    }
                }
                pdos.decode(t, &batch, &mut items);
            }
            Err(e) => failed = Some(e),
        }
        if !send_all(&tx, &mut items).await {
            return;
        }
        let Some(e) = failed else { continue };
        match &mut reader {
            Reader::Udp(_) => {
                // Nothing on an unconnected UDP socket should fail for long;
                // the pause keeps a persistent error from spinning.
                items.push(Item::Warning(format!("can {}: {e}", pdos.name)));
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            #[cfg(target_os = "linux")]
            Reader::Socket { iface, socket } => {
                let m = format!("can {iface}: {e}; reopening the interface");
                if tx.send(Item::Lost(clock.now(), m)).await.is_err() {
                    return;
                }
                pdos.restart();
                *socket = loop {
                    tokio::time::sleep(REOPEN_EVERY).await;
                    if tx.is_closed() {
                        return;
                    }
                    if let Ok(s) = open_socket(iface) {
                        break s;
                    }
                };
                items.push(Item::Warning(format!("can {iface}: reopened")));
                note_at = tokio::time::Instant::now() + WAITING_NOTE_AFTER;
            }
        }
        if !send_all(&tx, &mut items).await {
            return;
        }
    }
}

/// The decoding state shared by both transports: raw frames in, items out.
struct Pdos {
    /// What the frames are read from, for messages.
    name: String,
    /// A decoder that has seen nothing, to start again from after a gap.
    fresh: PdoDecoder,
    decoder: PdoDecoder,
    signals: Vec<SignalId>,
    /// The mapped identifiers.
    ids: Vec<u32>,
    /// Whether [`Item::Start`] has gone out.
    started: bool,
    /// Whether the note on identifiers not seen yet is given, or not needed.
    noted: bool,
    /// The changes of the frames received together: signal, value before,
    /// value now.
    changes: Vec<(SignalId, bool, bool)>,
}

impl Pdos {
    fn new(name: String, decoder: PdoDecoder, plant: &Plant) -> Pdos {
        Pdos {
            name,
            fresh: decoder.clone(),
            decoder,
            signals: plant.signals.iter().map(|(id, _)| id).collect(),
            ids: {
                let mut ids: Vec<u32> = plant.can.iter().map(|c| c.cob_id).collect();
                ids.sort_unstable();
                ids.dedup();
                ids
            },
            started: false,
            noted: false,
            changes: Vec::new(),
        }
    }

    /// Forgets every value: after a gap, the next [`Item::Start`] comes once
    /// every identifier has been seen again.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn restart(&mut self) {
        self.decoder = self.fresh.clone();
        self.started = false;
        self.noted = false;
    }

    /// Adds the frames of one datagram (or one socket read) to `batch`, or
    /// warns that they are not whole 16-byte frames.
    fn append(&self, bytes: &[u8], batch: &mut Vec<u8>, out: &mut Vec<Item>) {
        if bytes.is_empty() || !bytes.len().is_multiple_of(CAN_FRAME_SIZE) {
            out.push(Item::Warning(format!(
                "can {}: {} bytes received, not a whole number of {CAN_FRAME_SIZE}-byte CAN frames: ignored",
                self.name,
                bytes.len()
            )));
            return;
        }
        batch.extend_from_slice(bytes);
    }

    /// Whether `batch` (whole frames) has a data frame of every mapped
    /// identifier: then no more frames can belong to its scan.
    fn has_every_identifier(&self, batch: &[u8]) -> bool {
        let present = |id: u32| {
            batch.chunks_exact(CAN_FRAME_SIZE).any(|chunk| {
                <&[u8; CAN_FRAME_SIZE]>::try_from(chunk)
                    .ok()
                    .and_then(|raw| decode_can_frame(raw).ok().flatten())
                    .is_some_and(|f| f.id == id)
            })
        };
        self.ids.iter().all(|&id| present(id))
    }

    /// Decodes one datagram received at `t`, as one scan.
    #[cfg(test)]
    fn receive(&mut self, t: Time, bytes: &[u8], out: &mut Vec<Item>) {
        let mut batch = Vec::new();
        self.append(bytes, &mut batch, out);
        self.decode(t, &batch, out);
    }

    /// Decodes `batch`, whole 16-byte frames received together at `t`, whose
    /// changes make one scan. Pushes what the monitor must hear to `out`.
    fn decode(&mut self, t: Time, batch: &[u8], out: &mut Vec<Item>) {
        if batch.is_empty() {
            return;
        }
        self.changes.clear();
        for chunk in batch.chunks_exact(CAN_FRAME_SIZE) {
            let Ok(raw) = <&[u8; CAN_FRAME_SIZE]>::try_from(chunk) else {
                continue;
            };
            let frame = match decode_can_frame(raw) {
                Ok(Some(f)) => f,
                Ok(None) => continue,
                Err(e) => {
                    out.push(Item::Warning(format!("can {}: {e}: ignored", self.name)));
                    continue;
                }
            };
            let decoded = match self.decoder.frame(t, frame.id, frame.data()) {
                Ok(d) => d,
                Err(e) => {
                    out.push(Item::Warning(format!(
                        "can {}: {e}: frame ignored",
                        self.name
                    )));
                    continue;
                }
            };
            if !self.started {
                // Values before the start go out whole, in `Item::Start`.
                continue;
            }
            for &(signal, value) in decoded {
                match self.changes.iter_mut().find(|c| c.0 == signal) {
                    Some(c) => c.2 = value,
                    // Once started, every signal has a value: this is a change.
                    None => self.changes.push((signal, !value, value)),
                }
            }
        }
        if !self.started {
            if self.decoder.is_complete() {
                let values = self
                    .signals
                    .iter()
                    .map(|&s| self.decoder.value(s).unwrap_or(false))
                    .collect();
                out.push(Item::Start(t, values));
                self.started = true;
                self.noted = true;
            }
            return;
        }
        // A signal that changed and changed back within the frames received
        // together did not change.
        self.changes.retain(|c| c.1 != c.2);
        if self.changes.is_empty() {
            return;
        }
        self.changes.sort_unstable_by_key(|c| c.0);
        out.push(Item::Scan(
            self.changes
                .iter()
                .map(|&(signal, _, value)| Event { t, signal, value })
                .collect(),
        ));
    }

    /// Says, once, which identifiers have not been seen yet.
    fn waiting_note(&mut self, out: &mut Vec<Item>) {
        if std::mem::replace(&mut self.noted, true) || self.started {
            return;
        }
        let unseen = self.decoder.unseen();
        if unseen.is_empty() {
            return;
        }
        let ids: Vec<String> = unseen.iter().map(|(id, _)| format!("{id:03X}")).collect();
        out.push(Item::Warning(format!(
            "can {}: no frame yet with identifier {}: diagnosis starts once every mapped identifier has been seen",
            self.name,
            ids.join(", ")
        )));
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use logs::IngestOptions;

    use super::*;

    fn plant() -> Plant {
        Plant::parse(
            r#"
            name = "t"
            [signals]
            S0 = { kind = "sensor" }
            S9 = { kind = "sensor" }
            X3 = { kind = "sensor" }
            A0 = { kind = "actuator" }
            [can]
            S0 = { cob_id = 0x181, bit = 0 }
            S9 = { cob_id = 0x181, bit = 9 }
            X3 = { cob_id = 0x12345678, bit = 3 }
            A0 = { cob_id = 0x201, bit = 0 }
            "#,
            Path::new("plant.toml"),
        )
        .expect("test plant parses")
    }

    /// Each `candump -L` line with the bytes a SocketCAN raw socket delivers
    /// for that frame (written out by hand, as the kernel lays them out).
    const FRAMES: [(&str, [u8; 16]); 5] = [
        (
            "181#0102",
            [0x81, 0x01, 0, 0, 2, 0, 0, 0, 0x01, 0x02, 0, 0, 0, 0, 0, 0],
        ),
        (
            "12345678#08",
            [
                0x78, 0x56, 0x34, 0x92, 1, 0, 0, 0, 0x08, 0, 0, 0, 0, 0, 0, 0,
            ],
        ),
        (
            "201#R",
            [0x01, 0x02, 0, 0x40, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            "20000080#0000000000000000",
            [0x80, 0, 0, 0x20, 8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            "201#FE.01",
            [0x01, 0x02, 0, 0, 2, 0, 0, 0, 0xFE, 0x01, 0, 0, 0, 0, 0, 0],
        ),
    ];

    #[test]
    fn decodes_the_kernel_layout() {
        let decoded: Vec<Option<(u32, bool, Vec<u8>)>> = FRAMES
            .iter()
            .map(|(_, b)| {
                decode_can_frame(b)
                    .expect("valid frame")
                    .map(|f| (f.id, f.extended, f.data().to_vec()))
            })
            .collect();
        assert_eq!(
            decoded,
            vec![
                Some((0x181, false, vec![1, 2])),
                Some((0x1234_5678, true, vec![8])),
                None,
                None,
                Some((0x201, false, vec![0xFE, 0x01])),
            ]
        );
        let mut too_long = FRAMES[0].1;
        too_long[4] = 9;
        assert!(decode_can_frame(&too_long).is_err());
    }

    /// The file path (`candump -L` parsed by learning's reader) and the raw
    /// path give every signal the same value from the same frames.
    #[test]
    fn raw_frames_decode_as_their_candump_lines() {
        let plant = plant();
        let dir = tempfile::tempdir().expect("temp dir");
        let log = dir.path().join("frames.log");
        let text: String = FRAMES
            .iter()
            .map(|(line, _)| format!("(1436509052.000000) vcan0 {line}\n"))
            .collect();
        std::fs::write(&log, text).expect("writes the log");
        let from_file = logs::candump::open(&log, &plant, &IngestOptions::default())
            .expect("the candump log opens");

        let mut pdos = Pdos::new(
            "test".into(),
            PdoDecoder::new(&plant).expect("mapped"),
            &plant,
        );
        let bytes: Vec<u8> = FRAMES.iter().flat_map(|(_, b)| *b).collect();
        let mut out = Vec::new();
        pdos.receive(1_436_509_052_000_000_000, &bytes, &mut out);
        match out.as_slice() {
            [Item::Start(t, values)] => {
                assert_eq!(*t, from_file.start);
                assert_eq!(values, &from_file.initial);
                // S0 = 1 (181 byte 0 bit 0), S9 = 1 (byte 1 bit 1), X3 = 1, A0 = 0.
                assert_eq!(values, &[true, true, true, false]);
            }
            other => panic!("expected the initial values, got {other:?}"),
        }
    }

    #[test]
    fn changes_of_one_datagram_make_one_scan_and_bad_records_warn() {
        let plant = plant();
        let mut pdos = Pdos::new(
            "test".into(),
            PdoDecoder::new(&plant).expect("mapped"),
            &plant,
        );
        let mut out = Vec::new();
        // Two identifiers only: no start yet.
        let first: Vec<u8> = [FRAMES[0].1, FRAMES[4].1].concat();
        pdos.receive(10, &first, &mut out);
        assert!(out.is_empty(), "{out:?}");
        pdos.receive(20, &FRAMES[1].1, &mut out);
        assert!(matches!(out.as_slice(), [Item::Start(20, _)]), "{out:?}");
        out.clear();
        // 181 clears S0, and 201 sets A0 then clears it again: one scan, S0 only.
        let mut s0_off = FRAMES[0].1;
        s0_off[8] = 0;
        let mut a0_on = FRAMES[4].1;
        a0_on[8] = 0x01;
        let batch: Vec<u8> = [s0_off, a0_on, FRAMES[4].1].concat();
        pdos.receive(30, &batch, &mut out);
        match out.as_slice() {
            [Item::Scan(events)] => {
                assert_eq!(events.len(), 1);
                assert_eq!(
                    (events[0].t, events[0].signal, events[0].value),
                    (30, SignalId(0), false)
                );
            }
            other => panic!("expected one scan, got {other:?}"),
        }
        out.clear();
        // Garbage, a frame too short for S9, a bad length: warnings only.
        pdos.receive(40, b"hello", &mut out);
        let mut short = FRAMES[0].1;
        short[4] = 1;
        pdos.receive(41, &short, &mut out);
        let mut long = FRAMES[0].1;
        long[4] = 12;
        pdos.receive(42, &long, &mut out);
        let warnings: Vec<&str> = out
            .iter()
            .filter_map(|i| match i {
                Item::Warning(w) => Some(w.as_str()),
                _ => None,
            })
            .collect();
        assert_eq!(warnings.len(), 3, "{out:?}");
        assert!(warnings[0].contains("5 bytes received"), "{}", warnings[0]);
        assert!(warnings[1].contains("has 1 data byte"), "{}", warnings[1]);
        assert!(warnings[2].contains("length 12"), "{}", warnings[2]);
        // Decoding goes on.
        out.clear();
        pdos.receive(50, &FRAMES[0].1, &mut out);
        assert!(
            matches!(out.as_slice(), [Item::Scan(e)] if e.len() == 1 && e[0].value),
            "{out:?}"
        );
    }

    #[test]
    fn says_which_identifiers_it_still_waits_for() {
        let plant = plant();
        let mut pdos = Pdos::new(
            "test".into(),
            PdoDecoder::new(&plant).expect("mapped"),
            &plant,
        );
        let mut out = Vec::new();
        pdos.receive(10, &FRAMES[0].1, &mut out);
        pdos.waiting_note(&mut out);
        match out.as_slice() {
            [Item::Warning(w)] => assert!(w.contains("identifier 201, 12345678"), "{w}"),
            other => panic!("expected one note, got {other:?}"),
        }
        // Once only.
        pdos.waiting_note(&mut out);
        assert_eq!(out.len(), 1);
    }
}
