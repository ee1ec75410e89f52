//! `gardefou fleet`: a fleet worker, diagnosing plants out of their NATS
//! JetStream streams with no PLC attached (see [`runtime::fleet`]): the
//! arguments, turned into the worker's settings.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use diagnoser::diagnosis::DiagnoserOptions;
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, Time, time};
use runtime::fleet::{Served, Settings};

/// Arguments of `gardefou fleet`.
#[derive(Debug, Args)]
pub struct FleetArgs {
    /// The NATS server with the plants' streams: `nats://HOST:PORT`.
    #[arg(long, value_name = "URL")]
    nats: String,
    /// Plant file of a plant served (repeat, each with its `--model`).
    /// Without any, the worker serves every plant of the model store
    /// (`gardefou learn … --publish URL`), each at its latest version.
    #[arg(long)]
    plant: Vec<PathBuf>,
    /// Learned model of each `--plant`, in the same order.
    #[arg(long)]
    model: Vec<PathBuf>,
    /// Each plant's name in the subjects, as its monitor published it, in
    /// the order of `--plant` (default: the plant file's name).
    #[arg(long, value_name = "NAME")]
    nats_plant: Vec<String>,
    /// The fleet: workers of one fleet share its plants, its checkpoints
    /// and its verdict subjects.
    #[arg(long, value_name = "NAME", default_value = "main")]
    fleet: String,
    /// This worker's name in the leases (default: host name and process id).
    #[arg(long, value_name = "NAME")]
    worker: Option<String>,
    /// How often each plant's checkpoint is written.
    #[arg(long, value_parser = time::parse_duration, default_value = "2s")]
    checkpoint_every: Time,
    /// Serve the fleet view on this address: `/` (a page that refreshes),
    /// `/status` (JSON) and `/metrics` (Prometheus).
    #[arg(long, value_name = "ADDR")]
    http: Option<SocketAddr>,
    /// Stop after this long, in wall-clock time (e.g. `10min`), giving the
    /// plants back; without it, the worker stops once every plant's monitor
    /// has stopped and its stream is diagnosed to its end.
    #[arg(long, value_parser = time::parse_duration)]
    duration: Option<Time>,
    /// Longest an unexpected sensor edge shows before the sensor reads its real
    /// value again.
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    glitch_max: Time,
}

/// Runs `gardefou fleet`.
pub fn run(args: FleetArgs) -> Result<(), Failure> {
    if args.plant.is_empty() && !args.nats_plant.is_empty() {
        return Err(Failure::bad(
            "--nats-plant names a --plant; the plants of the model store have their own names",
        ));
    }
    if args.plant.len() != args.model.len() {
        return Err(Failure::bad(format!(
            "--plant and --model: {} plant files and {} models; give one model per plant",
            args.plant.len(),
            args.model.len()
        )));
    }
    if !args.nats_plant.is_empty() && args.nats_plant.len() != args.plant.len() {
        return Err(Failure::bad(format!(
            "--nats-plant: {} names for {} plants; give one per --plant, or none",
            args.nats_plant.len(),
            args.plant.len()
        )));
    }
    let mut plants: Vec<Served> = Vec::new();
    for (i, (p, m)) in args.plant.iter().zip(&args.model).enumerate() {
        let plant = Plant::from_path(p).map_err(Failure::bad)?;
        let bytes = std::fs::read(m).map_err(|e| Failure::bad(format!("{}: {e}", m.display())))?;
        let model = Model::from_path(m).map_err(Failure::bad)?;
        let name = args
            .nats_plant
            .get(i)
            .cloned()
            .unwrap_or_else(|| plant.name.clone());
        if plants.iter().any(|s| s.name == name) {
            return Err(Failure::bad(format!(
                "--plant {}: a second plant named '{name}'; name each with --nats-plant",
                p.display()
            )));
        }
        plants.push(Served {
            name,
            plant,
            model,
            version: runtime::fleet::model_version(&bytes),
        });
    }
    let nanos = |t: Time| Duration::from_nanos(t.max(0) as u64);
    if args.checkpoint_every <= 0 {
        return Err(Failure::bad("--checkpoint-every: must be positive"));
    }
    let settings = Settings {
        url: args.nats,
        fleet: args.fleet,
        worker: args.worker.unwrap_or_else(default_worker),
        plants,
        checkpoint_every: nanos(args.checkpoint_every),
        duration: args.duration.map(nanos),
        http: args.http,
        // The diagnosers of the monitor that published the streams: its
        // source was not polled, and it ran without held reactions.
        options: DiagnoserOptions {
            glitch_max: args.glitch_max,
            ..DiagnoserOptions::default()
        },
    };
    runtime::fleet::run(settings)
}

/// The host's name and the process id.
fn default_worker() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "worker".into());
    format!("{host}-{}", std::process::id())
}
