//! `gardefou monitor`: online diagnosis beside a PLC. Events come from a
//! [`source::Source`] as they happen (Modbus TCP, SocketCAN, a replayed log,
//! JSON lines on stdin); every part's diagnoser reads them, and deadlines fire
//! on time from timers, with no new event. Verdict changes go out as JSON lines
//! (SPEC §3), the flags they raise go back to the PLC (Modbus), and `--http`
//! serves `/status` and `/metrics`.
//!
//! Time: the diagnosers run on the source's clock (the log's time, or a live
//! source's wall clock). A live clock maps it to the wall clock: `log_now =
//! anchor_log + (wall − anchor_wall) × speed`, re-anchored whenever an event
//! arrives ahead of it, so a late source never makes a deadline fire early.
//!
//! When a live source loses the plant (a dropped connection), no deadline fires
//! until it sees the plant again, since an event could be happening unseen.
//! The diagnosers then start again from the values read: what happened in the
//! gap is unknown. Flags already raised stay raised and are written again.

pub mod can;
pub mod http;
pub mod modbus;
pub mod source;
pub mod status;

use std::cell::{Cell, RefCell};
use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use clap::Args;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{Event, Plant, Time, TimeFormat, TimeUnit, time};
use learning::ingest::LogFormat;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use crate::Failure;
use crate::diagnose::verdict_line;
use crate::flags::FlagBoard;
use source::{Item, Link, Source};
use status::Status;

/// Arguments of `gardefou monitor`.
#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["modbus", "can", "replay", "stdin"])))]
pub struct MonitorArgs {
    /// Plant file: signals, parts, faults, partitions and the register map.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    model: PathBuf,
    /// Poll a PLC over Modbus TCP at the scan period (addresses: `[modbus]` of
    /// the plant file, or the default map) and write the flags back to it.
    #[arg(long, value_name = "HOST:PORT")]
    modbus: Option<String>,
    /// Read CANopen (CiA 401) PDOs from a SocketCAN interface, decoded with the
    /// plant file's `[can]` bit mapping. `udp:HOST:PORT` reads the same frames
    /// from UDP datagrams instead (16-byte SocketCAN `can_frame`s).
    #[arg(long, value_name = "IFACE")]
    can: Option<String>,
    /// Replay a log (any form) at its recorded pace, times `--speed`.
    #[arg(long, value_name = "LOG")]
    replay: Option<PathBuf>,
    /// Read events as JSON lines on standard input:
    /// `{"t": 1200, "signal": "C4", "value": 1}`. The lines of the first
    /// timestamp give the initial values (as in an events log).
    #[arg(long)]
    stdin: bool,
    /// Serve `/status` (JSON) and `/metrics` (Prometheus) on this address.
    #[arg(long, value_name = "ADDR")]
    http: Option<SocketAddr>,
    /// Write the verdict lines to this file instead of standard output
    /// (appended, so an earlier run's lines are kept).
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// How much faster than real time the source's clock runs (a replay, or a
    /// simulated PLC run with `simulate --speed`).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Stop after this long, in wall-clock time (e.g. `10min`).
    #[arg(long, value_parser = time::parse_duration)]
    duration: Option<Time>,
    /// Modbus unit identifier of the PLC.
    #[arg(long, default_value_t = 1)]
    unit_id: u8,
    /// Log form for `--replay` (default: detected).
    #[arg(long)]
    format: Option<LogFormat>,
    /// Unit of numeric timestamps (default: the plant file's).
    #[arg(long)]
    time_unit: Option<TimeUnit>,
    /// Longest an unexpected sensor edge shows before the sensor reads its real
    /// value again.
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    glitch_max: Time,
}

fn bad(e: impl std::fmt::Display) -> Failure {
    Failure::BadInput(e.to_string())
}

/// Runs `gardefou monitor`.
pub fn run(args: MonitorArgs) -> Result<(), Failure> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        return Err(bad("--speed: must be a positive number"));
    }
    let plant = Plant::from_path(&args.plant).map_err(bad)?;
    let model = Model::from_path(&args.model).map_err(bad)?;
    let diagnoser = PlantDiagnoser::new(
        &plant,
        &model,
        &DiagnoserOptions {
            glitch_max: args.glitch_max,
        },
    )
    .map_err(|e| bad(format!("{}: {e}", args.model.display())))?;
    let unit = args.time_unit.unwrap_or(plant.time_unit);
    let output: Box<dyn Write> = match &args.output {
        Some(path) => Box::new(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|e| Failure::Io(format!("{}: {e}", path.display())))?,
        ),
        None => Box::new(std::io::stdout()),
    };
    let terminal = args.output.is_none() && std::io::stdout().is_terminal();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    let result = runtime.block_on(async {
        let (source, name): (Box<dyn Source>, String) = if let Some(path) = args.replay.clone() {
            let name = format!("replay {}", path.display());
            (
                Box::new(source::Replay::open(path, args.format, unit, &plant)?),
                name,
            )
        } else if let Some(addr) = &args.modbus {
            let s = modbus::ModbusSource::new(addr, args.unit_id, &plant, args.speed)?;
            (Box::new(s), format!("modbus {addr}"))
        } else if let Some(iface) = &args.can {
            let s = can::CanSource::new(iface, &plant, args.speed)?;
            (Box::new(s), format!("can {iface}"))
        } else {
            let s = source::Stdin {
                plant: plant.clone(),
                unit,
            };
            (Box::new(s), "stdin".to_string())
        };
        monitor(&args, plant, diagnoser, source, name, output, terminal).await
    });
    // A read of standard input cannot be cancelled: waiting for it would keep
    // a stopped monitor alive until the writer closes its end.
    runtime.shutdown_background();
    result
}

/// How the monitor writes verdict lines.
struct Writer {
    out: Box<dyn Write>,
    terminal: bool,
    time: TimeFormat,
    error: Option<std::io::Error>,
}

impl Writer {
    fn line(&mut self, v: &Verdict) {
        if self.error.is_some() {
            return;
        }
        let text = if self.terminal {
            readable(v, self.time)
        } else {
            verdict_line(v, self.time, None)
        };
        if let Err(e) = writeln!(self.out, "{text}").and_then(|()| self.out.flush()) {
            self.error = Some(e);
        }
    }
}

async fn monitor(
    args: &MonitorArgs,
    plant: Plant,
    mut diagnoser: PlantDiagnoser,
    source: Box<dyn Source>,
    source_name: String,
    output: Box<dyn Write>,
    terminal: bool,
) -> Result<(), Failure> {
    let time_format = source.time_format();
    let knows_ahead = source.knows_ahead();
    let status = Arc::new(Mutex::new(Status::new(&plant, source_name, time_format)));
    if let Some(addr) = args.http {
        http::serve(addr, status.clone()).await?;
    }
    // Room for a replay to read well ahead of its pace.
    let (tx, mut rx) = mpsc::channel::<Item>(16_384);
    let (flag_tx, flag_rx) = watch::channel(vec![false; plant.flags().len()]);
    source.spawn(Link {
        items: tx,
        flags: flag_rx,
    });

    let writer = RefCell::new(Writer {
        out: output,
        terminal,
        time: time_format,
        error: None,
    });
    let board = RefCell::new(FlagBoard::default());
    // When the evidence of the verdicts being computed came: an event's
    // arrival or a deadline's expiry (for the latency).
    let evidence = Cell::new(Instant::now());
    let mut emit = |v: Verdict| {
        writer.borrow_mut().line(&v);
        let mut b = board.borrow_mut();
        let changed = b.update(&v);
        let Ok(mut s) = status.lock() else { return };
        s.verdict(&v);
        s.latency.record(evidence.get().elapsed());
        if changed {
            s.set_flags(b.raised(), b.suspects());
            let _ = flag_tx.send(b.image(&plant));
        }
    };
    let with_status = |f: &mut dyn FnMut(&mut Status)| {
        if let Ok(mut s) = status.lock() {
            f(&mut s);
        }
    };

    let stop_at = args
        .duration
        .map(|d| Instant::now() + Duration::from_nanos(d.max(0) as u64));
    let speed = args.speed;
    // The live clock: `anchor` maps a log time to a wall instant.
    let mut anchor: Option<(Time, Instant)> = None;
    let wall_of = |anchor: (Time, Instant), t: Time| -> Instant {
        let ahead = ((t - anchor.0).max(0) as f64 / speed) as u64;
        anchor.1 + Duration::from_nanos(ahead)
    };
    let log_now = |anchor: (Time, Instant)| -> Time {
        anchor.0 + (anchor.1.elapsed().as_nanos() as f64 * speed) as Time
    };
    let mut started = false;
    // The source has lost the plant: no deadline may fire.
    let mut blind = false;
    let mut lost_at: Option<Time> = None;
    let mut last_t: Option<Time> = None;
    let mut warnings = 0u64;
    let mut events = 0u64;
    let warn = |m: String, warnings: &mut u64| {
        *warnings += 1;
        eprintln!("warning: {m}");
        with_status(&mut |s| s.warnings += 1);
    };
    // A scan received, waiting for its time on the live clock (replay).
    let mut pending: Option<(Vec<Event>, Instant)> = None;
    // The pending scan's time has come.
    let mut ready = false;
    let mut terminate = terminate_signal()?;
    let stopped = loop {
        // The next deadline, as a wall instant.
        let deadline = match (anchor, diagnoser.next_deadline(), blind) {
            (Some(a), Some(d), false) => Some(wall_of(a, d)),
            _ => None,
        };
        let pending_t = pending.as_ref().and_then(|s| s.0.first()).map(|e| e.t);
        let due = match (pending_t, anchor) {
            (Some(t), Some(a)) if knows_ahead => Some(wall_of(a, t)),
            (Some(_), _) => pending.as_ref().map(|p| p.1),
            (None, _) => None,
        };
        // A live source's deadline fires when the wall clock passes it. A
        // replay knows what comes next: its deadline fires only before the
        // next scan (once the source ends, `finish` fires the rest).
        let deadline_first = match (deadline, knows_ahead) {
            (None, _) => false,
            (Some(d), false) => due.is_none_or(|due| d < due),
            (Some(_), true) => diagnoser
                .next_deadline()
                .zip(pending_t)
                .is_some_and(|(d, t)| d < t),
        };
        let far = Instant::now() + Duration::from_secs(86_400);
        tokio::select! {
            biased;
            _ = tokio::signal::ctrl_c() => break Some("interrupted"),
            _ = terminate.recv() => break Some("terminated"),
            () = tokio::time::sleep_until(stop_at.unwrap_or(far)), if stop_at.is_some() => {
                break Some("--duration reached");
            }
            () = wake_at(deadline.unwrap_or(far)), if deadline_first => {
                if let (Some(d), Some(at)) = (diagnoser.next_deadline(), deadline) {
                    evidence.set(at);
                    diagnoser.advance_to(d, &mut emit);
                    with_status(&mut |s| s.evidence.record(at.elapsed()));
                }
            }
            () = wake_at(due.unwrap_or(far)), if due.is_some() => ready = true,
            item = rx.recv(), if pending.is_none() => {
                let Some(item) = item else { break None };
                match item {
                    Item::Start(t0, initial) => {
                        if started {
                            let gap = lost_at.map_or(String::new(), |l| {
                                format!(" after a gap of {:.3} s", (t0 - l) as f64 / 1e9)
                            });
                            eprintln!(
                                "monitor: plant seen again{gap}; the diagnosers start again from the values read now, flags raised stay raised"
                            );
                        }
                        diagnoser.start(t0, &initial);
                        anchor = Some((t0, Instant::now()));
                        last_t = Some(t0);
                        started = true;
                        blind = false;
                        lost_at = None;
                        with_status(&mut |s| {
                            s.connected = true;
                            s.t = Some(t0);
                        });
                    }
                    Item::Scan(_) if !started || blind => {
                        warn("events before the initial values ignored".into(), &mut warnings);
                    }
                    Item::Scan(scan) => {
                        let t = scan.first().map_or(Time::MIN, |e| e.t);
                        if last_t.is_some_and(|l| t < l) {
                            warn(
                                format!(
                                    "time went backwards ({} after {}): {} events ignored",
                                    time_format.format(t),
                                    last_t.map_or_else(String::new, |l| time_format.format(l)),
                                    scan.len()
                                ),
                                &mut warnings,
                            );
                        } else if !scan.is_empty() {
                            pending = Some((scan, Instant::now()));
                            // A live scan is due as soon as it arrives.
                            ready = !knows_ahead;
                        }
                    }
                    Item::Lost(t, why) => {
                        // Deadlines already past still count: they passed
                        // while the plant was seen.
                        if let Some(l) = last_t
                            && t > l
                        {
                            evidence.set(Instant::now());
                            diagnoser.advance_to(t, &mut emit);
                            last_t = Some(t);
                        }
                        blind = true;
                        lost_at = Some(t);
                        warn(
                            format!("{why}; no deadline fires until the plant is seen again"),
                            &mut warnings,
                        );
                        with_status(&mut |s| {
                            s.connected = false;
                            s.gaps += 1;
                        });
                    }
                    Item::FoundRaised(flags) => {
                        eprintln!(
                            "monitor: flags already up on the PLC, kept raised: {}",
                            flags.join(" ")
                        );
                        let mut b = board.borrow_mut();
                        for f in &flags {
                            b.adopt(f);
                        }
                        let image = b.image(&plant);
                        with_status(&mut |s| s.set_flags(b.raised(), b.suspects()));
                        let _ = flag_tx.send(image);
                    }
                    Item::FlagsWritten(up) => {
                        if !up.is_empty() {
                            eprintln!("monitor: flags written to the PLC: {}", up.join(" "));
                        }
                        with_status(&mut |s| s.flag_writes += 1);
                    }
                    Item::Warning(w) => warn(w, &mut warnings),
                    Item::Fatal(f) => return Err(f),
                }
            }
        }
        if ready
            && let Some((scan, arrived)) = pending.take()
            && let Some(t) = scan.first().map(|e| e.t)
        {
            ready = false;
            evidence.set(if knows_ahead {
                due.unwrap_or(arrived)
            } else {
                arrived
            });
            if let Some(a) = anchor
                && t > log_now(a)
            {
                anchor = Some((t, Instant::now()));
            }
            // Deadlines before this scan fire first.
            if let Some(l) = last_t
                && t > l
            {
                diagnoser.advance_to(t - 1, &mut emit);
            }
            let n = scan.len() as u64;
            events += n;
            for e in scan {
                diagnoser.push(e, &mut emit);
            }
            diagnoser.advance_to(t, &mut emit);
            last_t = Some(t);
            let took = evidence.get().elapsed();
            with_status(&mut |s| {
                s.events += n;
                s.t = Some(t);
                s.evidence.record(took);
            });
        }
        let error = writer.borrow_mut().error.take();
        if let Some(e) = error {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(Failure::output(e));
        }
    };
    drop(rx);
    if started {
        // Deadlines up to now (or the last event) still count, unless blind.
        let end = match (stopped, anchor, blind) {
            (_, _, true) => last_t.unwrap_or(0),
            (Some(_), Some(a), false) => log_now(a).max(last_t.unwrap_or(a.0)),
            _ => last_t.unwrap_or(0),
        };
        evidence.set(Instant::now());
        let summary = diagnoser.finish(end, &mut emit);
        let error = writer.borrow_mut().error.take();
        if let Some(e) = error
            && e.kind() != std::io::ErrorKind::BrokenPipe
        {
            return Err(Failure::output(e));
        }
        let flagged: Vec<String> = summary.iter().flat_map(|p| p.flags.clone()).collect();
        let b = board.borrow();
        let mut flags: Vec<String> = b.raised().to_vec();
        for f in flagged {
            if !flags.contains(&f) {
                flags.push(f);
            }
        }
        let (lines, labels, evidence) = status
            .lock()
            .map(|s| (s.verdict_changes, s.latency.clone(), s.evidence.clone()))
            .unwrap_or_default();
        eprintln!(
            "monitor {}: {events} events, {lines} verdict changes, {warnings} warnings; flags: {}",
            stopped.unwrap_or("source ended"),
            if flags.is_empty() {
                "none".to_string()
            } else {
                flags.join(" ")
            },
        );
        eprintln!(
            "monitor latency: labels {}; every scan and deadline {}",
            labels.summary(),
            evidence.summary()
        );
    }
    Ok(())
}

/// How close to a wake-up the monitor stops sleeping and polls instead: the
/// runtime's timers have a resolution of a millisecond, too coarse for labels
/// due within one.
const SPIN: Duration = Duration::from_millis(2);

/// Waits until `at`, to the microsecond: a timer for most of the wait, then
/// yields to the runtime (so that events keep being read) until the instant.
async fn wake_at(at: Instant) {
    if let Some(early) = at.checked_sub(SPIN)
        && early > Instant::now()
    {
        tokio::time::sleep_until(early).await;
    }
    while Instant::now() < at {
        tokio::task::yield_now().await;
    }
}

/// SIGTERM, as a stream of signals (a stream that never yields where there is
/// no such signal).
fn terminate_signal() -> Result<Terminate, Failure> {
    #[cfg(unix)]
    {
        tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .map(Terminate)
            .map_err(|e| Failure::Io(format!("cannot watch SIGTERM: {e}")))
    }
    #[cfg(not(unix))]
    {
        Ok(Terminate)
    }
}

#[cfg(unix)]
struct Terminate(tokio::signal::unix::Signal);
#[cfg(not(unix))]
struct Terminate;

impl Terminate {
    async fn recv(&mut self) {
        #[cfg(unix)]
        {
            if self.0.recv().await.is_none() {
                std::future::pending::<()>().await;
            }
        }
        #[cfg(not(unix))]
        std::future::pending::<()>().await
    }
}

/// One verdict change for people: time, part, verdict, labels, flags, reason.
fn readable(v: &Verdict, time: TimeFormat) -> String {
    let flags = if v.flags.is_empty() {
        String::new()
    } else {
        format!(" [{}]", v.flags.join(" "))
    };
    format!(
        "{} {:<16} {:<9} {}{}  {}",
        time.format(v.t),
        v.part,
        serde_json::to_value(v.verdict)
            .ok()
            .and_then(|x| x.as_str().map(str::to_string))
            .unwrap_or_default(),
        v.labels.join(" "),
        flags,
        v.reason
    )
}
