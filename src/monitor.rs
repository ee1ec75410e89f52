//! `gardefou monitor`: online diagnosis. Events come from a source as they
//! happen; every part's diagnoser reads them, and deadlines fire on time from
//! timers, with no new event. Verdict changes go out as JSON lines (SPEC §3).
//!
//! Time: the diagnosers run on the source's clock (the log's time). A live
//! clock maps it to the wall clock: `log_now = anchor_log + (wall − anchor_wall)
//! × speed`, re-anchored whenever an event arrives ahead of it, so a late
//! source never makes a deadline fire early.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{Event, Plant, Time, TimeFormat, TimeUnit, time};
use learning::ingest::{IngestOptions, LogFormat, open};
use tokio::io::AsyncBufReadExt;
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::Failure;
use crate::diagnose::verdict_line;

/// Arguments of `gardefou monitor`.
#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["replay", "stdin"])))]
pub struct MonitorArgs {
    /// Plant file: signals, parts, faults and partitions.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    model: PathBuf,
    /// Replay a log (any form) at its recorded pace, times `--speed`.
    #[arg(long, value_name = "LOG")]
    replay: Option<PathBuf>,
    /// Read events as JSON lines on standard input:
    /// `{"t": 1200, "signal": "C4", "value": 1}`. The lines of the first
    /// timestamp give the initial values (as in an events log).
    #[arg(long)]
    stdin: bool,
    /// How much faster than real time the source's clock runs.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Stop after this long, in wall-clock time (e.g. `10min`).
    #[arg(long, value_parser = time::parse_duration)]
    duration: Option<Time>,
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

/// What a source sends.
enum Item {
    /// The initial values, at the source's first timestamp.
    Start(Time, Vec<bool>),
    /// One scan: the changes seen at one time.
    Scan(Vec<Event>),
    /// A problem that does not stop the monitor.
    Warning(String),
    /// A problem that does.
    Fatal(Failure),
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
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    runtime.block_on(monitor(args, plant, diagnoser, unit))
}

async fn monitor(
    args: MonitorArgs,
    plant: Plant,
    mut diagnoser: PlantDiagnoser,
    unit: TimeUnit,
) -> Result<(), Failure> {
    let (tx, mut rx) = mpsc::channel::<Item>(1024);
    let time_format;
    if let Some(path) = args.replay.clone() {
        let options = IngestOptions {
            format: args.format,
            time_unit: unit,
            ..IngestOptions::default()
        };
        let stream = open(&path, &plant, &options).map_err(bad)?;
        time_format = stream.time;
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
                        let _ = tx.blocking_send(Item::Fatal(bad(e)));
                        return;
                    }
                }
            }
            if !scan.is_empty() {
                let _ = tx.blocking_send(Item::Scan(scan));
            }
        });
    } else {
        time_format = TimeFormat::Numeric(unit);
        let plant = plant.clone();
        tokio::spawn(read_stdin(plant, unit, tx));
    }

    let terminal = std::io::stdout().is_terminal();
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let lines = std::cell::Cell::new(0u64);
    let write_err: std::cell::RefCell<Option<std::io::Error>> = std::cell::RefCell::new(None);
    let mut emit = |v: Verdict| {
        lines.set(lines.get() + 1);
        if write_err.borrow().is_some() {
            return;
        }
        let text = if terminal {
            readable(&v, time_format)
        } else {
            verdict_line(&v, time_format, None)
        };
        if let Err(e) = writeln!(out, "{text}").and_then(|()| out.flush()) {
            *write_err.borrow_mut() = Some(e);
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
    let mut last_t: Option<Time> = None;
    let mut warnings = 0u64;
    let mut events = 0u64;
    // A scan received, waiting for its time on the live clock (replay).
    let mut pending: Option<Vec<Event>> = None;
    let stopped = loop {
        // The next deadline, as a wall instant.
        let deadline = match (anchor, diagnoser.next_deadline()) {
            (Some(a), Some(d)) => Some(wall_of(a, d)),
            _ => None,
        };
        let pending_t = pending.as_ref().and_then(|s| s.first()).map(|e| e.t);
        let due = match (pending_t, anchor) {
            (Some(t), Some(a)) if args.replay.is_some() => Some(wall_of(a, t)),
            (Some(_), _) => Some(Instant::now()),
            (None, _) => None,
        };
        // A live source's deadline fires when the wall clock passes it. A
        // replay knows what comes next: its deadline fires only before the
        // next scan (once the source ends, `finish` fires the rest).
        let deadline_first = match (deadline, args.replay.is_some()) {
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
            () = tokio::time::sleep_until(stop_at.unwrap_or(far)), if stop_at.is_some() => {
                break Some("--duration reached");
            }
            () = tokio::time::sleep_until(deadline.unwrap_or(far)), if deadline_first => {
                if let Some(d) = diagnoser.next_deadline() {
                    diagnoser.advance_to(d, &mut emit);
                }
            }
            () = tokio::time::sleep_until(due.unwrap_or(far)), if due.is_some() => {
                let Some(scan) = pending.take() else { continue };
                let Some(t) = scan.first().map(|e| e.t) else { continue };
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
                events += scan.len() as u64;
                for e in scan {
                    diagnoser.push(e, &mut emit);
                }
                diagnoser.advance_to(t, &mut emit);
                last_t = Some(t);
            }
            item = rx.recv(), if pending.is_none() => {
                let Some(item) = item else { break None };
                match item {
                    Item::Start(t0, initial) => {
                        diagnoser.start(t0, &initial);
                        anchor = Some((t0, Instant::now()));
                        last_t = Some(t0);
                        started = true;
                    }
                    Item::Scan(_) if !started => {
                        warnings += 1;
                        eprintln!("warning: events before the initial values ignored");
                    }
                    Item::Scan(scan) => {
                        let t = scan.first().map_or(Time::MIN, |e| e.t);
                        if last_t.is_some_and(|l| t < l) {
                            warnings += 1;
                            eprintln!(
                                "warning: time went backwards ({} after {}): {} events ignored",
                                time_format.format(t),
                                last_t.map_or_else(String::new, |l| time_format.format(l)),
                                scan.len()
                            );
                        } else if !scan.is_empty() {
                            pending = Some(scan);
                        }
                    }
                    Item::Warning(w) => {
                        warnings += 1;
                        eprintln!("warning: {w}");
                    }
                    Item::Fatal(f) => return Err(f),
                }
            }
        }
        if let Some(e) = write_err.borrow_mut().take() {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(Failure::output(e));
        }
    };
    if started {
        // Deadlines up to now (or the last event) still count.
        let end = match (stopped, anchor) {
            (Some(_), Some(a)) => log_now(a).max(last_t.unwrap_or(a.0)),
            _ => last_t.unwrap_or(0),
        };
        let summary = diagnoser.finish(end, &mut emit);
        if let Some(e) = write_err.borrow_mut().take()
            && e.kind() != std::io::ErrorKind::BrokenPipe
        {
            return Err(Failure::output(e));
        }
        let flagged: Vec<String> = summary.iter().flat_map(|p| p.flags.clone()).collect();
        eprintln!(
            "monitor {}: {events} events, {} verdict changes, {warnings} warnings; flags: {}",
            stopped.unwrap_or("source ended"),
            lines.get(),
            if flagged.is_empty() {
                "none".to_string()
            } else {
                flagged.join(" ")
            }
        );
    }
    Ok(())
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
