//! Graphviz export of part models: one `digraph` per part.

use std::fmt::Write;

use vocabulary::model::{Model, ModelClock, PartModel};

/// The DOT text of one part's model: states as nodes (stable states, where the
/// part waits for a command, drawn double), transitions as edges labelled with
/// their event, guard and clock.
pub fn part_to_dot(model: &Model, part: &PartModel) -> String {
    let unit = model.time_unit.name();
    let mut out = String::new();
    let _ = writeln!(out, "digraph \"{}\" {{", escape(&part.name));
    let _ = writeln!(
        out,
        "  rankdir=LR;\n  node [shape=box, style=rounded, fontname=\"Helvetica\"];"
    );
    let _ = writeln!(
        out,
        "  label=\"{} — {}\";",
        escape(&model.plant),
        escape(&part.name)
    );
    for s in &part.states {
        let label = part
            .signals
            .iter()
            .zip(&s.values)
            .map(|(n, &v)| format!("{n}={}", u8::from(v)))
            .collect::<Vec<_>>()
            .join(" ");
        let shape = if s.stable { ", peripheries=2" } else { "" };
        let _ = writeln!(
            out,
            "  s{} [label=\"{}\\n({} visits)\"{shape}];",
            s.id,
            escape(&label),
            s.visits
        );
    }
    for t in &part.transitions {
        let guard = if t.command {
            String::new()
        } else if t.timed {
            let clock = if ModelClock::parse(&t.clock) == Some(ModelClock::Command) {
                String::new()
            } else {
                format!(" after {}", t.clock)
            };
            format!("\\n[{}, {}] {unit}{clock}", t.guard.lo, t.guard.hi)
        } else {
            "\\n(untimed)".to_string()
        };
        let style = if t.command { ", style=bold" } else { "" };
        let _ = writeln!(
            out,
            "  s{} -> s{} [label=\"{}{guard}\\n×{}\"{style}];",
            t.from,
            t.to,
            escape(&t.event),
            t.count
        );
    }
    out.push_str("}\n");
    out
}

fn escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}
