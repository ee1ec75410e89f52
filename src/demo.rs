//! `gardefou demo`: the whole chain on the embedded sorting line, with no
//! argument, in closed loop.
//!
//! One simulated hour of fault-free operation under safe control by
//! constraints is learned. Then each turntable fault (C4 and C5 stuck at 0 and
//! at 1, the plate blocked at a position or in transit) starts at a random time
//! after a warm-up, and the line runs one hour in three modes:
//! (a) the filter reads the sensors as they are; (b) `def_` flags switch failed
//! sensors to their estimates and send a flagged element's part to the
//! fallback; (c) `suspect_` flags also switch sensors. Each run reports
//! deliveries against the fault-free run, damage, the detection delay and the
//! time halted, all counted from the onset.

use std::io::Write;
use std::path::Path;

use clap::Args;
use datasets::inject::{FaultSpec, Injection};
use datasets::sorting::plant;
use diagnoser::{Failure, MS, SECOND, Time, TimeFormat, TimeUnit};
use filter_coupling::filter::Coupling;
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
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
}

/// One row of the experiment.
#[derive(Debug, Clone, Serialize)]
struct Row {
    scenario: String,
    mode: &'static str,
    boxes_per_hour: f64,
    nominal_boxes_per_hour: f64,
    damage_events: usize,
    detection_delay_ms: Option<f64>,
    halted_ms: f64,
}

/// The scenarios: seed 002's turntable faults on C4, C5 and the plate.
const SCENARIOS: [&str; 8] = ["F1", "F2", "F3", "F4", "F5", "F6", "F11", "F12"];
const MODES: [(&str, Coupling); 3] = [
    ("a", Coupling::None),
    ("b", Coupling::Flags),
    ("c", Coupling::FlagsAndSuspects),
];
const SEED: u64 = 11;
const DURATION: Time = 3600 * SECOND;
/// Onsets are drawn in [WARM_UP, WARM_UP + SPREAD).
const WARM_UP: Time = 600 * SECOND;
const SPREAD: Time = 600 * SECOND;

/// Where `demo --write-docs` writes its table.
const DOCS_TABLE: &str = "docs/demo.md";

/// Runs `gardefou demo`.
pub fn run(args: DemoArgs) -> Result<(), Failure> {
    let plant = plant();
    let internal = |e: String| Failure::Io(format!("embedded sorting plant: {e}"));
    let normal = closed_loop::record(&plant, 7, 3600 * SECOND).map_err(internal)?;
    let mut learner = Learner::new(&plant, LearnOptions::default()).map_err(internal)?;
    learner
        .learn_log(
            LogStream::from_events(
                "simulated normal hour",
                TimeFormat::Numeric(TimeUnit::Ms),
                normal.start,
                normal.initial.clone(),
                normal.events,
            ),
            |_| {},
        )
        .map_err(|e| internal(e.to_string()))?;
    let model = learner.finish();

    // Every run of the experiment, with its onset drawn once per scenario.
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut jobs: Vec<(String, &'static str, LoopRun)> = Vec::new();
    for label in SCENARIOS {
        let onset = WARM_UP + rng.random_range(0..SPREAD / MS) * MS;
        let fault = Injection::resolve(
            &FaultSpec {
                what: label.to_string(),
                onset,
            },
            &plant,
        )
        .map_err(internal)?;
        // The same run without the fault, counted over the same window.
        jobs.push((
            String::new(),
            "",
            LoopRun {
                coupling: Coupling::None,
                seed: SEED,
                duration: DURATION,
                fault: None,
                from: onset,
            },
        ));
        for (mode, coupling) in MODES {
            jobs.push((
                format!("{label} {}", fault.template),
                mode,
                LoopRun {
                    coupling,
                    seed: SEED,
                    duration: DURATION,
                    fault: Some(fault.clone()),
                    from: onset,
                },
            ));
        }
    }
    let outcomes = run_all(&plant, &model, &jobs).map_err(internal)?;

    let mut rows = Vec::new();
    let mut nominal = 0.0;
    for ((scenario, mode, job), outcome) in jobs.iter().zip(&outcomes) {
        let hours = (DURATION - job.from) as f64 / (3600 * SECOND) as f64;
        let per_hour = outcome.delivered as f64 / hours;
        // The fault-free reference of the scenarios that follow.
        if job.fault.is_none() {
            nominal = per_hour;
            continue;
        }
        rows.push(Row {
            scenario: scenario.clone(),
            mode,
            boxes_per_hour: round1(per_hour),
            nominal_boxes_per_hour: round1(nominal),
            damage_events: outcome.damage.len(),
            detection_delay_ms: outcome.detected.map(|t| (t - job.from) as f64 / MS as f64),
            halted_ms: outcome.halted as f64 / MS as f64,
        });
    }

    let table = markdown(&rows);
    if args.write_docs {
        write_docs(&table).map_err(|e| Failure::Io(format!("{DOCS_TABLE}: {e}")))?;
        eprintln!("table written to {DOCS_TABLE}");
    }
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.json {
        let text = serde_json::to_string_pretty(&rows).map_err(|e| Failure::Io(e.to_string()))?;
        writeln!(out, "{text}").map_err(Failure::output)?;
        return Ok(());
    }
    writeln!(
        out,
        "Closed loop on the simulated sorting line: model learned from one fault-free hour \
         ({} events); each fault starts 10 to 20 min into a 1 h run (seed {SEED}).\n\
         Modes: (a) no coupling, (b) def_ flags, (c) def_ and suspect_ flags. \
         Counts start at the onset.\n",
        model.learned_from.events
    )
    .map_err(Failure::output)?;
    write!(out, "{table}").map_err(Failure::output)?;
    Ok(())
}

fn round1(x: f64) -> f64 {
    (x * 10.0).round() / 10.0
}

/// Runs the jobs on every core, keeping their order.
fn run_all(
    plant: &diagnoser::Plant,
    model: &diagnoser::model::Model,
    jobs: &[(String, &'static str, LoopRun)],
) -> Result<Vec<LoopOutcome>, String> {
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<Option<Result<LoopOutcome, String>>>> =
        std::sync::Mutex::new(vec![None; jobs.len()]);
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(job) = jobs.get(i) else { break };
                    let r = closed_loop::run(plant, model, &job.2);
                    if let Ok(mut all) = results.lock() {
                        all[i] = Some(r);
                    }
                }
            });
        }
    });
    let all = results
        .into_inner()
        .map_err(|_| "a run panicked".to_string())?;
    all.into_iter()
        .map(|r| r.unwrap_or_else(|| Err("a run did not finish".into())))
        .collect()
}

fn markdown(rows: &[Row]) -> String {
    let mut t = String::from(
        "| scenario | mode | boxes/h | nominal | % | damage | detected after | halted |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let pct = if r.nominal_boxes_per_hour > 0.0 {
            format!("{:.0}", 100.0 * r.boxes_per_hour / r.nominal_boxes_per_hour)
        } else {
            "-".into()
        };
        let detected = r
            .detection_delay_ms
            .map_or("never".to_string(), |d| format!("{d} ms"));
        t.push_str(&format!(
            "| {} | {} | {:.1} | {:.1} | {} | {} | {} | {:.0} s |\n",
            r.scenario,
            r.mode,
            r.boxes_per_hour,
            r.nominal_boxes_per_hour,
            pct,
            r.damage_events,
            detected,
            r.halted_ms / 1000.0
        ));
    }
    t
}

/// Replaces `docs/demo.md` whole, through a temporary file.
fn write_docs(table: &str) -> std::io::Result<()> {
    let text = format!(
        "# `gardefou demo`: closed-loop results\n\n\
         Written by `cargo run --release -- demo` (deterministic: seed {SEED}). \
         Each turntable fault starts 10 to 20 min into a one-hour run of the simulated \
         sorting line under safe control by constraints. Modes: (a) the filter reads the \
         sensors as they are; (b) `def_` flags switch failed sensors to their temporal \
         estimates, and send a flagged element's part to the fallback; (c) `suspect_` flags \
         also switch sensors. Throughput, damage and halts are counted from the onset; \
         *nominal* is the same window of the fault-free run; *halted* is the time with boxes \
         on the line and no delivery for over a minute, beyond that minute.\n\n{table}"
    );
    let tmp = Path::new(DOCS_TABLE).with_extension("md.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, DOCS_TABLE)
}
