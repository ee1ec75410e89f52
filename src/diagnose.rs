//! `gardefou diagnose`: offline replay of logs through every part's diagnoser.

use std::io::{BufWriter, IsTerminal, Write};
use std::path::PathBuf;

use clap::Args;
use diagnoser::diagnosis::{PartSummary, PartwiseReplay, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, TimeFormat};
use logs::open_ahead;

use crate::args::ReplayArgs;
use crate::progress::LogsProgress;

/// Arguments of `gardefou diagnose`.
#[derive(Debug, Args)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    replay: ReplayArgs,
    /// Print, per part, a table of the final verdict, first detection time and
    /// flags, instead of the verdict changes.
    #[arg(long)]
    summary: bool,
    /// Also write the HTML fault review of the logs (as `gardefou report`) to
    /// this file.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Threads that run the parts' diagnosers side by side (default: the
    /// machine's cores but one, which reads the log). The verdict lines are
    /// the same whatever the number.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
}

/// Runs `gardefou diagnose`.
pub fn run(args: DiagnoseArgs) -> Result<(), Failure> {
    let replay = &args.replay;
    let plant = Plant::from_path(&replay.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&replay.model).map_err(Failure::bad)?;
    let diagnoser = PlantDiagnoser::new(&plant, &model, &replay.options())
        .map_err(|e| Failure::bad(format!("{}: {e}", replay.model.display())))?;
    // The log is read on a thread of its own: the parts get the other cores.
    let threads = args.threads.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| usize::from(n).saturating_sub(1)),
        usize::from,
    );
    let mut diagnoser = PartwiseReplay::new(diagnoser, threads);
    let ingest = replay.ingest(&plant);
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let paths = replay.log_files()?;
    let several = paths.len() > 1;
    let mut progress = LogsProgress::new("diagnosing", paths.len());
    let mut summaries: Vec<(String, TimeFormat, Vec<PartSummary>)> = Vec::new();
    for (path, stream) in open_ahead(paths, &plant, &ingest) {
        let stream = stream.map_err(Failure::bad)?;
        let time = stream.time;
        let name = path.display().to_string();
        let log = several.then_some(name.as_str());
        let mut write_err: Option<std::io::Error> = None;
        let mut emit = |v: Verdict| {
            if !args.summary && write_err.is_none() {
                let line = v.json_line(time, log);
                if let Err(e) = writeln!(out, "{line}") {
                    write_err = Some(e);
                }
            }
        };
        diagnoser.start(stream.start, &stream.initial);
        let mut last = stream.start;
        let mut read = 0u64;
        for batch in stream.batches {
            let batch = batch.map_err(Failure::bad)?;
            diagnoser.push_batch(&batch, &mut emit);
            if let Some(e) = batch.last() {
                last = e.t;
            }
            read += batch.len() as u64;
            progress.read(read);
        }
        progress.log_done();
        let last = stream.end.extend(last, replay.end(&plant));
        let mut summary = diagnoser.finish(last, &mut emit);
        summary.push(diagnoser.plant_summary(last, &summary));
        if let Some(e) = write_err {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(Failure::output(e));
        }
        summaries.push((name, time, summary));
    }
    progress.finish();
    if args.summary {
        let colour = std::io::stdout().is_terminal() && std::env::var_os("NO_COLOR").is_none();
        write_summary(&mut out, &summaries, several, colour).map_err(Failure::output)?;
    }
    if let Some(path) = &args.report {
        let request = report::Request {
            replay: replay.for_report(&plant)?,
            coupling: filter_coupling::filter::Coupling::Flags,
            layout: Some(report::pictures::Layout::Auto),
        };
        let page = report::build(&plant, &model, &request)?;
        diagnoser::output::write_file(path, page.as_bytes())?;
        eprintln!(
            "report written to {} ({} bytes)",
            path.display(),
            page.len()
        );
    }
    match out.flush() {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(Failure::output(e)),
        _ => Ok(()),
    }
}

/// The per-part summary as an aligned table: final verdict, labels, first
/// detection and flags.
fn write_summary(
    out: &mut impl Write,
    summaries: &[(String, TimeFormat, Vec<PartSummary>)],
    several: bool,
    colour: bool,
) -> std::io::Result<()> {
    for (log, time, parts) in summaries {
        if several {
            writeln!(out, "{log}")?;
        }
        let rows: Vec<[String; 5]> = parts
            .iter()
            .map(|p| {
                [
                    p.part.clone(),
                    p.verdict.name().to_string(),
                    p.labels.join(" "),
                    p.detected.map_or("-".to_string(), |t| time.format(t)),
                    if p.flags.is_empty() {
                        "-".to_string()
                    } else {
                        p.flags.join(" ")
                    },
                ]
            })
            .collect();
        let head = ["part", "verdict", "labels", "first detection", "flags"];
        let mut width = head.map(str::len);
        for r in &rows {
            for (w, c) in width.iter_mut().zip(r) {
                *w = (*w).max(c.chars().count());
            }
        }
        let line = |cells: [&str; 5]| {
            let mut s = String::new();
            for (i, (c, w)) in cells.iter().zip(width).enumerate() {
                if i + 1 == cells.len() {
                    s.push_str(c);
                } else {
                    s.push_str(&format!("{c:<w$}  "));
                }
            }
            s
        };
        writeln!(out, "{}", line(head))?;
        for (r, p) in rows.iter().zip(parts.iter()) {
            let text = line([&r[0], &r[1], &r[2], &r[3], &r[4]]);
            if colour {
                // Colour the whole row after padding, so that the escape codes
                // never count as width: green normal, red certain, yellow ambiguous.
                let code = match p.verdict {
                    VerdictKind::Normal => "32",
                    VerdictKind::Certain => "1;31",
                    VerdictKind::Ambiguous => "33",
                };
                writeln!(out, "\x1b[{code}m{text}\x1b[0m")?;
            } else {
                writeln!(out, "{text}")?;
            }
        }
    }
    Ok(())
}
