//! `gardefou filter`: the safety filter's constraints, rewritten with fault flags
//! and temporal estimates (`rewrite`), and the whole filter as IEC 61131-3
//! Structured Text (`st`).

use std::io::Write;
use std::path::PathBuf;

use clap::{Args, Subcommand, ValueEnum};
use diagnoser::model::Model;
use diagnoser::{Failure, Flag, Plant, TimeFormat, TimeUnit};
use filter_coupling::filter::{Coupling, Filter, Mode, sensor_partition};
use filter_coupling::rewrite::{Estimate, RewriteOptions, rewrite};
use filter_coupling::st::{StOptions, generate};

use logs::{IngestOptions, LogFormat, open};

use crate::args::CouplingArg;
/// Arguments of `gardefou filter`.
#[derive(Debug, Args)]
pub struct FilterArgs {
    #[command(subcommand)]
    command: FilterCommand,
}

#[derive(Debug, Subcommand)]
enum FilterCommand {
    /// Print the safety constraints rewritten so that failed sensors read their
    /// temporal estimates (conservatively in the uncertain intervals).
    Rewrite(RewriteArgs),
    /// Print the safety filter as an IEC 61131-3 Structured Text function block:
    /// observers, estimate intervals (TON), the check of the orders and the
    /// fallback; with `--control`, safe control by constraints as well.
    St(StArgs),
    /// Replay logs against the safety constraints: one JSON line each time a
    /// constraint starts to hold, with the literals that made it true.
    Check(CheckArgs),
}

/// Arguments of `gardefou filter check`.
#[derive(Debug, Args)]
struct CheckArgs {
    /// Plant file: signals, observers and constraints.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (the sensors' estimates); needed with `--flags`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Flags raised for the whole replay, e.g. `def_C4`: the constraints read
    /// the flagged sensors' estimates (then every scan period is checked, not
    /// only the scans with a change, since the estimates move with time).
    #[arg(long, value_delimiter = ',')]
    flags: Vec<String>,
    /// Logs to check (any form).
    #[arg(required = true, value_name = "LOG")]
    logs: Vec<PathBuf>,
    /// Log form (default: detected from each file's header).
    #[arg(long)]
    format: Option<LogFormat>,
    /// Unit of numeric timestamps in the logs (default: the plant file's).
    #[arg(long)]
    time_unit: Option<TimeUnit>,
}

/// Arguments of `gardefou filter st`.
#[derive(Debug, Args)]
struct StArgs {
    /// Plant file: signals, observers, constraints, faults and partitions.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (the sensors' estimates); needed unless `--coupling none`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// How the flags are used [default: def, or def+suspect with --suspects].
    #[arg(long, value_enum)]
    coupling: Option<CouplingArg>,
    /// Also read a sensor as the union of its reading and its estimate on
    /// `suspect_<partition>` (same as `--coupling def+suspect`).
    #[arg(long)]
    suspects: bool,
    /// Compute the orders by safe control by constraints (seed 001 §4) instead
    /// of checking the control program's.
    #[arg(long)]
    control: bool,
    /// Name of the function block.
    #[arg(long, default_value = "GARDEFOU_FILTER")]
    name: String,
}

/// Arguments of `gardefou filter rewrite`.
#[derive(Debug, Args)]
struct RewriteArgs {
    /// Plant file: constraints, faults and partitions.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (the sensors' estimates).
    #[arg(long)]
    model: PathBuf,
    /// Rewrite only for these flags, e.g. `def_C4,def_C5` (default: every sensor
    /// with an estimate).
    #[arg(long, value_delimiter = ',')]
    flags: Vec<String>,
    /// Also read a sensor as the union of its reading and its estimate on
    /// `suspect_<partition>`.
    #[arg(long)]
    suspects: bool,
}

/// Runs `gardefou filter`.
pub fn run(args: FilterArgs) -> Result<(), Failure> {
    match args.command {
        FilterCommand::Rewrite(a) => rewrite_cmd(a),
        FilterCommand::St(a) => st_cmd(a),
        FilterCommand::Check(a) => check_cmd(a),
    }
}

fn rewrite_cmd(args: RewriteArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&args.model).map_err(Failure::bad)?;
    let mut estimates = Vec::new();
    for part in &model.parts {
        for e in &part.sensor_estimates {
            let partition = sensor_partition(&plant, &e.sensor);
            let wanted = args.flags.is_empty()
                || args
                    .flags
                    .iter()
                    .any(|f| *f == Flag::def(&partition).to_string());
            if wanted {
                estimates.push(
                    Estimate::from_model(&e.sensor, &partition, &e.intervals(), &e.uncertain)
                        .map_err(|m| Failure::bad(format!("{}: {m}", args.model.display())))?,
                );
            }
        }
    }
    for f in &args.flags {
        if !estimates
            .iter()
            .any(|e| Flag::def(&e.partition).to_string() == *f)
        {
            return Err(Failure::bad(format!(
                "--flags: '{f}' is not the flag of a sensor with a learned estimate"
            )));
        }
    }
    let options = RewriteOptions {
        use_suspects: args.suspects,
    };
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    for c in &plant.constraints {
        let r = rewrite(&c.expr, &estimates, options);
        if r != c.expr {
            writeln!(out, "{} = {}", c.name, r).map_err(Failure::output)?;
        }
    }
    for e in &estimates {
        writeln!(
            out,
            "# {}: estimate {} (uncertain: {})",
            e.sensor,
            e.certain
                .iter()
                .chain(&e.uncertain)
                .cloned()
                .collect::<Vec<_>>()
                .join(" | "),
            e.uncertain.join(", ")
        )
        .map_err(Failure::output)?;
    }
    Ok(())
}

fn st_cmd(args: StArgs) -> Result<(), Failure> {
    let coupling = match (args.coupling, args.suspects) {
        (None, false) => Coupling::Flags,
        (None | Some(CouplingArg::DefSuspect), true) | (Some(CouplingArg::DefSuspect), false) => {
            Coupling::FlagsAndSuspects
        }
        (Some(CouplingArg::Def), false) => Coupling::Flags,
        (Some(CouplingArg::None), false) => Coupling::None,
        (Some(c @ (CouplingArg::None | CouplingArg::Def)), true) => {
            return Err(Failure::bad(format!(
                "--suspects means --coupling def+suspect, not --coupling {}",
                c.to_possible_value()
                    .map_or_else(String::new, |v| v.get_name().to_string())
            )));
        }
    };
    let identifier = args
        .name
        .starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
        && args
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !args.name.contains("__")
        && !args.name.ends_with('_');
    if !identifier {
        return Err(Failure::bad(format!(
            "--name: '{}' is not a Structured Text identifier",
            args.name
        )));
    }
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let model = match &args.model {
        Some(path) => {
            let model = Model::from_path(path).map_err(Failure::bad)?;
            (model.fits(&plant)).map_err(|e| Failure::bad(format!("{}: {e}", path.display())))?;
            Some(model)
        }
        None if coupling != Coupling::None => {
            return Err(Failure::bad(format!(
                "--model is needed for --coupling {} (the sensors' estimates); use --coupling none without it",
                coupling.name()
            )));
        }
        None => None,
    };
    let filter = Filter::new(&plant, model.as_ref(), coupling).map_err(|m| {
        let source = args.model.as_ref().unwrap_or(&args.plant);
        Failure::bad(format!("{}: {m}", source.display()))
    })?;
    let options = StOptions {
        mode: if args.control {
            Mode::Control
        } else {
            Mode::Filter
        },
        name: args.name,
    };
    let text = generate(&plant, &filter, &options)
        .map_err(|m| Failure::bad(format!("{}: {m}", args.plant.display())))?;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    out.write_all(text.as_bytes()).map_err(Failure::output)?;
    out.flush().map_err(Failure::output)
}

fn check_cmd(args: CheckArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    let model = match &args.model {
        Some(path) => Some(Model::from_path(path).map_err(Failure::bad)?),
        None if !args.flags.is_empty() => {
            return Err(Failure::bad(
                "--flags needs --model: a flagged sensor reads its learned estimate",
            ));
        }
        None => None,
    };
    let coupling = if args.flags.is_empty() {
        Coupling::None
    } else {
        Coupling::Flags
    };
    let ingest = IngestOptions {
        format: args.format,
        time_unit: args.time_unit.unwrap_or(plant.time_unit),
        ..IngestOptions::default()
    };
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let several = args.logs.len() > 1;
    let (mut episodes, mut scans) = (0u64, 0u64);
    for path in &args.logs {
        let mut filter = Filter::new(&plant, model.as_ref(), coupling).map_err(|m| {
            Failure::bad(format!(
                "{}: {m}",
                args.model.as_ref().unwrap_or(&args.plant).display()
            ))
        })?;
        for f in &args.flags {
            if !filter.set(f, true) {
                return Err(Failure::bad(format!(
                    "--flags: '{f}' is not a flag of the plant"
                )));
            }
        }
        let stream = open(path, &plant, &ingest).map_err(Failure::bad)?;
        let time = stream.time;
        let name = path.display().to_string();
        let mut io = stream.initial.clone();
        let mut holding: Vec<String> = Vec::new();
        let mut check =
            |t: diagnoser::Time, io: &[bool], out: &mut dyn Write| -> std::io::Result<()> {
                scans += 1;
                let violated = filter.violations(t, io);
                for v in &violated {
                    if !holding.contains(&v.constraint) {
                        episodes += 1;
                        let t = match time {
                            TimeFormat::Numeric(_) => time.format(t),
                            TimeFormat::Rfc3339 => {
                                serde_json::Value::String(time.format(t)).to_string()
                            }
                        };
                        let log = if several {
                            format!("\"log\":{},", serde_json::Value::String(name.clone()))
                        } else {
                            String::new()
                        };
                        writeln!(
                            out,
                            "{{\"t\":{t},{log}\"constraint\":{},\"literals\":{}}}",
                            serde_json::Value::String(v.constraint.clone()),
                            serde_json::Value::from(v.literals.clone())
                        )?;
                    }
                }
                holding.clear();
                holding.extend(violated.into_iter().map(|v| v.constraint));
                Ok(())
            };
        let period = plant.scan_period.max(1);
        let every_scan = !args.flags.is_empty();
        let mut t = stream.start;
        check(t, &io, &mut out).map_err(Failure::output)?;
        let mut pending: Option<diagnoser::Time> = None;
        for batch in stream.batches {
            let batch = batch.map_err(Failure::bad)?;
            for e in &batch {
                if pending.is_some_and(|p| p != e.t) {
                    // The scan at `p` is complete.
                    if let Some(p) = pending {
                        if every_scan {
                            while t + period < p {
                                t += period;
                                check(t, &io, &mut out).map_err(Failure::output)?;
                            }
                        }
                        t = p;
                        check(t, &io, &mut out).map_err(Failure::output)?;
                    }
                }
                pending = Some(e.t);
                if let Some(v) = io.get_mut(e.signal.index()) {
                    *v = e.value;
                }
            }
        }
        if let Some(p) = pending {
            if every_scan {
                while t + period < p {
                    t += period;
                    check(t, &io, &mut out).map_err(Failure::output)?;
                }
            }
            check(p, &io, &mut out).map_err(Failure::output)?;
        }
    }
    out.flush().map_err(Failure::output)?;
    eprintln!("{scans} scans checked: {episodes} times a safety constraint started to hold");
    Ok(())
}
