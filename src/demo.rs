//! `gardefou demo`: the whole chain on the embedded sorting plant, with no
//! argument. One simulated hour of normal operation is learned; then each of
//! seed 002's twelve turntable faults is injected into a fresh run and the
//! diagnosers replay it. The table gives, per fault, the final labels, the
//! delay from the onset to the first detection, and the flags raised.

use std::io::Write;

use clap::Args;
use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig};
use datasets::sorting::{plant, simulate_in_memory};
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, VerdictKind};
use diagnoser::{MS, SECOND, TimeFormat, TimeUnit};
use learning::ingest::LogStream;
use learning::learn::{LearnOptions, Learner};
use serde::Serialize;

use crate::Failure;

/// Arguments of `gardefou demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Print the rows as a JSON array instead of a table.
    #[arg(long)]
    json: bool,
}

/// One row of the demo's table.
#[derive(Debug, Serialize)]
struct Row {
    fault: String,
    template: String,
    verdict: VerdictKind,
    labels: Vec<String>,
    detection_delay_ms: Option<f64>,
    flags: Vec<String>,
}

const ONSET: i64 = 600 * SECOND;

fn sim(seed: u64, duration: i64, faults: Vec<Injection>) -> Result<MemorySink, Failure> {
    let config = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults,
    };
    simulate_in_memory(&config)
        .map(|(sink, _)| sink)
        .map_err(|e| Failure::Io(format!("simulation failed: {e}")))
}

/// Runs `gardefou demo`.
pub fn run(args: DemoArgs) -> Result<(), Failure> {
    let plant = plant();
    let internal = |e: String| Failure::Io(format!("embedded sorting plant: {e}"));
    // Learn from one hour of normal operation.
    let normal = sim(7, 3600 * SECOND, Vec::new())?;
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
    let mut diagnoser =
        PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).map_err(internal)?;

    let mut rows = Vec::new();
    for def in &plant.faults {
        let spec = FaultSpec {
            what: def.label.clone(),
            onset: ONSET,
        };
        let injection = Injection::resolve(&spec, &plant).map_err(internal)?;
        let run = sim(11, ONSET + 600 * SECOND, vec![injection])?;
        diagnoser.start(run.start, &run.initial);
        for &e in &run.events {
            diagnoser.push(e, &mut |_| {});
        }
        let end = run.events.last().map_or(run.start, |e| e.t);
        let summary = diagnoser.finish(end, &mut |_| {});
        let view = diagnoser.plant_view(end);
        let detected = summary.iter().filter_map(|p| p.detected).min();
        rows.push(Row {
            fault: def.label.clone(),
            template: def.template.to_string(),
            verdict: view.verdict,
            labels: view.labels,
            detection_delay_ms: detected.map(|t| (t - ONSET) as f64 / MS as f64),
            flags: view.flags,
        });
    }

    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let io = Failure::output;
    if args.json {
        let text = serde_json::to_string_pretty(&rows).map_err(|e| Failure::Io(e.to_string()))?;
        writeln!(out, "{text}").map_err(io)?;
        return Ok(());
    }
    writeln!(
        out,
        "learned {} parts from one simulated hour ({} events); each fault injected at 10 min:",
        model.parts.len(),
        model.learned_from.events
    )
    .map_err(io)?;
    writeln!(
        out,
        "{:<5} {:<28} {:<10} {:<12} {:>15}  flags",
        "fault", "template", "verdict", "labels", "detected after"
    )
    .map_err(io)?;
    for r in &rows {
        let delay = r
            .detection_delay_ms
            .map_or("never".to_string(), |d| format!("{d} ms"));
        writeln!(
            out,
            "{:<5} {:<28} {:<10} {:<12} {:>15}  {}",
            r.fault,
            r.template,
            serde_json::to_value(r.verdict)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default(),
            r.labels.join(" "),
            delay,
            if r.flags.is_empty() {
                "-".to_string()
            } else {
                r.flags.join(" ")
            }
        )
        .map_err(io)?;
    }
    Ok(())
}
