//! Arguments that several verbs share: what a replay reads, and how a filter
//! uses the diagnosers' flags.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use diagnoser::diagnosis::DiagnoserOptions;
use diagnoser::{Failure, Plant, Time, TimeUnit, time};
use filter_coupling::filter::Coupling;
use logs::{IngestOptions, LogFormat};

/// What `diagnose` and `report` both read: the plant, the model, the logs, and
/// how to replay them.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Plant file: signals, parts, faults and partitions.
    #[arg(long)]
    pub plant: PathBuf,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    pub model: PathBuf,
    /// Logs to replay (any form); each is replayed from its own initial values.
    /// A directory stands for the logs in it (`.csv`, `.parquet`, `.log`,
    /// `.vcd`), by name; a quoted file name with `*` or `?` for the files it
    /// matches, by name (more than a command line holds).
    #[arg(required = true, value_name = "LOG")]
    pub logs: Vec<PathBuf>,
    /// Log form (default: detected from each file's header): events-csv,
    /// intervals-csv, scans-csv, events-parquet, intervals-parquet, scans-parquet,
    /// candump or vcd.
    #[arg(long)]
    pub format: Option<LogFormat>,
    /// Unit of numeric timestamps in the logs (default: the plant file's).
    #[arg(long)]
    pub time_unit: Option<TimeUnit>,
    /// Longest an unexpected sensor edge shows before the sensor reads its real
    /// value again (longer, it is a stuck sensor).
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    pub glitch_max: Time,
    /// Time at which the logs end, when later than their last event (in the
    /// logs' time unit): deadlines up to it still count. Default: the log's end
    /// row if it has one (events form), else its last event.
    #[arg(long, value_name = "TIME")]
    pub end: Option<f64>,
}

impl ReplayArgs {
    /// How the logs are read.
    pub fn ingest(&self, plant: &Plant) -> IngestOptions {
        IngestOptions {
            format: self.format,
            time_unit: self.time_unit.unwrap_or(plant.time_unit),
            ..IngestOptions::default()
        }
    }

    /// The diagnosers' settings.
    pub fn options(&self) -> DiagnoserOptions {
        DiagnoserOptions {
            glitch_max: self.glitch_max,
            ..DiagnoserOptions::default()
        }
    }

    /// `--end` in nanoseconds.
    pub fn end(&self, plant: &Plant) -> Option<Time> {
        let unit = self.time_unit.unwrap_or(plant.time_unit);
        self.end.map(|e| (e * unit.nanos() as f64).round() as Time)
    }

    /// The log files, directories and patterns replaced by the logs they
    /// stand for.
    pub fn log_files(&self) -> Result<Vec<PathBuf>, Failure> {
        logs::expand_dirs(&self.logs).map_err(Failure::bad)
    }

    /// What the report replays: these files, read and diagnosed as `diagnose`
    /// does.
    pub fn for_report(&self, plant: &Plant) -> Result<report::Replay, Failure> {
        Ok(report::Replay {
            plant_path: self.plant.clone(),
            model_path: self.model.clone(),
            logs: self.log_files()?,
            ingest: self.ingest(plant),
            options: self.options(),
            end: self.end(plant),
        })
    }
}

/// How a filter uses the diagnosers' flags (the virtual PLC's, the generated
/// Structured Text's, the report's replay).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CouplingArg {
    /// The constraints read the sensors as they are.
    None,
    /// `def_<partition>` switches a sensor to its estimate, and sends to its
    /// fallback the part of an actuator, element, or sensor with no estimate.
    Def,
    /// As `def`, and on `suspect_<partition>` a sensor reads the union of its
    /// reading and its estimate.
    #[value(name = "def+suspect")]
    DefSuspect,
}

impl From<CouplingArg> for Coupling {
    fn from(c: CouplingArg) -> Coupling {
        match c {
            CouplingArg::None => Coupling::None,
            CouplingArg::Def => Coupling::Flags,
            CouplingArg::DefSuspect => Coupling::FlagsAndSuspects,
        }
    }
}
