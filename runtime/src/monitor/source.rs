//! Where the monitor's events come from. Every source runs as its own task and
//! sends [`Item`]s over a channel; sources that can write to the PLC (Modbus)
//! also receive the flags to write back, and with `--probe` the probing moves.
//!
//! Live sources work in event time: each scan carries the time the plant was
//! seen, and [`Item::Watermark`] says up to when the source's view is
//! complete. The monitor fires a deadline only once a watermark has passed it,
//! so a slow network or a paused producer delays a verdict and never makes
//! one.

use std::path::Path;

use diagnoser::{Event, Failure, Plant, Time, TimeFormat, TimeUnit};
use logs::{IngestOptions, open};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// What a source sends.
#[derive(Debug)]
pub enum Item {
    /// Every signal's value at `t`: the first values of the run, or the values
    /// read again after a gap (see [`Item::Lost`]).
    Start(Time, Vec<bool>),
    /// One scan: the changes seen at one time, complete: the source has shown
    /// everything up to that time (a watermark at it).
    Scan(Vec<Event>),
    /// The source has shown everything up to this time (inclusive): a
    /// deadline up to it is evidence. Deadlines of a live source fire only
    /// from watermarks, never from the wall clock.
    Watermark(Time),
    /// Data behind the watermark, ignored.
    Late(String),
    /// Data far ahead of the live clock, ignored.
    FarAhead(String),
    /// The source can no longer see the plant (connection lost at `t`): no
    /// deadline may fire until the next [`Item::Start`], since an event could
    /// be happening unseen.
    Lost(Time, String),
    /// `def_` flags found up on the PLC on connecting (raised by an earlier
    /// run): they count as raised.
    FoundRaised(Vec<String>),
    /// Flag coils were written to the PLC; these are the flags written up.
    FlagsWritten(Vec<String>),
    /// Probe coils were written to the PLC and acknowledged: the probing
    /// moves they now ask for.
    ProbesWritten(ProbeImage),
    /// The PLC's filter refused the probing move of this actuator in a scan
    /// (its `_PROBE_REFUSED` coil read 1): a safety constraint forbids it
    /// there. Said once per move.
    ProbeRefused(String),
    /// A problem that does not stop the monitor.
    Warning(String),
    /// A problem that does.
    Fatal(Failure),
}

/// The flags to write back to the PLC: every flag of the plant, in
/// [`Plant::flags`] order, up or down.
pub type FlagImage = Vec<bool>;

/// The probing moves to write to the PLC (`--probe`): per actuator of the
/// plant, in plant-file order, the value asked for, or `None` (no move: its
/// `_PROBE` coil at 0).
pub type ProbeImage = Vec<Option<bool>>;

/// A source's ends of the channels to the monitor.
pub struct Link {
    /// Items to the monitor.
    pub items: mpsc::Sender<Item>,
    /// The flags to write back; changes whenever one goes up or down.
    pub flags: watch::Receiver<FlagImage>,
    /// The probing moves to write (read only by a source that probes).
    pub probes: watch::Receiver<ProbeImage>,
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
    stream: Option<logs::LogStream>,
}

impl Replay {
    /// Opens the log as `options` say; fails if it cannot be read or its
    /// header is wrong.
    pub fn open(path: &Path, options: &IngestOptions, plant: &Plant) -> Result<Replay, Failure> {
        let stream = open(path, plant, options).map_err(|e| Failure::BadInput(e.to_string()))?;
        Ok(Replay {
            unit: options.time_unit,
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
