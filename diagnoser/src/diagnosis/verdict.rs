//! A part's verdict as SPEC §3 writes it: normal, certain or ambiguous, with
//! its labels, flags, suspects and reason, one JSON line per change.

use serde::{Deserialize, Serialize};

use crate::{Time, TimeFormat};

/// A part's verdict (SPEC §3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VerdictKind {
    /// Certainly no fault: the labels are `["N"]`.
    Normal,
    /// Certainly one fault: exactly one label, not `N`.
    Certain,
    /// Several candidate labels.
    Ambiguous,
}

impl VerdictKind {
    /// The verdict as SPEC §3 writes it: `normal`, `certain` or `ambiguous`.
    pub fn name(self) -> &'static str {
        match self {
            VerdictKind::Normal => "normal",
            VerdictKind::Certain => "certain",
            VerdictKind::Ambiguous => "ambiguous",
        }
    }
}

/// The label given when no mode of the model explains what was observed.
pub const UNKNOWN_LABEL: &str = "unknown";

/// A change of one part's verdict: one JSON line of `gardefou diagnose`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// When it changed, in nanoseconds (written in the log's time form).
    #[serde(skip)]
    pub t: Time,
    /// The part.
    pub part: String,
    /// Normal, certain or ambiguous.
    pub verdict: VerdictKind,
    /// `["N"]` when normal; otherwise the candidate fault labels.
    pub labels: Vec<String>,
    /// The `def_<partition>` flags raised so far (they are never lowered).
    pub flags: Vec<String>,
    /// Partitions of the candidate labels, when not normal.
    pub suspects: Vec<String>,
    /// What was observed, in words.
    pub reason: String,
}

impl Verdict {
    /// The verdict as a JSON line of SPEC §3, its time in the log's
    /// representation, naming the log it came from when there are several.
    pub fn json_line(&self, time: TimeFormat, log: Option<&str>) -> String {
        let t = match time {
            TimeFormat::Numeric(_) => time.format(self.t),
            TimeFormat::Rfc3339 => serde_json::Value::String(time.format(self.t)).to_string(),
        };
        let body = serde_json::to_string(self).unwrap_or_else(|_| "{}".to_string());
        let log = log
            .map(|l| format!("\"log\":{},", serde_json::Value::String(l.to_string())))
            .unwrap_or_default();
        format!(
            "{{\"t\":{t},{log}{}",
            body.strip_prefix('{').unwrap_or(&body)
        )
    }
}
