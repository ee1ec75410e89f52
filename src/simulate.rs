//! `gardefou simulate`: run a reference plant and write its logs, ground truth
//! and damage record, or run it in real time as a virtual PLC served over
//! Modbus TCP (`--serve-modbus`, see [`runtime::virtual_plc`]).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use datasets::generated::{Family, GeneratedPlant, Size};
use datasets::inject::{FaultSpec, Injection};
use datasets::output::{ArchiveWriter, RunFiles, write_run};
use datasets::sim::SimConfig;
use datasets::{cylinders, sorting};
use diagnoser::model::Model;
use diagnoser::{Failure, MS, Time, time};
use filter_coupling::filter::{Coupling, Filter};
use indicatif::{ProgressBar, ProgressStyle};
use runtime::closed_loop::CoupledPlc;
use runtime::virtual_plc::{self, VirtualPlc};

use crate::args::CouplingArg;

/// Which plant to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PlantKind {
    /// The box-sorting line of seeds 001 and 002.
    Sorting,
    /// The four-cylinder rig of seed 001 §5.
    Cylinders,
    /// A plant drawn from --plant-seed and --size: a line of stations with
    /// cylinders, arms, tables, grippers, conveyors and magazines.
    Generated,
}

/// The size of a generated plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SizeArg {
    /// 2 to 5 parts.
    Small,
    /// 6 to 11 parts.
    Medium,
    /// 12 to 20 parts.
    Large,
}

/// What a generated plant is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FamilyArg {
    /// A line of assembly stations: cylinders, swivel arms, grippers, rotary
    /// tables, conveyors, magazines.
    Assembly,
    /// Tanks with level switches, inlet and outlet valves or pumps, heaters
    /// or coolers with thermostats.
    Process,
    /// Positioning cells: electric axes with cam switches, creep speed, brake,
    /// a clamp and recipes.
    Axes,
    /// An assembly line beside tanks and positioning cells.
    Mixed,
}

impl From<FamilyArg> for Family {
    fn from(f: FamilyArg) -> Family {
        match f {
            FamilyArg::Assembly => Family::Assembly,
            FamilyArg::Process => Family::Process,
            FamilyArg::Axes => Family::Axes,
            FamilyArg::Mixed => Family::Mixed,
        }
    }
}

impl From<SizeArg> for Size {
    fn from(s: SizeArg) -> Size {
        match s {
            SizeArg::Small => Size::Small,
            SizeArg::Medium => Size::Medium,
            SizeArg::Large => Size::Large,
        }
    }
}

/// Where the orders come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ControlKind {
    /// The plant's control program (the sorting line: seed 001's eq. 68–74).
    Program,
    /// Safe control by constraints through the safety filter, flags unused
    /// (sorting line only).
    Constraints,
}

/// Arguments of `gardefou simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Plant to simulate.
    #[arg(long, value_enum, default_value = "sorting")]
    plant: PlantKind,
    /// Which generated plant (with --plant generated); --seed draws the run.
    #[arg(long, value_name = "N")]
    plant_seed: Option<u64>,
    /// Size of the generated plant (with --plant generated).
    #[arg(long, value_enum, default_value = "medium")]
    size: SizeArg,
    /// What the generated plant is made of (with --plant generated).
    #[arg(long, value_enum, default_value = "assembly")]
    family: FamilyArg,
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
    /// PLC scan period in milliseconds [default: 10; a generated plant's own].
    #[arg(long)]
    scan_ms: Option<f64>,
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
    /// Where the orders come from [default: program; constraints with
    /// --serve-modbus].
    #[arg(long, value_enum)]
    control: Option<ControlKind>,
    /// Instead of writing files, run the sorting line as a virtual PLC serving
    /// its sensors, orders and flags over Modbus TCP on ADDR (e.g.
    /// 127.0.0.1:5020; port 0 picks a free port). Needs --realtime and --model.
    #[arg(long, value_name = "ADDR", conflicts_with_all = ["out", "scans", "parquet"])]
    serve_modbus: Option<String>,
    /// Run in real time: one scan per scan period of wall time (divided by
    /// --speed). Only with --serve-modbus.
    #[arg(long)]
    realtime: bool,
    /// Simulated time per wall-clock time in real time, e.g. 10 [default: 1].
    #[arg(long)]
    speed: Option<f64>,
    /// Learned model whose estimates the virtual PLC's filter uses (with
    /// --serve-modbus).
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// How the virtual PLC's filter uses the flags clients write [default: def].
    #[arg(long, value_enum)]
    coupling: Option<CouplingArg>,
    /// A plant file for the virtual PLC's filter and register map (its
    /// constraints, observers, faults, partitions and `[modbus]`) instead of
    /// the shipped sorting line's; its signals must be the sorting line's, in
    /// the same order. Only with --serve-modbus.
    #[arg(long, value_name = "FILE")]
    plant_file: Option<PathBuf>,
}

/// The generated plant of `--plant-seed` and `--size`, if asked for.
fn generated(args: &SimulateArgs) -> Result<Option<GeneratedPlant>, Failure> {
    match (args.plant, args.plant_seed) {
        (PlantKind::Generated, Some(seed)) => {
            GeneratedPlant::generate_family(seed, args.size.into(), args.family.into())
                .map(Some)
                .map_err(|e| {
                    Failure::Io(format!(
                        "the generator wrote a plant file that does not load: {e}"
                    ))
                })
        }
        (PlantKind::Generated, None) => Err(Failure::BadInput(
            "--plant generated needs --plant-seed N: the seed that draws the plant".into(),
        )),
        (_, Some(_)) => Err(Failure::BadInput(
            "--plant-seed only goes with --plant generated".into(),
        )),
        (_, None) => Ok(None),
    }
}

/// Runs `gardefou simulate`.
pub fn run(args: SimulateArgs) -> Result<(), Failure> {
    let generated = generated(&args)?;
    let scan_period = match args.scan_ms {
        Some(ms) if !(ms.is_finite() && (0.001..=60_000.0).contains(&ms)) => {
            return Err(Failure::BadInput(format!(
                "bad --scan-ms {ms}: expected a period between 0.001 and 60000 ms"
            )));
        }
        Some(ms) => (ms * MS as f64).round() as Time,
        None => generated
            .as_ref()
            .map_or(10 * MS, |g| g.plant().scan_period),
    };
    let plant = match (&generated, args.plant, &args.plant_file) {
        (_, PlantKind::Sorting, Some(file)) if args.serve_modbus.is_some() => {
            sorting_plant_file(file)?
        }
        (_, _, Some(_)) => {
            return Err(Failure::BadInput(
                "--plant-file only goes with --serve-modbus ADDR (the virtual PLC, sorting line)"
                    .into(),
            ));
        }
        (Some(g), _, None) => g.plant().clone(),
        (None, PlantKind::Cylinders, None) => cylinders::plant(),
        (None, _, None) => sorting::plant(),
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
    let control = args.control.unwrap_or(if args.serve_modbus.is_some() {
        ControlKind::Constraints
    } else {
        ControlKind::Program
    });
    if control == ControlKind::Constraints && args.plant != PlantKind::Sorting {
        let what = if args.serve_modbus.is_some() {
            "--serve-modbus"
        } else {
            "--control constraints"
        };
        return Err(Failure::BadInput(format!(
            "{what}: only the sorting plant is supported, not {}",
            plant.name
        )));
    }
    let Some(addr) = &args.serve_modbus else {
        let virtual_only = [
            ("--realtime", args.realtime),
            ("--speed", args.speed.is_some()),
            ("--model", args.model.is_some()),
            ("--coupling", args.coupling.is_some()),
        ];
        if let Some((name, _)) = virtual_only.iter().find(|(_, given)| *given) {
            return Err(Failure::BadInput(format!(
                "{name} only goes with --serve-modbus ADDR (the virtual PLC)"
            )));
        }
        return write_files(
            &args,
            &plant,
            generated.as_ref(),
            control,
            scan_period,
            faults,
        );
    };
    if !args.realtime {
        return Err(Failure::BadInput(
            "--serve-modbus needs --realtime: the virtual PLC scans in real time".into(),
        ));
    }
    let Some(model_path) = &args.model else {
        return Err(Failure::BadInput(
            "--serve-modbus needs --model M: the filter's sensor estimates".into(),
        ));
    };
    if control != ControlKind::Constraints {
        return Err(Failure::BadInput(
            "--serve-modbus runs safe control by constraints: --control program is not supported"
                .into(),
        ));
    }
    let speed = args.speed.unwrap_or(1.0);
    if !(speed.is_finite() && (0.01..=10_000.0).contains(&speed)) {
        return Err(Failure::BadInput(format!(
            "bad --speed {speed}: expected a factor between 0.01 and 10000"
        )));
    }
    let model = Model::from_path(model_path).map_err(|e| Failure::BadInput(e.to_string()))?;
    let plc = VirtualPlc {
        addr: addr.clone(),
        speed,
        model,
        coupling: args.coupling.map_or(Coupling::Flags, Coupling::from),
        config: SimConfig {
            duration: args.duration,
            scan_period,
            seed: args.seed,
            faults,
        },
    };
    virtual_plc::run(&plant, plc)
}

/// The plant file `path`, for the virtual PLC: the sorting line's physics
/// drive its signals by index, so they must be the sorting line's, in order.
fn sorting_plant_file(path: &Path) -> Result<diagnoser::Plant, Failure> {
    let plant = diagnoser::Plant::from_path(path).map_err(Failure::bad)?;
    let signals = |p: &diagnoser::Plant| -> Vec<(String, diagnoser::SignalKind)> {
        p.signals
            .iter()
            .map(|(_, s)| (s.name.clone(), s.kind))
            .collect()
    };
    let line = signals(&sorting::plant());
    if signals(&plant) != line {
        let names: Vec<&str> = line.iter().map(|(n, _)| n.as_str()).collect();
        return Err(Failure::BadInput(format!(
            "{}: field 'signals': the virtual PLC runs the sorting line: its plant file must declare the line's signals, in order ({})",
            path.display(),
            names.join(" ")
        )));
    }
    Ok(plant)
}

/// Runs the plant to the end and writes its files into `--out`.
fn write_files(
    args: &SimulateArgs,
    plant: &diagnoser::Plant,
    generated: Option<&GeneratedPlant>,
    control: ControlKind,
    scan_period: Time,
    faults: Vec<Injection>,
) -> Result<(), Failure> {
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
    crate::interrupt::remove_on_interrupt(datasets::output::staging_dir(&args.out));

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
        archive: args
            .parquet
            .then_some(write_parquet_archive as ArchiveWriter),
    };
    let progress = |t: Time| bar.set_position((t / scan_period.max(1)) as u64);
    let report = match args.plant {
        PlantKind::Sorting => {
            let mut line = sorting::SortingLine::new(sorting::SortingConfig::default());
            if control == ControlKind::Constraints {
                let mut control = constraint_control(plant)?;
                write_run(&files, &mut line, &mut control, &config, progress)
            } else {
                let mut control = sorting::SynthesisedControl::new(line.ids());
                write_run(&files, &mut line, &mut control, &config, progress)
            }
        }
        PlantKind::Cylinders => {
            let mut rig = cylinders::CylinderRig::new(cylinders::CylinderConfig::default());
            let mut control = cylinders::ConstraintControl::new(rig.ids());
            write_run(&files, &mut rig, &mut control, &config, progress)
        }
        PlantKind::Generated => {
            let Some(g) = generated else {
                return Err(Failure::BadInput(
                    "--plant generated needs --plant-seed".into(),
                ));
            };
            write_run(
                &files,
                &mut g.physics(),
                &mut g.program(),
                &config,
                progress,
            )
        }
    }
    .map_err(|e| Failure::Io(format!("cannot write {}: {e}", args.out.display())))?;
    bar.finish_and_clear();

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

/// Safe control by constraints through the safety filter, flags unused: the
/// control under which the demo records the runs it learns from.
fn constraint_control(plant: &diagnoser::Plant) -> Result<CoupledPlc, Failure> {
    let filter = Filter::new(plant, None, Coupling::None).map_err(Failure::BadInput)?;
    Ok(CoupledPlc::new(filter, None, 0))
}

/// Writes `intervals.parquet` beside a finished run's `events.csv`.
fn write_parquet_archive(dir: &Path, plant: &diagnoser::Plant, end: Time) -> std::io::Result<()> {
    let log = logs::read_events(&dir.join("events.csv"), &plant.signals, plant.time_unit)
        .map_err(std::io::Error::other)?;
    logs::write_intervals_parquet(&log, &plant.signals, &dir.join("intervals.parquet"), end)
}

#[cfg(test)]
mod tests {
    use datasets::sim::{MemorySink, SimConfig};
    use diagnoser::SECOND;

    use super::*;

    #[test]
    fn constraint_control_is_the_demo_recording() {
        let plant = sorting::plant();
        let (seed, duration) = (5, 600 * SECOND);
        let mut line = sorting::SortingLine::new(sorting::SortingConfig::default());
        let Ok(mut control) = constraint_control(&plant) else {
            panic!("the sorting plant has a filter");
        };
        let config = SimConfig {
            duration,
            scan_period: plant.scan_period,
            seed,
            faults: Vec::new(),
        };
        let mut ours = MemorySink::default();
        datasets::sim::run(&mut line, &mut control, &config, &mut ours, |_| {}).expect("runs");
        let demo = runtime::closed_loop::record(&plant, seed, duration).expect("runs");
        assert!(ours.events.len() > 100, "{} events", ours.events.len());
        assert_eq!(ours.initial, demo.initial);
        assert_eq!(ours.events, demo.events);
    }
}
