//! `gardefou report`: a self-contained HTML fault review for maintenance
//! engineers.
//!
//! Each log is replayed through every part's diagnoser and the safety filter
//! ([`collect`]); the page ([`html`]) then gives, per part, the verdict and its
//! meaning, a timeline of the signals with the learned windows, the verdict
//! changes, filter trips and rewrites, explanations at seed 002's levels
//! (current state, state before stop, last changes, hypothesis), and pictures of
//! the learned model and of the diagnoser ([`pictures`]). The file needs no
//! network: styles, script, data and pictures are inline.
//!
//! It is not for live monitoring (that is `monitor`'s `/status`), nor a
//! substitute for the JSON lines of `diagnose`, which stay the machine-readable
//! record.

pub mod collect;
pub mod html;
pub mod pictures;
pub mod words;

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use diagnoser::Plant;
use diagnoser::model::Model;
use filter_coupling::filter::Coupling;
use indicatif::{ProgressBar, ProgressStyle};
use learning::ingest::open;

use crate::args::CouplingArg;
use crate::args::ReplayArgs;
use diagnoser::Failure;

/// How the model pictures are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LayoutArg {
    /// Graphviz `dot` when installed, else the built-in layout.
    Auto,
    /// Graphviz `dot` (an error when it cannot run).
    Graphviz,
    /// The built-in layered layout.
    Builtin,
    /// No pictures.
    None,
}

/// Arguments of `gardefou report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    #[command(flatten)]
    replay: ReplayArgs,
    /// The HTML file to write.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Which flags the replayed safety filter reads.
    #[arg(long, value_enum, default_value = "def")]
    coupling: CouplingArg,
    /// How the pictures of the models are drawn.
    #[arg(long, value_enum, default_value = "auto")]
    layout: LayoutArg,
}

/// What a report is made from, shared by `report` and `diagnose --report`.
pub struct Request<'a> {
    /// The plant, model and logs, and how to replay them.
    pub replay: &'a ReplayArgs,
    /// Which flags the filter reads.
    pub coupling: Coupling,
    /// How pictures are drawn (`None`: no pictures).
    pub layout: Option<pictures::Layout>,
}

/// Runs `gardefou report`.
pub fn run(args: ReportArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.replay.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&args.replay.model).map_err(Failure::bad)?;
    let request = Request {
        replay: &args.replay,
        coupling: match args.coupling {
            CouplingArg::None => Coupling::None,
            CouplingArg::Def => Coupling::Flags,
            CouplingArg::DefSuspect => Coupling::FlagsAndSuspects,
        },
        layout: match args.layout {
            LayoutArg::Auto => Some(pictures::Layout::Auto),
            LayoutArg::Graphviz => Some(pictures::Layout::Graphviz),
            LayoutArg::Builtin => Some(pictures::Layout::BuiltIn),
            LayoutArg::None => None,
        },
    };
    let page = build(&plant, &model, &request)?;
    write_atomically(&args.output, page.as_bytes())?;
    eprintln!(
        "report written to {} ({} bytes)",
        args.output.display(),
        page.len()
    );
    Ok(())
}

/// Replays every log of `request` and renders the page.
pub fn build(plant: &Plant, model: &Model, request: &Request<'_>) -> Result<String, Failure> {
    let bar = if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new_spinner();
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} reviewing {msg}: {human_pos} events ({per_sec})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let args = request.replay;
    let ingest = args.ingest(plant);
    let options = args.options();
    let setup = collect::Setup {
        plant,
        model,
        options: &options,
        coupling: request.coupling,
    };
    let mut replays = Vec::new();
    for path in &args.logs {
        let stream = open(path, plant, &ingest).map_err(Failure::bad)?;
        let name = path.display().to_string();
        bar.set_message(name.clone());
        let replay = collect::replay(setup, stream, &name, args.end(plant), |n| {
            bar.set_position(n)
        })
        .map_err(|e| Failure::bad(format!("{name}: {e}")))?;
        replays.push(replay);
    }
    bar.finish_and_clear();
    let pictures = match request.layout {
        Some(layout) => html::pictures(plant, model, &options, layout)
            .map_err(|e| Failure::bad(format!("{}: {e}", args.model.display())))?,
        None => Vec::new(),
    };
    Ok(html::page(&html::Page {
        plant,
        model,
        plant_path: &args.plant,
        model_path: &args.model,
        coupling: request.coupling,
        replays: &replays,
        pictures: &pictures,
    }))
}

/// Writes `bytes` to `path` through a temporary file in the same directory, so
/// that a failure never leaves a half-written report in place of a good one.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let fail = |e: std::io::Error| Failure::Io(format!("cannot write {}: {e}", path.display()));
    if path.is_dir() {
        return Err(Failure::BadInput(format!(
            "{}: is a directory, not a file to write the report to",
            path.display()
        )));
    }
    let mut tmp = tempfile::NamedTempFile::new_in(&dir).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            Failure::BadInput(format!(
                "{}: no such directory to write the report in",
                dir.display()
            ))
        } else {
            fail(e)
        }
    })?;
    tmp.write_all(bytes).map_err(fail)?;
    tmp.flush().map_err(fail)?;
    // A temporary file is private; a report is an ordinary document.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(path).map_or(0o644, |m| m.permissions().mode() & 0o777);
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(mode))
            .map_err(fail)?;
    }
    tmp.persist(path).map_err(|e| fail(e.error))?;
    Ok(())
}
