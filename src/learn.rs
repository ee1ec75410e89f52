//! `gardefou learn`: learn one timed model per plant part from logs.

use std::fs;
use std::path::PathBuf;

use clap::Args;
use diagnoser::model::{Model, SensorKind};
use diagnoser::output::write_file;
use diagnoser::{Failure, Plant, Time, TimeUnit, time};
use learning::conformance::deviations;
use learning::graph::part_digraph;
use learning::learn::{LearnOptions, Learner};
use learning::suggest::{SuggestOptions, suggest_parts, to_toml};
use logs::{IngestOptions, LogFormat, open};
use runtime::jetstream::models::Bundle;

use crate::progress::LogsProgress;

/// Arguments of `gardefou learn`.
#[derive(Debug, Args)]
pub struct LearnArgs {
    /// Plant file: signals and parts (with --suggest-parts, only the signals).
    #[arg(long)]
    plant: PathBuf,
    /// Logs of normal operation (any form; several are combined). A
    /// directory stands for the logs in it (`.csv`, `.parquet`, `.log`,
    /// `.vcd`), by name; a quoted file name with `*` or `?` for the files it
    /// matches, by name.
    #[arg(required = true, value_name = "LOG")]
    logs: Vec<PathBuf>,
    /// Where to write the model (`-`: standard output, the learning report then
    /// going to standard error). A file is replaced whole or not at all; a
    /// symbolic link is written through; a device or FIFO is written to.
    #[arg(short = 'o', long, default_value = "model.json")]
    output: PathBuf,
    /// Log form (default: detected from each file's header): events-csv,
    /// intervals-csv, scans-csv, events-parquet, intervals-parquet, scans-parquet,
    /// candump or vcd.
    #[arg(long)]
    format: Option<LogFormat>,
    /// Unit of numeric timestamps in the logs (default: the plant file's).
    #[arg(long)]
    time_unit: Option<TimeUnit>,
    /// Absolute widening of each guard on each side (default: one scan period).
    #[arg(long, value_parser = time::parse_duration)]
    margin: Option<Time>,
    /// Relative widening of each guard on each side, as a fraction of its width.
    #[arg(long, default_value_t = 0.0)]
    margin_rel: f64,
    /// Share of samples dropped on each side of each guard (outliers), e.g. 0.001.
    #[arg(long, default_value_t = 0.0)]
    trim: f64,
    /// How many standard deviations of the drift between runs each guard
    /// covers (measured over the logs given, as a share of each duration; 0:
    /// no widening for drift).
    #[arg(long, default_value_t = 3.0)]
    drift: f64,
    /// Make the sensors that are wholly inputs (none of their edges follows a
    /// clock of their part; see the report's `sensor` lines) inputs of their
    /// part, allowed in any state. Parts whose plant entry gives `inputs` keep
    /// those.
    #[arg(long)]
    learn_inputs: bool,
    /// Also write one Graphviz file per part into this directory.
    #[arg(long, value_name = "DIR")]
    dot: Option<PathBuf>,
    /// Replay these logs against the learned model and list every violation.
    #[arg(long = "check", value_name = "LOG")]
    checks: Vec<PathBuf>,
    /// Do not learn: suggest [[parts]] (actuators with the sensors that follow them).
    #[arg(long)]
    suggest_parts: bool,
    /// Also store the model in the NATS JetStream object store
    /// `gardefou-models` of this server (`nats://HOST:PORT`), with the plant
    /// file, as the plant's new version: fleet workers and monitors with
    /// `--follow-models` take it up.
    #[arg(long, value_name = "URL")]
    publish: Option<String>,
    /// The plant's name in the store and the subjects (default: the plant
    /// file's name).
    #[arg(long, value_name = "NAME", requires = "publish")]
    nats_plant: Option<String>,
    /// Print nothing but errors.
    #[arg(short, long)]
    quiet: bool,
}

/// Runs `gardefou learn`.
pub fn run(args: LearnArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.plant).map_err(Failure::bad)?;
    if !(0.0..0.5).contains(&args.trim) {
        return Err(Failure::bad(format!(
            "bad --trim {}: expected a share in [0, 0.5)",
            args.trim
        )));
    }
    if !(args.margin_rel.is_finite() && args.margin_rel >= 0.0) {
        return Err(Failure::bad(format!(
            "bad --margin-rel {}: expected a fraction >= 0",
            args.margin_rel
        )));
    }
    if !(args.drift.is_finite() && args.drift >= 0.0) {
        return Err(Failure::bad(format!(
            "bad --drift {}: expected a number of standard deviations >= 0",
            args.drift
        )));
    }
    let ingest = IngestOptions {
        format: args.format,
        time_unit: args.time_unit.unwrap_or(plant.time_unit),
        ..IngestOptions::default()
    };
    let paths = logs::expand_dirs(&args.logs).map_err(Failure::bad)?;
    let mut progress = LogsProgress::new("learning", paths.len());

    if args.suggest_parts {
        let mut streams = Vec::new();
        for path in &paths {
            streams.push(open(path, &plant, &ingest).map_err(Failure::bad)?);
        }
        let suggestion = suggest_parts(&plant.signals, streams, &SuggestOptions::default())
            .map_err(Failure::bad)?;
        progress.finish();
        print!("{}", to_toml(&suggestion, &plant.signals));
        return Ok(());
    }

    let options = LearnOptions {
        margin: args.margin,
        margin_relative: args.margin_rel,
        trim: args.trim,
        drift: args.drift,
        learn_inputs: args.learn_inputs,
        ..LearnOptions::default()
    };
    let mut learner = Learner::new(&plant, options).map_err(Failure::bad)?;
    for (_, stream) in logs::open_ahead(paths, &plant, &ingest) {
        let stream = stream.map_err(Failure::bad)?;
        learner
            .learn_log(stream, |n| progress.read(n))
            .map_err(Failure::bad)?;
        progress.log_done();
    }
    let unassigned = learner.unassigned_sensors().join(", ");
    let model = learner.finish();
    progress.finish();

    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        fs::create_dir_all(dir)
            .map_err(|e| Failure::Io(format!("cannot create {}: {e}", dir.display())))?;
    }
    let model_json = serde_json::to_vec_pretty(&model).map_err(|e| Failure::Io(e.to_string()))?;
    write_file(&args.output, &model_json)?;
    if let Some(url) = &args.publish {
        publish(url, &args, &plant, model_json)?;
    }
    if let Some(dir) = &args.dot {
        fs::create_dir_all(dir)
            .map_err(|e| Failure::Io(format!("cannot create {}: {e}", dir.display())))?;
        for part in &model.parts {
            write_file(
                &dir.join(format!("{}.dot", part.name)),
                part_digraph(&model, part).to_dot().as_bytes(),
            )?;
        }
    }
    if !args.quiet {
        // With the model on standard output, the report must not mix into it.
        let report = learning_report(&model);
        if args.output.as_os_str() == "-" {
            eprint!("{report}");
        } else {
            print!("{report}");
        }
        if !unassigned.is_empty() {
            eprintln!("note: sensors in no part, not learned: {unassigned}");
        }
        eprintln!(
            "learned {} part(s) from {} event(s) over {} {}; wrote {}",
            model.parts.len(),
            model.learned_from.events,
            model.learned_from.duration,
            model.time_unit,
            args.output.display()
        );
    }

    for path in &args.checks {
        let stream = open(path, &plant, &ingest).map_err(Failure::bad)?;
        let found = deviations(&model, &plant, stream).map_err(Failure::bad)?;
        for v in &found {
            println!(
                "{}",
                serde_json::json!({
                    "log": path.display().to_string(),
                    "t": v.t as f64 / model.time_unit.nanos() as f64,
                    "part": v.part,
                    "violation": v.message,
                })
            );
        }
        if !args.quiet {
            eprintln!("{}: {} violation(s)", path.display(), found.len());
        }
    }
    Ok(())
}

/// Stores the model just written, with the plant file, as the plant's new
/// version in the store at `url`.
fn publish(url: &str, args: &LearnArgs, plant: &Plant, model_json: Vec<u8>) -> Result<(), Failure> {
    let plant_text = fs::read_to_string(&args.plant)
        .map_err(|e| Failure::bad(format!("{}: {e}", args.plant.display())))?;
    let model_text = String::from_utf8(model_json).map_err(|e| Failure::Io(e.to_string()))?;
    let bundle = Bundle::new(plant_text, model_text);
    let name = args.nats_plant.as_deref().unwrap_or(&plant.name);
    runtime::jetstream::models::publish(url, name, &bundle)?;
    if !args.quiet {
        eprintln!(
            "published model {} of plant {name} to {url} (object store {})",
            bundle.version,
            runtime::jetstream::models::BUCKET
        );
    }
    Ok(())
}

/// The learning report: per part and transition, the samples and the guard used.
fn learning_report(model: &Model) -> String {
    let unit = model.time_unit.name();
    let mut out = String::new();
    let s = &model.settings;
    if s.drift_sigma > 0.0 {
        out.push_str(&format!(
            "drift between the logs: {:.2} % of a duration (one standard deviation); guards cover {} of them\n",
            100.0 * s.drift_sigma,
            s.drift
        ));
    }
    for part in &model.parts {
        out.push_str(&format!(
            "\n{} ({} states, {} transitions)\n",
            part.name,
            part.states.len(),
            part.transitions.len()
        ));
        out.push_str(&format!(
            "  {:<24} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9}  {:<22} {}\n",
            "event", "n", "min", "q01", "q50", "q99", "max", "guard used", "clock"
        ));
        for t in &part.transitions {
            let g = &t.guard;
            let used = if t.command {
                "(command)".to_string()
            } else if t.timed {
                format!("[{}, {}] {unit}", g.lo, g.hi)
            } else {
                "(untimed)".to_string()
            };
            out.push_str(&format!(
                "  {:<24} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9}  {:<22} {}\n",
                t.event, t.count, g.min, g.q01, g.q50, g.q99, g.max, used, t.clock
            ));
        }
        for e in &part.sensor_estimates {
            out.push_str(&format!(
                "  estimate {} = {}  (uncertain: {})\n",
                e.sensor,
                e.expr,
                e.uncertain.join(", ")
            ));
        }
        for u in &part.untimed {
            out.push_str(&format!("  untimed: {u}\n"));
        }
        for c in &part.sensor_classes {
            let why = if c.why.is_empty() {
                String::new()
            } else {
                format!(": {}", c.why)
            };
            out.push_str(&format!("  sensor {}: {}{why}\n", c.sensor, c.class.name()));
        }
        if !part.inputs.is_empty() {
            out.push_str(&format!("  inputs: {}\n", part.inputs.join(", ")));
        }
        for (class, how) in [
            (
                SensorKind::Input,
                "write `inputs = [{}]` in the part, or learn with --learn-inputs",
            ),
            (SensorKind::PartlyInput, "write `inputs = [{}]` in the part"),
        ] {
            let names: Vec<&str> = part
                .sensor_classes
                .iter()
                .filter(|c| c.class == class && !part.inputs.contains(&c.sensor))
                .map(|c| c.sensor.as_str())
                .collect();
            if !names.is_empty() {
                let quoted: Vec<String> = names.iter().map(|n| format!("\"{n}\"")).collect();
                out.push_str(&format!(
                    "  to let {} change in any state, {}\n",
                    names.join(", "),
                    how.replace("{}", &quoted.join(", "))
                ));
            }
        }
    }
    out
}
