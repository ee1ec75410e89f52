//! What a `model.json` must mean, beyond its schema: checked when it is read,
//! so that an edited or damaged model is refused with the place and the
//! reason, instead of changing the verdicts.
//!
//! Per part: signals named once, actuators among them; states numbered in
//! order, each of the part's width, no two alike; transitions numbered in
//! order, between existing states, named by the edges that tell their states
//! apart, on a clock of the part, with a guard `0 ≤ lo ≤ hi`; each expected
//! event one of the state's own transitions; clock intervals that partition
//! `[0, ∞)` in order, and estimates made of them.

use std::collections::HashSet;

use super::{
    CommandEstimate, Model, ModelClock, PartModel, StateModel, TransitionModel, edge_name,
};

/// Why a model is not valid: where in it, and what.
type Invalid = String;

/// Checks `model`; the error names the part and the element.
pub(super) fn validate(model: &Model) -> Result<(), Invalid> {
    if !(model.scan_period.is_finite() && model.scan_period > 0.0) {
        return Err(format!(
            "scan_period {} is not a positive time",
            model.scan_period
        ));
    }
    let mut names = HashSet::new();
    for part in &model.parts {
        if !names.insert(part.name.as_str()) {
            return Err(format!("part '{}' is modelled twice", part.name));
        }
        validate_part(part).map_err(|why| format!("part '{}': {why}", part.name))?;
    }
    Ok(())
}

fn validate_part(part: &PartModel) -> Result<(), Invalid> {
    let mut seen = HashSet::new();
    if let Some(twice) = part.signals.iter().find(|s| !seen.insert(s.as_str())) {
        return Err(format!("signal '{twice}' is listed twice"));
    }
    if part.actuators > part.signals.len() {
        return Err(format!(
            "{} actuators, more than its {} signals",
            part.actuators,
            part.signals.len()
        ));
    }
    if let Some(input) = part.inputs.iter().find(|i| !seen.contains(i.as_str())) {
        return Err(format!("input '{input}' is not one of its signals"));
    }
    validate_states(part)?;
    for (k, t) in part.transitions.iter().enumerate() {
        validate_transition(part, k, t).map_err(|why| format!("transition {k}: {why}"))?;
    }
    for (i, s) in part.states.iter().enumerate() {
        validate_expected(part, s).map_err(|why| format!("state {i}: {why}"))?;
    }
    validate_estimates(part)
}

fn validate_states(part: &PartModel) -> Result<(), Invalid> {
    let mut seen = HashSet::new();
    for (i, s) in part.states.iter().enumerate() {
        if s.id != i {
            return Err(format!(
                "state {i} has id {}: states are numbered in order",
                s.id
            ));
        }
        if s.values.len() != part.signals.len() {
            return Err(format!(
                "state {i} has {} values for {} signals",
                s.values.len(),
                part.signals.len()
            ));
        }
        if !seen.insert(&s.values) {
            return Err(format!("state {i} has the values of an earlier state"));
        }
    }
    Ok(())
}

fn validate_transition(part: &PartModel, k: usize, t: &TransitionModel) -> Result<(), Invalid> {
    if t.id != k {
        return Err(format!(
            "has id {}: transitions are numbered in order",
            t.id
        ));
    }
    let state = |s: usize| {
        part.states
            .get(s)
            .ok_or_else(|| format!("joins state {s}, which the part does not have"))
    };
    let (from, to) = (state(t.from)?, state(t.to)?);
    let edges: Vec<String> = (part.signals.iter().zip(from.values.iter().zip(&to.values)))
        .filter(|(_, (a, b))| a != b)
        .map(|(signal, (_, &rising))| edge_name(signal, rising))
        .collect();
    let named: Vec<&str> = t.event.split_whitespace().collect();
    if edges.is_empty()
        || named.len() != edges.len()
        || !edges.iter().all(|e| named.contains(&e.as_str()))
    {
        return Err(format!(
            "event '{}' is not the edges from state {} to state {} ({})",
            t.event,
            t.from,
            t.to,
            edges.join(" ")
        ));
    }
    validate_clock(part, &t.clock)?;
    let g = &t.guard;
    if !(g.lo.is_finite() && g.hi.is_finite()) || g.lo < 0.0 {
        return Err(format!(
            "guard [{}, {}] is not made of times from 0",
            g.lo, g.hi
        ));
    }
    if g.lo > g.hi {
        return Err(format!("guard [{}, {}] is empty", g.lo, g.hi));
    }
    Ok(())
}

fn validate_clock(part: &PartModel, clock: &str) -> Result<(), Invalid> {
    match ModelClock::parse(clock) {
        Some(ModelClock::Command) => Ok(()),
        Some(ModelClock::Edge { signal, .. }) if part.signals.contains(&signal) => Ok(()),
        _ => Err(format!(
            "clock '{clock}' is neither 'command' nor an edge of the part's signals"
        )),
    }
}

fn validate_expected(part: &PartModel, s: &StateModel) -> Result<(), Invalid> {
    for e in &s.expected {
        let Some(t) = part.transitions.get(e.transition) else {
            return Err(format!(
                "expects transition {}, which the part does not have",
                e.transition
            ));
        };
        if t.from != s.id || t.event != e.event {
            return Err(format!(
                "expects transition {} ({}), which does not leave it",
                e.transition, e.event
            ));
        }
        validate_clock(part, &e.clock)?;
    }
    Ok(())
}

fn validate_estimates(part: &PartModel) -> Result<(), Invalid> {
    let mut names = HashSet::new();
    for estimate in &part.estimates {
        validate_partition(estimate)
            .map_err(|why| format!("estimate after {}: {why}", estimate.actuators))?;
        names.extend(estimate.intervals.iter().map(|i| i.name.as_str()));
        for schedule in &estimate.sensors {
            let known = part.signals.contains(&schedule.sensor);
            let width = schedule.values.len() == estimate.intervals.len();
            let values =
                (schedule.values.iter()).all(|v| matches!(v.as_str(), "0" | "1" | "uncertain"));
            if !(known && width && values) {
                return Err(format!(
                    "estimate after {}: sensor '{}' needs one value (0, 1 or uncertain) per interval",
                    estimate.actuators, schedule.sensor
                ));
            }
        }
    }
    for e in &part.sensor_estimates {
        let intervals = e.intervals();
        let unknown = (intervals.iter().copied())
            .chain(e.uncertain.iter().map(String::as_str))
            .find(|i| !names.contains(i));
        if let Some(name) = unknown {
            return Err(format!(
                "estimate of '{}' uses interval '{name}', which no estimate defines",
                e.sensor
            ));
        }
        if !part.signals.contains(&e.sensor) {
            return Err(format!(
                "estimate of '{}', which is not one of its signals",
                e.sensor
            ));
        }
    }
    Ok(())
}

/// The intervals of one estimate partition `[0, ∞)`: from 0, each starting
/// where the last ended, each `from < to`, only the last unbounded.
fn validate_partition(estimate: &CommandEstimate) -> Result<(), Invalid> {
    let mut start = 0.0;
    let last = estimate.intervals.len().saturating_sub(1);
    for (k, i) in estimate.intervals.iter().enumerate() {
        let bad = |why: &str| {
            Err(format!(
                "interval {} [{}, {:?}[ {why}",
                i.name, i.from, i.to
            ))
        };
        if i.from != start {
            return bad(&format!(
                "does not start at {start}, where the one before it ends"
            ));
        }
        match i.to {
            Some(to) if !(to.is_finite() && to > i.from) => return bad("is empty"),
            Some(to) if k < last => start = to,
            Some(_) => return bad("is the last, and bounded: the intervals must cover every time"),
            None if k < last => return bad("is unbounded, and not the last"),
            None => {}
        }
    }
    Ok(())
}
