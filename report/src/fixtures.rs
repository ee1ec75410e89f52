//! What the unit tests replay: the sorting line's shipped runs, and a model
//! learned from its fault-free run as `gardefou learn` learns it.

use std::path::{Path, PathBuf};

use diagnoser::Plant;
use diagnoser::diagnosis::DiagnoserOptions;
use diagnoser::model::Model;
use filter_coupling::filter::Coupling;
use learning::learn::{LearnOptions, Learner};
use logs::{IngestOptions, open};

use crate::collect::{self, LogReplay, Setup};

/// A run of the sorting line in `datasets/data/sorting/` (`normal`, `F1`…).
pub fn sorting(run: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../datasets/data/sorting")
        .join(run)
}

/// The sorting line's plant file.
pub fn plant() -> Plant {
    Plant::from_path(&sorting("normal").join("plant.toml")).unwrap_or_else(|e| panic!("{e}"))
}

/// How the sorting line's logs are read.
fn ingest(plant: &Plant) -> IngestOptions {
    IngestOptions {
        time_unit: plant.time_unit,
        ..IngestOptions::default()
    }
}

/// A model learned from the fault-free run.
pub fn learned(plant: &Plant) -> Model {
    let mut learner =
        Learner::new(plant, LearnOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    let log = open(&sorting("normal").join("events.csv"), plant, &ingest(plant))
        .unwrap_or_else(|e| panic!("{e}"));
    learner
        .learn_log(log, |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    learner.finish()
}

/// The events log of `run` replayed as `gardefou report` replays it (default
/// settings, the filter reading the `def_` flags).
pub fn replay(plant: &Plant, model: &Model, run: &str) -> LogReplay {
    let path = sorting(run).join("events.csv");
    let stream = open(&path, plant, &ingest(plant)).unwrap_or_else(|e| panic!("{e}"));
    let setup = Setup {
        plant,
        model,
        options: &DiagnoserOptions::default(),
        coupling: Coupling::Flags,
    };
    collect::replay(setup, stream, &path.display().to_string(), None, |_| {})
        .unwrap_or_else(|e| panic!("{run}: {e}"))
}
