//! `gardefou filter`: the safety filter's constraints, rewritten with fault flags
//! and temporal estimates.

use std::io::Write;
use std::path::PathBuf;

use clap::{Args, Subcommand};
use diagnoser::model::Model;
use diagnoser::{FaultTemplate, Plant};
use filter_coupling::rewrite::{Estimate, RewriteOptions, rewrite};

use crate::Failure;

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
    /// Also switch to the estimate on `suspect_<partition>`.
    #[arg(long)]
    suspects: bool,
}

fn bad(e: impl std::fmt::Display) -> Failure {
    Failure::BadInput(e.to_string())
}

/// Runs `gardefou filter`.
pub fn run(args: FilterArgs) -> Result<(), Failure> {
    match args.command {
        FilterCommand::Rewrite(a) => rewrite_cmd(a),
    }
}

/// The partition holding a sensor fault of `sensor`, else the sensor's name.
fn partition_of(plant: &Plant, sensor: &str) -> String {
    plant
        .faults
        .iter()
        .filter(|f| {
            matches!(
                &f.template,
                FaultTemplate::Stuck0(s) | FaultTemplate::Stuck1(s)
                | FaultTemplate::UnexpectedRise(s) | FaultTemplate::UnexpectedFall(s) if s == sensor
            )
        })
        .find_map(|f| plant.partition_of(&f.label))
        .map_or_else(|| sensor.to_string(), |p| p.name.clone())
}

fn rewrite_cmd(args: RewriteArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(bad)?;
    let model = Model::from_path(&args.model).map_err(bad)?;
    let mut estimates = Vec::new();
    for part in &model.parts {
        for e in &part.sensor_estimates {
            let partition = partition_of(&plant, &e.sensor);
            let wanted = args.flags.is_empty()
                || args.flags.iter().any(|f| *f == format!("def_{partition}"));
            if wanted {
                estimates.push(
                    Estimate::from_model(&e.sensor, &partition, &e.expr, &e.uncertain)
                        .map_err(|m| bad(format!("{}: {m}", args.model.display())))?,
                );
            }
        }
    }
    for f in &args.flags {
        if !estimates
            .iter()
            .any(|e| format!("def_{}", e.partition) == *f)
        {
            return Err(bad(format!(
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
