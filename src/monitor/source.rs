//! Where the monitor's events come from. Every source runs as its own task and
//! sends [`Item`]s over a channel; sources that can write to the PLC (Modbus)
//! also receive the flags to write back.

use std::path::PathBuf;
use std::time::Duration;

use diagnoser::{Event, Plant, Time, TimeFormat, TimeUnit, time};
use learning::ingest::{IngestOptions, LogFormat, open};
use tokio::io::AsyncBufReadExt;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use crate::Failure;

/// What a source sends.
#[derive(Debug)]
pub enum Item {
    /// Every signal's value at `t`: the first values of the run, or the values
    /// read again after a gap (see [`Item::Lost`]).
    Start(Time, Vec<bool>),
    /// One scan: the changes seen at one time.
    Scan(Vec<Event>),
    /// The source can no longer see the plant (connection lost at `t`): no
    /// deadline may fire until the next [`Item::Start`], since an event could
    /// be happening unseen.
    Lost(Time, String),
    /// `def_` flags found up on the PLC on connecting (raised by an earlier
    /// run): they count as raised.
    FoundRaised(Vec<String>),
    /// Flag coils were written to the PLC; these are the flags written up.
    FlagsWritten(Vec<String>),
    /// A problem that does not stop the monitor.
    Warning(String),
    /// A problem that does.
    Fatal(Failure),
}

/// The flags to write back to the PLC: every flag of the plant, in
/// [`Plant::flags`] order, up or down.
pub type FlagImage = Vec<bool>;

/// A source's ends of the channels to the monitor.
pub struct Link {
    /// Items to the monitor.
    pub items: mpsc::Sender<Item>,
    /// The flags to write back; changes whenever one goes up or down.
    pub flags: watch::Receiver<FlagImage>,
}

/// A source of events.
pub trait Source: Send + 'static {
    /// How the source's timestamps are printed.
    fn time_format(&self) -> TimeFormat;

    /// Whether the source knows its next scan before its time comes (a replay).
    /// A deadline then fires only if it falls before that next scan; a live
    /// source's deadline fires when the clock passes it.
    fn knows_ahead(&self) -> bool {
        false
    }

    /// Starts the source on the current runtime (or its own thread). It sends
    /// items until it ends, then drops `link`.
    fn spawn(self: Box<Self>, link: Link);
}

/// The clock of a live source: wall time since the epoch when the source
/// started, then running `speed` times faster than the wall clock.
#[derive(Debug, Clone, Copy)]
pub struct LiveClock {
    origin_t: Time,
    origin: Instant,
    speed: f64,
}

impl LiveClock {
    /// A clock starting now.
    pub fn new(speed: f64) -> LiveClock {
        let origin_t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as Time);
        LiveClock {
            origin_t,
            origin: Instant::now(),
            speed,
        }
    }

    /// The source's time now.
    pub fn now(&self) -> Time {
        self.origin_t + (self.origin.elapsed().as_nanos() as f64 * self.speed) as Time
    }
}

/// A log replayed at its recorded pace (times the monitor's `--speed`).
pub struct Replay {
    /// Unit of numeric timestamps.
    unit: TimeUnit,
    stream: Option<learning::ingest::LogStream>,
}

impl Replay {
    /// Opens the log; fails if it cannot be read or its header is wrong.
    pub fn open(
        path: PathBuf,
        format: Option<LogFormat>,
        unit: TimeUnit,
        plant: &Plant,
    ) -> Result<Replay, Failure> {
        let options = IngestOptions {
            format,
            time_unit: unit,
            ..IngestOptions::default()
        };
        let stream = open(&path, plant, &options).map_err(|e| Failure::BadInput(e.to_string()))?;
        Ok(Replay {
            unit,
            stream: Some(stream),
        })
    }
}

impl Source for Replay {
    fn time_format(&self) -> TimeFormat {
        self.stream
            .as_ref()
            .map_or(TimeFormat::Numeric(self.unit), |s| s.time)
    }

    fn knows_ahead(&self) -> bool {
        true
    }

    fn spawn(mut self: Box<Self>, link: Link) {
        let Some(stream) = self.stream.take() else {
            return;
        };
        let tx = link.items;
        // Reading is blocking: it runs on its own thread.
        std::thread::spawn(move || {
            if tx
                .blocking_send(Item::Start(stream.start, stream.initial.clone()))
                .is_err()
            {
                return;
            }
            let mut scan: Vec<Event> = Vec::new();
            for batch in stream.batches {
                match batch {
                    Ok(events) => {
                        for e in events {
                            if scan.first().is_some_and(|f| f.t != e.t)
                                && tx
                                    .blocking_send(Item::Scan(std::mem::take(&mut scan)))
                                    .is_err()
                            {
                                return;
                            }
                            scan.push(e);
                        }
                    }
                    Err(e) => {
                        let _ = tx.blocking_send(Item::Fatal(Failure::BadInput(e.to_string())));
                        return;
                    }
                }
            }
            if !scan.is_empty() {
                let _ = tx.blocking_send(Item::Scan(scan));
            }
        });
    }
}

/// JSON events on standard input.
pub struct Stdin {
    /// The plant.
    pub plant: Plant,
    /// Unit of numeric timestamps.
    pub unit: TimeUnit,
}

impl Source for Stdin {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Numeric(self.unit)
    }

    fn spawn(self: Box<Self>, link: Link) {
        tokio::spawn(read_stdin(self.plant, self.unit, link.items));
    }
}

/// JSON lines on standard input: `{"t": …, "signal": "C4", "value": 1}`. Lines
/// with one timestamp form a scan, complete when a later timestamp comes or
/// when no line has come for [`SCAN_IDLE`].
async fn read_stdin(plant: Plant, unit: TimeUnit, tx: mpsc::Sender<Item>) {
    let mut lines = tokio::io::BufReader::new(tokio::io::stdin()).lines();
    let mut initial = vec![false; plant.signals.len()];
    let mut first: Option<Time> = None;
    let mut sent = false;
    let mut scan: Vec<Event> = Vec::new();
    let mut number = 0u64;
    loop {
        let next = if scan.is_empty() && sent {
            Ok(lines.next_line().await)
        } else {
            tokio::time::timeout(SCAN_IDLE, lines.next_line()).await
        };
        let line = match next {
            // Quiet: the scan (or the initial values) is complete.
            Err(_) => {
                if !send_start(&tx, first, &mut sent, &mut initial).await
                    || !send_scan(&tx, &mut scan).await
                {
                    return;
                }
                continue;
            }
            Ok(Ok(Some(l))) => l,
            Ok(Ok(None)) => break,
            Ok(Err(e)) => {
                let _ = tx
                    .send(Item::Fatal(Failure::Io(format!("standard input: {e}"))))
                    .await;
                return;
            }
        };
        number += 1;
        if line.trim().is_empty() {
            continue;
        }
        let e = match parse_event(&line, &plant, unit) {
            Ok(e) => e,
            Err(m) => {
                let m = format!("standard input: line {number}: {m}");
                if tx.send(Item::Warning(m)).await.is_err() {
                    return;
                }
                continue;
            }
        };
        match first {
            None => {
                first = Some(e.t);
                initial[e.signal.index()] = e.value;
            }
            Some(t0) if !sent && e.t == t0 => initial[e.signal.index()] = e.value,
            Some(_) => {
                if !send_start(&tx, first, &mut sent, &mut initial).await
                    || scan.first().is_some_and(|f| f.t != e.t) && !send_scan(&tx, &mut scan).await
                {
                    return;
                }
                scan.push(e);
            }
        }
    }
    if send_start(&tx, first, &mut sent, &mut initial).await {
        send_scan(&tx, &mut scan).await;
    }
}

/// Sends the initial values once; false if the monitor has gone.
async fn send_start(
    tx: &mpsc::Sender<Item>,
    first: Option<Time>,
    sent: &mut bool,
    initial: &mut Vec<bool>,
) -> bool {
    match first {
        Some(t0) if !*sent => {
            *sent = true;
            tx.send(Item::Start(t0, std::mem::take(initial)))
                .await
                .is_ok()
        }
        _ => true,
    }
}

/// Sends the scan gathered so far, if any; false if the monitor has gone.
async fn send_scan(tx: &mpsc::Sender<Item>, scan: &mut Vec<Event>) -> bool {
    scan.is_empty() || tx.send(Item::Scan(std::mem::take(scan))).await.is_ok()
}

/// How long standard input may stay quiet before the lines read so far count
/// as a complete scan.
const SCAN_IDLE: Duration = Duration::from_millis(2);

/// One JSON event line.
fn parse_event(line: &str, plant: &Plant, unit: TimeUnit) -> Result<Event, String> {
    let v: serde_json::Value = serde_json::from_str(line).map_err(|e| format!("not JSON: {e}"))?;
    let t = match &v["t"] {
        serde_json::Value::Number(n) => n
            .as_f64()
            .map(|x| (x * unit.nanos() as f64).round() as Time)
            .ok_or("field 't': not a number")?,
        serde_json::Value::String(s) => {
            time::parse_rfc3339(s).ok_or("field 't': not an RFC 3339 time")?
        }
        _ => return Err("field 't': missing".into()),
    };
    let name = v["signal"].as_str().ok_or("field 'signal': missing")?;
    let signal = plant
        .signals
        .id(name)
        .ok_or_else(|| format!("field 'signal': unknown signal '{name}'"))?;
    let value = match &v["value"] {
        serde_json::Value::Bool(b) => *b,
        serde_json::Value::Number(n) if n.as_u64() == Some(0) => false,
        serde_json::Value::Number(n) if n.as_u64() == Some(1) => true,
        _ => return Err("field 'value': expected 0, 1, true or false".into()),
    };
    Ok(Event { t, signal, value })
}
