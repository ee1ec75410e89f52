//! `gardefou monitor`: online diagnosis beside a PLC. Events come from a
//! [`source::Source`] as they happen (Modbus TCP, SocketCAN, a replayed log,
//! JSON lines on stdin); every part's diagnoser reads them. Verdict changes go
//! out as JSON lines (SPEC §3), the flags they raise go back to the PLC
//! (Modbus), and `--http` serves `/status` and `/metrics`.
//!
//! **Event time.** The diagnosers run on the source's clock: the time each
//! scan was seen, not the time it arrived. A live source also sends
//! watermarks ([`source::Item::Watermark`]): how far its view of the plant is
//! complete. A deadline fires only once a watermark has passed it, since only
//! then is the missing edge evidence. So a late reply, a paused producer or a
//! flood delays a verdict and never changes it: the verdicts equal `diagnose`
//! on the same events. When the watermark falls behind the live clock by more
//! than `--max-lag` of wall time, the plant counts as *not observed*
//! (`/status`, `/metrics`, a warning) until it catches up.
//!
//! A replay knows its next scan ahead: its deadlines fire at their own time on
//! a clock mapped to the wall clock (`--speed`), before the next scan.
//!
//! When a live source loses the plant (a dropped connection), the watermark
//! stays where it was until the plant is seen again; the diagnosers then
//! start again from the values read, with every clock unknown: what happened
//! in the gap is unknown. Flags already raised stay raised and are written
//! again. A `def_` flag goes up only once its verdict has held for
//! `--confirm` beyond the watermark.

pub mod can;
pub mod http;
pub mod modbus;
pub mod source;
pub mod status;
pub mod stdin;

use std::cell::Cell;
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

use crate::flags::FlagBoard;
use diagnoser::Failure;
use source::{FlagImage, Item, Link, Source};
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
    /// timestamp give the initial values (as in an events log). A line with
    /// only a time, `{"t": 1500}`, is a watermark: nothing else happened up
    /// to then (a quiet plant's deadlines fire on it).
    #[arg(long)]
    stdin: bool,
    /// How late (in the source's time) a line on standard input may come
    /// after a later one; later than that, it is a warning and ignored.
    #[arg(long, value_parser = time::parse_duration, default_value = "0ms")]
    lateness: Time,
    /// How long a `def_` flag's verdict must hold, in the source's time beyond
    /// the watermark, before the flag is raised and written to the PLC
    /// (default: one scan period).
    #[arg(long, value_parser = time::parse_duration)]
    confirm: Option<Time>,
    /// Wall time the watermark may lag the live clock before the plant counts
    /// as not observed.
    #[arg(long, value_parser = time::parse_duration, default_value = "1s")]
    max_lag: Time,
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

/// Runs `gardefou monitor`.
pub fn run(args: MonitorArgs) -> Result<(), Failure> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        return Err(Failure::bad("--speed: must be a positive number"));
    }
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&args.model).map_err(Failure::bad)?;
    let diagnoser = PlantDiagnoser::new(
        &plant,
        &model,
        &DiagnoserOptions {
            glitch_max: args.glitch_max,
            // A poll may see two of the PLC's scans at once; a log or a
            // producer on stdin gives the scans as they were.
            polled: args.modbus.is_some() || args.can.is_some(),
        },
    )
    .map_err(|e| Failure::bad(format!("{}: {e}", args.model.display())))?;
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
    // A replay is opened before the runtime starts: its reader (Parquet's
    // among them) may run a runtime of its own.
    let replay = match args.replay.clone() {
        Some(path) => Some((
            source::Replay::open(path.clone(), args.format, unit, &plant)?,
            format!("replay {}", path.display()),
        )),
        None => None,
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    let result = runtime.block_on(async {
        let (source, name): (Box<dyn Source>, String) = if let Some((r, name)) = replay {
            (Box::new(r), name)
        } else if let Some(addr) = &args.modbus {
            let s = modbus::ModbusSource::new(addr, args.unit_id, &plant, args.speed)?;
            (Box::new(s), format!("modbus {addr}"))
        } else if let Some(iface) = &args.can {
            let s = can::CanSource::new(iface, &plant, args.speed)?;
            (Box::new(s), format!("can {iface}"))
        } else {
            let s = stdin::Stdin {
                plant: plant.clone(),
                unit,
                lateness: args.lateness,
                speed: args.speed,
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
            v.json_line(self.time, None)
        };
        if let Err(e) = writeln!(self.out, "{text}").and_then(|()| self.out.flush()) {
            self.error = Some(e);
        }
    }
}

/// Where verdicts go: the output, the flags, the status and the PLC.
struct Outputs {
    writer: Writer,
    board: FlagBoard,
    status: Arc<Mutex<Status>>,
    flag_tx: watch::Sender<FlagImage>,
    plant: Plant,
    /// When the evidence of the verdicts being computed came: a scan's or a
    /// watermark's arrival, a replayed deadline's expiry (for the latency).
    evidence: Cell<Instant>,
}

impl Outputs {
    fn emit(&mut self, v: Verdict) {
        self.writer.line(&v);
        let changed = self.board.update(&v);
        let Ok(mut s) = self.status.lock() else {
            return;
        };
        s.verdict(&v);
        s.latency.record(self.evidence.get().elapsed());
        drop(s);
        if changed {
            self.publish_flags();
        }
    }

    /// Raises the `def_` flags whose verdict has held long enough by `upto`,
    /// and says why each goes up.
    fn confirm(&mut self, upto: Time) {
        let up = self.board.confirm(upto);
        if up.is_empty() {
            return;
        }
        let time = self.writer.time;
        for c in &up {
            eprintln!(
                "monitor: {} raised at {}: the verdict of {} held since {} ({})",
                c.flag,
                time.format(upto),
                c.part,
                time.format(c.since),
                c.evidence
            );
        }
        self.publish_flags();
    }

    /// The flags up now, to the status and to the PLC.
    fn publish_flags(&mut self) {
        self.status(|s| s.set_flags(self.board.raised(), self.board.suspects()));
        let _ = self.flag_tx.send(self.board.image(&self.plant));
    }

    fn status(&self, f: impl FnOnce(&mut Status)) {
        if let Ok(mut s) = self.status.lock() {
            f(&mut s);
        }
    }

    fn warn(&self, m: &str) {
        eprintln!("warning: {m}");
        self.status(|s| s.warnings += 1);
    }
}

/// The diagnosers fed in event time.
struct Run {
    diagnoser: PlantDiagnoser,
    out: Outputs,
    speed: f64,
    /// Maps the source's time to the wall clock: `(t, when t was now)`.
    anchor: Option<(Time, Instant)>,
    started: bool,
    /// The source has lost the plant: no deadline may fire.
    blind: bool,
    lost_at: Option<Time>,
    /// The source's view is complete up to this time (inclusive).
    watermark: Option<Time>,
    /// Whether the watermark keeps up with the live clock.
    observed: bool,
}

impl Run {
    /// The source's time now, on the live clock.
    fn live_now(&self) -> Option<Time> {
        self.anchor
            .map(|(t, at)| t + (at.elapsed().as_nanos() as f64 * self.speed) as Time)
    }

    /// The wall instant of the source's time `t`.
    fn wall_of(&self, t: Time) -> Option<Instant> {
        self.anchor
            .map(|(t0, at)| at + Duration::from_nanos(((t - t0).max(0) as f64 / self.speed) as u64))
    }

    /// Advances the diagnosers to `t` (deadlines up to it fire) and raises
    /// the flags confirmed by then.
    fn advance_to(&mut self, t: Time) {
        let out = &mut self.out;
        self.diagnoser.advance_to(t, &mut |v| out.emit(v));
        self.out.confirm(self.diagnoser.now());
    }

    fn start(&mut self, t0: Time, initial: &[bool]) {
        if self.started {
            let gap = self.lost_at.map_or(String::new(), |l| {
                format!(" after a gap of {:.3} s", (t0 - l) as f64 / 1e9)
            });
            eprintln!(
                "monitor: plant seen again{gap}; the diagnosers start again from the values read now, with every clock unknown; flags raised stay raised"
            );
        }
        self.diagnoser.start(t0, initial);
        self.anchor = Some((t0, Instant::now()));
        self.watermark = Some(t0);
        self.started = true;
        self.blind = false;
        self.lost_at = None;
        self.out.status(|s| {
            s.connected = true;
            s.observed = true;
            s.t = Some(t0);
        });
        self.observed = true;
    }

    /// One complete scan (its time is also a watermark).
    fn scan(&mut self, scan: Vec<Event>, arrived: Instant) {
        let Some(t) = scan.first().map(|e| e.t) else {
            return;
        };
        if !self.started || self.blind {
            self.out.warn("events before the initial values ignored");
            return;
        }
        if let Some(w) = self.watermark
            && t <= w
        {
            let m = format!(
                "{} events at {} are behind the watermark {}: ignored",
                scan.len(),
                self.out.writer.time.format(t),
                self.out.writer.time.format(w),
            );
            self.out.warn(&m);
            self.out.status(|s| s.late += 1);
            return;
        }
        self.out.evidence.set(arrived);
        if self.live_now().is_some_and(|now| t > now) {
            self.anchor = Some((t, Instant::now()));
        }
        // Deadlines before this scan fire first.
        self.advance_to(t - 1);
        let n = scan.len() as u64;
        let out = &mut self.out;
        for e in scan {
            self.diagnoser.push(e, &mut |v| out.emit(v));
        }
        self.advance_to(t);
        self.watermark = Some(t);
        let took = arrived.elapsed();
        self.out.status(|s| {
            s.events += n;
            s.t = Some(t);
            s.evidence.record(took);
        });
    }

    /// The source has shown everything up to `w`: deadlines up to it fire.
    fn watermark(&mut self, w: Time) {
        if !self.started || self.blind || self.watermark.is_some_and(|old| w <= old) {
            return;
        }
        let arrived = Instant::now();
        self.out.evidence.set(arrived);
        self.advance_to(w);
        self.watermark = Some(w);
        let took = arrived.elapsed();
        self.out.status(|s| s.evidence.record(took));
    }

    fn lost(&mut self, t: Time, why: &str) {
        // The watermark stays: what happened since it is unknown.
        self.blind = true;
        self.lost_at = Some(t);
        self.out.warn(&format!(
            "{why}; no deadline fires until the plant is seen again"
        ));
        self.out.status(|s| {
            s.connected = false;
            s.gaps += 1;
        });
    }

    /// Whether the watermark keeps up with the live clock (live sources).
    fn check_lag(&mut self, max_lag: Duration) {
        let (Some(now), Some(w)) = (self.live_now(), self.watermark) else {
            return;
        };
        if !self.started || self.blind {
            return;
        }
        let lag = Duration::from_nanos(((now - w).max(0) as f64 / self.speed) as u64);
        let observed = lag <= max_lag;
        if observed == self.observed {
            return;
        }
        self.observed = observed;
        if observed {
            eprintln!("monitor: plant observed again: the source caught up with the live clock");
        } else {
            self.out.warn(&format!(
                "plant not observed: the source has shown nothing after {} for {:.3} s; no deadline fires until it catches up",
                self.out.writer.time.format(w),
                lag.as_secs_f64()
            ));
        }
        self.out.status(|s| s.observed = observed);
    }

    fn found_raised(&mut self, flags: &[String]) {
        eprintln!(
            "monitor: flags already up on the PLC, kept raised: {}",
            flags.join(" ")
        );
        for f in flags {
            self.out.board.adopt(f);
        }
        self.out.publish_flags();
    }

    /// Takes in one item from a live source.
    fn item(&mut self, item: Item) -> Result<(), Failure> {
        match item {
            Item::Start(t0, initial) => self.start(t0, &initial),
            Item::Scan(scan) => self.scan(scan, Instant::now()),
            Item::Watermark(w) => self.watermark(w),
            Item::Lost(t, why) => self.lost(t, &why),
            Item::FoundRaised(flags) => self.found_raised(&flags),
            Item::FlagsWritten(up) => {
                if !up.is_empty() {
                    eprintln!("monitor: flags written to the PLC: {}", up.join(" "));
                }
                self.out.status(|s| s.flag_writes += 1);
            }
            Item::Late(m) => {
                self.out.warn(&m);
                self.out.status(|s| s.late += 1);
            }
            Item::FarAhead(m) => {
                self.out.warn(&m);
                self.out.status(|s| s.far_ahead += 1);
            }
            Item::Warning(w) => self.out.warn(&w),
            Item::Fatal(f) => return Err(f),
        }
        Ok(())
    }
}

async fn monitor(
    args: &MonitorArgs,
    plant: Plant,
    diagnoser: PlantDiagnoser,
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
    let confirmation = args.confirm.unwrap_or(plant.scan_period);
    let mut run = Run {
        diagnoser,
        out: Outputs {
            writer: Writer {
                out: output,
                terminal,
                time: time_format,
                error: None,
            },
            board: FlagBoard::with_confirmation(confirmation),
            status: status.clone(),
            flag_tx,
            plant,
            evidence: Cell::new(Instant::now()),
        },
        speed: args.speed,
        anchor: None,
        started: false,
        blind: false,
        lost_at: None,
        watermark: None,
        observed: true,
    };
    let stop_at = args
        .duration
        .map(|d| Instant::now() + Duration::from_nanos(d.max(0) as u64));
    let max_lag = Duration::from_nanos(args.max_lag.max(0) as u64);
    let mut lag_check = tokio::time::interval(Duration::from_millis(100));
    lag_check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // A replayed scan received, waiting for its time on the live clock.
    let mut pending: Option<(Vec<Event>, Instant)> = None;
    let mut terminate = terminate_signal()?;
    let stopped = loop {
        let pending_t = pending.as_ref().and_then(|p| p.0.first()).map(|e| e.t);
        // A replay's deadline fires at its own time, if before the next scan.
        let deadline = match (run.diagnoser.next_deadline(), pending_t) {
            (Some(d), Some(t)) if d < t => run.wall_of(d).map(|at| (d, at)),
            _ => None,
        };
        let due = pending.as_ref().map(|p| p.1);
        let far = Instant::now() + Duration::from_secs(86_400);
        tokio::select! {
            biased;
            _ = tokio::signal::ctrl_c() => break Some("interrupted"),
            _ = terminate.recv() => break Some("terminated"),
            () = tokio::time::sleep_until(stop_at.unwrap_or(far)), if stop_at.is_some() => {
                break Some("--duration reached");
            }
            () = wake_at(deadline.map_or(far, |d| d.1)), if deadline.is_some() => {
                if let Some((d, at)) = deadline {
                    run.out.evidence.set(at);
                    // Past the deadline, so that the loop always moves on.
                    run.advance_to(d.max(run.diagnoser.now() + 1));
                    run.out.status(|s| s.evidence.record(at.elapsed()));
                }
            }
            () = wake_at(due.unwrap_or(far)), if due.is_some() => {
                if let Some((scan, at)) = pending.take() {
                    run.scan(scan, at);
                }
            }
            _ = lag_check.tick(), if !knows_ahead => run.check_lag(max_lag),
            item = rx.recv(), if pending.is_none() => {
                let Some(item) = item else { break None };
                match item {
                    Item::Scan(scan) if knows_ahead && run.started => {
                        let t = scan.first().map_or(0, |e| e.t);
                        let at = run.wall_of(t).unwrap_or_else(Instant::now);
                        pending = Some((scan, at));
                    }
                    item => run.item(item)?,
                }
            }
        }
        let error = run.out.writer.error.take();
        if let Some(e) = error {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(Failure::output(e));
        }
        // Whatever the input, the runtime gets its turn now and then, so that
        // signals are always heard.
        tokio::task::consume_budget().await;
    };
    drop(rx);
    finish(&mut run, stopped, knows_ahead)
}

/// Ends the run: deadlines up to the watermark (a replay: up to its clock, or
/// its last scan) still count; then the summary on stderr (also when the
/// plant was never seen).
fn finish(run: &mut Run, stopped: Option<&str>, knows_ahead: bool) -> Result<(), Failure> {
    let last = run.watermark.unwrap_or(0);
    let end = match (stopped, knows_ahead, run.live_now()) {
        (Some(_), true, Some(now)) if !run.blind => now.max(last),
        _ => last,
    };
    run.out.evidence.set(Instant::now());
    let out = &mut run.out;
    let summary = if run.started {
        run.diagnoser.finish(end, &mut |v| out.emit(v))
    } else {
        Vec::new()
    };
    run.out.confirm(end);
    let error = run.out.writer.error.take();
    if let Some(e) = error
        && e.kind() != std::io::ErrorKind::BrokenPipe
    {
        return Err(Failure::output(e));
    }
    let flagged: Vec<String> = summary.iter().flat_map(|p| p.flags.clone()).collect();
    let mut flags: Vec<String> = run.out.board.raised().to_vec();
    for f in flagged {
        if !flags.contains(&f) {
            flags.push(f);
        }
    }
    let (events, lines, warnings, labels, evidence) = run
        .out
        .status
        .lock()
        .map(|s| {
            (
                s.events,
                s.verdict_changes,
                s.warnings,
                s.latency.clone(),
                s.evidence.clone(),
            )
        })
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
