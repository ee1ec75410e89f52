//! `--modbus HOST:PORT`: a PLC polled over Modbus TCP, with the flags written
//! back to it.
//!
//! Twice per scan period (divided by `--speed`) the source reads the coils and
//! discrete inputs of the plant file's register map ([`ModbusMap`]), twice
//! over (coils, inputs, coils, inputs, so that a PLC scan falling between two
//! reads is seen and never splits a sensor's change from the order the PLC
//! gave in the same scan: see [`Session::snapshot`]): one *poll*, stamped with
//! the time its requests were sent. The first poll after
//! a connection gives every signal's value ([`Item::Start`]); each later one
//! gives its changes as a scan, or only a watermark at its time.
//!
//! **Event time.** Polls are pipelined: a poll's requests go out on time even
//! while earlier replies are late (Modbus TCP's transaction ids match replies
//! to requests), and polls are released to the monitor in the order they were
//! sent, once complete. A reply delayed on the network therefore delays the
//! watermark, never a timestamp: the edges it holds keep the time they were
//! read, and no deadline fires while it is in flight. A poll whose reply is
//! overtaken by a later poll's for [`OVERTAKEN_AFTER`], or that gets none
//! within [`REPLY_TIMEOUT`] while the link still answers, is skipped (a
//! missing sample: the next poll shows its changes).
//!
//! When the connection fails (an I/O error, a reply that is not Modbus, or
//! nothing at all within [`REPLY_TIMEOUT`]), the source reports [`Item::Lost`]
//! and reconnects with a backoff doubling from [`BACKOFF_FIRST`] to
//! [`BACKOFF_MAX`]. On every (re)connection it writes every flag coil first, so
//! that a PLC that restarted and forgot its coils gets the raised flags back
//! before anything else. An exception reply (the PLC has no such address) is
//! a configuration error and stops the monitor.
//!
//! Two polls delivered more than ten PLC scans apart (a stalled machine, lost
//! replies) leave the edges between them untimed: the source reports the gap
//! as a lost plant ([`Item::Lost`]) and starts again from the next poll's
//! values, so that no deadline in the gap fires and no edge is judged on a
//! stamp it may not have had.
//!
//! With `--probe`, the source also writes the probe coils of the map
//! ([`diagnoser::plant::ProbeCoil`]): on every (re)connection, every `_PROBE`
//! coil to 0 (a move asked before a gap is never asked again); then, as the
//! monitor's probing moves change, a move as `_PROBE_VALUE`, then `_PROBE` to
//! 1, and its end as `_PROBE` to 0. While a move is written, each poll also
//! reads its `_PROBE_REFUSED` coil. Without `--probe` it never writes a probe
//! coil.
//!
//! The source runs on two threads of its own (one writes, one reads), paced by
//! the operating system's clock: the runtime's timers tick by the millisecond,
//! which at a high `--speed` would skip polls.

use std::collections::{HashMap, VecDeque};
use std::io::{Read, Write};
use std::net::{Shutdown, TcpStream, ToSocketAddrs};
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use diagnoser::plant::{ModbusMap, ModbusTable, ProbeCoils};
use diagnoser::{Event, Failure, Flag, FlagKind, Plant, SignalId, Time, TimeFormat};

use super::source::{Item, Link, LiveClock, ProbeImage, Source};
/// Longest wait for a reply: a poll unanswered this long is skipped, and a
/// link that answers nothing this long is lost.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(3);
/// First wait before reconnecting.
pub const BACKOFF_FIRST: Duration = Duration::from_millis(100);
/// Longest wait between reconnection attempts.
pub const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// Most bits one Modbus read may ask for.
const MAX_BITS: u16 = 2000;
/// How long a poll's reply may lag behind a later poll's before the poll is
/// skipped as lost.
const OVERTAKEN_AFTER: Duration = Duration::from_millis(50);
/// Most requests awaiting their reply on one connection; polls wait beyond.
const MAX_IN_FLIGHT: usize = 16_384;

/// A PLC polled over Modbus TCP.
pub struct ModbusSource {
    addr: String,
    unit: u8,
    map: ModbusMap,
    /// Flags in [`Plant::flags`] order with their coils.
    flags: Vec<(Flag, u16)>,
    /// With `--probe`: each actuator, in plant-file order, with its probe
    /// coils.
    probes: Option<Vec<(String, ProbeCoils)>>,
    /// Wall time between polls.
    period: Duration,
    speed: f64,
}

/// The reads of one poll: a table and a run of addresses.
#[derive(Debug, Clone, Copy)]
struct Block {
    table: ModbusTable,
    from: u16,
    count: u16,
}

impl ModbusSource {
    /// A source polling `addr` (`HOST:PORT`) for unit `unit` with `plant`'s
    /// register map, writing probe coils only if `probing`. Nothing is
    /// connected yet.
    pub fn new(
        addr: &str,
        unit: u8,
        plant: &Plant,
        speed: f64,
        probing: bool,
    ) -> Result<ModbusSource, Failure> {
        match addr.rsplit_once(':') {
            Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => {}
            _ => {
                return Err(Failure::BadInput(format!(
                    "--modbus '{addr}': expected HOST:PORT, e.g. 192.168.0.10:502"
                )));
            }
        }
        let map = plant.modbus_map();
        let flags = plant
            .flags()
            .into_iter()
            .map(|f| {
                let coil = map.flag(&f).unwrap_or(ModbusMap::FLAGS_FROM);
                (f, coil)
            })
            .collect();
        let probes = probing.then(|| {
            map.probes
                .iter()
                .map(|p| (plant.signals.name(p.actuator).to_string(), *p))
                .collect()
        });
        // Twice per scan: polls are not in step with the PLC's scans, and one
        // poll per scan would now and then miss a scan and see the edges of two
        // scans as one (an order and its sensor's answer at once).
        let period = Duration::from_nanos((plant.scan_period.max(1) as f64 / speed / 2.0) as u64);
        Ok(ModbusSource {
            addr: addr.to_string(),
            unit,
            map,
            flags,
            probes,
            period: period.max(Duration::from_micros(100)),
            speed,
        })
    }

    /// The runs of addresses to read, in at most [`MAX_BITS`] bits each.
    fn blocks(&self) -> Vec<Block> {
        let mut blocks = Vec::new();
        // Coils (the orders) before discrete inputs (the sensors): a scan of
        // the PLC between the two reads then shows a sensor's change before
        // the order reacting to it, never an order before its cause.
        for table in [ModbusTable::Coil, ModbusTable::DiscreteInput] {
            let addrs = self
                .map
                .signals
                .iter()
                .filter(|s| s.0 == table)
                .map(|s| s.1);
            let (Some(lo), Some(hi)) = (addrs.clone().min(), addrs.max()) else {
                continue;
            };
            let mut from = lo;
            loop {
                let count = (hi - from).saturating_add(1).min(MAX_BITS);
                blocks.push(Block { table, from, count });
                match from.checked_add(count) {
                    Some(next) if next <= hi => from = next,
                    _ => break,
                }
            }
        }
        blocks
    }
}

impl Source for ModbusSource {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Rfc3339
    }

    fn spawn(self: Box<Self>, link: Link) {
        std::thread::spawn(move || run(*self, link));
    }
}

/// How a session on one connection ended.
enum Ended {
    /// The monitor has stopped listening.
    Gone,
    /// The connection failed: reconnect.
    Lost(String),
    /// The PLC refused a request: the register map is wrong.
    Refused(String),
}

fn run(source: ModbusSource, mut link: Link) {
    let clock = LiveClock::new(source.speed);
    let mut backoff = BACKOFF_FIRST;
    let mut connected_once = false;
    let mut adopted = vec![false; source.flags.len()];
    loop {
        let stream = match connect(&source.addr) {
            Ok(s) => s,
            Err(e) => {
                let what = if connected_once {
                    "reconnecting"
                } else {
                    "connecting"
                };
                let m = format!(
                    "modbus {}: {what}: {e}; next try in {} ms",
                    source.addr,
                    backoff.as_millis()
                );
                if link.items.blocking_send(Item::Warning(m)).is_err() {
                    return;
                }
                std::thread::sleep(backoff);
                backoff = (backoff * 2).min(BACKOFF_MAX);
                continue;
            }
        };
        if connected_once {
            let m = format!("modbus {}: reconnected", source.addr);
            let _ = link.items.blocking_send(Item::Warning(m));
        }
        connected_once = true;
        let mut session = Session::new(&source, &clock, stream, &mut backoff);
        let ended = session.run(&mut link, &mut adopted);
        if matches!(ended, Ended::Refused(_)) {
            // The monitor stops on a wrong map: no move stays asked for.
            session.drop_probes();
        }
        session.close();
        match ended {
            Ended::Gone => return,
            Ended::Refused(m) => {
                let f = Failure::BadInput(format!(
                    "modbus {}: {m}; check the [modbus] table of the plant file",
                    source.addr
                ));
                let _ = link.items.blocking_send(Item::Fatal(f));
                return;
            }
            Ended::Lost(m) => {
                let m = format!(
                    "modbus {}: connection lost ({m}); reconnecting",
                    source.addr
                );
                if link
                    .items
                    .blocking_send(Item::Lost(clock.now(), m))
                    .is_err()
                {
                    return;
                }
                std::thread::sleep(backoff);
                backoff = (backoff * 2).min(BACKOFF_MAX);
            }
        }
    }
}

fn connect(addr: &str) -> Result<TcpStream, String> {
    let addrs: Vec<_> = addr
        .to_socket_addrs()
        .map_err(|e| format!("cannot resolve: {e}"))?
        .collect();
    let mut last = String::from("no address");
    for a in addrs {
        match TcpStream::connect_timeout(&a, REPLY_TIMEOUT) {
            Ok(s) => {
                let _ = s.set_nodelay(true);
                let _ = s.set_write_timeout(Some(REPLY_TIMEOUT));
                return Ok(s);
            }
            Err(e) => last = e.to_string(),
        }
    }
    Err(last)
}

/// What a request awaits.
#[derive(Debug, Clone, Copy)]
enum Awaited {
    /// Block `block` of poll `seq`.
    Poll { seq: u64, block: usize },
    /// The value of a flag (on connecting).
    FlagRead,
    /// The write of a flag, in batch `batch`.
    FlagWrite { batch: u64 },
    /// The write of a probe coil, in batch `batch`.
    ProbeWrite { batch: u64 },
    /// The `_PROBE_REFUSED` coil of the actuator `index` (in plant-file order).
    ProbeRefused { index: usize },
}

/// A poll sent, waiting for its replies.
struct Poll {
    t: Time,
    sent: Instant,
    bits: Vec<Option<Vec<bool>>>,
}

/// From the reading thread.
enum Reply {
    /// One Modbus TCP reply: its transaction id and PDU.
    Adu(u16, Vec<u8>),
    /// The connection ended or sent something that is not Modbus TCP.
    Closed(String),
}

/// One connection: its writing side (this thread) and its reading thread.
struct Session<'a> {
    source: &'a ModbusSource,
    clock: &'a LiveClock,
    stream: TcpStream,
    replies: std_mpsc::Receiver<Reply>,
    reader: Option<std::thread::JoinHandle<()>>,
    backoff: &'a mut Duration,
    blocks: Vec<Block>,
    next_tid: u16,
    awaited: HashMap<u16, Awaited>,
    polls: VecDeque<Poll>,
    /// Sequence number of the first poll in `polls`.
    first_seq: u64,
    last_reply: Instant,
    values: Option<Vec<bool>>,
    /// Per flag: the value last sent.
    written: Vec<Option<bool>>,
    /// Flag write batches: replies still awaited, flags written up.
    batches: HashMap<u64, (usize, Vec<String>)>,
    next_batch: u64,
    /// Per actuator with probe coils: the move last written on this
    /// connection.
    probes_written: Vec<Option<bool>>,
    /// Probe write batches: replies still awaited, the moves written.
    probe_batches: HashMap<u64, (usize, ProbeImage)>,
    /// Per actuator: whether the refusal of its move was told.
    refusal_told: Vec<bool>,
    /// Polls skipped on this connection.
    skipped: u64,
    /// Time of the last poll delivered.
    last_t: Option<Time>,
}

impl<'a> Session<'a> {
    fn new(
        source: &'a ModbusSource,
        clock: &'a LiveClock,
        stream: TcpStream,
        backoff: &'a mut Duration,
    ) -> Session<'a> {
        let (tx, replies) = std_mpsc::channel();
        let reader = stream
            .try_clone()
            .map(|s| std::thread::spawn(move || read_replies(s, &tx)))
            .ok();
        Session {
            source,
            clock,
            stream,
            replies,
            reader,
            backoff,
            blocks: source.blocks().repeat(2),
            next_tid: 0,
            awaited: HashMap::new(),
            polls: VecDeque::new(),
            first_seq: 0,
            last_reply: Instant::now(),
            values: None,
            written: vec![None; source.flags.len()],
            batches: HashMap::new(),
            next_batch: 0,
            probes_written: Vec::new(),
            probe_batches: HashMap::new(),
            refusal_told: Vec::new(),
            skipped: 0,
            last_t: None,
        }
    }

    /// Ends the connection and waits for the reading thread.
    fn close(&mut self) {
        let _ = self.stream.shutdown(Shutdown::Both);
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }

    /// The flags found and written, then polls until the connection fails or
    /// the monitor stops.
    fn run(&mut self, link: &mut Link, adopted: &mut [bool]) -> Ended {
        if self.reader.is_none() {
            return Ended::Lost("cannot read the connection".into());
        }
        if let Err(e) = self.adopt_flags(link, adopted) {
            return e;
        }
        // Then every flag: the PLC may have restarted and forgotten them.
        if let Err(e) = self.write_flags(link, adopted) {
            return e;
        }
        if let Err(e) = self.clear_probes(link) {
            return e;
        }
        let mut next = Instant::now();
        loop {
            match link.flags.has_changed() {
                Err(_) => return Ended::Gone,
                Ok(true) => {
                    if let Err(e) = self.write_flags(link, adopted) {
                        return e;
                    }
                }
                Ok(false) => {}
            }
            if self.source.probes.is_some() {
                match link.probes.has_changed() {
                    Err(_) => return Ended::Gone,
                    Ok(true) => {
                        if let Err(e) = self.write_probes(link) {
                            return e;
                        }
                    }
                    Ok(false) => {}
                }
            }
            let now = Instant::now();
            if now >= next {
                if let Err(e) = self.send_poll() {
                    return e;
                }
                // Missed polls are skipped, not made up in a burst.
                next = (next + self.source.period).max(now);
            }
            if let Err(e) = self.release(link) {
                return e;
            }
            match self
                .replies
                .recv_timeout(next.saturating_duration_since(Instant::now()))
            {
                Ok(r) => {
                    if let Err(e) = self.take(r, link) {
                        return e;
                    }
                }
                Err(std_mpsc::RecvTimeoutError::Timeout) => {}
                Err(std_mpsc::RecvTimeoutError::Disconnected) => {
                    return Ended::Lost("the connection closed".into());
                }
            }
        }
    }

    /// Sends one request; returns its transaction id.
    fn request(&mut self, pdu: &[u8], awaited: Awaited) -> Result<(), Ended> {
        let tid = self.next_tid;
        self.next_tid = self.next_tid.wrapping_add(1);
        let frame = adu(tid, self.source.unit, pdu);
        self.stream
            .write_all(&frame)
            .map_err(|e| Ended::Lost(format!("sending a request: {e}")))?;
        self.awaited.insert(tid, awaited);
        Ok(())
    }

    /// Sends one poll's reads, unless too many requests await their replies.
    fn send_poll(&mut self) -> Result<(), Ended> {
        if self.awaited.len() + self.blocks.len() > MAX_IN_FLIGHT {
            return Ok(());
        }
        let seq = self.first_seq + self.polls.len() as u64;
        self.polls.push_back(Poll {
            t: self.clock.now(),
            sent: Instant::now(),
            bits: vec![None; self.blocks.len()],
        });
        for block in 0..self.blocks.len() {
            let b = self.blocks[block];
            let code = match b.table {
                ModbusTable::Coil => 1,
                ModbusTable::DiscreteInput => 2,
            };
            let [ah, al] = b.from.to_be_bytes();
            let [ch, cl] = b.count.to_be_bytes();
            self.request(&[code, ah, al, ch, cl], Awaited::Poll { seq, block })?;
        }
        self.ask_refusals()
    }

    /// Takes in one reply.
    fn take(&mut self, r: Reply, link: &mut Link) -> Result<(), Ended> {
        let (tid, pdu) = match r {
            Reply::Adu(tid, pdu) => (tid, pdu),
            Reply::Closed(m) => return Err(Ended::Lost(m)),
        };
        self.last_reply = Instant::now();
        // A reply to a request already given up (a skipped poll) is ignored.
        let Some(awaited) = self.awaited.remove(&tid) else {
            return Ok(());
        };
        match awaited {
            Awaited::Poll { seq, block } => {
                let b = self.blocks[block];
                let bits = read_bits(&pdu, b.count)
                    .map_err(|e| self.trouble(&format!("reading {}", b.describe()), e))?;
                if let Some(p) = seq
                    .checked_sub(self.first_seq)
                    .and_then(|i| self.polls.get_mut(i as usize))
                {
                    p.bits[block] = Some(bits);
                }
            }
            Awaited::FlagRead => {}
            Awaited::FlagWrite { batch } => {
                let coil = "writing a flag coil";
                check_echo(&pdu).map_err(|e| self.trouble(coil, e))?;
                self.flag_written(batch, link)?;
            }
            Awaited::ProbeWrite { batch } => {
                let coil = "writing a probe coil";
                check_echo(&pdu).map_err(|e| self.trouble(coil, e))?;
                self.probe_written(batch, link)?;
            }
            Awaited::ProbeRefused { index } => {
                let what = "reading a _PROBE_REFUSED coil";
                let bits = read_bits(&pdu, 1).map_err(|e| self.trouble(what, e))?;
                self.refusal_read(index, bits.first().copied().unwrap_or(false), link)?;
            }
        }
        Ok(())
    }

    fn trouble(&self, what: &str, e: PduError) -> Ended {
        match e {
            PduError::Refused(code) => Ended::Refused(format!("{what}: the PLC answered {code}")),
            PduError::Malformed(m) => Ended::Lost(format!("{what}: {m}")),
        }
    }

    /// Sends the complete polls, in the order sent; skips a poll unanswered
    /// for [`REPLY_TIMEOUT`], or gives up on a link that answers nothing.
    fn release(&mut self, link: &mut Link) -> Result<(), Ended> {
        while let Some(p) = self.polls.front() {
            if p.bits.iter().all(Option::is_some) {
                let p = self.polls.pop_front().expect("a poll");
                self.first_seq += 1;
                self.deliver(p, link)?;
                continue;
            }
            // A later poll already complete: the reply is lost or overtaken,
            // and waiting longer would only hold the watermark back.
            let overtaken = p.sent.elapsed() >= OVERTAKEN_AFTER
                && self
                    .polls
                    .iter()
                    .skip(1)
                    .any(|q| q.bits.iter().all(Option::is_some));
            if overtaken {
                self.skip_front(link)?;
                continue;
            }
            if p.sent.elapsed() < REPLY_TIMEOUT {
                break;
            }
            if self.last_reply.elapsed() >= REPLY_TIMEOUT {
                return Err(Ended::Lost(format!(
                    "no reply within {} ms",
                    REPLY_TIMEOUT.as_millis()
                )));
            }
            self.skip_front(link)?;
        }
        Ok(())
    }

    /// Gives up on the oldest poll: a missing sample.
    fn skip_front(&mut self, link: &mut Link) -> Result<(), Ended> {
        let seq = self.first_seq;
        self.polls.pop_front();
        self.first_seq += 1;
        self.awaited
            .retain(|_, a| !matches!(a, Awaited::Poll { seq: s, .. } if *s == seq));
        self.skipped += 1;
        // The first, then one in a thousand: a lossy link must not flood stderr.
        if self.skipped % 1000 != 1 {
            return Ok(());
        }
        let m = format!(
            "modbus {}: {} poll(s) skipped so far, a reply lost or overtaken (the next poll shows the changes)",
            self.source.addr, self.skipped
        );
        link.items
            .blocking_send(Item::Warning(m))
            .map_err(|_| Ended::Gone)
    }

    /// One complete poll to the monitor: the first values, a scan, or only a
    /// watermark. A poll that straddles the PLC's scans is skipped.
    fn deliver(&mut self, p: Poll, link: &mut Link) -> Result<(), Ended> {
        *self.backoff = BACKOFF_FIRST;
        let half = self.blocks.len() / 2;
        let first = self.signal_values(&self.blocks[..half], &p.bits[..half]);
        let second = self.signal_values(&self.blocks[half..], &p.bits[half..]);
        let Some(read) = self.snapshot(first, second) else {
            return Ok(());
        };
        if let Some(last) = self.last_t.replace(p.t)
            && p.t - last > self.max_gap()
        {
            // An edge between two polls this far apart could have come at any
            // time between them: its stamp would not be evidence.
            let m = format!(
                "modbus {}: two polls {:.1} ms apart (the plant's time), more than {:.1} ms: what happened between them is not timed",
                self.source.addr,
                (p.t - last) as f64 / 1e6,
                self.max_gap() as f64 / 1e6
            );
            let lost = Item::Lost(last, m);
            link.items.blocking_send(lost).map_err(|_| Ended::Gone)?;
            self.values = None;
        }
        let item = match self.values.as_mut() {
            None => {
                self.values = Some(read.clone());
                Item::Start(p.t, read)
            }
            Some(old) => {
                let events = changes(old, &read, p.t);
                if events.is_empty() {
                    Item::Watermark(p.t)
                } else {
                    Item::Scan(events)
                }
            }
        };
        link.items.blocking_send(item).map_err(|_| Ended::Gone)
    }

    /// The longest time between two polls (the source's time) whose edges are
    /// still timed: ten scans of the PLC, beyond the margin a model learned
    /// for polling usually has.
    fn max_gap(&self) -> Time {
        (self.source.period.as_nanos() as f64 * self.source.speed * 20.0) as Time
    }

    /// The values of one PLC scan from a poll's two reads (coils, inputs,
    /// coils, inputs). A scan of the PLC may fall between a coil read and an
    /// input read, and the pair would then show a sensor's change without
    /// the order the PLC gave in the same scan (or the reverse). If the coils
    /// did not change between the reads, the first pair is one scan's; if
    /// only they changed, the second pair is; if both changed, no pair is
    /// sure and the poll is skipped (the next one shows the changes).
    fn snapshot(&self, first: Vec<bool>, second: Vec<bool>) -> Option<Vec<bool>> {
        let tables = &self.source.map.signals;
        let same = |table: ModbusTable| {
            tables
                .iter()
                .zip(first.iter().zip(&second))
                .all(|(s, (a, b))| s.0 != table || a == b)
        };
        if same(ModbusTable::Coil) {
            Some(first)
        } else if same(ModbusTable::DiscreteInput) {
            Some(second)
        } else {
            None
        }
    }

    /// Every mapped signal's value from one read of `blocks`.
    fn signal_values(&self, blocks: &[Block], bits: &[Option<Vec<bool>>]) -> Vec<bool> {
        let bit = |table: ModbusTable, a: u16| {
            blocks.iter().zip(bits).any(|(b, bits)| {
                b.table == table
                    && a >= b.from
                    && bits
                        .as_ref()
                        .and_then(|v| v.get(usize::from(a - b.from)).copied())
                        .unwrap_or(false)
            })
        };
        self.source
            .map
            .signals
            .iter()
            .map(|&(table, a)| bit(table, a))
            .collect()
    }

    /// Reads the `def_` flag coils and counts those up as raised: left by an
    /// earlier run of the monitor, they are lowered only by people (after a
    /// repair). A `suspect_` flag follows the present doubts, not an earlier
    /// run's.
    fn adopt_flags(&mut self, link: &mut Link, adopted: &mut [bool]) -> Result<(), Ended> {
        let coils: Vec<(usize, Flag, u16)> = self
            .source
            .flags
            .iter()
            .enumerate()
            .filter(|(_, (flag, _))| flag.kind == FlagKind::Def)
            .map(|(i, (flag, coil))| (i, flag.clone(), *coil))
            .collect();
        for (index, name, coil) in coils {
            let [ah, al] = coil.to_be_bytes();
            self.request(&[1, ah, al, 0, 1], Awaited::FlagRead)?;
            let pdu = self.await_reply()?;
            let what = format!("reading flag {name} from coil {coil}");
            let bits = read_bits(&pdu, 1).map_err(|e| self.trouble(&what, e))?;
            adopted[index] |= bits.first().copied().unwrap_or(false);
        }
        let found: Vec<String> = self
            .source
            .flags
            .iter()
            .zip(adopted.iter())
            .filter(|(_, up)| **up)
            .map(|(f, _)| f.0.to_string())
            .collect();
        if !found.is_empty() && link.items.blocking_send(Item::FoundRaised(found)).is_err() {
            return Err(Ended::Gone);
        }
        Ok(())
    }

    /// Waits for the reply to the one request in flight.
    fn await_reply(&mut self) -> Result<Vec<u8>, Ended> {
        loop {
            match self.replies.recv_timeout(REPLY_TIMEOUT) {
                Ok(Reply::Adu(tid, pdu)) => {
                    if self.awaited.remove(&tid).is_some() {
                        self.last_reply = Instant::now();
                        return Ok(pdu);
                    }
                }
                Ok(Reply::Closed(m)) => return Err(Ended::Lost(m)),
                Err(std_mpsc::RecvTimeoutError::Timeout) => {
                    return Err(Ended::Lost(format!(
                        "no reply within {} ms",
                        REPLY_TIMEOUT.as_millis()
                    )));
                }
                Err(std_mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(Ended::Lost("the connection closed".into()));
                }
            }
        }
    }

    /// Sends the flag coils whose value differs from the one last sent; a
    /// flag found raised on the PLC is written up whatever the image says.
    fn write_flags(&mut self, link: &mut Link, adopted: &[bool]) -> Result<(), Ended> {
        let mut image = link.flags.borrow_and_update().clone();
        for (up, &kept) in image.iter_mut().zip(adopted) {
            *up |= kept;
        }
        let batch = self.next_batch;
        let mut count = 0;
        let mut up_names = Vec::new();
        for i in 0..self.written.len() {
            let up = image.get(i).copied().unwrap_or(false);
            if self.written[i] == Some(up) {
                continue;
            }
            let [ah, al] = self.source.flags[i].1.to_be_bytes();
            let value = if up { 0xFF } else { 0x00 };
            self.request(&[5, ah, al, value, 0], Awaited::FlagWrite { batch })?;
            self.written[i] = Some(up);
            count += 1;
            if up {
                up_names.push(self.source.flags[i].0.to_string());
            }
        }
        if count > 0 {
            self.batches.insert(batch, (count, up_names));
            self.next_batch += 1;
        }
        Ok(())
    }

    /// One write of a batch acknowledged; the batch is reported once all are.
    fn flag_written(&mut self, batch: u64, link: &mut Link) -> Result<(), Ended> {
        let Some(b) = self.batches.get_mut(&batch) else {
            return Ok(());
        };
        b.0 -= 1;
        if b.0 > 0 {
            return Ok(());
        }
        let (_, up) = self.batches.remove(&batch).unwrap_or_default();
        link.items
            .blocking_send(Item::FlagsWritten(up))
            .map_err(|_| Ended::Gone)
    }

    /// Sends one write of a coil (function 5).
    fn write_coil(&mut self, coil: u16, up: bool, awaited: Awaited) -> Result<(), Ended> {
        let [ah, al] = coil.to_be_bytes();
        let value = if up { 0xFF } else { 0x00 };
        self.request(&[5, ah, al, value, 0], awaited)
    }

    /// On connecting, with `--probe`: every `_PROBE` coil to 0. A move the
    /// monitor asked before is not asked again: it was meant for verdicts
    /// that a gap has made stale, and the monitor ends it when it hears of
    /// the gap. What it asks from now on is written as it changes.
    fn clear_probes(&mut self, link: &mut Link) -> Result<(), Ended> {
        let source = self.source;
        let Some(probes) = &source.probes else {
            return Ok(());
        };
        link.probes.borrow_and_update();
        let batch = self.next_batch;
        self.next_batch += 1;
        for (_, coils) in probes {
            self.write_coil(coils.probe, false, Awaited::ProbeWrite { batch })?;
        }
        self.probes_written = vec![None; probes.len()];
        self.refusal_told = vec![false; probes.len()];
        self.probe_batches
            .insert(batch, (probes.len(), self.probes_written.clone()));
        Ok(())
    }

    /// Writes the probing moves that changed: a move ending as `_PROBE` to
    /// 0, a new one as its value, then `_PROBE` to 1, so that the PLC never
    /// reads `_PROBE` at 1 with another move's value.
    fn write_probes(&mut self, link: &mut Link) -> Result<(), Ended> {
        let source = self.source;
        let Some(probes) = &source.probes else {
            return Ok(());
        };
        let image = link.probes.borrow_and_update().clone();
        let batch = self.next_batch;
        let mut count = 0;
        for (i, (_, coils)) in probes.iter().enumerate() {
            let want = image.get(i).copied().flatten();
            let had = self.probes_written.get(i).copied().flatten();
            if want == had {
                continue;
            }
            let awaited = Awaited::ProbeWrite { batch };
            if had.is_some() {
                self.write_coil(coils.probe, false, awaited)?;
                count += 1;
            }
            if let Some(value) = want {
                self.write_coil(coils.value, value, awaited)?;
                self.write_coil(coils.probe, true, awaited)?;
                count += 2;
            }
            if let Some(w) = self.probes_written.get_mut(i) {
                *w = want;
            }
            if let Some(told) = self.refusal_told.get_mut(i) {
                *told = false;
            }
        }
        if count > 0 {
            self.probe_batches
                .insert(batch, (count, self.probes_written.clone()));
            self.next_batch += 1;
        }
        Ok(())
    }

    /// One write of a probe batch acknowledged; the moves it leaves on the
    /// PLC are reported once all are.
    fn probe_written(&mut self, batch: u64, link: &mut Link) -> Result<(), Ended> {
        let Some(b) = self.probe_batches.get_mut(&batch) else {
            return Ok(());
        };
        b.0 -= 1;
        if b.0 > 0 {
            return Ok(());
        }
        let (_, image) = self.probe_batches.remove(&batch).unwrap_or_default();
        link.items
            .blocking_send(Item::ProbesWritten(image))
            .map_err(|_| Ended::Gone)
    }

    /// Writes `_PROBE` to 0 where a move was written, without waiting for
    /// the replies: the connection is being closed.
    fn drop_probes(&mut self) {
        let source = self.source;
        let Some(probes) = &source.probes else {
            return;
        };
        for (i, (_, coils)) in probes.iter().enumerate() {
            if self.probes_written.get(i).copied().flatten().is_some() {
                let batch = u64::MAX;
                let _ = self.write_coil(coils.probe, false, Awaited::ProbeWrite { batch });
            }
        }
    }

    /// Reads the `_PROBE_REFUSED` coil of every move written.
    fn ask_refusals(&mut self) -> Result<(), Ended> {
        let source = self.source;
        let Some(probes) = &source.probes else {
            return Ok(());
        };
        for (index, (_, coils)) in probes.iter().enumerate() {
            if self.probes_written.get(index).copied().flatten().is_some() {
                let [ah, al] = coils.refused.to_be_bytes();
                self.request(&[1, ah, al, 0, 1], Awaited::ProbeRefused { index })?;
            }
        }
        Ok(())
    }

    /// A `_PROBE_REFUSED` coil read: a refusal of the move under way is told
    /// once.
    fn refusal_read(&mut self, index: usize, refused: bool, link: &mut Link) -> Result<(), Ended> {
        let up = self.probes_written.get(index).copied().flatten().is_some();
        let Some(told) = self.refusal_told.get_mut(index) else {
            return Ok(());
        };
        if !refused || !up || *told {
            return Ok(());
        }
        *told = true;
        let name = self.source.probes.as_ref().and_then(|p| p.get(index));
        let Some((actuator, _)) = name else {
            return Ok(());
        };
        link.items
            .blocking_send(Item::ProbeRefused(actuator.clone()))
            .map_err(|_| Ended::Gone)
    }
}

impl Block {
    fn describe(&self) -> String {
        let what = match self.table {
            ModbusTable::DiscreteInput => "discrete inputs",
            ModbusTable::Coil => "coils",
        };
        let last = u32::from(self.from) + u32::from(self.count) - 1;
        format!("{what} {}-{last}", self.from)
    }
}

/// The events that take `old` to `new`, stamped `t`; `old` becomes `new`.
fn changes(old: &mut [bool], new: &[bool], t: Time) -> Vec<Event> {
    let mut events = Vec::new();
    for (i, (o, &n)) in old.iter_mut().zip(new).enumerate() {
        if *o != n {
            *o = n;
            events.push(Event {
                t,
                signal: SignalId(i as u32),
                value: n,
            });
        }
    }
    events
}

/// A Modbus TCP frame: the MBAP header, then the PDU.
fn adu(tid: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let len = (pdu.len() + 1) as u16;
    let mut f = Vec::with_capacity(7 + pdu.len());
    f.extend_from_slice(&tid.to_be_bytes());
    f.extend_from_slice(&[0, 0]);
    f.extend_from_slice(&len.to_be_bytes());
    f.push(unit);
    f.extend_from_slice(pdu);
    f
}

/// Reads replies until the connection ends; every reply goes to `tx`.
fn read_replies(mut s: TcpStream, tx: &std_mpsc::Sender<Reply>) {
    loop {
        let reply = read_adu(&mut s).unwrap_or_else(Reply::Closed);
        let closed = matches!(reply, Reply::Closed(_));
        if tx.send(reply).is_err() || closed {
            return;
        }
    }
}

fn read_adu(s: &mut TcpStream) -> Result<Reply, String> {
    let mut header = [0u8; 7];
    s.read_exact(&mut header).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => "the PLC closed the connection".to_string(),
        _ => e.to_string(),
    })?;
    let tid = u16::from_be_bytes([header[0], header[1]]);
    let protocol = u16::from_be_bytes([header[2], header[3]]);
    let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
    if protocol != 0 || !(2..=254).contains(&len) {
        return Err("a reply that is not Modbus TCP".into());
    }
    let mut pdu = vec![0u8; len - 1];
    s.read_exact(&mut pdu).map_err(|e| e.to_string())?;
    Ok(Reply::Adu(tid, pdu))
}

/// What is wrong with a reply's PDU.
#[derive(Debug)]
enum PduError {
    /// An exception reply: the PLC refused the request.
    Refused(String),
    /// Not the reply asked for.
    Malformed(String),
}

/// The bits of a read reply (function 1 or 2).
fn read_bits(pdu: &[u8], count: u16) -> Result<Vec<bool>, PduError> {
    refused(pdu)?;
    let n = usize::from(count);
    let bytes = pdu.get(2..).unwrap_or_default();
    if pdu.len() < 2 || usize::from(pdu[1]) != bytes.len() || bytes.len() * 8 < n {
        return Err(PduError::Malformed(format!(
            "a reply of {} bytes for {n} bits",
            pdu.len()
        )));
    }
    Ok((0..n).map(|i| bytes[i / 8] >> (i % 8) & 1 == 1).collect())
}

/// A write reply (function 5) echoes its request.
fn check_echo(pdu: &[u8]) -> Result<(), PduError> {
    refused(pdu)?;
    if pdu.len() != 5 || pdu[0] != 5 {
        return Err(PduError::Malformed("not the echo of a coil write".into()));
    }
    Ok(())
}

fn refused(pdu: &[u8]) -> Result<(), PduError> {
    match pdu {
        [code, exception, ..] if code & 0x80 != 0 => {
            Err(PduError::Refused(exception_name(*exception)))
        }
        [] => Err(PduError::Malformed("an empty reply".into())),
        _ => Ok(()),
    }
}

fn exception_name(code: u8) -> String {
    match code {
        1 => "IllegalFunction".into(),
        2 => "IllegalDataAddress".into(),
        3 => "IllegalDataValue".into(),
        4 => "ServerDeviceFailure".into(),
        6 => "ServerDeviceBusy".into(),
        c => format!("exception {c}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_and_replies_follow_modbus_tcp() {
        assert_eq!(
            adu(0x0102, 1, &[1, 0, 100, 0, 8]),
            [1, 2, 0, 0, 0, 6, 1, 1, 0, 100, 0, 8]
        );
        // Bits come least significant first.
        let bits = read_bits(&[2, 2, 0b0000_0101, 0b1], 9).expect("bits");
        assert_eq!(
            bits,
            [true, false, true, false, false, false, false, false, true]
        );
        assert!(matches!(
            read_bits(&[2, 1, 0], 9),
            Err(PduError::Malformed(_))
        ));
        assert!(
            matches!(read_bits(&[0x82, 2], 9), Err(PduError::Refused(m)) if m == "IllegalDataAddress")
        );
        assert!(check_echo(&[5, 0, 100, 0xFF, 0]).is_ok());
        assert!(check_echo(&[6, 0, 100, 0xFF, 0]).is_err());
    }

    #[test]
    fn a_poll_gives_the_changes_at_its_time() {
        let mut old = vec![false, true, false];
        let e = changes(&mut old, &[true, true, false], 7);
        assert_eq!(e.len(), 1);
        assert_eq!((e[0].t, e[0].signal, e[0].value), (7, SignalId(0), true));
        assert_eq!(old, [true, true, false]);
    }
}
