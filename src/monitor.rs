//! `gardefou monitor`: online diagnosis beside a PLC (see
//! [`runtime::monitor`]): the arguments, checked and turned into the
//! monitor's settings.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, Time, TimeUnit, time};
use filter_coupling::filter::{Coupling, Filter};
use logs::{IngestOptions, LogFormat};
use runtime::monitor::{Config, FollowModels, SourceConfig};

/// Arguments of `gardefou monitor`.
#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["modbus", "can", "mqtt", "opcua", "replay", "stdin"])))]
pub struct MonitorArgs {
    /// Plant file: signals, parts, faults, partitions and the register map.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (from `gardefou learn`). With `--follow-models` and
    /// without it, the plant's version in the model store.
    #[arg(long, required_unless_present = "follow_models")]
    model: Option<PathBuf>,
    /// Poll a PLC over Modbus TCP at the scan period (addresses: `[modbus]` of
    /// the plant file, or the default map) and write the flags back to it.
    #[arg(long, value_name = "HOST:PORT")]
    modbus: Option<String>,
    /// Read CANopen (CiA 401) PDOs from a SocketCAN interface, decoded with the
    /// plant file's `[can]` bit mapping. `udp:HOST:PORT` reads the same frames
    /// from UDP datagrams instead (16-byte SocketCAN `can_frame`s).
    #[arg(long, value_name = "IFACE")]
    can: Option<String>,
    /// Read the plant from an MQTT broker (`mqtt://HOST:PORT`) as the
    /// metrics of a Sparkplug B edge node (`--sparkplug`), by signal name,
    /// and write the flags back to it as commands.
    #[arg(long, value_name = "URL", requires = "sparkplug")]
    mqtt: Option<String>,
    /// The Sparkplug B edge node whose metrics are the plant's signals, or
    /// one of its devices: `GROUP/EDGE` or `GROUP/EDGE/DEVICE`.
    #[arg(long, value_name = "GROUP/EDGE[/DEVICE]", requires = "mqtt")]
    sparkplug: Option<String>,
    /// Subscribe to the variables of an OPC UA server
    /// (`opc.tcp://HOST:PORT`): each signal is the variable the plant file's
    /// `[opcua]` table names by NodeId, or the one of its browse name below
    /// the Objects folder. Times are the values' SourceTimestamps; the flags
    /// are written back to their variables. Security policy None.
    #[arg(long, value_name = "URL")]
    opcua: Option<String>,
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
    /// after a later one, a Sparkplug B message after the time its node's
    /// last one says, or an OPC UA change after its SourceTimestamp; later
    /// than that, it is a warning and ignored (default: 0ms on standard
    /// input, 100ms over Sparkplug B and OPC UA).
    #[arg(long, value_parser = time::parse_duration)]
    lateness: Option<Time>,
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
    /// Publish the plant's events, verdict lines and flags to NATS
    /// JetStream (`nats://HOST:PORT`): streams GARDEFOU_EVENTS_PLANT,
    /// GARDEFOU_VERDICTS and GARDEFOU_FLAGS, subjects
    /// `gardefou.{events,verdicts,flags}.PLANT`. The monitor never waits for
    /// the broker: what it cannot publish waits in an outbox, sent in order
    /// when the broker is back.
    #[arg(long, value_name = "URL")]
    nats: Option<String>,
    /// The plant's name in the subjects (default: the plant file's name).
    #[arg(long, value_name = "NAME", requires = "nats")]
    nats_plant: Option<String>,
    /// The file the outbox spills to while the broker is away (default: in
    /// the temporary directory, named by plant and process).
    #[arg(long, value_name = "FILE", requires = "nats")]
    nats_outbox: Option<PathBuf>,
    /// Megabytes the outbox may hold; beyond, messages are dropped, with a
    /// warning.
    #[arg(long, value_name = "MB", default_value_t = 256, requires = "nats")]
    nats_outbox_mb: u64,
    /// Take the plant's new model versions from the model store of the
    /// `--nats` server (`gardefou learn … --publish URL`), each between two
    /// scans: the diagnosers then start again from the values read, every
    /// clock unknown, and flags raised stay raised. Verdict lines name the
    /// model version. The plant file stays this one.
    #[arg(long, requires = "nats")]
    follow_models: bool,
    /// Make probing moves (with --modbus only): where a part's verdict stays
    /// ambiguous while its orders wait, ask the PLC's filter, through the
    /// probe coils, for a move of one of the part's outputs that a copy of the
    /// filter (coupling def+suspect) accepts under every candidate and after
    /// which silence tells some candidates apart. Off by default: without it,
    /// no probe coil is ever written.
    #[arg(long)]
    probe: bool,
}

/// The jitter allowed by default between a Sparkplug B node's messages: a
/// tenth of a second, well above a broker's on one site.
const SPARKPLUG_LATENESS: Time = 100 * diagnoser::MS;

/// The jitter allowed by default between an OPC UA change and its
/// notification (sampling, queueing, the network): as over Sparkplug B.
const OPCUA_LATENESS: Time = 100 * diagnoser::MS;

/// Runs `gardefou monitor`.
pub fn run(args: MonitorArgs) -> Result<(), Failure> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        return Err(Failure::bad("--speed: must be a positive number"));
    }
    if args.probe && args.modbus.is_none() {
        return Err(Failure::bad(
            "--probe needs --modbus HOST:PORT: probing moves are written to the PLC's probe coils",
        ));
    }
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let mut config = config(&args, &plant);
    let (model, version, named) = model(&args, &config)?;
    if let (true, Some(nats)) = (args.follow_models, &config.nats) {
        config.models = Some(FollowModels {
            url: nats.url.clone(),
            plant: nats.plant.clone(),
            version,
            options: DiagnoserOptions::default(),
        });
    }
    if args.probe {
        // The coupling the PLC's filter reads the flags with: a suspected
        // sensor reads the union of reading and estimate, so a move it
        // accepts is safe under every candidate.
        let filter = Filter::new(&plant, Some(&model), Coupling::FlagsAndSuspects)
            .map_err(|e| Failure::bad(format!("{named}: {e}")))?;
        config.probe = Some(filter);
    }
    let options = DiagnoserOptions {
        glitch_max: args.glitch_max,
        polled: config.source.polled(),
        // Beside a live PLC, the flags go back to its filter, which may then
        // hold the control's reaction to an edge back.
        held_reactions: config.source.polled(),
    };
    if let Some(follow) = config.models.as_mut() {
        follow.options = options;
    }
    let diagnoser = PlantDiagnoser::new(&plant, &model, &options)
        .map_err(|e| Failure::bad(format!("{named}: {e}")))?;
    runtime::monitor::run(plant, diagnoser, config)
}

/// The model the monitor starts with, its version, and how errors name it:
/// `--model`'s file, or the plant's version in the store.
fn model(args: &MonitorArgs, config: &Config) -> Result<(Model, String, String), Failure> {
    if let Some(path) = &args.model {
        let bytes =
            std::fs::read(path).map_err(|e| Failure::bad(format!("{}: {e}", path.display())))?;
        let model = Model::from_path(path).map_err(Failure::bad)?;
        let version = runtime::jetstream::models::model_version(&bytes);
        return Ok((model, version, path.display().to_string()));
    }
    let nats = config
        .nats
        .as_ref()
        .ok_or_else(|| Failure::bad("--model: required without --follow-models"))?;
    let v = runtime::jetstream::models::fetch(&nats.url, &nats.plant)?;
    let named = format!("model {} of plant {} in the store", v.version, nats.plant);
    Ok((v.model, v.version, named))
}

/// The source the arguments name (clap lets exactly one through).
fn source(args: &MonitorArgs) -> SourceConfig {
    if let Some(log) = &args.replay {
        SourceConfig::Replay { log: log.clone() }
    } else if let Some(address) = &args.modbus {
        SourceConfig::Modbus {
            address: address.clone(),
            unit_id: args.unit_id,
        }
    } else if let Some(interface) = &args.can {
        SourceConfig::Can {
            interface: interface.clone(),
        }
    } else if let (Some(broker), Some(target)) = (&args.mqtt, &args.sparkplug) {
        SourceConfig::Sparkplug {
            broker: broker.clone(),
            target: target.clone(),
            lateness: args.lateness.unwrap_or(SPARKPLUG_LATENESS),
        }
    } else if let Some(url) = &args.opcua {
        SourceConfig::Opcua {
            url: url.clone(),
            lateness: args.lateness.unwrap_or(OPCUA_LATENESS),
        }
    } else {
        SourceConfig::Stdin {
            lateness: args.lateness.unwrap_or(0),
        }
    }
}

/// Where `--nats` publishes.
fn nats_settings(args: &MonitorArgs, url: &str, plant: &Plant) -> runtime::jetstream::Settings {
    let name = args
        .nats_plant
        .clone()
        .unwrap_or_else(|| plant.name.clone());
    let outbox = args.nats_outbox.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "gardefou-outbox-{name}-{}.spool",
            std::process::id()
        ))
    });
    runtime::jetstream::Settings {
        url: url.to_string(),
        plant: name,
        outbox,
        outbox_bytes: args.nats_outbox_mb.saturating_mul(1 << 20),
    }
}

/// The monitor's settings from the arguments.
fn config(args: &MonitorArgs, plant: &Plant) -> Config {
    let wall = |t: Time| Duration::from_nanos(t.max(0) as u64);
    Config {
        source: source(args),
        ingest: IngestOptions {
            format: args.format,
            time_unit: args.time_unit.unwrap_or(plant.time_unit),
            ..IngestOptions::default()
        },
        confirm: args.confirm,
        max_lag: wall(args.max_lag),
        http: args.http,
        output: args.output.clone(),
        speed: args.speed,
        duration: args.duration.map(wall),
        probe: None,
        nats: args
            .nats
            .as_ref()
            .map(|url| nats_settings(args, url, plant)),
        models: None,
    }
}
