//! The report's sentences: faults, signals, edges and constraints in words.
//!
//! They are plain text, which the page's templates escape; only [`highlight`]
//! returns markup, built through maud as well.

use diagnoser::fault::FaultTemplate;
use diagnoser::{Plant, Time, TimeFormat};
use maud::{Markup, html};

/// A signal's description from the plant file, or its name.
pub fn description<'a>(plant: &'a Plant, name: &'a str) -> &'a str {
    plant
        .signals
        .id(name)
        .map(|id| plant.signals.get(id).description.as_str())
        .filter(|d| !d.is_empty())
        .unwrap_or(name)
}

/// The part whose element `element` is, for "the turntable (P)".
fn element_words(plant: &Plant, element: &str) -> String {
    plant
        .parts
        .iter()
        .find(|p| p.element.as_deref() == Some(element))
        .map_or_else(
            || format!("element {element}"),
            |p| format!("the {} ({element})", p.name.replace('_', " ")),
        )
}

/// What a fault label means, in words: e.g. "C4 stuck at 1: C4 (turntable at
/// loading position) stays on when the plant leaves that state".
pub fn fault_meaning(plant: &Plant, label: &str) -> String {
    let Some(fault) = plant.fault(label) else {
        return match label {
            "N" => "no fault".to_string(),
            diagnoser::diagnosis::UNKNOWN_LABEL => {
                "no mode of the learned model explains what was observed".to_string()
            }
            _ => label.to_string(),
        };
    };
    let d = |s: &str| description(plant, s).to_string();
    match &fault.template {
        FaultTemplate::Stuck0(s) => format!(
            "{s} stuck at 0: {s} ({}) stays off even when the plant gets there",
            d(s)
        ),
        FaultTemplate::Stuck1(s) => format!(
            "{s} stuck at 1: {s} ({}) stays on even when the plant leaves",
            d(s)
        ),
        FaultTemplate::UnexpectedRise(s) => format!(
            "unexpected rise of {s}: {s} ({}) comes on with nothing in the plant to explain it",
            d(s)
        ),
        FaultTemplate::UnexpectedFall(s) => format!(
            "unexpected fall of {s}: {s} ({}) goes off with nothing in the plant to explain it",
            d(s)
        ),
        FaultTemplate::ActuatorStuck0(a) => format!(
            "actuator {a} stuck off: {a} ({}) does nothing whatever the order",
            d(a)
        ),
        FaultTemplate::ActuatorStuck1(a) => format!(
            "actuator {a} stuck on: {a} ({}) keeps acting whatever the order",
            d(a)
        ),
        FaultTemplate::BlockedAt { element, at } => format!(
            "{} blocked at {at}: it cannot leave the position where {at} ({}) is on",
            element_words(plant, element),
            d(at)
        ),
        FaultTemplate::BlockedBetween { element, from, to } => format!(
            "{} blocked between {from} and {to}: it left the position of {from} ({}) and never reached that of {to} ({})",
            element_words(plant, element),
            d(from),
            d(to)
        ),
        FaultTemplate::Slow(x) if plant.parts.iter().any(|p| p.element.as_deref() == Some(x)) => {
            format!(
                "{x} slow: {} still moves, but its motions take longer than learned (a degraded element)",
                element_words(plant, x)
            )
        }
        FaultTemplate::Slow(a) => format!(
            "{a} slow: what {a} ({}) drives still moves, but takes longer than learned",
            d(a)
        ),
    }
}

/// `RE(A4)` or `FE(C4)` for an edge of `signal` to `value`.
pub fn edge(name: &str, value: bool) -> String {
    diagnoser::model::edge_name(name, value)
}

/// A time as the log writes it, with its unit for numeric logs.
pub fn absolute(time: TimeFormat, t: Time) -> String {
    match time {
        TimeFormat::Numeric(unit) => format!("{} {}", time.format(t), unit.name()),
        TimeFormat::Rfc3339 => time.format(t),
    }
}

/// An offset from the log's start, `+1:02:03.450` (hours only when needed).
pub fn offset(d: Time) -> String {
    let sign = if d < 0 { "-" } else { "+" };
    let d = d.unsigned_abs();
    let ms = (d + 500_000) / 1_000_000;
    let (h, m, s, milli) = (ms / 3_600_000, ms / 60_000 % 60, ms / 1000 % 60, ms % 1000);
    if h > 0 {
        format!("{sign}{h}:{m:02}:{s:02}.{milli:03}")
    } else {
        format!("{sign}{m}:{s:02}.{milli:03}")
    }
}

/// A duration in the most readable unit: `850 ms`, `2.82 s`, `3 min 5 s`, `2 h 10 min`.
pub fn duration(d: Time) -> String {
    let ms = d as f64 / 1e6;
    if ms < 1.0 {
        format!("{} µs", (d as f64 / 1e3).round())
    } else if ms < 1000.0 {
        format!("{} ms", ms.round())
    } else if ms < 60_000.0 {
        format!("{:.2} s", ms / 1000.0)
    } else if ms < 3_600_000.0 {
        let s = (ms / 1000.0).round() as u64;
        format!("{} min {} s", s / 60, s % 60)
    } else {
        let m = (ms / 60_000.0).round() as u64;
        format!("{} h {} min", m / 60, m % 60)
    }
}

/// `expr` as HTML, each occurrence of a true literal in a `<mark class="literal">`.
///
/// A literal matches whole tokens only: `C4` does not match inside `C40`, nor
/// the `C4` of `!C4`.
pub fn highlight(expr: &str, literals: &[String]) -> Markup {
    let mut lits: Vec<&str> = literals.iter().map(String::as_str).collect();
    lits.sort_by_key(|l| std::cmp::Reverse(l.len()));
    let bytes = expr.as_bytes();
    let word = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    // The text before each literal found, and the literal.
    let mut pieces: Vec<(&str, &str)> = Vec::new();
    let mut i = 0;
    let mut plain = 0;
    while i < expr.len() {
        let found = lits.iter().find(|l| {
            expr[i..].starts_with(**l)
                && (i == 0
                    || !(word(bytes[i - 1]) || (!l.starts_with('!') && bytes[i - 1] == b'!')))
                && bytes
                    .get(i + l.len())
                    .is_none_or(|&b| !(word(b) || b == b'('))
        });
        match found {
            Some(l) => {
                pieces.push((&expr[plain..i], l));
                i += l.len();
                plain = i;
            }
            None => {
                i += expr[i..].chars().next().map_or(1, char::len_utf8);
            }
        }
    }
    html! {
        @for (text, literal) in pieces {
            (text) mark class="literal" { (literal) }
        }
        (&expr[plain..])
    }
}

/// What the filter does about a true literal of a violated constraint, if it is
/// an order: `A3` → "forces A3 off".
pub fn filter_action(plant: &Plant, literal: &str) -> Option<String> {
    let (negated, body) = match literal.strip_prefix('!') {
        Some(b) => (true, b),
        None => (false, literal),
    };
    let (name, kind) =
        if let Some(inner) = body.strip_prefix("RE(").and_then(|b| b.strip_suffix(')')) {
            (inner, "rise")
        } else if let Some(inner) = body.strip_prefix("FE(").and_then(|b| b.strip_suffix(')')) {
            (inner, "fall")
        } else {
            (body, "level")
        };
    let id = plant.signals.id(name)?;
    if plant.signals.get(id).kind != diagnoser::SignalKind::Actuator {
        return None;
    }
    let d = description(plant, name);
    Some(match (kind, negated) {
        ("level", false) => format!("forces {name} off ({d})"),
        ("level", true) => format!("holds {name} on ({d})"),
        ("rise", false) => format!("cancels the rise of {name}: it stays off ({d})"),
        ("fall", false) => format!("cancels the fall of {name}: it stays on ({d})"),
        _ => format!("acts on {name} ({d})"),
    })
}

/// A literal in words: `!C5` → "C5 = 0 (turntable at unloading position)".
pub fn literal_words(plant: &Plant, literal: &str) -> String {
    let (negated, body) = match literal.strip_prefix('!') {
        Some(b) => (true, b),
        None => (false, literal),
    };
    for (prefix, what) in [("RE(", "rises"), ("FE(", "falls"), ("prev(", "was")] {
        if let Some(inner) = body.strip_prefix(prefix).and_then(|b| b.strip_suffix(')')) {
            let d = description(plant, inner);
            return match (what, negated) {
                ("was", n) => format!("{inner} was {} in the scan before ({d})", u8::from(!n)),
                (w, false) => format!("{inner} {w} ({d})"),
                (w, true) => format!("{inner} does not {} ({d})", w.trim_end_matches('s')),
            };
        }
    }
    if plant.signals.id(body).is_some() {
        format!(
            "{body} = {} ({})",
            u8::from(!negated),
            description(plant, body)
        )
    } else {
        // Observers, flags and estimate intervals.
        format!("{body} = {}", u8::from(!negated))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn highlight_marks_whole_literals_only() {
        let lits = vec!["!C4".to_string(), "A4".to_string(), "C5".to_string()];
        assert_eq!(
            highlight("!C4 & A4 & C50 & !C5", &lits).into_string(),
            "<mark class=\"literal\">!C4</mark> &amp; <mark class=\"literal\">A4</mark> &amp; C50 &amp; !C5"
        );
        let lits = vec!["RE(A4)".to_string()];
        assert_eq!(
            highlight("!C4 & RE(A4)", &lits).into_string(),
            "!C4 &amp; <mark class=\"literal\">RE(A4)</mark>"
        );
    }

    /// `s` as the page shows text, escaped by maud.
    fn text(s: &str) -> String {
        html! { (s) }.into_string()
    }

    #[test]
    fn offsets_and_durations_read_naturally() {
        assert_eq!(offset(605_690 * 1_000_000), "+10:05.690");
        assert_eq!(offset(3_723_450 * 1_000_000), "+1:02:03.450");
        assert_eq!(duration(2_820 * 1_000_000), "2.82 s");
        assert_eq!(duration(120 * 1_000_000), "120 ms");
        assert_eq!(duration(185 * 1_000_000_000), "3 min 5 s");
    }

    proptest::proptest! {
        /// Highlighting only adds marks: without them, the text is the escaped
        /// expression, whatever the expression and the literals.
        #[test]
        fn highlight_only_adds_marks(
            expr in "[!&|() A-Z0-9_<>\"é]{0,40}",
            literals in proptest::collection::vec("!?[A-Z]{1,2}[0-9]?", 0..4),
        ) {
            let out = highlight(&expr, &literals).into_string();
            let plain = out
                .replace("<mark class=\"literal\">", "")
                .replace("</mark>", "");
            proptest::prop_assert_eq!(plain, text(&expr));
            // A mark holds a literal.
            for piece in out.split("<mark class=\"literal\">").skip(1) {
                let inner = piece.split("</mark>").next().unwrap_or("");
                proptest::prop_assert!(literals.iter().any(|l| text(l) == inner));
            }
        }
    }
}
