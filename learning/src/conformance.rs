//! Replaying a log against a learned model: every transition must be one the
//! model knows, within its guard, and every expected sensor event must come by its
//! deadline.
//!
//! This is the acceptance test of a model (a model learned on normal runs must
//! accept other normal runs) and a first, part-local fault detector.

use std::collections::HashMap;

use vocabulary::model::{Model, ModelClock, PartModel};
use vocabulary::{Located, Location, Plant, Time, TimeUnit};

use crate::replay::{Change, PartRoutes};
use logs::LogStream;

/// A deviation from the model.
#[derive(Debug, Clone, PartialEq)]
pub struct Deviation {
    /// When it was detected (for a missed deadline: the deadline itself).
    pub t: Time,
    /// The part.
    pub part: String,
    /// What happened, in one sentence.
    pub message: String,
}

struct PartCheck<'m> {
    model: &'m PartModel,
    /// The part's current state vector.
    state: u64,
    origin: Option<Time>,
    last_edge: Vec<Option<Time>>,
    states: HashMap<u64, usize>,
    trans: HashMap<(u64, u64), usize>,
    /// Deadline of the current state visit, once reported.
    reported: bool,
    entered: Time,
}

impl<'m> PartCheck<'m> {
    fn clock_origin(&self, clock: &str) -> Option<Time> {
        match ModelClock::parse(clock)? {
            ModelClock::Command => self.origin,
            ModelClock::Edge { signal, rising } => {
                let bit = self.model.signals.iter().position(|s| *s == signal)?;
                self.last_edge[2 * bit + usize::from(rising)]
            }
        }
    }

    /// The time by which the current state must have been left, if any: the
    /// latest end of the windows of the transitions it expects.
    fn deadline(&self, unit: TimeUnit) -> Option<Time> {
        let id = *self.states.get(&self.state)?;
        let st = &self.model.states[id];
        if st.stable || st.expected.is_empty() {
            return None;
        }
        st.expected
            .iter()
            .filter_map(|e| {
                let window = self.model.transitions.get(e.transition)?.guard.window(unit);
                self.clock_origin(&e.clock).map(|o| o + window.hi)
            })
            .max()
    }

    fn label(&self, v: u64) -> String {
        self.model
            .signals
            .iter()
            .enumerate()
            .map(|(b, n)| format!("{n}={}", v >> b & 1))
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// Replays `log` against `model` and returns every violation, in time order per part.
pub fn deviations(model: &Model, plant: &Plant, log: LogStream) -> Result<Vec<Deviation>, Located> {
    let unit = model.time_unit;
    let mut parts: Vec<PartCheck> = Vec::new();
    let mut routes = PartRoutes::new(plant.signals.len());
    for pm in &model.parts {
        let ids = pm
            .signals
            .iter()
            .map(|name| {
                plant.signals.id(name).ok_or_else(|| {
                    Located::new(
                        Location::new(&log.path, 0, 0),
                        format!("the model's part '{}' reads '{name}', which plant '{}' does not declare", pm.name, plant.name),
                    )
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        routes.add_part(ids);
        let states = pm
            .states
            .iter()
            .map(|s| {
                (
                    s.values
                        .iter()
                        .enumerate()
                        .fold(0u64, |v, (b, &x)| v | (u64::from(x) << b)),
                    s.id,
                )
            })
            .collect::<HashMap<_, _>>();
        let vec_of = |id: usize| {
            states
                .iter()
                .find(|&(_, &i)| i == id)
                .map(|(&v, _)| v)
                .unwrap_or(0)
        };
        let trans = pm
            .transitions
            .iter()
            .map(|t| ((vec_of(t.from), vec_of(t.to)), t.id))
            .collect();
        parts.push(PartCheck {
            model: pm,
            state: 0,
            origin: None,
            last_edge: vec![None; 2 * pm.signals.len()],
            states,
            trans,
            reported: false,
            entered: log.start,
        });
    }

    let mut states = routes.states(&log.initial);
    for (pc, &state) in parts.iter_mut().zip(&states) {
        pc.state = state;
    }
    let mut out = Vec::new();
    let declared = log.end.clone();
    let (_, last_t) = routes.replay(
        log.batches,
        log.start,
        &mut states,
        |t, changes| step(&mut parts, t, changes, unit, &mut out),
        |_| {},
    )?;
    // Deadlines up to the log's declared end count: nothing changed until then.
    let end = declared.extend(last_t, None);
    for pc in &mut parts {
        missed(pc, end, unit, &mut out);
    }
    out.sort_by_key(|v| v.t);
    Ok(out)
}

/// Reports a missed deadline of the current state if `now` is past it.
fn missed(pc: &mut PartCheck, now: Time, unit: TimeUnit, out: &mut Vec<Deviation>) {
    if pc.reported {
        return;
    }
    let Some(deadline) = pc.deadline(unit) else {
        return;
    };
    if now > deadline {
        pc.reported = true;
        let st = &pc.model.states[pc.states[&pc.state]];
        let expected: Vec<String> = st
            .expected
            .iter()
            .map(|e| {
                let g = &pc.model.transitions[e.transition].guard;
                format!(
                    "{} within [{}, {}] after {}",
                    e.event,
                    g.lo,
                    g.hi,
                    ModelClock::parse(&e.clock).map_or(e.clock.clone(), |c| c.since())
                )
            })
            .collect();
        out.push(Deviation {
            // A state entered after its deadline (clocks that other edges reset)
            // is late from the moment it is entered.
            t: deadline.max(pc.entered),
            part: pc.model.name.clone(),
            message: format!(
                "in state {}: no {}",
                pc.label(pc.state),
                expected.join(", nor ")
            ),
        });
    }
}

fn step(
    parts: &mut [PartCheck],
    t: Time,
    changes: &[Change],
    unit: TimeUnit,
    out: &mut Vec<Deviation>,
) {
    for pc in parts.iter_mut() {
        missed(pc, t, unit, out);
    }
    for &Change {
        part,
        from,
        changed,
    } in changes
    {
        let pc = &mut parts[part];
        let to = from ^ changed;
        match pc.trans.get(&(from, to)).map(|&i| &pc.model.transitions[i]) {
            // Independent edges that happened to fall in one scan: accepted when
            // they split into a sequence of known transitions.
            None if decomposes(&pc.trans, from, changed) => {}
            None => out.push(Deviation {
                t,
                part: pc.model.name.clone(),
                message: format!(
                    "unexpected change from {} to {}",
                    pc.label(from),
                    pc.label(to)
                ),
            }),
            Some(tr) if tr.timed => {
                if let Some(o) = pc.clock_origin(&tr.clock)
                    && !tr.guard.window(unit).admits(t - o)
                {
                    let clock = (t - o) as f64 / unit.nanos() as f64;
                    out.push(Deviation {
                        t,
                        part: pc.model.name.clone(),
                        message: format!(
                            "{} at {clock} after {}, outside its guard [{}, {}]",
                            tr.event,
                            ModelClock::parse(&tr.clock).map_or(tr.clock.clone(), |c| c.since()),
                            tr.guard.lo,
                            tr.guard.hi
                        ),
                    });
                }
            }
            Some(_) => {}
        }
        for (bit, _) in pc.model.signals.iter().enumerate() {
            if changed >> bit & 1 == 1 {
                pc.last_edge[2 * bit + usize::from(to >> bit & 1 == 1)] = Some(t);
            }
        }
        let act_mask = if pc.model.actuators >= 64 {
            u64::MAX
        } else {
            (1u64 << pc.model.actuators) - 1
        };
        if changed & act_mask != 0 {
            pc.origin = Some(t);
        }
        pc.state = to;
        pc.reported = false;
        pc.entered = t;
    }
}

/// Whether the edges `changed` from state `from` split into a sequence of known
/// transitions (groups of edges, in some order). Parts have few signals, so the
/// search over subsets stays small.
fn decomposes(trans: &HashMap<(u64, u64), usize>, from: u64, changed: u64) -> bool {
    if changed.count_ones() < 2 || changed.count_ones() > 8 {
        return false;
    }
    fn search(trans: &HashMap<(u64, u64), usize>, from: u64, rest: u64) -> bool {
        if rest == 0 {
            return true;
        }
        // Enumerate the non-empty subsets of `rest`.
        let mut sub = rest;
        while sub != 0 {
            if trans.contains_key(&(from, from ^ sub)) && search(trans, from ^ sub, rest ^ sub) {
                return true;
            }
            sub = (sub - 1) & rest;
        }
        false
    }
    search(trans, from, changed)
}
