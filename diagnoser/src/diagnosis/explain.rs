//! Verdict reasons in words: what was observed, or what failed to come.

use super::engine::Engine;
use super::part::{Clock, Hypothesis, Move, PartDiagnoser, Readings};
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
    let words = Words {
        part,
        last_command,
        unit,
    };
    let before = engine.state(previous);
    let after = engine.state(now);
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
        (None, Some(h)) => words.stuck_not_glitch(h),
        (None, None) => {
            let missed = words.expectations(subject, &|_| true);
            if missed.is_empty() {
                "time passed with no event".to_string()
            } else {
                format!("no {}", missed.join(", nor "))
            }
        }
        (Some((obs, changed)), _) => words.scan(obs, changed, readings, normal_lost),
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

/// A part's times, windows, clocks and expectations in words.
struct Words<'a> {
    part: &'a PartDiagnoser,
    /// The last command's scan (observed before, changed bits), which the
    /// command clock counts from.
    last_command: Option<(u32, u32)>,
    unit: TimeUnit,
}

impl Words<'_> {
    /// What clock `clock` counts from, e.g. `RE(Y1)` or `FE(C1)`.
    fn clock(&self, clock: u8) -> String {
        match self.part.clocks.get(clock as usize) {
            Some(Clock::Command) => match self.last_command {
                Some((obs, changed)) => self.part.edges(obs, changed),
                None => "the last command".to_string(),
            },
            _ => self.part.clock_name(clock),
        }
    }

    /// A duration, e.g. `120 ms`.
    fn duration(&self, ns: i64) -> String {
        format!("{} {}", self.unit.format(ns), self.unit.name())
    }

    /// A window, e.g. `[80, 120] ms`.
    fn window(&self, lo: i64, hi: i64) -> String {
        format!(
            "[{}, {}] {}",
            self.unit.format(lo),
            self.unit.format(hi),
            self.unit.name()
        )
    }

    /// The events that hypothesis `h`'s model state expects, among those
    /// `due`, as `E within [lo, hi] after C`, with the bounds as `h` reads
    /// them (a slow element's are stretched).
    fn expectations(&self, h: Option<Hypothesis>, due: &dyn Fn(&Move) -> bool) -> Vec<String> {
        let part = self.part;
        let Some((h, st)) = h.and_then(|h| Some((h, part.model_state(h.phys)?))) else {
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
                    self.window(m.lo, part.slow_bound(h, m)),
                    self.clock(m.clock)
                )
            })
            .collect()
    }

    /// A glitch hypothesis lost because its sensor kept the value too long.
    fn stuck_not_glitch(&self, h: Hypothesis) -> String {
        let mode = &self.part.modes[h.mode as usize];
        let sensor = mode
            .template
            .as_ref()
            .and_then(|t| t.signal())
            .unwrap_or("?");
        format!(
            "{sensor} kept its value over {}: a stuck sensor, not an unexpected edge",
            self.duration(self.part.glitch_max())
        )
    }

    /// The scan that changed `changed` from `obs`, and, when it ruled out the
    /// normal hypothesis, why the model did not expect it.
    fn scan(&self, obs: u32, changed: u32, readings: &Readings, normal_lost: bool) -> String {
        let part = self.part;
        let edges = part.edges(obs, changed);
        let s = match readings.first().copied().flatten() {
            Some(c) if changed & part.actuator_mask() == 0 => {
                format!("{edges} at {} after {}", self.duration(c), self.clock(0))
            }
            _ => edges.clone(),
        };
        if normal_lost {
            self.unexpected(s, &edges, obs, changed, readings)
        } else {
            s
        }
    }

    /// `s`, the scan's `edges`, completed with why the normal model rules it
    /// out: a known transition out of its window, or unknown there.
    fn unexpected(
        &self,
        mut s: String,
        edges: &str,
        obs: u32,
        changed: u32,
        readings: &Readings,
    ) -> String {
        let part = self.part;
        let known = part.model_state(obs).and_then(|st| {
            let motion = part.motion(changed);
            part.moves(st).iter().find(|m| m.changed == motion)
        });
        let reading = |clock: u8| readings.get(clock as usize).copied().flatten();
        match known {
            // Out of its window on its own clock: say so on that clock.
            Some(m) if m.timed && reading(m.clock).is_some_and(|r| r < m.lo || r > m.hi) => {
                s = format!(
                    "{edges} at {} after {}, outside its window {} after {}",
                    self.duration(reading(m.clock).unwrap_or_default()),
                    self.clock(m.clock),
                    self.window(m.lo, m.hi),
                    self.clock(m.clock)
                );
            }
            // In its window, into a state whose deadline has passed.
            Some(_) => {
                // As the normal hypothesis reads them: the one ruled out.
                let normal = part.initial(obs ^ changed).first().copied();
                let late =
                    self.expectations(normal, &|m| reading(m.clock).is_some_and(|r| r > m.hi));
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
        s
    }
}
