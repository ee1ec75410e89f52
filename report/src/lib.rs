//! The HTML fault review for maintenance engineers: the library behind
//! `gardefou report` and `gardefou diagnose --report`.
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
//! record. It reads no command line: the binary turns its arguments into a
//! [`Request`].

pub mod collect;
pub mod html;
pub mod pictures;
pub mod words;

#[cfg(test)]
mod fixtures;

use std::io::IsTerminal;
use std::path::PathBuf;

use diagnoser::diagnosis::DiagnoserOptions;
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, Time};
use filter_coupling::filter::Coupling;
use indicatif::{ProgressBar, ProgressStyle};
use logs::{IngestOptions, open};

/// The logs to replay and how: what `diagnose` reads too.
#[derive(Debug, Clone)]
pub struct Replay {
    /// Where the plant file is (named on the page).
    pub plant_path: PathBuf,
    /// Where the model is (named on the page and in its errors).
    pub model_path: PathBuf,
    /// The logs, each replayed from its own initial values.
    pub logs: Vec<PathBuf>,
    /// How the logs are read.
    pub ingest: IngestOptions,
    /// The diagnosers' settings.
    pub options: DiagnoserOptions,
    /// When the logs end, if later than their own end: deadlines up to it count.
    pub end: Option<Time>,
}

/// What a report is made from, shared by `report` and `diagnose --report`.
#[derive(Debug, Clone)]
pub struct Request {
    /// The plant, model and logs, and how to replay them.
    pub replay: Replay,
    /// Which flags the filter reads.
    pub coupling: Coupling,
    /// How pictures are drawn (`None`: no pictures).
    pub layout: Option<pictures::Layout>,
}

/// Replays every log of `request` and renders the page.
pub fn build(plant: &Plant, model: &Model, request: &Request) -> Result<String, Failure> {
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
    let replay = &request.replay;
    let setup = collect::Setup {
        plant,
        model,
        options: &replay.options,
        coupling: request.coupling,
    };
    let mut replays = Vec::new();
    for path in &replay.logs {
        let stream = open(path, plant, &replay.ingest).map_err(Failure::bad)?;
        let name = path.display().to_string();
        bar.set_message(name.clone());
        let log = collect::replay(setup, stream, &name, replay.end, |n| bar.set_position(n))
            .map_err(|e| Failure::bad(format!("{name}: {e}")))?;
        replays.push(log);
    }
    bar.finish_and_clear();
    let pictures = match request.layout {
        Some(layout) => html::pictures(plant, model, &replay.options, layout)
            .map_err(|e| Failure::bad(format!("{}: {e}", replay.model_path.display())))?,
        None => Vec::new(),
    };
    Ok(html::page(&html::Page {
        plant,
        model,
        plant_path: &replay.plant_path,
        model_path: &replay.model_path,
        coupling: request.coupling,
        replays: &replays,
        pictures: &pictures,
    }))
}
