//! Running every part's diagnoser over a stream of events.

use serde::Serialize;

use super::engine::Engine;
use super::fusion::Coordinator;
use super::part::PartDiagnoser;
use super::part_run::PartRun;
use super::verdict::{Verdict, VerdictKind};
use crate::model::Model;
use crate::{Event, Plant, Time};

/// Settings of the diagnosers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiagnoserOptions {
    /// Longest an unexpected edge (seed 002's unexpected rise or fall) shows
    /// before the sensor reads its real value again, in nanoseconds. Longer, it
    /// is a stuck sensor.
    pub glitch_max: Time,
    /// The events come from polls of a running PLC, not from its own log: one
    /// observed scan may hold two of the PLC's scans (a poll late by a scan,
    /// a PLC catching up), an order and the sensor's answer to it in the
    /// next scan seen together. A part's scan that one step does not explain
    /// as normal is then also tried as two steps at the same time, the orders
    /// first or the sensors first.
    pub polled: bool,
    /// The orders pass a safety filter coupled to the flags, which may hold
    /// the control's reaction to a sensor edge back (the union reading of a
    /// suspected sensor): a reaction the model learned in the edge's scan
    /// may then come later, and the edge alone is judged on its own timing
    /// ([`PartDiagnoser::with_held_reactions`]).
    pub held_reactions: bool,
}

impl Default for DiagnoserOptions {
    fn default() -> Self {
        DiagnoserOptions {
            glitch_max: 100 * crate::MS,
            polled: false,
            held_reactions: false,
        }
    }
}

/// What a part's diagnoser concluded, at the end of a replay.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PartSummary {
    /// The part.
    pub part: String,
    /// Its last verdict.
    pub verdict: VerdictKind,
    /// Its last labels.
    pub labels: Vec<String>,
    /// First time its verdict left normal, in nanoseconds.
    #[serde(skip)]
    pub detected: Option<Time>,
    /// Flags raised.
    pub flags: Vec<String>,
    /// Verdict changes.
    pub changes: u64,
}

/// Every part's diagnoser, fed with a plant's events.
///
/// Events go in with [`PlantDiagnoser::push`], in time order; events with the
/// same time are one PLC scan. Verdict changes come out through the callback,
/// including those that time alone causes (a deadline passing) — at the
/// deadline, as soon as a later event or [`PlantDiagnoser::advance_to`] shows
/// the time has come.
#[derive(Debug, Clone)]
pub struct PlantDiagnoser {
    parts: Vec<PartRun>,
    /// Per plant signal, the parts that read it and at which bit.
    routes: Routes,
    pending: Vec<(u16, u32)>,
    scan: Option<Time>,
    /// Time of the last scan or of the start: deadlines before it have fired.
    now: Time,
    earliest: Option<Time>,
    coordinator: Coordinator,
}

impl PlantDiagnoser {
    /// Builds the diagnosers of every part of `plant` that `model` has learned.
    pub fn new(plant: &Plant, model: &Model, options: &DiagnoserOptions) -> Result<Self, String> {
        model.fits(plant)?;
        let mut parts = Vec::new();
        for part in &plant.parts {
            let Some(pm) = model.parts.iter().find(|p| p.name == part.name) else {
                return Err(format!("the model has no part '{}'", part.name));
            };
            let built = PartDiagnoser::build(plant, part, pm, model.time_unit, options.glitch_max)?;
            let engine = Engine::new(if options.held_reactions {
                built.with_held_reactions()
            } else {
                built
            });
            parts.push(PartRun::new(engine, model.time_unit, options.polled));
        }
        let routes = routes(plant, &parts);
        let coordinator = Coordinator::new(
            plant,
            parts
                .iter()
                .map(|r| {
                    let part = &r.engine.part;
                    let labels = part.modes[1..].iter().map(|m| m.label.clone()).collect();
                    (part.name.clone(), labels)
                })
                .collect(),
        );
        Ok(PlantDiagnoser {
            coordinator,
            parts,
            routes,
            pending: Vec::new(),
            scan: None,
            now: Time::MIN,
            earliest: None,
        })
    }

    /// The parts' runs, the routes of the signals to them, and the
    /// coordinator.
    pub(crate) fn into_parts(self) -> (Vec<PartRun>, Routes, Coordinator) {
        (self.parts, self.routes, self.coordinator)
    }

    /// The parts' engines, in plant order.
    pub fn engines(&self) -> impl ExactSizeIterator<Item = &Engine> {
        self.parts.iter().map(|r| &r.engine)
    }

    /// Starts a replay at `t0` (the time of the first record) with every
    /// signal's initial value. Clocks are unknown until their first edge.
    pub fn start(&mut self, t0: Time, initial: &[bool]) {
        self.pending.clear();
        self.scan = None;
        self.earliest = None;
        self.coordinator.reset();
        for r in &mut self.parts {
            r.start(initial);
        }
        self.now = t0;
    }

    /// Feeds one event. Verdict changes it completes go to `out`.
    #[inline]
    pub fn push(&mut self, e: Event, out: &mut impl FnMut(Verdict)) {
        if self.scan != Some(e.t) {
            if let Some(t) = self.scan {
                self.flush(t, out);
            }
            self.scan = Some(e.t);
        }
        let Some(routes) = self.routes.get(e.signal.index()) else {
            return;
        };
        for &(part, bit) in routes {
            let mask = 1u32 << bit;
            let i = match self.pending.iter().position(|p| p.0 == part) {
                Some(i) => i,
                None => {
                    self.pending.push((part, 0));
                    self.pending.len() - 1
                }
            };
            let now = (self.parts[part as usize].obs() ^ self.pending[i].1) & mask != 0;
            if now != e.value {
                self.pending[i].1 ^= mask;
            }
        }
    }

    /// Completes the current scan and gives every verdict change due up to `t`
    /// (deadlines that have passed with no event).
    pub fn advance_to(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        if let Some(s) = self.scan.take() {
            self.flush(s, out);
        }
        if t > self.now {
            self.fire_timers(t, out);
            self.now = t;
        }
    }

    /// The earliest pending deadline of any part, if any: when a live monitor
    /// must call [`Self::advance_to`] even if no event comes.
    pub fn next_deadline(&self) -> Option<Time> {
        self.earliest
    }

    /// The time the diagnosers have reached: the last scan, or the last
    /// [`Self::advance_to`].
    pub fn now(&self) -> Time {
        self.now
    }

    /// Ends a replay at `end` (the time of the log's last record) and summarises
    /// each part.
    pub fn finish(&mut self, end: Time, out: &mut impl FnMut(Verdict)) -> Vec<PartSummary> {
        self.advance_to(end, out);
        self.parts.iter().map(PartRun::summary).collect()
    }

    /// The coordinator's plant view of the parts' latest verdicts.
    pub fn plant_view(&mut self, t: Time) -> Verdict {
        self.coordinator.view(t)
    }

    /// The plant view at `t` as a summary row after the parts' `summaries`
    /// (from [`Self::finish`]): detected when the first part was.
    pub fn plant_summary(&mut self, t: Time, summaries: &[PartSummary]) -> PartSummary {
        plant_summary(&mut self.coordinator, t, summaries)
    }

    fn fire_timers(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        while let Some(at) = self.earliest {
            if at > t {
                return;
            }
            // Fire the earliest timer of all parts, then look again.
            let mut first: Option<(usize, Time)> = None;
            for (p, run) in self.parts.iter().enumerate() {
                if let Some(x) = run.next_timer()
                    && first.is_none_or(|(_, f)| x < f)
                {
                    first = Some((p, x));
                }
            }
            match first {
                Some((p, x)) if x <= t => {
                    let verdict = self.parts[p].fire(x);
                    self.earliest = earliest(&self.parts);
                    self.emit(p, verdict, out);
                }
                Some((_, x)) => {
                    self.earliest = Some(x);
                    return;
                }
                None => {
                    self.earliest = None;
                    return;
                }
            }
        }
    }

    fn flush(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        if self.earliest.is_some_and(|x| x <= t) {
            self.fire_timers(t, out);
        }
        self.now = self.now.max(t);
        let mut pending = std::mem::take(&mut self.pending);
        for &(part, changed) in &pending {
            if changed == 0 {
                continue;
            }
            let p = part as usize;
            // Timers up to `t` have fired: the state is already up to date.
            let verdict = self.parts[p].scan(t, changed);
            if verdict.is_some() {
                // An unknown part starts again, with other deadlines.
                self.earliest = earliest(&self.parts);
            } else if let Some(x) = self.parts[p].next_timer()
                && self.earliest.is_none_or(|e| x < e)
            {
                self.earliest = Some(x);
            }
            self.emit(p, verdict, out);
        }
        pending.clear();
        self.pending = pending;
    }

    /// Gives part `p`'s verdict, if any, then the plant view it changes.
    fn emit(&mut self, p: usize, verdict: Option<Verdict>, out: &mut impl FnMut(Verdict)) {
        if let Some(v) = verdict {
            let view = self.coordinator.update(p, &v);
            out(v);
            if let Some(view) = view {
                out(view);
            }
        }
    }
}

/// The plant view at `t` as a summary row after the parts' `summaries`:
/// detected when the first part was.
pub(crate) fn plant_summary(
    coordinator: &mut Coordinator,
    t: Time,
    summaries: &[PartSummary],
) -> PartSummary {
    let view = coordinator.view(t);
    PartSummary {
        part: view.part,
        verdict: view.verdict,
        labels: view.labels,
        detected: summaries.iter().filter_map(|p| p.detected).min(),
        flags: view.flags,
        changes: 0,
    }
}

/// Per plant signal, the parts that read it and at which bit, parts in plant
/// order.
pub(crate) type Routes = Vec<Vec<(u16, u8)>>;

/// The [`Routes`] of `plant`'s signals to `parts`.
pub(crate) fn routes(plant: &Plant, parts: &[PartRun]) -> Routes {
    let mut routes = vec![Vec::new(); plant.signals.len()];
    for (p, r) in parts.iter().enumerate() {
        for (bit, s) in r.engine.part.signals.iter().enumerate() {
            if let Some(route) = routes.get_mut(s.index()) {
                route.push((p as u16, bit as u8));
            }
        }
    }
    routes
}

fn earliest(parts: &[PartRun]) -> Option<Time> {
    parts.iter().filter_map(PartRun::next_timer).min()
}
