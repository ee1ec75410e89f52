//! `gardefou diagnose`: offline replay of logs through every part's diagnoser.

use std::io::{BufWriter, IsTerminal, Write};
use std::path::PathBuf;

use clap::Args;
use diagnoser::diagnosis::{DiagnoserOptions, PartSummary, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{Plant, Time, TimeFormat, TimeUnit, time};
use indicatif::{ProgressBar, ProgressStyle};
use learning::ingest::{IngestOptions, LogFormat, open};

use crate::Failure;

/// Arguments of `gardefou diagnose`.
#[derive(Debug, Args)]
pub struct DiagnoseArgs {
    /// Plant file: signals, parts, faults and partitions.
    #[arg(long)]
    plant: PathBuf,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    model: PathBuf,
    /// Logs to replay (any form); each is replayed from its own initial values.
    #[arg(required = true, value_name = "LOG")]
    logs: Vec<PathBuf>,
    /// Log form (default: detected from each file's header): events-csv,
    /// intervals-csv, scans-csv, events-parquet, intervals-parquet, scans-parquet,
    /// candump or vcd.
    #[arg(long)]
    format: Option<LogFormat>,
    /// Unit of numeric timestamps in the logs (default: the plant file's).
    #[arg(long)]
    time_unit: Option<TimeUnit>,
    /// Longest an unexpected sensor edge shows before the sensor reads its real
    /// value again (longer, it is a stuck sensor).
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    glitch_max: Time,
    /// Print, per part, the final verdict, first detection time and flags,
    /// instead of the verdict changes.
    #[arg(long)]
    summary: bool,
}

fn bad(e: impl std::fmt::Display) -> Failure {
    Failure::BadInput(e.to_string())
}

fn io(e: std::io::Error) -> Failure {
    Failure::Io(format!("cannot write the output: {e}"))
}

/// One verdict as a JSON line of SPEC §3, its time in the log's representation.
pub fn verdict_line(v: &Verdict, time: TimeFormat, log: Option<&str>) -> String {
    let t = match time {
        TimeFormat::Numeric(_) => time.format(v.t),
        TimeFormat::Rfc3339 => serde_json::Value::String(time.format(v.t)).to_string(),
    };
    let body = serde_json::to_string(v).unwrap_or_else(|_| "{}".to_string());
    let log = log
        .map(|l| format!("\"log\":{},", serde_json::Value::String(l.to_string())))
        .unwrap_or_default();
    format!(
        "{{\"t\":{t},{log}{}",
        body.strip_prefix('{').unwrap_or(&body)
    )
}

/// Runs `gardefou diagnose`.
pub fn run(args: DiagnoseArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(bad)?;
    let model = Model::from_path(&args.model).map_err(bad)?;
    let mut diagnoser = PlantDiagnoser::new(
        &plant,
        &model,
        &DiagnoserOptions {
            glitch_max: args.glitch_max,
        },
    )
    .map_err(|e| bad(format!("{}: {e}", args.model.display())))?;
    let ingest = IngestOptions {
        format: args.format,
        time_unit: args.time_unit.unwrap_or(plant.time_unit),
        ..IngestOptions::default()
    };
    let bar = if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new_spinner();
        bar.set_style(
            ProgressStyle::with_template("{spinner} diagnosing: {human_pos} events ({per_sec})")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let several = args.logs.len() > 1;
    let mut summaries: Vec<(String, TimeFormat, Vec<PartSummary>)> = Vec::new();
    for path in &args.logs {
        let stream = open(path, &plant, &ingest).map_err(bad)?;
        let time = stream.time;
        let name = path.display().to_string();
        let log = several.then_some(name.as_str());
        let mut write_err: Option<std::io::Error> = None;
        let mut emit = |v: Verdict| {
            if !args.summary && write_err.is_none() {
                let line = verdict_line(&v, time, log);
                if let Err(e) = writeln!(out, "{line}") {
                    write_err = Some(e);
                }
            }
        };
        diagnoser.start(stream.start, &stream.initial);
        let mut last = stream.start;
        let mut read = 0u64;
        for batch in stream.batches {
            let batch = batch.map_err(bad)?;
            for &e in &batch {
                diagnoser.push(e, &mut emit);
            }
            if let Some(e) = batch.last() {
                last = e.t;
            }
            read += batch.len() as u64;
            bar.set_position(read);
        }
        let summary = diagnoser.finish(last, &mut emit);
        if let Some(e) = write_err {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(io(e));
        }
        summaries.push((name, time, summary));
    }
    bar.finish_and_clear();
    if args.summary {
        for (log, time, parts) in &summaries {
            for p in parts {
                let mut v = serde_json::to_value(p).unwrap_or_default();
                if let Some(obj) = v.as_object_mut() {
                    let detected = match (p.detected, time) {
                        (None, _) => serde_json::Value::Null,
                        (Some(t), TimeFormat::Numeric(_)) => {
                            serde_json::from_str(&time.format(t)).unwrap_or_default()
                        }
                        (Some(t), TimeFormat::Rfc3339) => serde_json::Value::String(time.format(t)),
                    };
                    obj.insert("first_detection".to_string(), detected);
                    if several {
                        obj.insert("log".to_string(), serde_json::Value::String(log.clone()));
                    }
                }
                writeln!(out, "{v}").map_err(io)?;
            }
        }
    }
    match out.flush() {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(io(e)),
        _ => Ok(()),
    }
}
