//! Many logs at once: a directory stands for the logs in it, and each log is
//! opened (its reader started) while the one before is still being read, so
//! that reading one log and diagnosing or learning another overlap.
//!
//! ```no_run
//! use std::path::PathBuf;
//! use logs::{IngestOptions, expand_dirs, open_ahead};
//! # fn run(plant: vocabulary::Plant) -> Result<(), vocabulary::Located> {
//! let paths = expand_dirs(&[PathBuf::from("archive/2026-11")])?;
//! for (path, stream) in open_ahead(paths, &plant, &IngestOptions::default()) {
//!     let stream = stream?;
//!     for batch in stream.batches {
//!         let events = batch?;
//!         // ...
//!     }
//! }
//! # Ok(()) }
//! ```

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;

use vocabulary::{Located, Location, Plant};

use crate::{IngestOptions, LogStream, open};

/// The endings of the files a directory's logs are taken from: the tabular
/// forms as CSV or Parquet, `candump -L` logs and value change dumps.
pub const LOG_ENDINGS: [&str; 4] = [".csv", ".parquet", ".log", ".vcd"];

/// `paths` with each directory replaced by the logs in it (files ending in
/// one of [`LOG_ENDINGS`], by name; not its subdirectories). A directory
/// with no log is an error, as a missing file would be.
pub fn expand_dirs(paths: &[PathBuf]) -> Result<Vec<PathBuf>, Located> {
    let mut out = Vec::new();
    for path in paths {
        if !path.is_dir() {
            out.push(path.clone());
            continue;
        }
        let logs = logs_in(path)?;
        if logs.is_empty() {
            return Err(error(
                path,
                format!(
                    "a directory with no log (files ending in {})",
                    LOG_ENDINGS.join(", ")
                ),
            ));
        }
        out.extend(logs);
    }
    Ok(out)
}

/// The logs directly in `dir`, sorted by name.
fn logs_in(dir: &Path) -> Result<Vec<PathBuf>, Located> {
    let entries = std::fs::read_dir(dir).map_err(|e| error(dir, format!("cannot list: {e}")))?;
    let mut logs = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|e| error(dir, format!("cannot list: {e}")))?
            .path();
        let name = path.file_name().map(|n| n.to_string_lossy().to_lowercase());
        if path.is_file() && name.is_some_and(|n| LOG_ENDINGS.iter().any(|e| n.ends_with(e))) {
            logs.push(path);
        }
    }
    logs.sort();
    Ok(logs)
}

fn error(path: &Path, message: String) -> Located {
    Located::new(Location::new(path, 0, 0), message)
}

/// Each of `paths` [`open`]ed in turn, the next one opened on a thread of
/// its own while the present one is read. A log that cannot be opened gives
/// its error in its turn, after the logs before it.
pub fn open_ahead(paths: Vec<PathBuf>, plant: &Plant, options: &IngestOptions) -> OpenAhead {
    let mut ahead = OpenAhead {
        paths: paths.into_iter(),
        plant: Arc::new(plant.clone()),
        options: options.clone(),
        next: None,
    };
    ahead.next = ahead.spawn();
    ahead
}

/// The iterator of [`open_ahead`]: each log's path and opened stream.
#[derive(Debug)]
pub struct OpenAhead {
    paths: std::vec::IntoIter<PathBuf>,
    plant: Arc<Plant>,
    options: IngestOptions,
    next: Option<Opening>,
}

type Opening = (PathBuf, JoinHandle<Result<LogStream, Located>>);

impl OpenAhead {
    /// Starts opening the next path, if any.
    fn spawn(&mut self) -> Option<Opening> {
        let path = self.paths.next()?;
        let (plant, options, at) = (Arc::clone(&self.plant), self.options.clone(), path.clone());
        let handle = std::thread::spawn(move || open(&at, &plant, &options));
        Some((path, handle))
    }
}

impl Iterator for OpenAhead {
    type Item = (PathBuf, Result<LogStream, Located>);

    fn next(&mut self) -> Option<Self::Item> {
        let (path, handle) = self.next.take()?;
        let stream = handle
            .join()
            .unwrap_or_else(|_| Err(error(&path, "the log's reader stopped".to_string())));
        self.next = self.spawn();
        Some((path, stream))
    }
}
