//! `gardefou demo`: the whole chain on an embedded plant (the sorting line
//! with no argument, or `--plant cylinders`), in closed loop.
//!
//! One simulated hour of fault-free operation under safe control by
//! constraints is learned. Then each fault (by default the plant file's list:
//! seed 002's twelve turntable faults; with `--faults all`, every fault the
//! plant's parts can have) starts at a random time after a warm-up, so at a
//! random phase of the line's cycle, and the line runs one hour in three modes:
//! (a) the filter reads the sensors as they are; (b) `def_` flags switch failed
//! sensors to their estimates and send the part of a flagged actuator, element
//! or sensor with no estimate to the fallback; (c) `suspect_` flags also switch
//! sensors. With `--seeds N` every scenario runs on N seeds, each with its own
//! onset. Each row gives, over those runs, the throughput against the same
//! seed's fault-free run counted from the same onset, damage, the detection
//! delay and the time halted, all counted from the onset.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::Path;

use clap::{Args, ValueEnum};
use datasets::inject::Injection;
use diagnoser::model::Model;
use diagnoser::{Failure, FaultTemplate, MS, Plant, SECOND, Time};
use filter_coupling::filter::Coupling;
use indicatif::{ProgressBar, ProgressStyle};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use runtime::closed_loop::{self, LoopOutcome, LoopRun};
use serde::Serialize;

/// Arguments of `gardefou demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Print the rows as a JSON array instead of a table.
    #[arg(long)]
    json: bool,
    /// Also write the table to docs/demo.md (run from the repository's root).
    #[arg(long)]
    write_docs: bool,
    /// Runs per scenario and mode, each on its own seed with its own onset.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    seeds: u32,
    /// The faults injected: the plant file's list, or every fault its parts
    /// can have (each sensor stuck or pulsing, each actuator stuck, each
    /// element blocked), which the diagnosers then also learn.
    #[arg(long, value_enum, default_value_t = FaultSet::Listed)]
    faults: FaultSet,
    /// The plant run in closed loop.
    #[arg(long, value_enum, default_value_t = PlantChoice::Sorting)]
    plant: PlantChoice,
}

/// The embedded plants the closed loop can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum PlantChoice {
    /// The sorting line (seed 002's turntable and its conveyors).
    Sorting,
    /// The four-cylinder teaching rig (seed 001), under its GRAFCETs.
    Cylinders,
}

impl PlantChoice {
    fn plant(self) -> Plant {
        match self {
            PlantChoice::Sorting => datasets::sorting::plant(),
            PlantChoice::Cylinders => datasets::cylinders::plant(),
        }
    }

    fn name(self) -> &'static str {
        match self {
            PlantChoice::Sorting => "sorting",
            PlantChoice::Cylinders => "cylinders",
        }
    }

    /// The plant and its unit of work, as the preamble says them.
    fn described(self) -> (&'static str, &'static str) {
        match self {
            PlantChoice::Sorting => ("sorting line", "boxes delivered"),
            PlantChoice::Cylinders => (
                "four-cylinder rig, under its GRAFCETs",
                "objects moved from corner to corner",
            ),
        }
    }
}

/// Which faults the experiment injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FaultSet {
    /// The plant file's `[faults]`.
    Listed,
    /// Every fault the plant's parts can have, in the default partitions.
    All,
}

/// One row of the experiment: a scenario in one mode, over every seed.
#[derive(Debug, Clone, Serialize)]
struct Row {
    /// Label and template, e.g. `F1 stuck0(C4)`.
    scenario: String,
    /// What the coupling does once the fault is declared: `estimate` (the
    /// sensor's temporal estimate stands in) or `part stopped` (its part goes
    /// to the fallback).
    declared: &'static str,
    mode: &'static str,
    runs: usize,
    /// What a unit of work is: `boxes delivered`, `objects moved`.
    work: &'static str,
    /// Mean over the runs of work done per hour from the onset.
    work_per_hour: f64,
    /// The same, for each run's seed without the fault, from the same onset.
    nominal_work_per_hour: f64,
    /// Throughput as a % of nominal, mean and worst run.
    throughput_mean_pct: f64,
    throughput_worst_pct: f64,
    /// Damage events over every run, and runs with at least one.
    damage_events: usize,
    damaged_runs: usize,
    /// Damage events by cause (the simulator's `cause`), over every run.
    damage_causes: BTreeMap<&'static str, usize>,
    /// Runs with a verdict other than normal after the onset.
    detected_runs: usize,
    detection_median_ms: Option<f64>,
    detection_worst_ms: Option<f64>,
    /// Time halted, mean and worst run.
    halted_mean_ms: f64,
    halted_worst_ms: f64,
    /// Probing moves made over every run (mode c), and what they told, once
    /// per distinct reason.
    probes: usize,
    probe_outcomes: Vec<String>,
    /// Why no probe was made where a part waited, ambiguous, once per reason.
    no_probe: Vec<String>,
}

/// A fault of the experiment.
struct Scenario {
    label: String,
    template: FaultTemplate,
    declared: &'static str,
}

/// One closed-loop run: of a scenario in a mode (indices), or `None` for a
/// seed's fault-free reference.
struct Job {
    scenario_mode: Option<(usize, usize)>,
    seed: usize,
    run: LoopRun,
}

const MODES: [(&str, Coupling); 3] = [
    ("a", Coupling::None),
    ("b", Coupling::Flags),
    ("c", Coupling::FlagsAndSuspects),
];
/// The first run's seed; run k of a scenario has seed `SEED + k`.
const SEED: u64 = 11;
/// The fault-free hour the model is learned from.
const LEARNING_SEED: u64 = 7;
const DURATION: Time = 3600 * SECOND;
/// Onsets are drawn in [WARM_UP, WARM_UP + SPREAD).
const WARM_UP: Time = 600 * SECOND;
const SPREAD: Time = 600 * SECOND;

/// Where `demo --write-docs` writes its table.
const DOCS_TABLE: &str = "docs/demo.md";

/// Runs `gardefou demo`.
pub fn run(args: DemoArgs) -> Result<(), Failure> {
    let internal = |e: String| Failure::Io(format!("embedded {} plant: {e}", args.plant.name()));
    let plant = match args.faults {
        FaultSet::Listed => args.plant.plant(),
        FaultSet::All => args.plant.plant().with_every_fault(),
    };
    let rig = closed_loop::Rig::of(&plant).map_err(internal)?;
    let model = closed_loop::learned(&plant, LEARNING_SEED, 3600 * SECOND).map_err(internal)?;
    let (scenarios, not_run) = scenarios(&plant, &model, rig);
    let jobs = jobs(&plant, &scenarios, args.seeds as usize).map_err(internal)?;
    let outcomes = run_all(&plant, &model, &jobs).map_err(internal)?;
    let rows = rows(&scenarios, &jobs, &outcomes, rig.work());

    let mut table = markdown(&rows);
    table.push_str(&not_run_notes(&not_run));
    if args.write_docs {
        write_docs(&table, &args, model.learned_from.events)
            .map_err(|e| Failure::Io(format!("{DOCS_TABLE}: {e}")))?;
        eprintln!("table written to {DOCS_TABLE}");
    }
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.json {
        let text = serde_json::to_string_pretty(&rows).map_err(|e| Failure::Io(e.to_string()))?;
        writeln!(out, "{text}").map_err(Failure::output)?;
        return Ok(());
    }
    writeln!(out, "{}\n", preamble(&args, model.learned_from.events)).map_err(Failure::output)?;
    write!(out, "{table}").map_err(Failure::output)?;
    Ok(())
}

/// The plant's faults the rig can simulate, with what the coupling does with
/// each once declared; and those it cannot, with why.
fn scenarios(plant: &Plant, model: &Model, rig: closed_loop::Rig) -> (Vec<Scenario>, Vec<String>) {
    let estimated = |s: &str| {
        model
            .parts
            .iter()
            .any(|p| p.sensor_estimates.iter().any(|e| e.sensor == s))
    };
    let mut not_run = Vec::new();
    let scenarios = plant
        .faults
        .iter()
        .filter(|f| match rig.simulates(&f.template) {
            Ok(()) => true,
            Err(why) => {
                not_run.push(format!("{} {}: {why}", f.label, f.template));
                false
            }
        })
        .map(|f| {
            let declared = if f.template.sensor().is_some_and(estimated) {
                "estimate"
            } else {
                "part stopped"
            };
            Scenario {
                label: f.label.clone(),
                template: f.template.clone(),
                declared,
            }
        })
        .collect();
    (scenarios, not_run)
}

/// Under the table: the faults the simulator cannot make, which the
/// diagnosers still learned.
fn not_run_notes(not_run: &[String]) -> String {
    if not_run.is_empty() {
        return String::new();
    }
    let lines: Vec<String> = not_run
        .iter()
        .map(|n| {
            format!(
                "- {n}
"
            )
        })
        .collect();
    format!(
        "
Not run, as the simulator cannot make them (the diagnosers learned them all the \
         same):

{}",
        lines.concat()
    )
}

/// Per seed: its fault-free run, then every scenario in every mode, from an
/// onset drawn once per scenario and seed.
fn jobs(plant: &Plant, scenarios: &[Scenario], seeds: usize) -> Result<Vec<Job>, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut jobs = Vec::new();
    for seed in 0..seeds {
        let run = |fault: Option<Injection>, coupling, from| LoopRun {
            coupling,
            seed: SEED + seed as u64,
            duration: DURATION,
            fault,
            from,
            probe: coupling == Coupling::FlagsAndSuspects,
        };
        jobs.push(Job {
            scenario_mode: None,
            seed,
            run: run(None, Coupling::None, 0),
        });
        for (i, s) in scenarios.iter().enumerate() {
            let onset = WARM_UP + rng.random_range(0..SPREAD / MS) * MS;
            let spec = datasets::inject::FaultSpec {
                what: s.label.clone(),
                onset,
                factor: None,
            };
            let fault = Injection::resolve(&spec, plant)?;
            for (m, &(_, coupling)) in MODES.iter().enumerate() {
                jobs.push(Job {
                    scenario_mode: Some((i, m)),
                    seed,
                    run: run(Some(fault.clone()), coupling, onset),
                });
            }
        }
    }
    Ok(jobs)
}

/// Runs the jobs on every core, keeping their order; a progress bar on a
/// terminal.
fn run_all(plant: &Plant, model: &Model, jobs: &[Job]) -> Result<Vec<LoopOutcome>, String> {
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<Option<Result<LoopOutcome, String>>>> =
        std::sync::Mutex::new(vec![None; jobs.len()]);
    let bar = progress_bar(jobs.len());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(job) = jobs.get(i) else { break };
                    let r = closed_loop::run(plant, model, &job.run);
                    if let Ok(mut all) = results.lock() {
                        all[i] = Some(r);
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    let all = results
        .into_inner()
        .map_err(|_| "a run panicked".to_string())?;
    all.into_iter()
        .map(|r| r.unwrap_or_else(|| Err("a run did not finish".into())))
        .collect()
}

fn progress_bar(runs: usize) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(runs as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} closed-loop runs [{bar:40}] {pos}/{len} ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// What one faulty run measured, against its seed's fault-free run.
struct Measured {
    work_per_hour: f64,
    nominal_per_hour: f64,
    damage: usize,
    causes: Vec<&'static str>,
    delay_ms: Option<f64>,
    halted_ms: f64,
    probes: Vec<String>,
    no_probe: Vec<String>,
}

/// One row per scenario and mode, over the seeds.
fn rows(
    scenarios: &[Scenario],
    jobs: &[Job],
    outcomes: &[LoopOutcome],
    work: &'static str,
) -> Vec<Row> {
    let nominal: Vec<&LoopOutcome> = jobs
        .iter()
        .zip(outcomes)
        .filter(|(j, _)| j.scenario_mode.is_none())
        .map(|(_, o)| o)
        .collect();
    let mut rows = Vec::new();
    for (i, s) in scenarios.iter().enumerate() {
        for (m, &(mode, _)) in MODES.iter().enumerate() {
            let runs: Vec<Measured> = jobs
                .iter()
                .zip(outcomes)
                .filter(|(j, _)| j.scenario_mode == Some((i, m)))
                .map(|(j, o)| measured(j, o, nominal[j.seed]))
                .collect();
            rows.push(row(s, mode, work, &runs));
        }
    }
    rows
}

fn measured(job: &Job, outcome: &LoopOutcome, nominal: &LoopOutcome) -> Measured {
    let from = job.run.from;
    let hours = (job.run.duration - from) as f64 / (3600 * SECOND) as f64;
    Measured {
        work_per_hour: outcome.delivered as f64 / hours,
        nominal_per_hour: nominal.delivered_from(from) as f64 / hours,
        damage: outcome.damage.len(),
        causes: outcome.damage.iter().map(|d| d.cause).collect(),
        delay_ms: outcome.detected.map(|t| (t - from) as f64 / MS as f64),
        halted_ms: outcome.halted as f64 / MS as f64,
        probes: outcome.probes.iter().map(|p| p.reason.clone()).collect(),
        no_probe: outcome.no_probe.clone(),
    }
}

fn row(s: &Scenario, mode: &'static str, work: &'static str, runs: &[Measured]) -> Row {
    let n = runs.len().max(1) as f64;
    let pct: Vec<f64> = runs
        .iter()
        .map(|r| 100.0 * r.work_per_hour / r.nominal_per_hour.max(f64::MIN_POSITIVE))
        .collect();
    let mut delays: Vec<f64> = runs.iter().filter_map(|r| r.delay_ms).collect();
    delays.sort_by(f64::total_cmp);
    let halted = runs.iter().map(|r| r.halted_ms);
    let mut damage_causes = BTreeMap::new();
    for cause in runs.iter().flat_map(|r| &r.causes) {
        *damage_causes.entry(*cause).or_default() += 1;
    }
    Row {
        scenario: format!("{} {}", s.label, s.template),
        declared: s.declared,
        mode,
        runs: runs.len(),
        work,
        work_per_hour: round1(runs.iter().map(|r| r.work_per_hour).sum::<f64>() / n),
        nominal_work_per_hour: round1(runs.iter().map(|r| r.nominal_per_hour).sum::<f64>() / n),
        throughput_mean_pct: round1(pct.iter().sum::<f64>() / n),
        throughput_worst_pct: round1(pct.iter().copied().fold(f64::INFINITY, f64::min)),
        damage_events: runs.iter().map(|r| r.damage).sum(),
        damaged_runs: runs.iter().filter(|r| r.damage > 0).count(),
        damage_causes,
        detected_runs: delays.len(),
        detection_median_ms: (!delays.is_empty()).then(|| delays[(delays.len() - 1) / 2]),
        detection_worst_ms: delays.last().copied(),
        halted_mean_ms: halted.clone().sum::<f64>() / n,
        halted_worst_ms: halted.fold(0.0, f64::max),
        probes: runs.iter().map(|r| r.probes.len()).sum(),
        probe_outcomes: distinct(runs.iter().flat_map(|r| &r.probes)),
        no_probe: distinct(runs.iter().flat_map(|r| &r.no_probe)),
    }
}

/// The distinct strings, in order of first appearance.
fn distinct<'a>(all: impl Iterator<Item = &'a String>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for s in all {
        if !out.contains(s) {
            out.push(s.clone());
        }
    }
    out
}

fn round1(x: f64) -> f64 {
    (x * 10.0).round() / 10.0
}

/// What the table shows, for the terminal and for docs/demo.md.
fn preamble(args: &DemoArgs, learned_events: u64) -> String {
    let faults = match args.faults {
        FaultSet::Listed => "each fault of the plant file",
        FaultSet::All => "every fault the plant's parts can have",
    };
    let (plant, work) = args.plant.described();
    format!(
        "Closed loop on the simulated {plant}, model learned from one fault-free hour \
         ({learned_events} events): {faults} starts 10 to 20 min into a 1 h run, on {} \
         seed(s) from {SEED}, each with its own onset. Modes: (a) no coupling, (b) def_ \
         flags, (c) def_ and suspect_ flags, and probing moves. Throughput ({work}) is against the \
         same seed's fault-free run over the same window; damage, detection and halts count from the \
         onset. *Declared* says what the coupling does once the fault is declared: the \
         sensor's temporal estimate stands in, or the part goes to its fallback (a sensor \
         whose edges follow the workpieces has no estimate).",
        args.seeds
    )
}

fn markdown(rows: &[Row]) -> String {
    let mut t = String::from(
        "| scenario | declared | mode | runs | throughput % mean | worst | damage | damaged runs \
         | detected | median delay | worst delay | halted mean | worst | probes | causes of damage |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    let ms = |d: Option<f64>| d.map_or("never".to_string(), |d| format!("{d} ms"));
    for r in rows {
        t.push_str(&format!(
            "| {} | {} | {} | {} | {:.1} | {:.1} | {} | {} | {} | {} | {} | {:.0} s | {:.0} s | {} | {} |\n",
            r.scenario,
            r.declared,
            r.mode,
            r.runs,
            r.throughput_mean_pct,
            r.throughput_worst_pct,
            r.damage_events,
            r.damaged_runs,
            r.detected_runs,
            ms(r.detection_median_ms),
            ms(r.detection_worst_ms),
            r.halted_mean_ms / 1000.0,
            r.halted_worst_ms / 1000.0,
            r.probes,
            causes(&r.damage_causes),
        ));
    }
    t.push_str(&probing_notes(rows));
    t
}

/// Under the table: what the probing moves told, and why none was made where
/// a part waited, ambiguous.
fn probing_notes(rows: &[Row]) -> String {
    let mut t = String::new();
    for r in rows {
        for o in &r.probe_outcomes {
            t.push_str(&format!("- {} ({}): {o}\n", r.scenario, r.mode));
        }
        for n in &r.no_probe {
            t.push_str(&format!("- {} ({}): no probe: {n}\n", r.scenario, r.mode));
        }
    }
    if t.is_empty() {
        return t;
    }
    format!(
        "\nProbing moves (mode c), and why none was made where a part waited, ambiguous:\n\n{t}"
    )
}

/// `box_collision 3, rollers_in_transit 1`.
fn causes(causes: &BTreeMap<&'static str, usize>) -> String {
    let all: Vec<String> = causes.iter().map(|(c, n)| format!("{c} {n}")).collect();
    all.join(", ")
}

/// The command that gives this run's table.
fn command(args: &DemoArgs) -> String {
    let mut command = String::from("cargo run --release -- demo");
    if args.plant != PlantChoice::Sorting {
        command.push_str(&format!(" --plant {}", args.plant.name()));
    }
    if args.faults == FaultSet::All {
        command.push_str(" --faults all");
    }
    if args.seeds != 1 {
        command.push_str(&format!(" --seeds {}", args.seeds));
    }
    command
}

/// Writes this run's section of `docs/demo.md`, between markers naming its
/// command: it replaces the section of the same command, or is appended. The
/// other sections are kept; the file is replaced through a temporary one.
fn write_docs(table: &str, args: &DemoArgs, learned_events: u64) -> std::io::Result<()> {
    let command = command(args);
    let begin = format!("<!-- {command} -->\n");
    let section = format!(
        "{begin}## `{command}`\n\n{}\n\n{table}{SECTION_END}",
        preamble(args, learned_events)
    );
    let old = match std::fs::read_to_string(DOCS_TABLE) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
        Err(e) => return Err(e),
    };
    let text = with_section(&old, &begin, &section);
    let tmp = Path::new(DOCS_TABLE).with_extension("md.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, DOCS_TABLE)
}

/// `old` with `section` (which starts with `begin`) in place of the section
/// starting with `begin`, or appended.
fn with_section(old: &str, begin: &str, section: &str) -> String {
    match old.find(begin) {
        Some(at) => {
            let end = old[at..]
                .find(SECTION_END)
                .map_or(old.len(), |e| at + e + SECTION_END.len());
            format!("{}{section}{}", &old[..at], &old[end..])
        }
        None if old.is_empty() => format!("{DOCS_HEADER}\n{section}"),
        None => format!("{old}\n{section}"),
    }
}

/// Ends a section of `docs/demo.md`.
const SECTION_END: &str = "<!-- end -->\n";

/// Opens a new `docs/demo.md`.
const DOCS_HEADER: &str = "# `gardefou demo`: closed-loop results\n\n\
Each section is written by the command in its title, with `--write-docs`; the runs \
are deterministic. docs/filter.md explains the coupling and reads the tables.\n";

#[cfg(test)]
mod tests {
    use super::*;

    fn section(command: &str, body: &str) -> (String, String) {
        let begin = format!("<!-- {command} -->\n");
        let section = format!("{begin}{body}\n{SECTION_END}");
        (begin, section)
    }

    #[test]
    fn a_section_replaces_its_own_and_keeps_the_others() {
        let (b1, s1) = section("demo", "one");
        let (b2, s2) = section("demo --seeds 20", "two");
        let file = with_section("", &b1, &s1);
        assert!(file.starts_with(DOCS_HEADER), "{file}");
        let file = with_section(&file, &b2, &s2);
        assert_eq!(file, format!("{DOCS_HEADER}\n{s1}\n{s2}"));
        let (_, s1_new) = section("demo", "one, again");
        let file = with_section(&file, &b1, &s1_new);
        assert_eq!(file, format!("{DOCS_HEADER}\n{s1_new}\n{s2}"));
        let (_, s2_new) = section("demo --seeds 20", "two, again");
        let file = with_section(&file, &b2, &s2_new);
        assert_eq!(file, format!("{DOCS_HEADER}\n{s1_new}\n{s2_new}"));
    }

    #[test]
    fn the_command_names_the_options_that_change_the_table() {
        let args = |seeds, faults| DemoArgs {
            json: true,
            write_docs: true,
            seeds,
            faults,
            plant: PlantChoice::Sorting,
        };
        assert_eq!(
            command(&args(1, FaultSet::Listed)),
            "cargo run --release -- demo"
        );
        assert_eq!(
            command(&args(20, FaultSet::All)),
            "cargo run --release -- demo --faults all --seeds 20"
        );
        let cylinders = DemoArgs {
            plant: PlantChoice::Cylinders,
            ..args(20, FaultSet::All)
        };
        assert_eq!(
            command(&cylinders),
            "cargo run --release -- demo --plant cylinders --faults all --seeds 20"
        );
    }
}
