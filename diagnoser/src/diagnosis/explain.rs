//! Verdict reasons in words: what was observed, or what failed to come.

use super::engine::Engine;
use super::part::{Clock, Hypothesis, Move, Readings};
use crate::TimeUnit;

/// Why part `engine` went from state `previous` to `now`: after a scan that
/// changed `scan = (observed before, changed bits)`, or (`None`) because time
/// passed. `readings` are the clocks at that moment.
pub(crate) fn reason(
    engine: &Engine,
    previous: u32,
    now: u32,
    scan: Option<(u32, u32)>,
    readings: &Readings,
    last_command: Option<(u32, u32)>,
    unit: TimeUnit,
) -> String {
    let part = &engine.part;
    let before = engine.state(previous);
    let after = engine.state(now);
    let clock_text = |clock: u8| match part.clocks.get(clock as usize) {
        Some(Clock::Command) => match last_command {
            Some((obs, changed)) => part.edges(obs, changed),
            None => "the last command".to_string(),
        },
        _ => part.clock_name(clock),
    };
    let fmt = |ns: i64| format!("{} {}", unit.format(ns), unit.name());
    let window =
        |lo: i64, hi: i64| format!("[{}, {}] {}", unit.format(lo), unit.format(hi), unit.name());
    // The events model state `state` expects, among those `due`, as
    // `E within [lo, hi] after C`.
    let expectations = |state: Option<usize>, due: &dyn Fn(&Move) -> bool| -> Vec<String> {
        let Some(st) = state else {
            return Vec::new();
        };
        part.expected(st)
            .iter()
            .map(|&k| &part.moves(st)[k])
            .filter(|m| due(m))
            .map(|m| {
                format!(
                    "{} within {} after {}",
                    part.event_name(m.id),
                    window(m.lo, m.hi),
                    clock_text(m.clock)
                )
            })
            .collect()
    };
    // The hypothesis whose loss best explains the change: the normal one first.
    let lost: Vec<Hypothesis> = before
        .hyps
        .iter()
        .filter(|h| !after.hyps.contains(h))
        .copied()
        .collect();
    let normal_lost =
        before.hyps.iter().any(|h| h.mode == 0) && !after.hyps.iter().any(|h| h.mode == 0);
    let subject = lost
        .iter()
        .find(|h| h.mode == 0)
        .or_else(|| lost.first())
        .copied();
    let glitch = subject.filter(|&h| h.mode != 0 && part.glitch_expired(h, readings));
    let mut text = match (scan, glitch) {
        (None, Some(h)) => {
            let mode = &part.modes[h.mode as usize];
            let sensor = mode
                .template
                .as_ref()
                .and_then(|t| t.signal())
                .unwrap_or("?");
            format!(
                "{sensor} kept its value over {}: a stuck sensor, not an unexpected edge",
                fmt(part.glitch_max())
            )
        }
        (None, None) => {
            let missed = expectations(subject.and_then(|h| part.model_state(h.phys)), &|_| true);
            if missed.is_empty() {
                "time passed with no event".to_string()
            } else {
                format!("no {}", missed.join(", nor "))
            }
        }
        (Some((obs, changed)), _) => {
            let edges = part.edges(obs, changed);
            let mut s = match readings.first().copied().flatten() {
                Some(c) if changed & part.actuator_mask() == 0 => {
                    format!("{edges} at {} after {}", fmt(c), clock_text(0))
                }
                _ => edges.clone(),
            };
            if normal_lost {
                // Was it a known transition out of its window, or unknown there?
                let known = part.model_state(obs).and_then(|st| {
                    let motion = part.motion(changed);
                    part.moves(st).iter().find(|m| m.changed == motion)
                });
                let reading = |clock: u8| readings.get(clock as usize).copied().flatten();
                match known {
                    // Out of its window on its own clock: say so on that clock.
                    Some(m)
                        if m.timed && reading(m.clock).is_some_and(|r| r < m.lo || r > m.hi) =>
                    {
                        s = format!(
                            "{edges} at {} after {}, outside its window {} after {}",
                            fmt(reading(m.clock).unwrap_or_default()),
                            clock_text(m.clock),
                            window(m.lo, m.hi),
                            clock_text(m.clock)
                        );
                    }
                    // In its window, into a state whose deadline has passed.
                    Some(_) => {
                        let late = expectations(part.model_state(obs ^ changed), &|m| {
                            reading(m.clock).is_some_and(|r| r > m.hi)
                        });
                        if late.is_empty() {
                            s.push_str(&format!(
                                ", not expected then in state {}",
                                part.describe(obs)
                            ));
                        } else {
                            s.push_str(&format!(
                                ", too late for the state it leads to, which expects {}",
                                late.join(", or ")
                            ));
                        }
                    }
                    None => s.push_str(&format!(", not expected in state {}", part.describe(obs))),
                }
            }
            s
        }
    };
    let labels_before = engine.labels(before.labels);
    let labels_after = engine.labels(after.labels);
    if !labels_before.normal && !labels_after.normal {
        let gone: Vec<&str> = labels_before
            .modes
            .iter()
            .filter(|m| !labels_after.modes.contains(m))
            .map(|&m| part.modes[m as usize].label.as_str())
            .collect();
        if !gone.is_empty() {
            text.push_str(&format!(": rules out {}", gone.join(", ")));
        }
    }
    if !labels_after.normal && labels_after.modes.is_empty() {
        text.push_str("; no fault of the model explains it");
    }
    text
}
