//! `gardefou simulate`: run a reference plant and write its logs, ground truth
//! and damage record.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use datasets::inject::{FaultSpec, Injection};
use datasets::output::{RunFiles, write_run};
use datasets::sim::SimConfig;
use datasets::{cylinders, sorting};
use diagnoser::{MS, Time, time};
use indicatif::{ProgressBar, ProgressStyle};

use crate::Failure;

/// Which reference plant to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PlantKind {
    /// The box-sorting line of seeds 001 and 002.
    Sorting,
    /// The four-cylinder rig of seed 001 §5.
    Cylinders,
}

/// Arguments of `gardefou simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Plant to simulate.
    #[arg(long, value_enum, default_value = "sorting")]
    plant: PlantKind,
    /// Simulated duration, e.g. 90s, 20min, 2h, 3d.
    #[arg(long, default_value = "1h", value_parser = time::parse_duration)]
    duration: Time,
    /// Seed of every random draw; the same seed gives byte-identical files.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Fault to inject, LABEL@TIME (a label of the plant file, e.g. F2@600s) or
    /// TEMPLATE@TIME (e.g. 'stuck1(C4)@10min'). Repeatable.
    #[arg(long = "fault", value_name = "LABEL@TIME")]
    faults: Vec<FaultSpec>,
    /// PLC scan period in milliseconds.
    #[arg(long, default_value_t = 10.0)]
    scan_ms: f64,
    /// Also write the wide form, scans.csv (one row per scan: large).
    #[arg(long)]
    scans: bool,
    /// Also write the archive form as Parquet, intervals.parquet.
    #[arg(long)]
    parquet: bool,
    /// Directory to write events.csv, intervals.csv, truth.json, damage.json and
    /// plant.toml into (created if needed; files are replaced only on success).
    #[arg(long, default_value = "simulation")]
    out: PathBuf,
}

/// Runs `gardefou simulate`.
pub fn run(args: SimulateArgs) -> Result<(), Failure> {
    if !(args.scan_ms.is_finite() && args.scan_ms >= 0.001 && args.scan_ms <= 60_000.0) {
        return Err(Failure::BadInput(format!(
            "bad --scan-ms {}: expected a period between 0.001 and 60000 ms",
            args.scan_ms
        )));
    }
    let scan_period = (args.scan_ms * MS as f64).round() as Time;
    let plant = match args.plant {
        PlantKind::Sorting => sorting::plant(),
        PlantKind::Cylinders => cylinders::plant(),
    };
    let faults = args
        .faults
        .iter()
        .map(|f| Injection::resolve(f, &plant))
        .collect::<Result<Vec<_>, _>>()
        .map_err(Failure::BadInput)?;
    if let Some(late) = faults.iter().find(|f| f.onset > args.duration) {
        return Err(Failure::BadInput(format!(
            "fault {} starts at {} s, after the end of the run ({} s)",
            late.label,
            late.onset as f64 / 1e9,
            args.duration as f64 / 1e9
        )));
    }
    if args.out.exists() && !args.out.is_dir() {
        return Err(Failure::BadInput(format!(
            "--out {} exists and is not a directory",
            args.out.display()
        )));
    }
    let config = SimConfig {
        duration: args.duration,
        scan_period,
        seed: args.seed,
        faults,
    };

    let bar = if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new((args.duration / scan_period.max(1)) as u64);
        bar.set_style(
            ProgressStyle::with_template("{spinner} simulating [{bar:40}] {percent}% ({eta} left)")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let files = RunFiles {
        dir: args.out.clone(),
        scans: args.scans,
    };
    let progress = |t: Time| bar.set_position((t / scan_period.max(1)) as u64);
    let report = match args.plant {
        PlantKind::Sorting => {
            let mut line = sorting::SortingLine::new(sorting::SortingConfig::default());
            let mut control = sorting::SynthesisedControl::new(line.ids());
            write_run(&files, &mut line, &mut control, &config, progress)
        }
        PlantKind::Cylinders => {
            let mut rig = cylinders::CylinderRig::new(cylinders::CylinderConfig::default());
            let mut control = cylinders::ConstraintControl::new(rig.ids());
            write_run(&files, &mut rig, &mut control, &config, progress)
        }
    }
    .map_err(|e| Failure::Io(format!("cannot write {}: {e}", args.out.display())))?;
    bar.finish_and_clear();
    if args.parquet {
        write_parquet_archive(&args.out, &plant, args.duration)?;
    }

    let counters: Vec<String> = report
        .counters
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    eprintln!(
        "simulated {} s of '{}' ({} scans): {} damage event(s); {}; wrote {}",
        args.duration as f64 / 1e9,
        plant.name,
        report.scans,
        report.damage.len(),
        counters.join(", "),
        args.out.display()
    );
    Ok(())
}

/// Writes `intervals.parquet` beside a finished run, from its `events.csv`.
fn write_parquet_archive(
    dir: &std::path::Path,
    plant: &diagnoser::Plant,
    end: Time,
) -> Result<(), Failure> {
    let log = diagnoser::log::read_events(&dir.join("events.csv"), &plant.signals, plant.time_unit)
        .map_err(|e| Failure::Io(e.to_string()))?;
    let tmp = dir.join(format!(".intervals.parquet.{}", std::process::id()));
    learning::ingest::write_intervals_parquet(&log, &plant.signals, &tmp, end)
        .and_then(|()| std::fs::rename(&tmp, dir.join("intervals.parquet")))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            Failure::Io(format!(
                "cannot write {}: {e}",
                dir.join("intervals.parquet").display()
            ))
        })
}
