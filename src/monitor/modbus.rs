//! `--modbus HOST:PORT`: a PLC polled over Modbus TCP, with the flags written
//! back to it.
//!
//! Twice per scan period (divided by `--speed`) the source reads the discrete
//! inputs and coils of the plant file's register map ([`ModbusMap`]) and sends
//! the changes as one scan, stamped with the time the poll started. The first
//! poll after a connection gives every signal's value ([`Item::Start`]).
//!
//! When the connection fails (an I/O error, a reply that is not Modbus, or no
//! reply within [`REPLY_TIMEOUT`]), the source reports [`Item::Lost`] and
//! reconnects with a backoff doubling from [`BACKOFF_FIRST`] to
//! [`BACKOFF_MAX`]. On every (re)connection it writes every flag coil first, so
//! that a PLC that restarted and forgot its coils gets the raised flags back
//! before anything else. An exception reply (the PLC has no such address) is
//! a configuration error and stops the monitor.

use std::net::SocketAddr;
use std::time::Duration;

use diagnoser::plant::{ModbusMap, ModbusTable};
use diagnoser::{Event, Plant, SignalId, TimeFormat};
use tokio_modbus::client::{Context, Reader, Writer};
use tokio_modbus::{ExceptionCode, Slave};

use super::source::{Item, Link, LiveClock, Source};
use crate::Failure;

/// Longest wait for a reply before the connection counts as lost.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(1);
/// First wait before reconnecting.
pub const BACKOFF_FIRST: Duration = Duration::from_millis(100);
/// Longest wait between reconnection attempts.
pub const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// Most bits one Modbus read may ask for.
const MAX_BITS: u16 = 2000;

/// A PLC polled over Modbus TCP.
pub struct ModbusSource {
    addr: String,
    unit: u8,
    map: ModbusMap,
    /// Flags in [`Plant::flags`] order with their coils.
    flags: Vec<(String, u16)>,
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
    /// register map. Nothing is connected yet.
    pub fn new(addr: &str, unit: u8, plant: &Plant, speed: f64) -> Result<ModbusSource, Failure> {
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
        // Twice per scan: polls are not in step with the PLC's scans, and one
        // poll per scan would now and then miss a scan and see the edges of two
        // scans as one (an order and its sensor's answer at once).
        let period = Duration::from_nanos((plant.scan_period.max(1) as f64 / speed / 2.0) as u64);
        Ok(ModbusSource {
            addr: addr.to_string(),
            unit,
            map,
            flags,
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

/// Why a poll or a write failed.
enum Trouble {
    /// The connection is gone or the peer does not speak Modbus: reconnect.
    Connection(String),
    /// The PLC refused the request: the register map is wrong.
    Refused(String),
}

fn call<T>(
    what: &str,
    r: Result<tokio_modbus::Result<T>, tokio::time::error::Elapsed>,
) -> Result<T, Trouble> {
    match r {
        Err(_) => Err(Trouble::Connection(format!(
            "{what}: no reply within {} ms",
            REPLY_TIMEOUT.as_millis()
        ))),
        Ok(Err(e)) => Err(Trouble::Connection(format!("{what}: {e}"))),
        Ok(Ok(Err(code))) => Err(Trouble::Refused(format!(
            "{what}: the PLC answered {}",
            exception_name(code)
        ))),
        Ok(Ok(Ok(v))) => Ok(v),
    }
}

fn exception_name(code: ExceptionCode) -> String {
    format!("{code:?}")
}

impl Source for ModbusSource {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Rfc3339
    }

    fn spawn(self: Box<Self>, link: Link) {
        // Its own thread and runtime: the polls sleep on the operating
        // system's clock (see `session`), which would stall the monitor.
        std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build();
            match runtime {
                Ok(rt) => rt.block_on(run(*self, link)),
                Err(e) => {
                    let f = Failure::Io(format!("cannot start the Modbus runtime: {e}"));
                    let _ = link.items.blocking_send(Item::Fatal(f));
                }
            }
        });
    }
}

async fn run(source: ModbusSource, mut link: Link) {
    let clock = LiveClock::new(source.speed);
    let mut backoff = BACKOFF_FIRST;
    let mut connected_once = false;
    let mut adopted = vec![false; source.flags.len()];
    loop {
        let mut ctx = match connect(&source).await {
            Ok(ctx) => ctx,
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
                if link.items.send(Item::Warning(m)).await.is_err() {
                    return;
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(BACKOFF_MAX);
                continue;
            }
        };
        if connected_once {
            let _ = link
                .items
                .send(Item::Warning(format!(
                    "modbus {}: reconnected",
                    source.addr
                )))
                .await;
        }
        connected_once = true;
        match session(
            &source,
            &clock,
            &mut ctx,
            &mut link,
            &mut backoff,
            &mut adopted,
        )
        .await
        {
            Ended::Gone => return,
            Ended::Refused(m) => {
                let f = Failure::BadInput(format!(
                    "modbus {}: {m}; check the [modbus] table of the plant file",
                    source.addr
                ));
                let _ = link.items.send(Item::Fatal(f)).await;
                return;
            }
            Ended::Lost(m) => {
                let m = format!(
                    "modbus {}: connection lost ({m}); reconnecting",
                    source.addr
                );
                if link.items.send(Item::Lost(clock.now(), m)).await.is_err() {
                    return;
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(BACKOFF_MAX);
            }
        }
    }
}

async fn connect(source: &ModbusSource) -> Result<Context, String> {
    let addrs: Vec<SocketAddr> = tokio::net::lookup_host(&source.addr)
        .await
        .map_err(|e| format!("cannot resolve: {e}"))?
        .collect();
    let mut last = String::from("no address");
    for a in addrs {
        match tokio::time::timeout(
            REPLY_TIMEOUT,
            tokio_modbus::client::tcp::connect_slave(a, Slave(source.unit)),
        )
        .await
        {
            Ok(Ok(ctx)) => return Ok(ctx),
            Ok(Err(e)) => last = e.to_string(),
            Err(_) => last = format!("no answer within {} ms", REPLY_TIMEOUT.as_millis()),
        }
    }
    Err(last)
}

/// How a session on one connection ended.
enum Ended {
    /// The monitor has stopped listening.
    Gone,
    /// The connection failed: reconnect.
    Lost(String),
    /// The PLC refused a request.
    Refused(String),
}

/// One connection: the flags found and written, then polls until the
/// connection fails or the monitor stops.
async fn session(
    source: &ModbusSource,
    clock: &LiveClock,
    ctx: &mut Context,
    link: &mut Link,
    backoff: &mut std::time::Duration,
    adopted: &mut [bool],
) -> Ended {
    let blocks = source.blocks();
    let n = source.map.signals.len();
    // `def_` flags already up on the PLC stay up: raised by an earlier run of
    // the monitor, they are lowered only by people (after a repair).
    let on_plc = match read_flags(source, ctx).await {
        Ok(v) => v,
        Err(t) => return trouble(t),
    };
    for (kept, &up) in adopted.iter_mut().zip(&on_plc) {
        *kept |= up;
    }
    let found: Vec<String> = source
        .flags
        .iter()
        .zip(adopted.iter())
        .filter(|(_, up)| **up)
        .map(|(f, _)| f.0.clone())
        .collect();
    if !found.is_empty() && link.items.send(Item::FoundRaised(found)).await.is_err() {
        return Ended::Gone;
    }
    // Then every flag: the PLC may have restarted and forgotten them.
    let mut written: Vec<Option<bool>> = vec![None; source.flags.len()];
    if let Err(t) = write_flags(source, ctx, link, &mut written, adopted).await {
        return trouble(t);
    }
    let mut values: Option<Vec<bool>> = None;
    // Polls are paced by the operating system's clock on this source's own
    // thread: the runtime's timers tick by the millisecond, which at a high
    // `--speed` would now and then skip a poll and merge two scans' edges.
    let mut next = std::time::Instant::now();
    loop {
        match link.flags.has_changed() {
            Err(_) => return Ended::Gone,
            Ok(true) => {
                if let Err(t) = write_flags(source, ctx, link, &mut written, adopted).await {
                    return trouble(t);
                }
            }
            Ok(false) => {}
        }
        let now = std::time::Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
        // Missed polls are skipped, not made up in a burst.
        next = (next + source.period).max(std::time::Instant::now());
        let t = clock.now();
        let read = match poll(source, &blocks, n, ctx).await {
            Ok(v) => v,
            Err(t) => return trouble(t),
        };
        *backoff = BACKOFF_FIRST;
        let item = match values.as_mut() {
            None => {
                values = Some(read.clone());
                Item::Start(t, read)
            }
            Some(old) => {
                let events: Vec<Event> = read
                    .iter()
                    .zip(old.iter_mut())
                    .enumerate()
                    .filter(|(_, (new, old))| *new != *old)
                    .map(|(i, (&new, old))| {
                        *old = new;
                        Event {
                            t,
                            signal: SignalId(i as u32),
                            value: new,
                        }
                    })
                    .collect();
                if events.is_empty() {
                    continue;
                }
                Item::Scan(events)
            }
        };
        if link.items.send(item).await.is_err() {
            return Ended::Gone;
        }
    }
}

fn trouble(t: Trouble) -> Ended {
    match t {
        Trouble::Connection(m) => Ended::Lost(m),
        Trouble::Refused(m) => Ended::Refused(m),
    }
}

/// Reads every mapped signal.
async fn poll(
    source: &ModbusSource,
    blocks: &[Block],
    n: usize,
    ctx: &mut Context,
) -> Result<Vec<bool>, Trouble> {
    let mut inputs: Vec<(u16, Vec<bool>)> = Vec::with_capacity(blocks.len());
    let mut coils: Vec<(u16, Vec<bool>)> = Vec::with_capacity(blocks.len());
    for b in blocks {
        let (what, r) = match b.table {
            ModbusTable::DiscreteInput => (
                "reading discrete inputs",
                tokio::time::timeout(REPLY_TIMEOUT, ctx.read_discrete_inputs(b.from, b.count))
                    .await,
            ),
            ModbusTable::Coil => (
                "reading coils",
                tokio::time::timeout(REPLY_TIMEOUT, ctx.read_coils(b.from, b.count)).await,
            ),
        };
        let what = format!(
            "{what} {}-{}",
            b.from,
            u32::from(b.from) + u32::from(b.count) - 1
        );
        let bits = call(&what, r)?;
        if bits.len() < usize::from(b.count) {
            return Err(Trouble::Connection(format!(
                "{what}: {} bits in the reply, {} asked",
                bits.len(),
                b.count
            )));
        }
        match b.table {
            ModbusTable::DiscreteInput => inputs.push((b.from, bits)),
            ModbusTable::Coil => coils.push((b.from, bits)),
        }
    }
    let bit = |runs: &[(u16, Vec<bool>)], a: u16| {
        runs.iter()
            .find(|(from, bits)| a >= *from && usize::from(a - from) < bits.len())
            .is_some_and(|(from, bits)| bits[usize::from(a - from)])
    };
    Ok((0..n)
        .map(|i| {
            let (table, a) = source.map.signals[i];
            match table {
                ModbusTable::DiscreteInput => bit(&inputs, a),
                ModbusTable::Coil => bit(&coils, a),
            }
        })
        .collect())
}

/// Reads the flag coils; only `def_` flags count as up (a `suspect_` flag
/// follows the diagnosers' present doubts, not an earlier run's).
async fn read_flags(source: &ModbusSource, ctx: &mut Context) -> Result<Vec<bool>, Trouble> {
    let mut up = vec![false; source.flags.len()];
    for (i, (name, coil)) in source.flags.iter().enumerate() {
        if !name.starts_with("def_") {
            continue;
        }
        let r = tokio::time::timeout(REPLY_TIMEOUT, ctx.read_coils(*coil, 1)).await;
        let bits = call(&format!("reading flag {name} from coil {coil}"), r)?;
        up[i] = bits.first().copied().unwrap_or(false);
    }
    Ok(up)
}

/// Writes the flag coils whose value differs from the one last written; a
/// flag found raised on the PLC is written up whatever the image says.
async fn write_flags(
    source: &ModbusSource,
    ctx: &mut Context,
    link: &mut Link,
    written: &mut [Option<bool>],
    adopted: &[bool],
) -> Result<(), Trouble> {
    let mut image = link.flags.borrow_and_update().clone();
    for (up, &kept) in image.iter_mut().zip(adopted) {
        *up |= kept;
    }
    let mut wrote = Vec::new();
    let mut any = false;
    for ((name, coil), (&up, last)) in source
        .flags
        .iter()
        .zip(image.iter().zip(written.iter_mut()))
    {
        if *last == Some(up) {
            continue;
        }
        let r = tokio::time::timeout(REPLY_TIMEOUT, ctx.write_single_coil(*coil, up)).await;
        call(&format!("writing flag {name} to coil {coil}"), r)?;
        *last = Some(up);
        any = true;
        if up {
            wrote.push(name.clone());
        }
    }
    if any {
        let _ = link.items.send(Item::FlagsWritten(wrote)).await;
    }
    Ok(())
}
