//! `gardefou fleet`: diagnosis of a plant out of its NATS JetStream stream,
//! with no PLC attached (see [`runtime::jetstream::replay`]): the arguments,
//! turned into the monitor's settings with the stream as source.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, Time, time};
use logs::IngestOptions;
use runtime::monitor::{Config, SourceConfig};

/// Arguments of `gardefou fleet`.
#[derive(Debug, Args)]
pub struct FleetArgs {
    /// The NATS server with the plants' streams: `nats://HOST:PORT`.
    #[arg(long, value_name = "URL")]
    nats: String,
    /// Plant file of the plant served.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    model: PathBuf,
    /// The plant's name in the subjects, as the monitor published it
    /// (default: the plant file's name).
    #[arg(long, value_name = "NAME")]
    nats_plant: Option<String>,
    /// Serve `/status` (JSON) and `/metrics` (Prometheus) on this address.
    #[arg(long, value_name = "ADDR")]
    http: Option<SocketAddr>,
    /// Stop after this long, in wall-clock time (e.g. `10min`); without it,
    /// the worker stops at the end of the monitor's run.
    #[arg(long, value_parser = time::parse_duration)]
    duration: Option<Time>,
    /// Longest an unexpected sensor edge shows before the sensor reads its real
    /// value again.
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    glitch_max: Time,
}

/// Runs `gardefou fleet`.
pub fn run(args: FleetArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&args.model).map_err(Failure::bad)?;
    let name = args
        .nats_plant
        .clone()
        .unwrap_or_else(|| plant.name.clone());
    let config = Config {
        source: SourceConfig::Stream {
            url: args.nats.clone(),
            plant: name.clone(),
        },
        ingest: IngestOptions::default(),
        confirm: None,
        // A worker catching up with an archive lags the live clock by design.
        max_lag: Duration::from_secs(365 * 86_400),
        http: args.http,
        output: None,
        speed: 1.0,
        duration: args.duration.map(|t| Duration::from_nanos(t.max(0) as u64)),
        probe: None,
        nats: None,
        plant_field: Some(name),
    };
    // The diagnosers of the monitor that published the stream: its source
    // was not polled; its flags may have gone back to a PLC, whose filter
    // may hold reactions back, but that monitor ran without it then.
    let options = DiagnoserOptions {
        glitch_max: args.glitch_max,
        ..DiagnoserOptions::default()
    };
    let diagnoser = PlantDiagnoser::new(&plant, &model, &options)
        .map_err(|e| Failure::bad(format!("{}: {e}", args.model.display())))?;
    runtime::monitor::run(plant, diagnoser, config)
}
