//! Online diagnosis beside a PLC (`gardefou monitor`). Events come from a
//! [`source::Source`] as they happen (Modbus TCP, SocketCAN, MQTT Sparkplug B,
//! OPC UA, a replayed log, JSON lines on stdin); every part's diagnoser reads
//! them. Verdict changes go out as JSON lines (SPEC §3), the flags they raise
//! go back to the PLC (Modbus, Sparkplug B, OPC UA), and [`Config::http`]
//! serves `/status` and `/metrics`.
//!
//! **Event time.** The diagnosers run on the source's clock: the time each
//! scan was seen, not the time it arrived. A live source also sends
//! watermarks ([`source::Item::Watermark`]): how far its view of the plant is
//! complete. A deadline fires only once a watermark has passed it, since only
//! then is the missing edge evidence. So a late reply, a paused producer or a
//! flood delays a verdict and never changes it: the verdicts equal `diagnose`
//! on the same events. When the watermark falls behind the live clock by more
//! than [`Config::max_lag`] of wall time, the plant counts as *not observed*
//! (`/status`, `/metrics`, a warning) until it catches up.
//!
//! A replay knows its next scan ahead: its deadlines fire at their own time on
//! a clock mapped to the wall clock ([`Config::speed`]), before the next scan.
//!
//! When a live source loses the plant (a dropped connection), the watermark
//! stays where it was until the plant is seen again; the diagnosers then
//! start again from the values read, with every clock unknown: what happened
//! in the gap is unknown. Flags already raised stay raised and are written
//! again. A `def_` flag goes up only once its verdict has held for
//! [`Config::confirm`] beyond the watermark.
//!
//! With [`Config::probe`] (Modbus only), the monitor also makes probing moves
//! where a part stays ambiguous while its control waits ([`probing`]).

pub mod can;
pub mod http;
pub mod modbus;
pub mod opcua;
mod probing;
pub mod source;
pub mod sparkplug;
pub mod status;
pub mod stdin;

use std::cell::Cell;
use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use diagnoser::diagnosis::{PlantDiagnoser, Verdict};
use diagnoser::{Event, Failure, Plant, SignalKind, Time, TimeFormat};
use filter_coupling::filter::Filter;
use logs::IngestOptions;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use crate::flags::FlagBoard;
use probing::Probing;
use source::{FlagImage, Item, Link, ProbeImage, Source};
use status::Status;

use crate::jetstream::Publisher;

/// Where the monitor's events come from.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceConfig {
    /// Poll a PLC over Modbus TCP at the scan period (addresses: the plant's
    /// [`diagnoser::plant::ModbusMap`]) and write the flags back to it.
    Modbus {
        /// `HOST:PORT` of the PLC.
        address: String,
        /// Modbus unit identifier of the PLC.
        unit_id: u8,
    },
    /// CANopen (CiA 401) PDOs, decoded with the plant's `[can]` bit mapping.
    Can {
        /// A SocketCAN interface, or `udp:HOST:PORT` for the same frames in
        /// UDP datagrams (16-byte SocketCAN `can_frame`s).
        interface: String,
    },
    /// A log (any form) replayed at its recorded pace, times the speed.
    Replay {
        /// The log.
        log: PathBuf,
    },
    /// The metrics of a Sparkplug B edge node or device, read from an MQTT
    /// broker; the flags go back as commands (see [`sparkplug`]).
    Sparkplug {
        /// The broker: `mqtt://HOST:PORT`.
        broker: String,
        /// `GROUP/EDGE[/DEVICE]`.
        target: String,
        /// The jitter allowed between the node's messages, in its time.
        lateness: Time,
    },
    /// The variables of an OPC UA server, followed with a subscription; the
    /// flags go back with writes (see [`opcua`]).
    Opcua {
        /// The server: `opc.tcp://HOST:PORT`.
        url: String,
        /// The jitter allowed between a change and its notification, in the
        /// source's time.
        lateness: Time,
    },
    /// Events as JSON lines on standard input (see [`stdin`]).
    Stdin {
        /// How late, in the source's time, a line may come after a later one;
        /// later than that, it is a warning and ignored.
        lateness: Time,
    },
}

impl SourceConfig {
    /// Whether the source polls a running PLC: a poll may see two of the
    /// PLC's scans at once, so its diagnosers need
    /// [`diagnoser::diagnosis::DiagnoserOptions::polled`]; a log or a
    /// producer on stdin gives the scans as they were.
    pub fn polled(&self) -> bool {
        matches!(self, SourceConfig::Modbus { .. } | SourceConfig::Can { .. })
    }
}

/// Settings of one monitor run.
#[derive(Debug, Clone)]
pub struct Config {
    /// Where the events come from.
    pub source: SourceConfig,
    /// How a replayed log is read (its form, or detected) and the unit of
    /// numeric timestamps (a replay's and stdin's).
    pub ingest: IngestOptions,
    /// How long a `def_` flag's verdict must hold, in the source's time beyond
    /// the watermark, before the flag is raised and written to the PLC
    /// (`None`: one scan period of the plant).
    pub confirm: Option<Time>,
    /// Wall time the watermark may lag the live clock before the plant counts
    /// as not observed.
    pub max_lag: Duration,
    /// Where to serve `/status` (JSON) and `/metrics` (Prometheus), if at all.
    pub http: Option<SocketAddr>,
    /// File the verdict lines are appended to; `None`: standard output (lines
    /// for people on a terminal, JSON lines otherwise).
    pub output: Option<PathBuf>,
    /// How much faster than real time the source's clock runs (a replay, or
    /// a simulated PLC run faster than real time); positive.
    pub speed: f64,
    /// Wall-clock time after which the monitor stops, if any.
    pub duration: Option<Duration>,
    /// Probing moves (`--probe`, Modbus only): the copy of the PLC's filter,
    /// built with the coupling the PLC uses, that every move is checked on.
    /// `None`: the monitor never writes a probe coil.
    pub probe: Option<Filter>,
    /// Where to publish the plant's events, verdicts and flags (`--nats`),
    /// if anywhere.
    pub nats: Option<crate::jetstream::Settings>,
    /// Where to take new model versions from (`--follow-models`), if
    /// anywhere.
    pub models: Option<FollowModels>,
}

/// New model versions of the plant, from the model store
/// ([`crate::jetstream::models`]), each taken at the next safe point: between
/// two items, the diagnosers start again from the values read, every clock
/// unknown, as after a reconnection; flags raised stay raised. The plant
/// file stays the monitor's own (its register map, its flags). Verdict lines
/// then name the model version.
#[derive(Debug, Clone)]
pub struct FollowModels {
    /// The server: `nats://HOST:PORT`.
    pub url: String,
    /// The plant's name in the store.
    pub plant: String,
    /// The version the monitor starts with.
    pub version: String,
    /// The diagnosers' options, for each new version.
    pub options: diagnoser::diagnosis::DiagnoserOptions,
}

/// How long a stopping monitor waits for the broker to take what it has not
/// yet published.
const PUBLISH_WAIT: Duration = Duration::from_secs(10);

/// How long a stopping monitor waits for the PLC to acknowledge the end of
/// its probing move.
const PROBE_CLEAR_WAIT: Duration = Duration::from_secs(2);

/// Runs the monitor of `plant` with `diagnoser` (built with
/// [`SourceConfig::polled`] as its `polled` option) until the source ends, a
/// signal (SIGINT, SIGTERM) or [`Config::duration`]; then prints the summary
/// on stderr.
pub fn run(plant: Plant, diagnoser: PlantDiagnoser, config: Config) -> Result<(), Failure> {
    if !(config.speed.is_finite() && config.speed > 0.0) {
        return Err(Failure::bad("--speed: must be a positive number"));
    }
    if config.probe.is_some() && config.models.is_some() {
        return Err(Failure::bad(
            "--probe and --follow-models: probing moves are checked on a copy of the filter built from the model given; follow new models without --probe",
        ));
    }
    if config.probe.is_some() && !matches!(config.source, SourceConfig::Modbus { .. }) {
        return Err(Failure::bad(
            "--probe needs --modbus HOST:PORT: probing moves are written to the PLC's probe coils",
        ));
    }
    let output: Box<dyn Write> = match &config.output {
        Some(path) => Box::new(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|e| Failure::Io(format!("{}: {e}", path.display())))?,
        ),
        None => Box::new(std::io::stdout()),
    };
    let terminal = config.output.is_none() && std::io::stdout().is_terminal();
    let open = prepare_source(&config, &plant)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    let result = runtime.block_on(async {
        let (source, name) = open()?;
        monitor(&config, plant, diagnoser, source, name, output, terminal).await
    });
    // A read of standard input cannot be cancelled: waiting for it would keep
    // a stopped monitor alive until the writer closes its end.
    runtime.shutdown_background();
    result
}

/// Opens the source inside the monitor's runtime, and names it (for
/// `/status`).
type OpenSource = Box<dyn FnOnce() -> Result<(Box<dyn Source>, String), Failure>>;

/// What opening the source of `config` takes. A replay is opened now, before
/// the runtime starts: its reader (Parquet's among them) may run a runtime of
/// its own. A live source is opened inside the runtime (a SocketCAN socket
/// registers with its reactor).
fn prepare_source(config: &Config, plant: &Plant) -> Result<OpenSource, Failure> {
    let plant = plant.clone();
    let speed = config.speed;
    let probing = config.probe.is_some();
    Ok(match config.source.clone() {
        SourceConfig::Replay { log } => {
            let replay = source::Replay::open(&log, &config.ingest, &plant)?;
            let name = format!("replay {}", log.display());
            Box::new(move || Ok((Box::new(replay) as Box<dyn Source>, name)))
        }
        SourceConfig::Modbus { address, unit_id } => Box::new(move || {
            let s = modbus::ModbusSource::new(&address, unit_id, &plant, speed, probing)?;
            Ok((Box::new(s) as Box<dyn Source>, format!("modbus {address}")))
        }),
        SourceConfig::Can { interface } => Box::new(move || {
            let s = can::CanSource::new(&interface, &plant, speed)?;
            Ok((Box::new(s) as Box<dyn Source>, format!("can {interface}")))
        }),
        SourceConfig::Sparkplug {
            broker,
            target,
            lateness,
        } => Box::new(move || {
            let s = sparkplug::SparkplugSource::new(&broker, &target, &plant, speed, lateness)?;
            let name = format!("sparkplug {broker} {target}");
            Ok((Box::new(s) as Box<dyn Source>, name))
        }),
        SourceConfig::Opcua { url, lateness } => Box::new(move || {
            let s = opcua::OpcuaSource::new(&url, &plant, speed, lateness)?;
            let name = format!("opcua {url}");
            Ok((Box::new(s) as Box<dyn Source>, name))
        }),
        SourceConfig::Stdin { lateness } => {
            let s = stdin::Stdin {
                plant,
                unit: config.ingest.time_unit,
                lateness,
                speed,
            };
            Box::new(move || Ok((Box::new(s) as Box<dyn Source>, "stdin".to_string())))
        }
    })
}

/// How the monitor writes verdict lines.
struct Writer {
    out: Box<dyn Write>,
    terminal: bool,
    time: TimeFormat,
    error: Option<std::io::Error>,
    /// The model version, named in every line (`--follow-models`).
    model: Option<String>,
}

impl Writer {
    /// The verdict's JSON line, naming the model version if followed.
    fn json(&self, v: &Verdict) -> String {
        let line = v.json_line(self.time, None);
        match &self.model {
            Some(model) => crate::jetstream::record::with_fields(&line, &[("model", model)]),
            None => line,
        }
    }

    fn line(&mut self, v: &Verdict) {
        if self.error.is_some() {
            return;
        }
        let text = if self.terminal {
            readable(v, self.time)
        } else {
            self.json(v)
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
    /// Probing moves, with `--probe`.
    probing: Option<Probing>,
    /// When the evidence of the verdicts being computed came: a scan's or a
    /// watermark's arrival, a replayed deadline's expiry (for the latency).
    evidence: Cell<Instant>,
    /// The plant's streams, with `--nats`.
    publisher: Option<Publisher>,
    /// The flags up last published.
    published_flags: Option<Vec<String>>,
}

impl Outputs {
    /// Verdict lines to `writer`, `def_` flags confirmed after
    /// `confirmation`, flags to the source through `flag_tx`.
    fn new(
        writer: Writer,
        confirmation: Time,
        status: Arc<Mutex<Status>>,
        flag_tx: watch::Sender<FlagImage>,
        plant: Plant,
    ) -> Outputs {
        Outputs {
            writer,
            board: FlagBoard::with_confirmation(confirmation),
            status,
            flag_tx,
            plant,
            probing: None,
            evidence: Cell::new(Instant::now()),
            publisher: None,
            published_flags: None,
        }
    }

    fn emit(&mut self, mut v: Verdict) {
        // The verdict a probe led to says what the probe told.
        if let Some(reason) = self.probing.as_mut().and_then(|p| p.verdict(&v)) {
            v.reason = reason;
        }
        self.writer.line(&v);
        if let Some(p) = self.publisher.as_mut() {
            p.verdict(&self.writer.json(&v));
        }
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
        let image = self.board.image(&self.plant);
        if let Some(p) = self.probing.as_mut() {
            p.flags(&image);
        }
        if let Some(p) = self.publisher.as_mut() {
            let up: Vec<String> = self
                .plant
                .flags()
                .iter()
                .zip(&image)
                .filter(|(_, up)| **up)
                .map(|(f, _)| f.to_string())
                .collect();
            if self.published_flags.as_ref() != Some(&up) {
                p.flags(&up);
                self.published_flags = Some(up);
            }
        }
        let _ = self.flag_tx.send(image);
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
    /// Every signal's value now (empty before the first start): where a new
    /// model version starts from.
    values: Vec<bool>,
}

impl Run {
    /// `diagnoser` fed in event time, its verdicts to `out`; the source's
    /// clock runs `speed` times faster than the wall clock.
    fn new(diagnoser: PlantDiagnoser, out: Outputs, speed: f64) -> Run {
        Run {
            diagnoser,
            out,
            speed,
            anchor: None,
            started: false,
            blind: false,
            lost_at: None,
            watermark: None,
            observed: true,
            values: Vec::new(),
        }
    }

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
        self.values = initial.to_vec();
        if let Some(p) = self.out.probing.as_mut() {
            p.start(initial);
        }
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
        if let Some(p) = self.out.probing.as_mut() {
            p.changes(&scan);
        }
        let out = &mut self.out;
        for e in scan {
            if let Some(v) = self.values.get_mut(e.signal.index()) {
                *v = e.value;
            }
            self.diagnoser.push(e, &mut |v| out.emit(v));
        }
        self.advance_to(t);
        self.probe(t);
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
        self.probe(w);
        self.watermark = Some(w);
        let took = arrived.elapsed();
        self.out.status(|s| s.evidence.record(took));
    }

    /// With `--probe`: the PLC as read at `t`, once the diagnosers are done
    /// with it; a move may start only while the plant is observed.
    fn probe(&mut self, t: Time) {
        if let Some(p) = self.out.probing.as_mut() {
            p.scan(t, &self.diagnoser, self.observed);
        }
    }

    fn lost(&mut self, t: Time, why: &str) {
        // The watermark stays: what happened since it is unknown.
        self.blind = true;
        if let Some(p) = self.out.probing.as_mut() {
            p.abandon("the source lost the plant");
        }
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
            if let Some(p) = self.out.probing.as_mut() {
                p.abandon("the plant is not observed");
            }
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

    /// A new model version, between two items (a safe point): the
    /// diagnosers start again from the values read, every clock unknown. A
    /// version that does not fit the plant is refused, and the old one stays.
    fn take_model(
        &mut self,
        v: crate::jetstream::models::Version,
        options: &diagnoser::diagnosis::DiagnoserOptions,
    ) {
        let old = self.out.writer.model.clone().unwrap_or_default();
        if v.version == old {
            return;
        }
        let mut diagnoser = match PlantDiagnoser::new(&self.out.plant, &v.model, options) {
            Ok(d) => d,
            Err(e) => {
                self.out.warn(&format!(
                    "model {} of plant {} from the store does not fit the plant file: {e}; model {old} stays",
                    v.version, v.name
                ));
                return;
            }
        };
        let at = if self.started && !self.blind {
            let t = self.diagnoser.now();
            diagnoser.start(t, &self.values);
            format!(
                "at {}: the diagnosers start again from the values read, with every clock unknown; flags raised stay raised",
                self.out.writer.time.format(t)
            )
        } else {
            "before the plant is seen".to_string()
        };
        eprintln!("monitor: model {} replaces {old} {at}", v.version);
        self.diagnoser = diagnoser;
        self.out.writer.model = Some(v.version);
    }

    /// A replay's deadline `d`, due on the live clock at `at`, has come.
    fn replayed_deadline(&mut self, d: Time, at: Instant) {
        self.out.evidence.set(at);
        // Past the deadline, so that the loop always moves on.
        self.advance_to(d.max(self.diagnoser.now() + 1));
        self.out.status(|s| s.evidence.record(at.elapsed()));
    }

    /// Takes in one item. A replay's scan (the source knows it ahead) comes
    /// back instead, to wait for its time on the live clock.
    fn receive(
        &mut self,
        item: Item,
        knows_ahead: bool,
    ) -> Result<Option<(Vec<Event>, Instant)>, Failure> {
        match item {
            Item::Scan(scan) if knows_ahead && self.started => {
                let t = scan.first().map_or(0, |e| e.t);
                let at = self.wall_of(t).unwrap_or_else(Instant::now);
                Ok(Some((scan, at)))
            }
            item => self.item(item).map(|()| None),
        }
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
            Item::ProbesWritten(image) => {
                if let Some(p) = self.out.probing.as_mut() {
                    p.written(&image);
                }
            }
            Item::ProbeRefused(actuator) => eprintln!(
                "monitor: the PLC refused the probing move of {actuator} ({actuator}_PROBE_REFUSED): its filter forbids it there; the move stays asked for"
            ),
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

/// Why the event loop ended.
enum End {
    /// A signal, [`Config::duration`], or the source's end (`None`): the
    /// summary follows.
    Stopped(Option<&'static str>),
    /// The reader of the verdict lines went away: nothing more to write.
    Closed,
}

/// The monitor on its opened source, inside the runtime: the status (served
/// over HTTP if asked), the channels to and from the source, the event loop,
/// then the summary.
async fn monitor(
    config: &Config,
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
    if let Some(addr) = config.http {
        http::serve(addr, status.clone()).await?;
    }
    // Room for a replay to read well ahead of its pace.
    let (tx, mut rx) = mpsc::channel::<Item>(16_384);
    let (flag_tx, flag_rx) = watch::channel(vec![false; plant.flags().len()]);
    let actuators = plant.signals.of_kind(SignalKind::Actuator).count();
    let (probe_tx, probe_rx) = watch::channel::<ProbeImage>(vec![None; actuators]);
    source.spawn(Link {
        items: tx,
        flags: flag_rx,
        probes: probe_rx,
    });
    let probing = config
        .probe
        .clone()
        .map(|filter| Probing::new(&plant, filter, probe_tx, time_format, status.clone()));
    let writer = Writer {
        out: output,
        terminal,
        time: time_format,
        error: None,
        model: config.models.as_ref().map(|m| m.version.clone()),
    };
    let confirmation = config.confirm.unwrap_or(plant.scan_period);
    let publisher = match &config.nats {
        Some(settings) => Some(Publisher::start(settings.clone(), &plant, time_format)?),
        None => None,
    };
    let mut out = Outputs::new(writer, confirmation, status, flag_tx, plant);
    out.probing = probing;
    out.publisher = publisher;
    let mut run = Run::new(diagnoser, out, config.speed);
    let mut versions = match &config.models {
        Some(follow) => crate::jetstream::models::follow(
            follow.url.clone(),
            follow.plant.clone(),
            follow.version.clone(),
        ),
        None => mpsc::channel(1).1,
    };
    let end = event_loop(&mut run, &mut rx, &mut versions, config, knows_ahead).await;
    end_probe(&mut run, &mut rx).await;
    let result = match end {
        Ok(End::Stopped(stopped)) => finish(&mut run, stopped, knows_ahead),
        Ok(End::Closed) => Ok(()),
        Err(e) => Err(e),
    };
    if let Some(p) = run.out.publisher.take() {
        let t = run.watermark.unwrap_or_else(|| run.diagnoser.now());
        match p.finish(t, PUBLISH_WAIT).await {
            Some(summary) => eprintln!(
                "monitor: nats: {} messages published ({} already there), {} dropped, {} not published",
                summary.published, summary.duplicates, summary.dropped, summary.left
            ),
            None => eprintln!(
                "warning: nats: the broker did not take every message within {} s; the rest is not published",
                PUBLISH_WAIT.as_secs()
            ),
        }
    }
    result
}

/// With `--probe`, as the monitor stops: ends the probe under way and waits
/// (at most [`PROBE_CLEAR_WAIT`]) for the PLC to acknowledge the end of any
/// move it may hold. Items that come meanwhile are not read.
async fn end_probe(run: &mut Run, rx: &mut mpsc::Receiver<Item>) {
    let Some(p) = run.out.probing.as_mut() else {
        return;
    };
    p.abandon("the monitor stops");
    let until = Instant::now() + PROBE_CLEAR_WAIT;
    while p.on_plc() {
        match tokio::time::timeout_at(until, rx.recv()).await {
            Ok(Some(Item::ProbesWritten(image))) => p.written(&image),
            Ok(Some(_)) => {}
            Ok(None) | Err(_) => {
                eprintln!(
                    "warning: the PLC did not acknowledge the end of the probing move within {} s: its _PROBE coil may still be 1",
                    PROBE_CLEAR_WAIT.as_secs()
                );
                return;
            }
        }
    }
}

/// Feeds `run` with the source's items until a signal, the duration or the
/// source's end. A replay's scans wait for their time on the live clock, and
/// its deadlines fire on that clock; a live source's fire only on its
/// watermarks.
async fn event_loop(
    run: &mut Run,
    rx: &mut mpsc::Receiver<Item>,
    versions: &mut mpsc::Receiver<crate::jetstream::models::Version>,
    config: &Config,
    knows_ahead: bool,
) -> Result<End, Failure> {
    let stop_at = config.duration.map(|d| Instant::now() + d);
    let mut lag_check = tokio::time::interval(Duration::from_millis(100));
    lag_check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // A replayed scan received, waiting for its time on the live clock.
    let mut pending: Option<(Vec<Event>, Instant)> = None;
    let mut terminate = terminate_signal()?;
    loop {
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
            _ = tokio::signal::ctrl_c() => return Ok(End::Stopped(Some("interrupted"))),
            _ = terminate.recv() => return Ok(End::Stopped(Some("terminated"))),
            () = tokio::time::sleep_until(stop_at.unwrap_or(far)), if stop_at.is_some() => {
                return Ok(End::Stopped(Some("--duration reached")));
            }
            () = wake_at(deadline.map_or(far, |d| d.1)), if deadline.is_some() => {
                if let Some((d, at)) = deadline {
                    run.replayed_deadline(d, at);
                }
            }
            () = wake_at(due.unwrap_or(far)), if due.is_some() => {
                if let Some((scan, at)) = pending.take() {
                    run.scan(scan, at);
                }
            }
            _ = lag_check.tick(), if !knows_ahead => run.check_lag(config.max_lag),
            Some(version) = versions.recv(), if config.models.is_some() => {
                if let Some(follow) = &config.models {
                    run.take_model(version, &follow.options);
                }
            }
            item = rx.recv(), if pending.is_none() => {
                let Some(item) = item else {
                    return Ok(End::Stopped(None));
                };
                if let Some(p) = run.out.publisher.as_mut() {
                    p.item(&item);
                }
                pending = run.receive(item, knows_ahead)?;
            }
        }
        let error = run.out.writer.error.take();
        if let Some(e) = error {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(End::Closed);
            }
            return Err(Failure::output(e));
        }
        // Whatever the input, the runtime gets its turn now and then, so that
        // signals are always heard.
        tokio::task::consume_budget().await;
    }
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
    let (events, lines, warnings, probes, labels, evidence) = run
        .out
        .status
        .lock()
        .map(|s| {
            (
                s.events,
                s.verdict_changes,
                s.warnings,
                s.probes,
                s.latency.clone(),
                s.evidence.clone(),
            )
        })
        .unwrap_or_default();
    let probes = match &run.out.probing {
        Some(_) => format!(", {probes} probing move(s)"),
        None => String::new(),
    };
    eprintln!(
        "monitor {}: {events} events, {lines} verdict changes, {warnings} warnings{probes}; flags: {}",
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
pub(crate) fn terminate_signal() -> Result<Terminate, Failure> {
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
pub(crate) struct Terminate(tokio::signal::unix::Signal);
#[cfg(not(unix))]
pub(crate) struct Terminate;

impl Terminate {
    pub(crate) async fn recv(&mut self) {
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

#[cfg(test)]
mod tests {
    use std::path::Path;

    use diagnoser::diagnosis::DiagnoserOptions;
    use diagnoser::model::Model;
    use logs::open;

    use super::*;

    /// Verdict lines written to memory, readable while the monitor runs.
    #[derive(Clone, Default)]
    struct Lines(Arc<Mutex<Vec<u8>>>);

    impl Write for Lines {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.0.lock().expect("lines").extend_from_slice(bytes);
            Ok(bytes.len())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Lines {
        fn read(&self) -> Vec<String> {
            let bytes = self.0.lock().expect("lines").clone();
            String::from_utf8(bytes)
                .expect("UTF-8")
                .lines()
                .map(str::to_string)
                .collect()
        }
    }

    /// The shipped F2 run (C4 stuck): the plant, a diagnoser, how its times
    /// print, its first values and its scans.
    struct F2 {
        plant: Plant,
        diagnoser: PlantDiagnoser,
        time: TimeFormat,
        t0: Time,
        initial: Vec<bool>,
        scans: Vec<Vec<Event>>,
    }

    fn f2() -> F2 {
        let at = |rel: &str| Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel);
        let plant = Plant::from_path(&at("datasets/data/sorting/F2/plant.toml")).expect("plant");
        let model = Model::from_path(&at("diagnoser/tests/fixtures/diagnosis/sorting-model.json"))
            .expect("model");
        let diagnoser =
            PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).expect("diagnoser");
        let options = IngestOptions {
            time_unit: plant.time_unit,
            ..IngestOptions::default()
        };
        let log = open(&at("datasets/data/sorting/F2/events.csv"), &plant, &options).expect("log");
        let mut scans: Vec<Vec<Event>> = Vec::new();
        for e in log.batches.flat_map(|b| b.expect("batch")) {
            match scans.last_mut() {
                Some(scan) if scan[0].t == e.t => scan.push(e),
                _ => scans.push(vec![e]),
            }
        }
        F2 {
            plant,
            diagnoser,
            time: log.time,
            t0: log.start,
            initial: log.initial,
            scans,
        }
    }

    /// What `diagnose` gives on the same scans up to the first deadline
    /// between two scans that changes a verdict (no event came in time): the
    /// verdict lines before it, those it gives, and its time.
    fn offline_until_deadline(f2: &F2) -> (Vec<String>, Vec<String>, Time) {
        let mut d = f2.diagnoser.clone();
        let mut lines = Vec::new();
        d.start(f2.t0, &f2.initial);
        for scan in &f2.scans {
            let t = scan[0].t;
            // The deadlines before the scan, one at a time.
            while let Some(x) = d.next_deadline().filter(|&x| x < t && x > d.now()) {
                let mut fired = Vec::new();
                d.advance_to(x, &mut |v| fired.push(v.json_line(f2.time, None)));
                if !fired.is_empty() {
                    return (lines, fired, x);
                }
            }
            let mut emit = |v: Verdict| lines.push(v.json_line(f2.time, None));
            d.advance_to(t - 1, &mut emit);
            for &e in scan {
                d.push(e, &mut emit);
            }
            d.advance_to(t, &mut emit);
        }
        panic!("no deadline changes a verdict between two scans of the F2 run");
    }

    /// The monitor's core for `f2`, its verdict lines to `lines`; its clock
    /// runs `speed` times faster than the wall clock.
    fn core(f2: &F2, lines: &Lines, speed: f64) -> Run {
        let status = Status::new(&f2.plant, "test".to_string(), f2.time);
        let (flag_tx, _) = watch::channel(Vec::new());
        let writer = Writer {
            out: Box::new(lines.clone()),
            terminal: false,
            time: f2.time,
            error: None,
            model: None,
        };
        let out = Outputs::new(
            writer,
            f2.plant.scan_period,
            Arc::new(Mutex::new(status)),
            flag_tx,
            f2.plant.clone(),
        );
        Run::new(f2.diagnoser.clone(), out, speed)
    }

    /// A live source's deadline fires on its watermark, never on the wall
    /// clock: with the watermark stopped just before it, however far the live
    /// clock runs past it, the verdict does not come; the watermark reaching
    /// it brings the verdict of `diagnose`.
    #[test]
    fn a_deadline_waits_for_the_watermark_not_the_wall_clock() {
        let f2 = f2();
        let (before, fired, deadline) = offline_until_deadline(&f2);
        let lines = Lines::default();
        // A million times faster than the wall clock: the live clock passes
        // the deadline within a millisecond.
        let mut run = core(&f2, &lines, 1e6);
        run.item(Item::Start(f2.t0, f2.initial.clone()))
            .expect("start");
        for scan in f2.scans.iter().take_while(|s| s[0].t < deadline) {
            run.item(Item::Scan(scan.clone())).expect("scan");
        }
        run.item(Item::Watermark(deadline - 1)).expect("watermark");
        std::thread::sleep(Duration::from_millis(20));
        assert!(
            run.live_now()
                .is_some_and(|now| now > deadline + 1_000 * diagnoser::MS)
        );
        run.check_lag(Duration::ZERO);
        assert!(!run.observed, "the watermark lags the live clock");
        assert_eq!(lines.read(), before);
        run.item(Item::Watermark(deadline)).expect("watermark");
        assert_eq!(lines.read(), [before, fired].concat());
    }

    /// A live source fed by the test, item by item; it ends when the test
    /// drops its sender.
    struct Fed(std::sync::mpsc::Receiver<Item>);

    impl Source for Fed {
        fn time_format(&self) -> TimeFormat {
            TimeFormat::Numeric(diagnoser::TimeUnit::Ms)
        }

        fn spawn(self: Box<Self>, link: Link) {
            std::thread::spawn(move || {
                for item in self.0 {
                    if link.items.blocking_send(item).is_err() {
                        return;
                    }
                }
            });
        }
    }

    /// The same through the monitor's event loop, with its timers and lag
    /// checks running: a paused source delays the deadline's verdict, and
    /// its watermark brings it.
    #[test]
    fn the_event_loop_fires_a_live_deadline_only_on_the_watermark() {
        let f2 = f2();
        let (before, fired, deadline) = offline_until_deadline(&f2);
        let want = [before.clone(), fired].concat();
        assert_eq!(f2.time, TimeFormat::Numeric(diagnoser::TimeUnit::Ms));
        let lines = Lines::default();
        let (items, fed) = std::sync::mpsc::channel();
        let config = Config {
            source: SourceConfig::Stdin { lateness: 0 },
            ingest: IngestOptions::default(),
            confirm: None,
            max_lag: Duration::from_millis(50),
            http: None,
            output: None,
            speed: 1e4,
            duration: None,
            probe: None,
            nats: None,
            models: None,
        };
        let output = lines.clone();
        let (plant, diagnoser) = (f2.plant.clone(), f2.diagnoser.clone());
        let monitor = std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .expect("runtime");
            let source = Box::new(Fed(fed));
            let name = "test".to_string();
            let output = Box::new(output);
            runtime.block_on(monitor(
                &config, plant, diagnoser, source, name, output, false,
            ))
        });
        let send = |item| items.send(item).expect("the monitor runs");
        send(Item::Start(f2.t0, f2.initial.clone()));
        for scan in f2.scans.iter().take_while(|s| s[0].t < deadline) {
            send(Item::Scan(scan.clone()));
        }
        send(Item::Watermark(deadline - 1));
        // The source pauses: ten thousand times faster than the wall clock,
        // the live clock runs an hour past the deadline.
        std::thread::sleep(Duration::from_millis(400));
        assert_eq!(lines.read(), before);
        send(Item::Watermark(deadline));
        let waited = std::time::Instant::now();
        while lines.read().len() < want.len() && waited.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(lines.read(), want);
        drop(items);
        monitor
            .join()
            .expect("the monitor ends")
            .expect("no failure");
    }
}
