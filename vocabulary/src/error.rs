//! Errors that point at a place in a file: the one-line message users see.

use std::fmt;
use std::path::{Path, PathBuf};

/// A place in an input file. Lines and columns count from 1; a column of 0 means
/// the whole line, a line of 0 the whole file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file.
    pub file: PathBuf,
    /// Line, from 1 (0: unknown).
    pub line: usize,
    /// Column, from 1 (0: unknown).
    pub column: usize,
    /// The field (CSV column name, TOML key) concerned, if any.
    pub field: Option<String>,
}

impl Location {
    /// A location at a line and column of `file`.
    pub fn new(file: &Path, line: usize, column: usize) -> Self {
        Location {
            file: file.to_path_buf(),
            line,
            column,
            field: None,
        }
    }

    /// The same location, naming a field.
    pub fn with_field(mut self, field: impl Into<String>) -> Self {
        self.field = Some(field.into());
        self
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}", self.line)?;
            if self.column > 0 {
                write!(f, ":{}", self.column)?;
            }
        }
        if let Some(field) = &self.field {
            write!(f, ": field '{field}'")?;
        }
        Ok(())
    }
}

/// An error at a [`Location`]: `file:line:column: field 'x': message`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{location}: {message}")]
pub struct Located {
    /// Where.
    pub location: Location,
    /// What, in one line.
    pub message: String,
}

impl Located {
    /// An error at `location`. A message is cut to [`LONGEST_MESSAGE`]
    /// characters, whatever it quotes.
    pub fn new(location: Location, message: impl Into<String>) -> Self {
        Located {
            location,
            message: cut(message.into(), LONGEST_MESSAGE),
        }
    }
}

/// The longest quotation of the input in a message, in characters.
pub const LONGEST_QUOTE: usize = 80;

/// The longest message, in characters: a bound for messages that quote
/// several things.
pub const LONGEST_MESSAGE: usize = 1_000;

/// `'text'`, as [`printable`] gives it: a message quotes the input it
/// rejects, never a megabyte of it, nor bytes that move a terminal's cursor.
pub fn quoted(text: &str) -> String {
    format!("'{}'", printable(text))
}

/// `text` cut to [`LONGEST_QUOTE`] characters with `…`, control characters
/// written as escapes (`\n`, `\u{c}`): one line, whatever the input holds.
pub fn printable(text: &str) -> String {
    let mut shown = String::new();
    for (i, c) in text.chars().enumerate() {
        if i == LONGEST_QUOTE {
            shown.push('…');
            break;
        }
        if c.is_control() {
            shown.extend(c.escape_debug());
        } else {
            shown.push(c);
        }
    }
    shown
}

/// `text` cut to `longest` characters, `…` marking the cut.
fn cut(mut text: String, longest: usize) -> String {
    if let Some((end, _)) = text.char_indices().nth(longest) {
        text.truncate(end);
        text.push('…');
    }
    text
}

/// Line and column (from 1) of a byte offset in `text`.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    // Bytes, not chars: the offset may fall inside a multi-byte character.
    let before = &text.as_bytes()[..offset.min(text.len())];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let column = match before.iter().rposition(|&b| b == b'\n') {
        Some(nl) => before.len() - nl,
        None => before.len() + 1,
    };
    (line, column)
}

/// How a command fails: bad input (exit code 2) or a failure of the machine (exit
/// code 1). Every library that a verb of the command line calls returns it, so
/// that the binary maps it to its exit code in one place.
#[derive(Debug)]
pub enum Failure {
    /// The user's input is wrong: one line saying where and why.
    BadInput(String),
    /// Something outside the user's input failed (disk full, ...).
    Io(String),
    /// The reader of standard output went away (e.g. `| head`): not an error.
    Closed,
}

impl Failure {
    /// Bad input, in one line: what `e` says.
    pub fn bad(e: impl fmt::Display) -> Failure {
        Failure::BadInput(e.to_string())
    }

    /// A failure to write the output.
    pub fn output(e: std::io::Error) -> Failure {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            Failure::Closed
        } else {
            Failure::Io(format!("cannot write the output: {e}"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quotation_is_cut_on_a_character_boundary() {
        assert_eq!(quoted("C4"), "'C4'");
        let long = "é".repeat(LONGEST_QUOTE + 1);
        let q = quoted(&long);
        assert_eq!(q.chars().count(), LONGEST_QUOTE + 3, "{q}");
        assert!(q.ends_with("é…'"), "{q}");
        assert_eq!(
            quoted(&long[..2 * LONGEST_QUOTE]),
            format!("'{}'", "é".repeat(LONGEST_QUOTE))
        );
    }

    #[test]
    fn a_message_is_bounded_whatever_it_quotes() {
        let e = Located::new(Location::new(Path::new("f"), 1, 1), "x".repeat(1 << 20));
        assert_eq!(e.message.chars().count(), LONGEST_MESSAGE + 1);
    }
}
