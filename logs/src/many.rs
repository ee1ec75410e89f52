//! Many logs at once: a directory stands for the logs in it, a file name
//! with `*` or `?` for the files it matches, and each log is opened (its
//! reader started) while the one before is still being read, so that
//! reading one log and diagnosing or learning another overlap.
//!
//! The patterns are expanded here, not only by the shell, so that an
//! archive of more files than a command line holds can be named at once
//! (`'archive/2026-*.parquet'`, quoted).
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
/// one of [`LOG_ENDINGS`], by name; not its subdirectories), and each path
/// that names no file but whose file name holds `*` (any characters) or `?`
/// (one character) replaced by the files of its directory that it matches,
/// by name. A directory with no log, or a pattern that matches no file, is
/// an error, as a missing file would be.
pub fn expand_dirs(paths: &[PathBuf]) -> Result<Vec<PathBuf>, Located> {
    let mut out = Vec::new();
    for path in paths {
        if !path.exists() && is_pattern(path) {
            out.extend(matching(path)?);
            continue;
        }
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

/// Whether the file name of `path` is a pattern.
fn is_pattern(path: &Path) -> bool {
    path.file_name()
        .is_some_and(|n| n.to_string_lossy().contains(['*', '?']))
}

/// The files of the pattern `path`'s directory whose names it matches, by
/// name.
fn matching(path: &Path) -> Result<Vec<PathBuf>, Located> {
    let pattern = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let entries = std::fs::read_dir(dir)
        .map_err(|e| error(path, format!("cannot list {}: {e}", dir.display())))?;
    let mut found = Vec::new();
    for entry in entries {
        let entry =
            entry.map_err(|e| error(path, format!("cannot list {}: {e}", dir.display())))?;
        let name = entry.file_name();
        if wildcard_match(&pattern, &name.to_string_lossy()) && entry.path().is_file() {
            found.push(path.with_file_name(name));
        }
    }
    if found.is_empty() {
        return Err(error(path, "no file matches this pattern".to_string()));
    }
    found.sort();
    Ok(found)
}

/// Whether `name` matches `pattern`, where `*` stands for any characters
/// and `?` for one. Linear: on a mismatch after a `*`, the star takes one
/// more character and the match resumes, which is all a pattern without
/// classes needs.
fn wildcard_match(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    let (mut i, mut j) = (0, 0);
    // The last star seen, and where in the name its match ends so far.
    let mut star: Option<(usize, usize)> = None;
    while j < n.len() {
        match p.get(i) {
            Some('*') => {
                star = Some((i, j));
                i += 1;
            }
            Some(&c) if c == '?' || c == n[j] => {
                i += 1;
                j += 1;
            }
            _ => match star {
                Some((si, sj)) => {
                    star = Some((si, sj + 1));
                    (i, j) = (si + 1, sj + 1);
                }
                None => return false,
            },
        }
    }
    p[i..].iter().all(|&c| c == '*')
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn wildcards_match_as_a_shell_does() {
        for (pattern, name, matches) in [
            ("*.csv", "a.csv", true),
            ("*.csv", "a.parquet", false),
            ("log-??.csv", "log-01.csv", true),
            ("log-??.csv", "log-1.csv", false),
            ("*", "", true),
            ("a*b*c", "aXbYbZc", true),
            ("a*b*c", "aXbYbZ", false),
            ("*ab", "aab", true),
            ("?", "", false),
            ("é*", "été.csv", true),
        ] {
            assert_eq!(
                wildcard_match(pattern, name),
                matches,
                "{pattern} on {name}"
            );
        }
    }

    proptest! {
        /// A name matches any pattern made from it by turning characters
        /// into `?` and runs of characters into `*`; and a pattern without
        /// wildcards matches only itself.
        #[test]
        fn a_name_matches_the_patterns_made_from_it(
            name in "[a-c.]{0,12}",
            cuts in proptest::collection::vec((0usize..12, 0usize..4, any::<bool>()), 0..4),
            other in "[a-c.]{0,12}",
        ) {
            // Each piece with whether it stands for one character of the name.
            let mut pieces: Vec<(String, bool)> = name.chars().map(|c| (c.to_string(), true)).collect();
            for (at, len, star) in cuts {
                if at >= pieces.len() {
                    continue;
                }
                let end = (at + len).min(pieces.len());
                if star {
                    pieces.splice(at..end, [("*".to_string(), false)]);
                } else if pieces[at].1 {
                    pieces[at].0 = "?".to_string();
                }
            }
            let pattern: Vec<String> = pieces.into_iter().map(|(p, _)| p).collect();
            let pattern = pattern.concat();
            prop_assert!(wildcard_match(&pattern, &name), "{} on {}", pattern, name);
            prop_assert_eq!(wildcard_match(&name, &other), name == other);
        }
    }

    #[test]
    fn a_pattern_stands_for_the_files_it_matches_by_name() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["b-2.csv", "a-1.csv", "a-1.parquet", "notes.txt"] {
            std::fs::write(dir.path().join(name), "t,signal,value\n").expect("writes");
        }
        let pattern = dir.path().join("?-*.csv");
        let found = expand_dirs(std::slice::from_ref(&pattern)).expect("expands");
        let names: Vec<_> = found
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect();
        assert_eq!(names, ["a-1.csv", "b-2.csv"]);
        let none = expand_dirs(&[dir.path().join("*.vcd")]).expect_err("matches nothing");
        assert!(none.to_string().contains("no file matches"), "{none}");
        // A file whose name holds a star is that file.
        let starred = dir.path().join("x*.csv");
        std::fs::write(&starred, "").expect("writes");
        assert_eq!(
            expand_dirs(std::slice::from_ref(&starred)).expect("a file"),
            [starred]
        );
    }
}
