//! Logs that cannot be read twice: pipes, FIFOs, character devices.
//!
//! Reading a log may open it more than once: once to tell its form, again to
//! read it, twice more for the intervals form, and Parquet needs to seek. A
//! FIFO gives its bytes once, so [`Spool::of`] copies such a log, once, to a
//! temporary regular file, and [`open_file`] then opens the copy whenever the
//! log's own path is asked for. Messages keep naming the log's path. A
//! regular file is never copied.

use std::collections::HashMap;
use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock, PoisonError};

use vocabulary::Located;

use crate::rows::file_error;

/// The copies of the logs being read, by the log's path.
fn copies() -> &'static Mutex<HashMap<PathBuf, PathBuf>> {
    static COPIES: OnceLock<Mutex<HashMap<PathBuf, PathBuf>>> = OnceLock::new();
    COPIES.get_or_init(Mutex::default)
}

/// The copy of one log that cannot be read twice; the copy is deleted when
/// this is dropped (open handles on it keep reading).
pub(crate) struct Spool {
    log: PathBuf,
    copy: tempfile::TempPath,
}

impl Spool {
    /// Copies the log at `path` if it is not a regular file; `None` if it is.
    pub(crate) fn of(path: &Path) -> Result<Option<Spool>, Located> {
        // A regular file (or one that cannot be seen: its reader says why) is
        // read in place; only the others are opened here.
        match fs::metadata(path) {
            Ok(meta) if !meta.is_file() => {}
            _ => return Ok(None),
        }
        let opened = File::open(path);
        let mut file = opened.map_err(|e| file_error(path, format!("cannot open the log: {e}")))?;
        let copy = tempfile::Builder::new()
            .prefix(".gardefou-log-")
            .tempfile()
            .map_err(|e| {
                file_error(
                    path,
                    format!("cannot copy the log to a temporary file: {e}"),
                )
            })?;
        let (mut out, copy) = copy.into_parts();
        io::copy(&mut file, &mut out).map_err(|e| {
            file_error(
                path,
                format!("cannot copy the log to a temporary file: {e}"),
            )
        })?;
        let mut all = copies().lock().unwrap_or_else(PoisonError::into_inner);
        all.insert(path.to_path_buf(), copy.to_path_buf());
        Ok(Some(Spool {
            log: path.to_path_buf(),
            copy,
        }))
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        let mut all = copies().lock().unwrap_or_else(PoisonError::into_inner);
        if all.get(&self.log) == Some(&self.copy.to_path_buf()) {
            all.remove(&self.log);
        }
    }
}

/// Where the log at `path` is read from: its copy if it has one, else
/// `path` itself.
pub(crate) fn readable(path: &Path) -> PathBuf {
    let all = copies().lock().unwrap_or_else(PoisonError::into_inner);
    all.get(path).cloned().unwrap_or_else(|| path.to_path_buf())
}

/// Opens the log at `path`: its copy if it has one, else the file itself.
pub(crate) fn open_file(path: &Path) -> Result<File, Located> {
    File::open(readable(path)).map_err(|e| file_error(path, format!("cannot open the log: {e}")))
}
