//! libFAUDES generators (`.gen`, untimed automata) and failure-type maps, and
//! event-diagnosability as libFAUDES's `IsEventDiagnosable` decides it.
//!
//! Why: libFAUDES is a reference implementation of diagnosability tests for
//! discrete event systems, with tutorial models to test against. Reading its files
//! lets us check a plant model written for libFAUDES without libFAUDES, and compare
//! our verdicts with its own (`scripts/faudes-compare.py`).
//!
//! Event-diagnosability (Sampath et al. 1995): a failure type `F` (a set of
//! unobservable failure events) is diagnosable when every occurrence of a failure of
//! type `F` is known for certain from the observation after a bounded number of
//! further events. It is not diagnosable exactly when there is an *indeterminate
//! cycle*: two runs with the same observation, one after a failure of type `F` and
//! one without any, that both go on forever. We look for one as libFAUDES does,
//! with the test of Jiang, Huang, Chandra and Kumar (IEEE TAC 46(8), 2001), one
//! failure type at a time: an observation automaton `G_o` whose states are
//! generator states labelled "failed or not", its twin plant `G_d = G_o || G_o`, and
//! a cycle of `G_d` through states with different labels. We return that cycle,
//! spelled out as two runs of the generator, as the counterexample.
//!
//! libFAUDES also requires three assumptions and answers "not diagnosable" when one
//! fails: the generator is live (every state, reachable or not, has a successor),
//! every failure event is unobservable, and there is no cycle of unobservable events
//! (anywhere in the generator). We report each failed assumption
//! ([`AssumptionViolation`]) and match that verdict, and still give each failure
//! type's own verdict, which concerns runs with infinitely many observations.
//!
//! Not supported: the XML form of generators (`<StateSet>`, `<TransitionRelation>`);
//! indicator events (i-diagnosability) are read and ignored, as `IsEventDiagnosable`
//! ignores them.

use std::collections::hash_map::Entry;
use std::collections::{HashMap, HashSet, VecDeque};
use std::path::Path;

use petgraph::algo::kosaraju_scc;
use petgraph::graph::{DiGraph, NodeIndex};

use crate::error::{Located, Location, line_column};

pub mod product;

/// An untimed automaton read from a libFAUDES `.gen` file.
///
/// States and events are numbered from 0 in file order; the vectors below are
/// indexed by these numbers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Generator {
    /// The generator's name (`"Generator"` when the file gives none, as libFAUDES).
    pub name: String,
    /// Event names.
    pub events: Vec<String>,
    /// Whether each event is observable (libFAUDES's default; `+o+` makes it
    /// unobservable).
    pub observable: Vec<bool>,
    /// State names; a state written as a bare index is named by that index.
    pub states: Vec<String>,
    /// Initial states.
    pub initial: Vec<usize>,
    /// Marked states (read for completeness; diagnosability ignores them).
    pub marked: Vec<usize>,
    /// Transitions `(from, event, to)`, without duplicates, in file order.
    pub transitions: Vec<(usize, usize, usize)>,
}

/// A failure-type map: each failure type names its failure events.
///
/// Indicator events (`<IndicatorEvents>`) are not kept: event-diagnosability does
/// not use them.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct FailureTypes {
    /// `(failure type, failure events)`, in file order.
    pub types: Vec<(String, Vec<String>)>,
}

/// The verdict of [`event_diagnosability`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct EventDiagnosability {
    /// libFAUDES's verdict: every assumption holds and every failure type is
    /// diagnosable.
    pub diagnosable: bool,
    /// The libFAUDES assumptions that do not hold (empty when all hold). Any of them
    /// makes the generator "not diagnosable" for libFAUDES, whatever the failure
    /// types' own verdicts.
    pub assumptions: Vec<AssumptionViolation>,
    /// One verdict per failure type, in the map's order.
    pub types: Vec<TypeVerdict>,
}

impl EventDiagnosability {
    /// libFAUDES's verdict for a map holding `failure_type` alone: its own verdict,
    /// the assumptions on the whole generator (liveness, no unobservable cycle) and
    /// those on its failure events. `None` for a type not in the map.
    ///
    /// Why: `IsEventDiagnosable` answers for the whole map only; asking it once per
    /// failure type gives per-type verdicts to compare with these.
    pub fn type_diagnosable(&self, failure_type: &str) -> Option<bool> {
        let verdict = self.types.iter().find(|t| t.failure_type == failure_type)?;
        let violated = self.assumptions.iter().any(|v| match v {
            AssumptionViolation::Deadlock { .. }
            | AssumptionViolation::UnobservableCycle { .. } => true,
            AssumptionViolation::UnknownFailureEvent {
                failure_type: t, ..
            }
            | AssumptionViolation::ObservableFailureEvent {
                failure_type: t, ..
            } => t == failure_type,
        });
        Some(verdict.diagnosable && !violated)
    }
}

/// A libFAUDES assumption of event-diagnosability that does not hold.
///
/// Kept apart from the failure types' verdicts because it is a property of the
/// model, not of what the observation reveals: the fix is in the model.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum AssumptionViolation {
    /// A failure event is not an event of the generator (libFAUDES refuses such a
    /// map with an exception).
    UnknownFailureEvent {
        /// The failure type naming it.
        failure_type: String,
        /// The event.
        event: String,
    },
    /// A failure event is observable: failures must be unobservable.
    ObservableFailureEvent {
        /// The failure type naming it.
        failure_type: String,
        /// The event.
        event: String,
    },
    /// States without any outgoing transition (the generator must be live; libFAUDES
    /// checks every state, reachable or not).
    Deadlock {
        /// Their names, in state order (at most [`LISTED_STATES`] of a product).
        states: Vec<String>,
        /// How many more there are, not listed (a product's dead states are
        /// every combination of its independent components' own).
        #[serde(default, skip_serializing_if = "is_zero")]
        more: usize,
    },
    /// A cycle of unobservable events (checked over every state, reachable or not).
    UnobservableCycle {
        /// States of the cycle: `states[i] --events[i]--> states[i+1]`, the last
        /// event leading back to `states[0]`.
        states: Vec<String>,
        /// Events of the cycle.
        events: Vec<String>,
    },
}

/// The verdict for one failure type.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TypeVerdict {
    /// The failure type.
    pub failure_type: String,
    /// No indeterminate cycle: every failure of this type is eventually known from
    /// the observation (along runs with infinitely many observations).
    pub diagnosable: bool,
    /// When not diagnosable: two runs that the observation cannot tell apart.
    pub counterexample: Option<Counterexample>,
}

/// Two runs of the generator with the same observation, one after a failure of the
/// type and one without any, both repeating a loop forever: the observer can never
/// conclude.
///
/// Each run is `stem loop loop loop ...`; the loop of a run starts right after its
/// `cycle_from`-th observable event.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Counterexample {
    /// The faulty run, stem then one turn of its loop, unobservable events included.
    /// A failure of the type occurs in the stem.
    pub faulty: Vec<String>,
    /// The normal run, stem then one turn of its loop; no failure of the type.
    pub normal: Vec<String>,
    /// What both runs show: their common sequence of observable events.
    pub observed: Vec<String>,
    /// Index in `observed` where the loop starts (the stem shows `cycle_from`
    /// events).
    pub cycle_from: usize,
}

// ---------------------------------------------------------------------------------
// Tokens

/// A token of the libFAUDES token format.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Tok {
    /// `<Name attr="value">`.
    Begin(String, Vec<(String, String)>),
    /// `</Name>` (also produced by `<Name/>`).
    End(String),
    /// A name, quoted (`"alpha"`) or bare (`alpha`).
    Str(String),
    /// A decimal integer.
    Int(u64),
    /// A hexadecimal integer (`0x0a`): event flags.
    Hex(u64),
    /// An option (`+o+`): event flags.
    Opt(String),
    /// End of the text.
    Eof,
}

#[derive(Debug, Clone)]
struct Token {
    tok: Tok,
    /// Byte offset of its first character.
    offset: usize,
}

fn describe(tok: &Tok) -> String {
    match tok {
        Tok::Begin(name, _) => format!("<{name}>"),
        Tok::End(name) => format!("</{name}>"),
        Tok::Str(s) => format!("\"{s}\""),
        Tok::Int(i) => i.to_string(),
        Tok::Hex(h) => format!("0x{h:x}"),
        Tok::Opt(o) => format!("+{o}+"),
        Tok::Eof => "the end of the file".to_string(),
    }
}

fn error_at(text: &str, path: &Path, offset: usize, field: &str, message: String) -> Located {
    let (line, column) = line_column(text, offset);
    Located::new(Location::new(path, line, column).with_field(field), message)
}

fn is_word_end(c: char) -> bool {
    c.is_whitespace() || c == '<' || c == '"' || c == '%'
}

/// Splits `text` into tokens. Comments (`%` to the end of the line), the XML
/// declaration and `<!DOCTYPE>` are dropped.
fn lex(text: &str, path: &Path) -> Result<Vec<Token>, Located> {
    let err = |offset: usize, message: String| error_at(text, path, offset, "token", message);
    let bytes = text.as_bytes();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let Some(ch) = text[i..].chars().next() else {
            break;
        };
        if ch.is_whitespace() {
            i += ch.len_utf8();
            continue;
        }
        let start = i;
        match bytes[i] {
            b'%' => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            b'<' => {
                let rest = &text[i..];
                if rest.starts_with("<?") || rest.starts_with("<!") {
                    match rest.find('>') {
                        Some(end) => i += end + 1,
                        None => return Err(err(start, "unterminated '<' markup".into())),
                    }
                    continue;
                }
                let close = match rest.find('>') {
                    Some(end) => end,
                    None => return Err(err(start, "unterminated tag: missing '>'".into())),
                };
                let inner = &rest[1..close];
                i += close + 1;
                tokens.extend(lex_tag(inner, start).map_err(|m| err(start, m))?);
            }
            b'"' => {
                let rest = &text[i + 1..];
                let end = rest
                    .find(['"', '\n'])
                    .filter(|&e| rest.as_bytes()[e] == b'"')
                    .ok_or_else(|| err(start, "unterminated string: missing '\"'".into()))?;
                tokens.push(Token {
                    tok: Tok::Str(rest[..end].to_string()),
                    offset: start,
                });
                i += end + 2;
            }
            b'+' => {
                let rest = &text[i + 1..];
                let end = rest
                    .find(['+', '\n'])
                    .filter(|&e| rest.as_bytes()[e] == b'+')
                    .ok_or_else(|| err(start, "unterminated option: missing '+'".into()))?;
                tokens.push(Token {
                    tok: Tok::Opt(rest[..end].to_string()),
                    offset: start,
                });
                i += end + 2;
            }
            _ => {
                let rest = &text[i..];
                let end = rest.find(is_word_end).unwrap_or(rest.len());
                let word = &rest[..end];
                i += end;
                let tok = if word.bytes().all(|b| b.is_ascii_digit()) {
                    Tok::Int(
                        word.parse()
                            .map_err(|_| err(start, format!("integer {word} is too large")))?,
                    )
                } else if let Some(hex) = word
                    .strip_prefix("0x")
                    .filter(|h| !h.is_empty() && h.bytes().all(|b| b.is_ascii_hexdigit()))
                {
                    Tok::Hex(
                        u64::from_str_radix(hex, 16)
                            .map_err(|_| err(start, format!("integer {word} is too large")))?,
                    )
                } else {
                    Tok::Str(word.to_string())
                };
                tokens.push(Token { tok, offset: start });
            }
        }
    }
    tokens.push(Token {
        tok: Tok::Eof,
        offset: text.len(),
    });
    Ok(tokens)
}

/// The tokens of one tag, given what is between `<` and `>`.
fn lex_tag(inner: &str, offset: usize) -> Result<Vec<Token>, String> {
    if let Some(name) = inner.strip_prefix('/') {
        let name = name.trim();
        if name.is_empty() || name.contains(char::is_whitespace) {
            return Err(format!("malformed end tag </{name}>"));
        }
        return Ok(vec![Token {
            tok: Tok::End(name.to_string()),
            offset,
        }]);
    }
    let (inner, empty) = match inner.strip_suffix('/') {
        Some(inner) => (inner, true),
        None => (inner, false),
    };
    let name_end = inner.find(char::is_whitespace).unwrap_or(inner.len());
    let name = &inner[..name_end];
    if name.is_empty() {
        return Err("malformed tag: no name after '<'".into());
    }
    let mut attrs = Vec::new();
    let mut rest = inner[name_end..].trim_start();
    while !rest.is_empty() {
        let eq = rest
            .find('=')
            .ok_or_else(|| format!("malformed attribute in <{name}>: missing '='"))?;
        let key = rest[..eq].trim().to_string();
        let after = rest[eq + 1..].trim_start();
        let (value, remaining) = if let Some(quoted) = after.strip_prefix('"') {
            let end = quoted
                .find('"')
                .ok_or_else(|| format!("unterminated attribute value in <{name}>"))?;
            (&quoted[..end], &quoted[end + 1..])
        } else {
            let end = after.find(char::is_whitespace).unwrap_or(after.len());
            (&after[..end], &after[end..])
        };
        attrs.push((key, value.to_string()));
        rest = remaining.trim_start();
    }
    let mut tokens = vec![Token {
        tok: Tok::Begin(name.to_string(), attrs),
        offset,
    }];
    if empty {
        tokens.push(Token {
            tok: Tok::End(name.to_string()),
            offset,
        });
    }
    Ok(tokens)
}

/// A cursor over the tokens of one file, for error messages that point at them.
struct Cursor<'a> {
    text: &'a str,
    path: &'a Path,
    tokens: Vec<Token>,
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn new(text: &'a str, path: &'a Path) -> Result<Self, Located> {
        Ok(Cursor {
            text,
            path,
            tokens: lex(text, path)?,
            pos: 0,
        })
    }

    fn peek(&self) -> &Tok {
        // The token list always ends with `Eof`, and `next` never moves past it.
        self.tokens.get(self.pos).map_or(&Tok::Eof, |t| &t.tok)
    }

    fn offset(&self) -> usize {
        self.tokens
            .get(self.pos)
            .map_or(self.text.len(), |t| t.offset)
    }

    fn bump(&mut self) -> (Tok, usize) {
        let token = (self.peek().clone(), self.offset());
        if self.pos + 1 < self.tokens.len() {
            self.pos += 1;
        }
        token
    }

    fn error(&self, offset: usize, field: &str, message: impl Into<String>) -> Located {
        error_at(self.text, self.path, offset, field, message.into())
    }

    /// The error for an unexpected token at the cursor (without consuming it).
    fn unexpected(&self, field: &str, expected: &str) -> Located {
        let found = self.peek();
        let message = if *found == Tok::Eof {
            format!("the file ends early: expected {expected}")
        } else {
            format!("expected {expected}, found {}", describe(found))
        };
        self.error(self.offset(), field, message)
    }

    /// Whether the next token begins one of `names`.
    fn at_begin(&self, names: &[&str]) -> Option<String> {
        match self.peek() {
            Tok::Begin(name, _) if names.contains(&name.as_str()) => Some(name.clone()),
            _ => None,
        }
    }

    /// Consumes `</name>` if it is next.
    fn eat_end(&mut self, name: &str) -> bool {
        if matches!(self.peek(), Tok::End(n) if n == name) {
            self.bump();
            true
        } else {
            false
        }
    }

    /// Skips a whole section whose `<name>` has just been consumed at `offset`.
    fn skip_section(&mut self, name: &str, offset: usize, field: &str) -> Result<(), Located> {
        let mut depth = 1usize;
        loop {
            match self.bump() {
                (Tok::Begin(..), _) => depth += 1,
                (Tok::End(_), _) if depth > 1 => depth -= 1,
                (Tok::End(n), end) => {
                    if n != name {
                        return Err(self.error(
                            end,
                            field,
                            format!("<{name}> is closed by </{n}>"),
                        ));
                    }
                    return Ok(());
                }
                (Tok::Eof, _) => {
                    return Err(self.error(
                        offset,
                        field,
                        format!("section <{name}> is never closed (the file ends early)"),
                    ));
                }
                _ => {}
            }
        }
    }

    /// Skips attributes after an element: options, flags and unknown sections other
    /// than `keep`.
    fn skip_attributes(&mut self, keep: &[&str], field: &str) -> Result<(), Located> {
        loop {
            match self.peek() {
                Tok::Opt(_) | Tok::Hex(_) => {
                    self.bump();
                }
                Tok::Begin(name, _) if !keep.contains(&name.as_str()) => {
                    let name = name.clone();
                    let (_, offset) = self.bump();
                    self.skip_section(&name, offset, field)?;
                }
                _ => return Ok(()),
            }
        }
    }

    /// After the last section: nothing but the end of the file.
    fn expect_eof(&self, after: &str) -> Result<(), Located> {
        if *self.peek() == Tok::Eof {
            Ok(())
        } else {
            Err(self.error(
                self.offset(),
                after,
                format!("unexpected {} after </{after}>", describe(self.peek())),
            ))
        }
    }
}

// ---------------------------------------------------------------------------------
// Generators

/// Event flags of libFAUDES (`AttributeCFlags`): bit 1 is "observable".
const OBSERVABLE_FLAG: u64 = 0x02;

/// Reads a generator in libFAUDES's token format.
///
/// Accepts what libFAUDES writes and reads: sections `<Alphabet>` (or `<A>`),
/// `<States>` (`<S>`), `<TransRel>` (`<T>`), `<InitStates>` (`<I>`) and
/// `<MarkedStates>` (`<M>`) in that order, all optional but `<TransRel>`; quoted or
/// bare names; states by index, by name, by `name#index`, or as
/// `<Consecutive> first last </Consecutive>` ranges; `%` comments; event flags as
/// options (`+o+` unobservable, `+O+` observable, `+C+` controllable...) or as
/// hexadecimal integers; attributes and unknown sections are skipped. As in
/// libFAUDES, states (events) met first in `<TransRel>` are declared there only when
/// the file has no `<States>` (`<Alphabet>`).
///
/// Errors name the file, line and column, and the section concerned.
pub fn parse_generator(text: &str, path: &Path) -> Result<Generator, Located> {
    check_leading_comments(text, path)?;
    let mut c = Cursor::new(text, path)?;
    let attrs = match c.bump() {
        (Tok::Begin(name, attrs), _) if name == "Generator" => attrs,
        (tok, offset) => {
            return Err(c.error(
                offset,
                "Generator",
                format!("expected <Generator>, found {}", describe(&tok)),
            ));
        }
    };
    let mut g = GenBuilder {
        name: attrs
            .iter()
            .find(|(k, _)| k == "name")
            .map_or_else(|| "Generator".to_string(), |(_, v)| v.clone()),
        ..GenBuilder::default()
    };
    if let Tok::Str(name) = c.peek() {
        g.name = name.clone();
        c.bump();
    }
    if let Some(label) = c.at_begin(&["Alphabet", "A"]) {
        c.bump();
        g.read_alphabet(&mut c, &label)?;
    }
    if let Some(label) = c.at_begin(&["States", "S"]) {
        c.bump();
        g.read_states(&mut c, &label)?;
    }
    if c.at_begin(&["StateSet", "TransitionRelation"]).is_some() {
        return Err(c.error(
            c.offset(),
            "Generator",
            "the XML form of generators is not supported: write the generator in libFAUDES's \
             token format (<States>, <TransRel>)",
        ));
    }
    match c.at_begin(&["TransRel", "T"]) {
        Some(label) => {
            c.bump();
            g.read_transitions(&mut c, &label)?;
        }
        None => return Err(c.unexpected("Generator", "<TransRel>")),
    }
    if let Some(label) = c.at_begin(&["InitStates", "I"]) {
        c.bump();
        g.initial = g.read_state_set(&mut c, &label)?;
    }
    if let Some(label) = c.at_begin(&["MarkedStates", "M"]) {
        c.bump();
        g.marked = g.read_state_set(&mut c, &label)?;
    }
    // What follows the core sections (a global attribute) does not concern us.
    const CORE: [&str; 10] = [
        "Alphabet",
        "A",
        "States",
        "S",
        "TransRel",
        "T",
        "InitStates",
        "I",
        "MarkedStates",
        "M",
    ];
    loop {
        match c.peek().clone() {
            Tok::End(name) if name == "Generator" => {
                c.bump();
                break;
            }
            Tok::Begin(name, _) if CORE.contains(&name.as_str()) => {
                return Err(c.error(
                    c.offset(),
                    "Generator",
                    format!(
                        "section <{name}> is out of place or repeated: libFAUDES reads \
                         <Alphabet>, <States>, <TransRel>, <InitStates>, <MarkedStates> \
                         in this order"
                    ),
                ));
            }
            Tok::Begin(name, _) => {
                let (_, offset) = c.bump();
                c.skip_section(&name, offset, "Generator")?;
            }
            _ => return Err(c.unexpected("Generator", "</Generator>")),
        }
    }
    c.expect_eof("Generator")?;
    Ok(g.finish())
}

/// libFAUDES refuses `<` and `>` in the comments that precede `<Generator>` (it
/// reads the start of the file to tell its formats apart); so do we, so that the
/// files we read are files it reads.
fn check_leading_comments(text: &str, path: &Path) -> Result<(), Located> {
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_start();
        if !trimmed.is_empty() {
            if !trimmed.starts_with('%') {
                break;
            }
            if let Some(at) = line.find(['<', '>']) {
                return Err(error_at(
                    text,
                    path,
                    offset + at,
                    "Generator",
                    "'<' or '>' in a comment before <Generator> (libFAUDES refuses them there)"
                        .into(),
                ));
            }
        }
        offset += line.len();
    }
    Ok(())
}

#[derive(Default)]
struct GenBuilder {
    name: String,
    events: Vec<String>,
    observable: Vec<bool>,
    event_index: HashMap<String, usize>,
    states: Vec<String>,
    /// libFAUDES state index -> our index.
    by_index: HashMap<u64, usize>,
    /// State name -> our index (named states only).
    by_name: HashMap<String, usize>,
    /// Largest libFAUDES state index so far.
    max_index: u64,
    initial: Vec<usize>,
    marked: Vec<usize>,
    transitions: Vec<(usize, usize, usize)>,
}

/// Largest `<Consecutive>` range accepted, to refuse absurd files rather than
/// exhaust memory.
const MAX_RANGE: u64 = 1_000_000;

impl GenBuilder {
    fn add_event(&mut self, name: String) -> usize {
        let e = self.events.len();
        self.event_index.insert(name.clone(), e);
        self.events.push(name);
        self.observable.push(true);
        e
    }

    fn add_state(&mut self, index: u64, name: Option<String>) -> usize {
        let x = self.states.len();
        self.by_index.insert(index, x);
        match name {
            Some(name) => {
                self.by_name.insert(name.clone(), x);
                self.states.push(name);
            }
            None => self.states.push(index.to_string()),
        }
        self.max_index = self.max_index.max(index);
        x
    }

    fn read_alphabet(&mut self, c: &mut Cursor, label: &str) -> Result<(), Located> {
        let field = "Alphabet";
        loop {
            match c.peek().clone() {
                Tok::Str(name) => {
                    let (_, offset) = c.bump();
                    if self.event_index.contains_key(&name) {
                        return Err(c.error(
                            offset,
                            field,
                            format!("event \"{name}\" is declared twice"),
                        ));
                    }
                    let e = self.add_event(name);
                    // The first flags given count, as in libFAUDES.
                    match c.peek().clone() {
                        Tok::Opt(opt) => {
                            if opt.contains('O') {
                                self.observable[e] = true;
                            }
                            if opt.contains('o') {
                                self.observable[e] = false;
                            }
                        }
                        Tok::Hex(flags) => self.observable[e] = flags & OBSERVABLE_FLAG != 0,
                        _ => {}
                    }
                    c.skip_attributes(&[], field)?;
                }
                Tok::End(name) if name == label => {
                    c.bump();
                    return Ok(());
                }
                Tok::Begin(name, _) if name == "Event" => {
                    return Err(c.error(
                        c.offset(),
                        field,
                        "the XML form of events (<Event name=...>) is not supported: write \
                         event names, each followed by its flags (+o+ for unobservable)",
                    ));
                }
                _ => return Err(c.unexpected(field, &format!("an event name or </{label}>"))),
            }
        }
    }

    fn read_states(&mut self, c: &mut Cursor, label: &str) -> Result<(), Located> {
        let field = "States";
        // As libFAUDES, a state given by name only gets the index "number of
        // states read so far + 1".
        let mut symnext: u64 = 1;
        let (mut implicit, mut explicit) = (false, false);
        loop {
            match c.peek().clone() {
                Tok::Int(index) => {
                    let (_, offset) = c.bump();
                    if index == 0 {
                        return Err(c.error(offset, field, "state index 0 is not allowed"));
                    }
                    if self.by_index.contains_key(&index) {
                        return Err(c.error(
                            offset,
                            field,
                            format!("state {index} is declared twice"),
                        ));
                    }
                    self.add_state(index, None);
                    symnext += 1;
                    c.skip_attributes(&["Consecutive"], field)?;
                }
                Tok::Str(word) => {
                    let (_, offset) = c.bump();
                    let (name, index) =
                        match word.split_once('#') {
                            None => {
                                implicit = true;
                                (word.clone(), symnext)
                            }
                            Some((name, suffix)) => {
                                explicit = true;
                                let index =
                                    suffix.parse::<u64>().ok().filter(|&i| i > 0).ok_or_else(
                                        || {
                                            c.error(
                                        offset,
                                        field,
                                        format!(
                                            "state \"{word}\": expected a positive index after '#'"
                                        ),
                                    )
                                        },
                                    )?;
                                (name.to_string(), index)
                            }
                        };
                    if implicit && explicit {
                        return Err(c.error(
                            offset,
                            field,
                            "states are given both with and without an explicit #index",
                        ));
                    }
                    if name.is_empty() {
                        return Err(c.error(offset, field, "empty state name"));
                    }
                    if self.by_name.contains_key(&name) || self.by_index.contains_key(&index) {
                        return Err(c.error(
                            offset,
                            field,
                            format!("state \"{name}\" is declared twice"),
                        ));
                    }
                    self.add_state(index, Some(name));
                    symnext += 1;
                    c.skip_attributes(&["Consecutive"], field)?;
                }
                Tok::Begin(name, _) if name == "Consecutive" => {
                    let (_, offset) = c.bump();
                    let (first, last) = self.read_range(c, field, offset)?;
                    for index in first..=last {
                        if self.by_index.contains_key(&index) {
                            return Err(c.error(
                                offset,
                                field,
                                format!("state {index} is declared twice"),
                            ));
                        }
                        self.add_state(index, None);
                        symnext += 1;
                    }
                }
                Tok::End(name) if name == label => {
                    c.bump();
                    return Ok(());
                }
                _ => {
                    return Err(c.unexpected(
                        field,
                        &format!("a state (index or name), <Consecutive> or </{label}>"),
                    ));
                }
            }
        }
    }

    /// Reads `first last </Consecutive>` after `<Consecutive>` at `offset`.
    fn read_range(
        &self,
        c: &mut Cursor,
        field: &str,
        offset: usize,
    ) -> Result<(u64, u64), Located> {
        let bound = |c: &mut Cursor| match c.peek().clone() {
            Tok::Int(i) => {
                c.bump();
                Ok(i)
            }
            _ => Err(c.unexpected(field, "a state index in <Consecutive>")),
        };
        let first = bound(c)?;
        let last = bound(c)?;
        if !c.eat_end("Consecutive") {
            return Err(c.unexpected(field, "</Consecutive>"));
        }
        if first == 0 || last < first {
            return Err(c.error(
                offset,
                field,
                format!("invalid range of states {first} to {last}"),
            ));
        }
        if last - first >= MAX_RANGE {
            return Err(c.error(
                offset,
                field,
                format!("range of states {first} to {last} is too large (at most {MAX_RANGE})"),
            ));
        }
        Ok((first, last))
    }

    fn read_transitions(&mut self, c: &mut Cursor, label: &str) -> Result<(), Located> {
        let field = "TransRel";
        // As libFAUDES: without <States>, states are declared by their first use,
        // all by index or all by name; without <Alphabet>, events likewise.
        let mut new_by_index = self.states.is_empty();
        let mut new_by_name = self.states.is_empty();
        let new_events = self.events.is_empty();
        let mut seen = HashSet::new();
        loop {
            if c.eat_end(label) {
                return Ok(());
            }
            let from = self.transition_state(c, &mut new_by_index, &mut new_by_name, "source")?;
            let event = match c.peek().clone() {
                Tok::Str(name) => {
                    let (_, offset) = c.bump();
                    match self.event_index.get(&name) {
                        Some(&e) => e,
                        None if new_events => self.add_event(name),
                        None => {
                            return Err(c.error(
                                offset,
                                field,
                                format!("unknown event \"{name}\" (not in <Alphabet>)"),
                            ));
                        }
                    }
                }
                _ => return Err(c.unexpected(field, "an event name")),
            };
            let to = self.transition_state(c, &mut new_by_index, &mut new_by_name, "target")?;
            c.skip_attributes(&[], field)?;
            if seen.insert((from, event, to)) {
                self.transitions.push((from, event, to));
            }
        }
    }

    /// Reads the source or target state of a transition.
    fn transition_state(
        &mut self,
        c: &mut Cursor,
        new_by_index: &mut bool,
        new_by_name: &mut bool,
        role: &str,
    ) -> Result<usize, Located> {
        let field = "TransRel";
        match c.peek().clone() {
            Tok::Int(index) => {
                let (_, offset) = c.bump();
                match self.by_index.get(&index) {
                    Some(&x) => Ok(x),
                    None if *new_by_index && index > 0 => {
                        *new_by_name = false;
                        Ok(self.add_state(index, None))
                    }
                    None => Err(c.error(
                        offset,
                        field,
                        format!("unknown state {index} (not in <States>)"),
                    )),
                }
            }
            Tok::Str(name) => {
                let (_, offset) = c.bump();
                match self.by_name.get(&name) {
                    Some(&x) => Ok(x),
                    None if *new_by_name => {
                        *new_by_index = false;
                        let index = self.max_index + 1;
                        Ok(self.add_state(index, Some(name)))
                    }
                    None => Err(c.error(
                        offset,
                        field,
                        format!("unknown state \"{name}\" (not in <States>)"),
                    )),
                }
            }
            _ => Err(c.unexpected(field, &format!("the {role} state of a transition"))),
        }
    }

    /// Reads `<InitStates>` or `<MarkedStates>` (after its begin tag).
    fn read_state_set(&self, c: &mut Cursor, label: &str) -> Result<Vec<usize>, Located> {
        let field = match label {
            "I" | "InitStates" => "InitStates",
            _ => "MarkedStates",
        };
        let mut set = Vec::new();
        let mut seen = HashSet::new();
        let mut add = |x: usize, set: &mut Vec<usize>| {
            if seen.insert(x) {
                set.push(x);
            }
        };
        loop {
            match c.peek().clone() {
                Tok::Int(index) => {
                    let (_, offset) = c.bump();
                    let x = *self.by_index.get(&index).ok_or_else(|| {
                        c.error(
                            offset,
                            field,
                            format!("unknown state {index} (not in <States>)"),
                        )
                    })?;
                    add(x, &mut set);
                    c.skip_attributes(&["Consecutive"], field)?;
                }
                Tok::Str(name) => {
                    let (_, offset) = c.bump();
                    let x = *self.by_name.get(&name).ok_or_else(|| {
                        c.error(
                            offset,
                            field,
                            format!("unknown state \"{name}\" (not in <States>)"),
                        )
                    })?;
                    add(x, &mut set);
                    c.skip_attributes(&["Consecutive"], field)?;
                }
                Tok::Begin(name, _) if name == "Consecutive" => {
                    let (_, offset) = c.bump();
                    let (first, last) = self.read_range(c, field, offset)?;
                    for index in first..=last {
                        let x = *self.by_index.get(&index).ok_or_else(|| {
                            c.error(
                                offset,
                                field,
                                format!("unknown state {index} (not in <States>)"),
                            )
                        })?;
                        add(x, &mut set);
                    }
                }
                Tok::Begin(name, _) => {
                    let (_, offset) = c.bump();
                    c.skip_section(&name, offset, field)?;
                }
                Tok::End(name) if name == label => {
                    c.bump();
                    return Ok(set);
                }
                _ => {
                    return Err(c.unexpected(
                        field,
                        &format!("a state (index or name), <Consecutive> or </{label}>"),
                    ));
                }
            }
        }
    }

    fn finish(self) -> Generator {
        Generator {
            name: self.name,
            events: self.events,
            observable: self.observable,
            states: self.states,
            initial: self.initial,
            marked: self.marked,
            transitions: self.transitions,
        }
    }
}

// ---------------------------------------------------------------------------------
// Failure types

/// Reads a failure-type map in libFAUDES's format (`AttributeFailureTypeMap`):
///
/// ```text
/// <FailureTypes>
/// "F1" <FailureEvents> "f1" "f1b" </FailureEvents> <IndicatorEvents> "i1" </IndicatorEvents>
/// "F2" <FailureEvents> "f2" </FailureEvents>
/// </FailureTypes>
/// ```
///
/// Indicator events are read and dropped. Errors name the file, line and column.
pub fn parse_failure_types(text: &str, path: &Path) -> Result<FailureTypes, Located> {
    let mut c = Cursor::new(text, path)?;
    let field = "FailureTypes";
    match c.bump() {
        (Tok::Begin(name, _), _) if name == "FailureTypes" => {}
        (tok, offset) => {
            return Err(c.error(
                offset,
                field,
                format!("expected <FailureTypes>, found {}", describe(&tok)),
            ));
        }
    }
    let mut types: Vec<(String, Vec<String>)> = Vec::new();
    loop {
        match c.peek().clone() {
            Tok::Str(name) => {
                let (_, offset) = c.bump();
                if types.iter().any(|(t, _)| *t == name) {
                    return Err(c.error(
                        offset,
                        field,
                        format!("failure type \"{name}\" is given twice"),
                    ));
                }
                // Flags of the failure type (libFAUDES's AttributeFlags): unused.
                while matches!(c.peek(), Tok::Opt(_) | Tok::Hex(_)) {
                    c.bump();
                }
                let mut failures = Vec::new();
                while let Some(section) = c.at_begin(&["FailureEvents", "IndicatorEvents"]) {
                    c.bump();
                    let events = read_event_set(&mut c, &section)?;
                    if section == "FailureEvents" {
                        for e in events {
                            if !failures.contains(&e) {
                                failures.push(e);
                            }
                        }
                    }
                }
                types.push((name, failures));
            }
            Tok::End(name) if name == "FailureTypes" => {
                c.bump();
                break;
            }
            _ => {
                return Err(c.unexpected(
                    field,
                    "a failure type name, <FailureEvents>, <IndicatorEvents> or </FailureTypes>",
                ));
            }
        }
    }
    c.expect_eof(field)?;
    Ok(FailureTypes { types })
}

/// Reads the event names of `<FailureEvents>` or `<IndicatorEvents>` (after its
/// begin tag).
fn read_event_set(c: &mut Cursor, label: &str) -> Result<Vec<String>, Located> {
    let mut events = Vec::new();
    loop {
        match c.peek().clone() {
            Tok::Str(name) => {
                c.bump();
                events.push(name);
                c.skip_attributes(&[], label)?;
            }
            Tok::End(name) if name == label => {
                c.bump();
                return Ok(events);
            }
            _ => return Err(c.unexpected(label, &format!("an event name or </{label}>"))),
        }
    }
}

// ---------------------------------------------------------------------------------
// Diagnosability

/// Decides event-diagnosability of `g` for each failure type of `f`, with
/// libFAUDES's semantics, and gives a counterexample for each failure type that is
/// not diagnosable.
///
/// Failure events that are not events of `g` are reported as
/// [`AssumptionViolation::UnknownFailureEvent`] (libFAUDES throws an exception).
/// Several initial states are allowed (libFAUDES refuses them); without any, the
/// generator has no run and every failure type is diagnosable. Transitions naming
/// states or events outside `g`'s vectors are ignored.
pub fn event_diagnosability(g: &Generator, f: &FailureTypes) -> EventDiagnosability {
    match event_diagnosability_within(g, f, usize::MAX) {
        Ok(result) => result,
        Err(too_large) => unreachable!("no verifier reaches usize::MAX: {too_large:?}"),
    }
}

/// [`event_diagnosability`], giving up once a failure type's verifier holds
/// more than `budget` nodes and edges: its memory grows with them, and with
/// the product of a generator's components.
pub fn event_diagnosability_within(
    g: &Generator,
    f: &FailureTypes,
    budget: usize,
) -> Result<EventDiagnosability, TooLarge> {
    event_diagnosability_explored(g, f, budget, BREADTH_FIRST)
}

/// [`event_diagnosability_within`], its twin plants explored whole and
/// breadth-first up to `breadth_first` nodes and edges (counterexamples with
/// the shortest stems), depth-first past that, stopping at the first
/// counterexample. The verdicts do not depend on `breadth_first`.
pub fn event_diagnosability_explored(
    g: &Generator,
    f: &FailureTypes,
    budget: usize,
    breadth_first: usize,
) -> Result<EventDiagnosability, TooLarge> {
    let sys = System::new(g);
    verdict(f, assumptions(g, &sys, f), |name, failures| {
        verify(g, &sys, failures, budget, breadth_first).map_err(|reached| TooLarge {
            failure_type: name.to_string(),
            reached,
        })
    })
}

/// The verdict from the assumptions that do not hold and, per failure type,
/// the counterexample `search` finds (if any).
fn verdict<E>(
    f: &FailureTypes,
    assumptions: Vec<AssumptionViolation>,
    mut search: impl FnMut(&str, &[String]) -> Result<Option<Counterexample>, E>,
) -> Result<EventDiagnosability, E> {
    let mut types: Vec<TypeVerdict> = Vec::new();
    for (name, failures) in &f.types {
        let counterexample = search(name, failures)?;
        types.push(TypeVerdict {
            failure_type: name.clone(),
            diagnosable: counterexample.is_none(),
            counterexample,
        });
    }
    Ok(EventDiagnosability {
        diagnosable: assumptions.is_empty() && types.iter().all(|t| t.diagnosable),
        assumptions,
        types,
    })
}

/// A verifier that outgrew its budget.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TooLarge {
    /// The failure type whose verifier it was.
    pub failure_type: String,
    /// Its nodes and edges when it was given up.
    pub reached: usize,
}

/// The generator as adjacency lists, keeping only well-formed transitions.
struct System {
    /// `out[x]`: `(event, target)` of the transitions leaving `x`.
    out: Vec<Vec<(usize, usize)>>,
    observable: Vec<bool>,
}

impl System {
    fn new(g: &Generator) -> Self {
        let n = g.states.len();
        let mut out = vec![Vec::new(); n];
        for &(x, e, y) in &g.transitions {
            if x < n && y < n && e < g.events.len() {
                out[x].push((e, y));
            }
        }
        let observable = (0..g.events.len())
            .map(|e| g.observable.get(e).copied().unwrap_or(true))
            .collect();
        System { out, observable }
    }
}

fn assumptions(g: &Generator, sys: &System, f: &FailureTypes) -> Vec<AssumptionViolation> {
    let mut violations = failure_event_violations(&g.events, &sys.observable, f);
    let dead: Vec<String> = (0..g.states.len())
        .filter(|&x| sys.out[x].is_empty())
        .map(|x| g.states[x].clone())
        .collect();
    if !dead.is_empty() {
        violations.push(AssumptionViolation::Deadlock {
            states: dead,
            more: 0,
        });
    }
    if let Some((states, events)) = unobservable_cycle(sys) {
        violations.push(AssumptionViolation::UnobservableCycle {
            states: states.into_iter().map(|x| g.states[x].clone()).collect(),
            events: events.into_iter().map(|e| g.events[e].clone()).collect(),
        });
    }
    violations
}

/// The failure events that are not `events`, or are observable.
fn failure_event_violations(
    events: &[String],
    observable: &[bool],
    f: &FailureTypes,
) -> Vec<AssumptionViolation> {
    let mut violations = Vec::new();
    for (failure_type, failures) in &f.types {
        for event in failures {
            match events.iter().position(|e| e == event) {
                None => violations.push(AssumptionViolation::UnknownFailureEvent {
                    failure_type: failure_type.clone(),
                    event: event.clone(),
                }),
                Some(e) if observable[e] => {
                    violations.push(AssumptionViolation::ObservableFailureEvent {
                        failure_type: failure_type.clone(),
                        event: event.clone(),
                    });
                }
                Some(_) => {}
            }
        }
    }
    violations
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// A cycle of unobservable transitions, as its states and events, if there is one.
fn unobservable_cycle(sys: &System) -> Option<(Vec<usize>, Vec<usize>)> {
    // Iterative depth-first search; `stack` holds the current path as
    // (state, next transition to try, event that led here).
    const NEW: u8 = 0;
    const ON_PATH: u8 = 1;
    const DONE: u8 = 2;
    let n = sys.out.len();
    let mut color = vec![NEW; n];
    for root in 0..n {
        if color[root] != NEW {
            continue;
        }
        let mut stack: Vec<(usize, usize, usize)> = vec![(root, 0, usize::MAX)];
        color[root] = ON_PATH;
        while let Some(top) = stack.last_mut() {
            let (x, next) = (top.0, top.1);
            if next == sys.out[x].len() {
                color[x] = DONE;
                stack.pop();
                continue;
            }
            top.1 += 1;
            let (e, y) = sys.out[x][next];
            if sys.observable[e] {
                continue;
            }
            match color[y] {
                NEW => {
                    color[y] = ON_PATH;
                    stack.push((y, 0, e));
                }
                ON_PATH => {
                    let start = stack.iter().position(|s| s.0 == y).unwrap_or(0);
                    let states: Vec<usize> = stack[start..].iter().map(|s| s.0).collect();
                    let mut events: Vec<usize> = stack[start + 1..].iter().map(|s| s.2).collect();
                    events.push(e);
                    return Some((states, events));
                }
                _ => {}
            }
        }
    }
    None
}

/// A move of the observation automaton: unobservable events then one observable
/// event.
struct ObsEdge {
    /// The observable event.
    event: usize,
    /// The node reached.
    to: usize,
}

/// The observation automaton (libFAUDES's G_o): a node is a state reached by
/// an observable event (or initial) with the label "a failure of the type has
/// occurred"; an edge is unobservable events then one observable event. Its
/// nodes, their edges and the initial nodes.
fn observation_automaton(
    g: &Generator,
    sys: &System,
    failure: &[bool],
    grow: &mut impl FnMut(usize) -> Result<(), usize>,
) -> Result<ObservationAutomaton, usize> {
    let mut nodes: Vec<(usize, bool)> = Vec::new();
    let mut node_of: HashMap<(usize, bool), usize> = HashMap::new();
    let mut edges: Vec<Vec<ObsEdge>> = Vec::new();
    let mut starts = Vec::new();
    for &x in &g.initial {
        if x < sys.out.len() && !node_of.contains_key(&(x, false)) {
            node_of.insert((x, false), nodes.len());
            starts.push(nodes.len());
            nodes.push((x, false));
        }
    }
    let mut next = 0;
    while next < nodes.len() {
        let moves = observation_moves(sys, failure, nodes[next]);
        let mut out = Vec::with_capacity(moves.len());
        // The runs behind the moves are not kept: the counterexample's few
        // are found again (`run_of`), and the rest would hold most of the memory.
        for (event, target, _run) in moves {
            let to = *node_of.entry(target).or_insert_with(|| {
                nodes.push(target);
                nodes.len() - 1
            });
            out.push(ObsEdge { event, to });
        }
        out.sort_by_key(|edge| edge.event);
        grow(1 + out.len())?;
        edges.push(out);
        next += 1;
    }
    Ok((nodes, edges, starts))
}

/// Nodes `(state, failed)`, each one's edges, and the initial nodes.
type ObservationAutomaton = (Vec<(usize, bool)>, Vec<Vec<ObsEdge>>, Vec<usize>);

/// A counterexample to the diagnosability of the failure type made of
/// `failures`, if there is one; `Err` with the verifier's size once it holds
/// more than `budget` nodes and edges.
fn verify(
    g: &Generator,
    sys: &System,
    failures: &[String],
    budget: usize,
    breadth_first: usize,
) -> Result<Option<Counterexample>, usize> {
    let failure: Vec<bool> = g.events.iter().map(|e| failures.contains(e)).collect();
    // Only unobservable failure events set the label (as in libFAUDES): without
    // any, no run is faulty.
    if !(0..failure.len()).any(|e| failure[e] && !sys.observable[e]) {
        return Ok(None);
    }
    let mut size = 0usize;
    let grow = |size: &mut usize, by: usize| {
        *size = size.saturating_add(by);
        if *size > budget { Err(*size) } else { Ok(()) }
    };

    let (nodes, edges, starts) =
        observation_automaton(g, sys, &failure, &mut |by| grow(&mut size, by))?;
    let observation_size = size;

    // 2. Its twin plant (libFAUDES's G_d = G_o || G_o), breadth-first while
    //    it is small; depth-first, stopping at the first counterexample, once
    //    it is not.
    let mut twin = Twin::new(&starts);
    while twin.next < twin.pairs.len() {
        let added = twin.expand(&nodes, &edges);
        grow(&mut size, 1 + added)?;
        if size > breadth_first && twin.next < twin.pairs.len() {
            drop(twin);
            // The search counts from the observation automaton, as the
            // breadth-first exploration it replaces did.
            let mut size = observation_size;
            let lasso = depth_first_lasso(&nodes, &edges, &starts, &mut |by| grow(&mut size, by))?;
            let lasso = lasso.map(|lasso| shorter_stem(&nodes, &edges, &starts, lasso, budget));
            return Ok(lasso.map(|lasso| spell_out(g, sys, &failure, &nodes, &edges, &lasso)));
        }
    }
    Ok(twin
        .lasso(&nodes)
        .map(|lasso| spell_out(g, sys, &failure, &nodes, &edges, &lasso)))
}

/// The size of the verifier (nodes and edges of the observation automaton and
/// of the twin plant) up to which the twin plant is explored whole,
/// breadth-first: the counterexample found then has the
/// shortest stem of all. Past it, a depth-first search stops at the first
/// indeterminate cycle: on products of many components, the whole twin
/// plant is far larger than the way to one of its cycles.
pub const BREADTH_FIRST: usize = 1 << 16;

/// A counterexample as the twin plant shows it: its steps (a pair of
/// observation nodes, the edge of each taken), the loop starting at step
/// `cycle_from` and going back to its first pair.
#[derive(Debug)]
struct Lasso {
    steps: Vec<((usize, usize), usize, usize)>,
    cycle_from: usize,
}

/// A lasso of the twin plant, found depth-first. Every cycle of pairs
/// with different labels (an indeterminate cycle) lies in a strongly connected
/// component of such pairs (a label only goes from "no failure yet" to
/// "failed", and pairs where both runs have failed are not expanded), and a
/// depth-first search meets a back edge in every such component: the first
/// back edge to a pair whose labels differ closes one. None if there is none;
/// `Err` with the size reached once the budget is spent.
fn depth_first_lasso(
    nodes: &[(usize, bool)],
    edges: &[Vec<ObsEdge>],
    starts: &[usize],
    grow: &mut impl FnMut(usize) -> Result<(), usize>,
) -> Result<Option<Lasso>, usize> {
    /// A pair on the search's path: its successors and how many were tried.
    struct Frame {
        pair: (usize, usize),
        next: Vec<((usize, usize), usize, usize)>,
        tried: usize,
    }
    let successors = |(a, b): (usize, usize)| -> Vec<((usize, usize), usize, usize)> {
        if nodes[a].1 && nodes[b].1 {
            return Vec::new();
        }
        (same_event_edges(&edges[a], &edges[b]).into_iter())
            .map(|(ia, jb)| ((edges[a][ia].to, edges[b][jb].to), ia, jb))
            .collect()
    };
    // On the path: its depth; done: `usize::MAX`.
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    let roots = starts
        .iter()
        .flat_map(|&a| starts.iter().map(move |&b| (a, b)));
    for root in roots {
        if seen.contains_key(&root) {
            continue;
        }
        let mut path = vec![Frame {
            pair: root,
            next: successors(root),
            tried: 0,
        }];
        seen.insert(root, 0);
        while let Some(top) = path.last_mut() {
            let Some(&(to, _, _)) = top.next.get(top.tried) else {
                seen.insert(top.pair, usize::MAX);
                path.pop();
                continue;
            };
            top.tried += 1;
            match seen.get(&to) {
                Some(&depth) if depth != usize::MAX => {
                    if nodes[to.0].1 != nodes[to.1].1 {
                        let steps = path.iter().map(|f| {
                            let (_, ia, jb) = f.next[f.tried - 1];
                            (f.pair, ia, jb)
                        });
                        return Ok(Some(Lasso {
                            steps: steps.collect(),
                            cycle_from: depth,
                        }));
                    }
                }
                Some(_) => {}
                None => {
                    let next = successors(to);
                    grow(1 + next.len())?;
                    seen.insert(to, path.len());
                    path.push(Frame {
                        pair: to,
                        next,
                        tried: 0,
                    });
                }
            }
        }
    }
    Ok(None)
}

/// The lasso with the shortest way into its loop: a breadth-first search
/// from the initial pairs to the first pair of the loop met, the loop then
/// turned to start there. The lasso as it was if the search would pass
/// `budget` pairs and edges.
fn shorter_stem(
    nodes: &[(usize, bool)],
    edges: &[Vec<ObsEdge>],
    starts: &[usize],
    lasso: Lasso,
    budget: usize,
) -> Lasso {
    let cycle = &lasso.steps[lasso.cycle_from..];
    let on_loop: HashMap<(usize, usize), usize> = cycle
        .iter()
        .enumerate()
        .map(|(k, step)| (step.0, k))
        .collect();
    let mut twin = Twin::new(starts);
    let mut size = 0usize;
    let mut looked = 0;
    loop {
        while looked < twin.pairs.len() {
            if let Some(&k) = on_loop.get(&twin.pairs[looked]) {
                let mut stem = Vec::new();
                let mut p = looked;
                while let Some((from, e)) = twin.parent[p] {
                    let (_, ia, jb) = twin.edges[from][e];
                    stem.push((twin.pairs[from], ia, jb));
                    p = from;
                }
                stem.reverse();
                let cycle_from = stem.len();
                stem.extend(cycle[k..].iter().chain(&cycle[..k]).copied());
                return Lasso {
                    steps: stem,
                    cycle_from,
                };
            }
            looked += 1;
        }
        if twin.next == twin.pairs.len() || size > budget {
            return lasso;
        }
        size += 1 + twin.expand(nodes, edges);
    }
}

/// The counterexample a lasso of the twin plant shows: both runs, the
/// faulty one first, with their unobservable events, and what they show.
fn spell_out(
    g: &Generator,
    sys: &System,
    failure: &[bool],
    nodes: &[(usize, bool)],
    edges: &[Vec<ObsEdge>],
    lasso: &Lasso,
) -> Counterexample {
    let ((a0, _), _, _) = lasso.steps[lasso.cycle_from];
    let faulty_first = nodes[a0].1;
    let (mut faulty, mut normal, mut observed) = (Vec::new(), Vec::new(), Vec::new());
    for &((a, b), ia, jb) in &lasso.steps {
        let (edge_a, edge_b) = (&edges[a][ia], &edges[b][jb]);
        let ((from_f, ef), (from_n, en)) = if faulty_first {
            ((a, edge_a), (b, edge_b))
        } else {
            ((b, edge_b), (a, edge_a))
        };
        let run = |from: usize, edge: &ObsEdge| run_of(sys, failure, nodes, from, edge);
        faulty.extend(run(from_f, ef).iter().map(|&e| g.events[e].clone()));
        normal.extend(run(from_n, en).iter().map(|&e| g.events[e].clone()));
        observed.push(g.events[ef.event].clone());
    }
    Counterexample {
        faulty,
        normal,
        observed,
        cycle_from: lasso.cycle_from,
    }
}

/// The twin plant explored so far: pairs of observation nodes moving on the
/// same observable event, breadth-first, each with the edges that leave it
/// once expanded. Twin edges remember which observation edges they pair.
struct Twin {
    pairs: Vec<(usize, usize)>,
    pair_of: HashMap<(usize, usize), usize>,
    /// `edges[p]` for the expanded pairs `p < next`: `(to, edge of a, edge of b)`.
    edges: Vec<Vec<(usize, usize, usize)>>,
    /// How each pair was first reached: the pair before and its edge number.
    parent: Vec<Option<(usize, usize)>>,
    next: usize,
}

impl Twin {
    fn new(starts: &[usize]) -> Twin {
        let mut twin = Twin {
            pairs: Vec::new(),
            pair_of: HashMap::new(),
            edges: Vec::new(),
            parent: Vec::new(),
            next: 0,
        };
        for &a in starts {
            for &b in starts {
                twin.pair_of.insert((a, b), twin.pairs.len());
                twin.pairs.push((a, b));
                twin.parent.push(None);
            }
        }
        twin
    }

    /// Expands the next pair; how many edges leave it.
    fn expand(&mut self, nodes: &[(usize, bool)], edges: &[Vec<ObsEdge>]) -> usize {
        let from = self.next;
        let (a, b) = self.pairs[from];
        let mut out = Vec::new();
        // Labels only go from "no failure yet" to "failed": from a pair where
        // both runs have failed, every pair reached has too, and none of them
        // lies on an indeterminate cycle. Left unexplored, they cost nothing;
        // the other pairs keep their breadth-first order.
        if !(nodes[a].1 && nodes[b].1) {
            for (ia, jb) in same_event_edges(&edges[a], &edges[b]) {
                let target = (edges[a][ia].to, edges[b][jb].to);
                let t = match self.pair_of.get(&target) {
                    Some(&t) => t,
                    None => {
                        let t = self.pairs.len();
                        self.pair_of.insert(target, t);
                        self.pairs.push(target);
                        // Breadth-first: the first way in is a shortest one.
                        self.parent.push(Some((from, out.len())));
                        t
                    }
                };
                out.push((t, ia, jb));
            }
        }
        let added = out.len();
        self.edges.push(out);
        self.next += 1;
        added
    }

    /// The lasso of an indeterminate cycle (a cycle of pairs whose labels
    /// differ) of the whole twin plant. Pairs are numbered breadth-first, so
    /// the first such pair found has a shortest stem.
    fn lasso(&self, nodes: &[(usize, bool)]) -> Option<Lasso> {
        let uncertain: Vec<bool> = (self.pairs.iter())
            .map(|&(a, b)| nodes[a].1 != nodes[b].1)
            .collect();
        let component = cyclic_components(&self.edges, &uncertain);
        let entry = (0..self.pairs.len()).find(|&p| component[p].is_some())?;
        let mut stem = Vec::new();
        let mut p = entry;
        while let Some((from, k)) = self.parent[p] {
            stem.push((from, k));
            p = from;
        }
        stem.reverse();
        let cycle = shortest_cycle(&self.edges, &component, entry);
        let steps = stem.iter().chain(cycle.iter()).map(|&(from, k)| {
            let (_, ia, jb) = self.edges[from][k];
            (self.pairs[from], ia, jb)
        });
        Some(Lasso {
            steps: steps.collect(),
            cycle_from: stem.len(),
        })
    }
}

/// The pairs `(i, j)` of an edge of `a` and an edge of `b` on the same event;
/// both lists are sorted by event.
fn same_event_edges(a: &[ObsEdge], b: &[ObsEdge]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let event = a[i].event;
        if event < b[j].event {
            i += 1;
        } else if event > b[j].event {
            j += 1;
        } else {
            let i_end = i + a[i..].iter().take_while(|e| e.event == event).count();
            let j_end = j + b[j..].iter().take_while(|e| e.event == event).count();
            out.extend((i..i_end).flat_map(|ia| (j..j_end).map(move |jb| (ia, jb))));
            i = i_end;
            j = j_end;
        }
    }
    out
}

/// The run behind the observation edge `edge` out of node `from`: the same
/// one `observation_moves` gave when the edge was made.
fn run_of(
    sys: &System,
    failure: &[bool],
    nodes: &[(usize, bool)],
    from: usize,
    edge: &ObsEdge,
) -> Vec<usize> {
    let moves = observation_moves(sys, failure, nodes[from]);
    (moves.into_iter())
        .find(|(event, target, _)| *event == edge.event && *target == nodes[edge.to])
        .map(|(_, _, run)| run)
        .unwrap_or_default()
}

/// How a (state, failed) pair was first reached: the pair before and the event.
type Reached = Option<((usize, bool), usize)>;

/// The observation moves from node `(x, failed)`: every `(event, (y, failed'),
/// run)` where `run` is unobservable events then the observable `event`, leading
/// from `x` to `y`, and `failed'` says whether a failure occurred (before or on the
/// run). One shortest run per move.
fn observation_moves(
    sys: &System,
    failure: &[bool],
    (x, failed): (usize, bool),
) -> Vec<(usize, (usize, bool), Vec<usize>)> {
    // Breadth-first over unobservable transitions, remembering how each
    // (state, failed) was first reached.
    let mut how: HashMap<(usize, bool), Reached> = HashMap::new();
    let mut queue = VecDeque::new();
    how.insert((x, failed), None);
    queue.push_back((x, failed));
    let mut moves = Vec::new();
    let mut seen = HashSet::new();
    while let Some((y, f)) = queue.pop_front() {
        for &(e, z) in &sys.out[y] {
            if sys.observable[e] {
                if seen.insert((e, z, f)) {
                    let mut run = vec![e];
                    let mut at = (y, f);
                    while let Some(Some((prev, ev))) = how.get(&at) {
                        run.push(*ev);
                        at = *prev;
                    }
                    run.reverse();
                    moves.push((e, (z, f), run));
                }
            } else {
                let next = (z, f || failure.get(e).copied().unwrap_or(false));
                if let Entry::Vacant(slot) = how.entry(next) {
                    slot.insert(Some(((y, f), e)));
                    queue.push_back(next);
                }
            }
        }
    }
    moves
}

/// Strongly connected components of the graph restricted to `keep` nodes, for the
/// components that hold a cycle: `component[p]` is the component's id, `None` for
/// nodes on no cycle.
fn cyclic_components(graph: &[Vec<(usize, usize, usize)>], keep: &[bool]) -> Vec<Option<usize>> {
    // Nodes past the end of `graph` have no edges yet (not expanded).
    let mut kept: DiGraph<(), ()> = DiGraph::with_capacity(keep.len(), 0);
    for _ in keep {
        kept.add_node(());
    }
    for (v, out) in graph.iter().enumerate().filter(|&(v, _)| keep[v]) {
        for &(w, _, _) in out.iter().filter(|&&(w, _, _)| keep[w]) {
            kept.add_edge(NodeIndex::new(v), NodeIndex::new(w), ());
        }
    }
    let mut component = vec![None; keep.len()];
    // Kosaraju: petgraph runs it iteratively, where its Tarjan recurses once per
    // node on a path, which a long cycle of pairs would overflow the stack with.
    let cyclic = kosaraju_scc(&kept)
        .into_iter()
        .filter(|members| members.len() > 1 || kept.contains_edge(members[0], members[0]));
    for (id, members) in cyclic.enumerate() {
        for node in members {
            component[node.index()] = Some(id);
        }
    }
    component
}

/// A shortest cycle through `start` inside its component, as (node, edge number)
/// steps.
fn shortest_cycle(
    graph: &[Vec<(usize, usize, usize)>],
    component: &[Option<usize>],
    start: usize,
) -> Vec<(usize, usize)> {
    let target = component[start];
    let mut how: HashMap<usize, (usize, usize)> = HashMap::new();
    let mut queue = VecDeque::from([start]);
    while let Some(v) = queue.pop_front() {
        for (k, &(w, _, _)) in graph[v].iter().enumerate() {
            if component[w] != target {
                continue;
            }
            if w == start {
                let mut steps = vec![(v, k)];
                let mut at = v;
                while at != start {
                    let Some(&(prev, pk)) = how.get(&at) else {
                        break;
                    };
                    steps.push((prev, pk));
                    at = prev;
                }
                steps.reverse();
                return steps;
            }
            if let Entry::Vacant(slot) = how.entry(w) {
                slot.insert((v, k));
                queue.push_back(w);
            }
        }
    }
    // Unreachable: `start` lies on a cycle of its component.
    Vec::new()
}

// ---------------------------------------------------------------------------------
// Rendering

/// The verdict as text for people: overall verdict, failed assumptions, then one
/// paragraph per failure type with its counterexample, loops in `( )*`:
///
/// ```text
/// not diagnosable
/// failure type F1: not diagnosable
///   faulty:   a f b (c)*
///   normal:   a b (c)*
///   observed: a b (c)*
/// ```
pub fn render(result: &EventDiagnosability) -> String {
    let mut out = String::new();
    out.push_str(if result.diagnosable {
        "diagnosable\n"
    } else {
        "not diagnosable\n"
    });
    for violation in &result.assumptions {
        out.push_str("  assumption violated: ");
        out.push_str(&match violation {
            AssumptionViolation::UnknownFailureEvent {
                failure_type,
                event,
            } => format!(
                "failure event {} of type {} is not an event of the generator",
                show(event),
                show(failure_type)
            ),
            AssumptionViolation::ObservableFailureEvent {
                failure_type,
                event,
            } => format!(
                "failure event {} of type {} is observable (failures must be unobservable)",
                show(event),
                show(failure_type)
            ),
            AssumptionViolation::Deadlock { states, more } => format!(
                "the generator is not live: no transition leaves state{} {}{}",
                if states.len() + more == 1 { "" } else { "s" },
                words(states),
                if *more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
            AssumptionViolation::UnobservableCycle { states, events } => {
                let mut cycle = String::new();
                for (x, e) in states.iter().zip(events) {
                    cycle.push_str(&format!("{} -{}-> ", show(x), show(e)));
                }
                if let Some(first) = states.first() {
                    cycle.push_str(&show(first));
                }
                format!("cycle of unobservable events {cycle}")
            }
        });
        out.push('\n');
    }
    for verdict in &result.types {
        out.push_str(&format!(
            "failure type {}: {}\n",
            show(&verdict.failure_type),
            if verdict.diagnosable {
                "diagnosable"
            } else {
                "not diagnosable"
            }
        ));
        if let Some(ce) = &verdict.counterexample {
            let split = |run: &[String]| {
                let mut seen = 0;
                let mut at = 0;
                for (i, event) in run.iter().enumerate() {
                    if seen == ce.cycle_from {
                        break;
                    }
                    if ce.observed.get(seen) == Some(event) {
                        seen += 1;
                        at = i + 1;
                    }
                }
                lasso(&run[..at], &run[at..])
            };
            out.push_str(&format!("  faulty:   {}\n", split(&ce.faulty)));
            out.push_str(&format!("  normal:   {}\n", split(&ce.normal)));
            let from = ce.cycle_from.min(ce.observed.len());
            out.push_str(&format!(
                "  observed: {}\n",
                lasso(&ce.observed[..from], &ce.observed[from..])
            ));
        }
    }
    out
}

/// `stem (loop)*`.
fn lasso(stem: &[String], cycle: &[String]) -> String {
    let cycle = format!("({})*", words(cycle));
    if stem.is_empty() {
        cycle
    } else {
        format!("{} {cycle}", words(stem))
    }
}

fn words(names: &[String]) -> String {
    names.iter().map(|n| show(n)).collect::<Vec<_>>().join(" ")
}

/// A name as written in libFAUDES files: bare when it can be, quoted otherwise.
fn show(name: &str) -> String {
    let bare = !name.is_empty()
        && !name.starts_with('+')
        && !name.contains(|c: char| is_word_end(c) || c == '(' || c == ')' || c == '*');
    if bare {
        name.to_string()
    } else {
        format!("\"{name}\"")
    }
}

#[cfg(test)]
mod tests {
    use super::cyclic_components;

    #[test]
    fn a_long_cycle_is_one_cyclic_component_and_a_dangling_node_none() {
        // Nodes 0 -> 1 -> … -> n-1 -> 0, longer than any recursion a test
        // thread's stack holds, and node n reached from the cycle only.
        let n = 100_000;
        let mut graph: Vec<Vec<(usize, usize, usize)>> =
            (0..n).map(|v| vec![((v + 1) % n, 0, 0)]).collect();
        graph[0].push((n, 0, 0));
        graph.push(Vec::new());
        let component = cyclic_components(&graph, &vec![true; n + 1]);
        assert!(
            component[..n]
                .iter()
                .all(|&c| c.is_some() && c == component[0])
        );
        assert_eq!(component[n], None);
        // Left out of the graph, one node breaks the cycle.
        let mut keep = vec![true; n + 1];
        keep[n / 2] = false;
        assert!(cyclic_components(&graph, &keep).iter().all(Option::is_none));
    }
}
