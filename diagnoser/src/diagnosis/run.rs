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
    pub(super) parts: Vec<PartRun>,
    /// Per plant signal, the parts that read it and at which bit.
    pub(super) routes: Routes,
    /// Per part, the bits the scan being read changed, with
    /// [`PlantDiagnoser::OPEN`] once the scan has touched the part.
    pub(super) open: Vec<u32>,
    /// Per part, the observed vector before the scan being read.
    pub(super) obs: Vec<u32>,
    /// The parts the scan being read touched, in the order of their first
    /// events.
    pub(super) touched: Vec<u16>,
    /// Per part, its next deadline ([`Time::MAX`]: none).
    pub(super) timers: Vec<Time>,
    pub(super) scan: Option<Time>,
    /// Time of the last scan or of the start: deadlines before it have fired.
    pub(super) now: Time,
    /// No deadline comes before it: the earliest, or earlier.
    pub(super) earliest: Option<Time>,
    pub(super) coordinator: Coordinator,
}

impl PlantDiagnoser {
    /// Marks a part the scan being read touched, beside its changed bits
    /// (a part has at most 16 signals).
    const OPEN: u32 = 1 << 31;

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
            parts.push(PartRun::new(
                engine,
                model.time_unit,
                options.polled,
                options.glitch_max,
            ));
        }
        let routes = Routes::new(plant, &parts);
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
        let n = parts.len();
        Ok(PlantDiagnoser {
            coordinator,
            parts,
            routes,
            open: vec![0; n],
            obs: vec![0; n],
            touched: Vec::new(),
            timers: vec![Time::MAX; n],
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
        self.touched.clear();
        self.scan = None;
        self.earliest = None;
        self.coordinator.reset();
        for (p, r) in self.parts.iter_mut().enumerate() {
            r.start(initial);
            self.obs[p] = r.obs();
            self.open[p] = 0;
            self.timers[p] = Time::MAX;
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
        for &(part, bit) in self.routes.of(e.signal.index()) {
            let p = part as usize;
            let open = &mut self.open[p];
            if *open == 0 {
                self.touched.push(part);
                *open = Self::OPEN;
            }
            let mask = 1u32 << bit;
            if ((self.obs[p] ^ *open) & mask != 0) != e.value {
                *open ^= mask;
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

    /// Fires every deadline up to `t`, earliest first, and at one time in
    /// part order.
    fn fire_timers(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        while self.earliest.is_some_and(|at| at <= t) {
            let (p, x) = self.first_timer();
            if x > t {
                self.earliest = (x != Time::MAX).then_some(x);
                return;
            }
            let verdict = self.parts[p].fire(x);
            self.timers[p] = self.parts[p].next_timer().unwrap_or(Time::MAX);
            self.earliest = Some(x);
            self.emit(p, verdict, out);
        }
    }

    /// The part with the earliest deadline (the first such part) and the
    /// deadline ([`Time::MAX`]: none).
    #[inline]
    fn first_timer(&self) -> (usize, Time) {
        let mut first = (0, Time::MAX);
        for (p, &x) in self.timers.iter().enumerate() {
            if x < first.1 {
                first = (p, x);
            }
        }
        first
    }

    fn flush(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        if self.earliest.is_some_and(|x| x <= t) {
            self.fire_timers(t, out);
        }
        self.now = self.now.max(t);
        for i in 0..self.touched.len() {
            let p = self.touched[i] as usize;
            let changed = std::mem::take(&mut self.open[p]) & !Self::OPEN;
            if changed == 0 {
                continue;
            }
            self.obs[p] ^= changed;
            // Timers up to `t` have fired: the state is already up to date.
            let verdict = self.parts[p].scan(t, changed);
            let x = self.parts[p].next_timer().unwrap_or(Time::MAX);
            self.timers[p] = x;
            if verdict.is_some() {
                // An unknown part starts again, with other deadlines.
                let (_, first) = self.first_timer();
                self.earliest = (first != Time::MAX).then_some(first);
                self.emit(p, verdict, out);
            } else if x != Time::MAX && self.earliest.is_none_or(|e| x < e) {
                self.earliest = Some(x);
            }
        }
        self.touched.clear();
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
/// order, in one flat array.
#[derive(Debug, Clone)]
pub(crate) struct Routes {
    /// Signal `s`'s routes are `routes[spans[s].0..spans[s].1]`.
    spans: Vec<(u32, u32)>,
    routes: Vec<(u16, u8)>,
    /// Per signal, its one route as `part << 8 | bit`, or [`Route::None`]'s
    /// or [`Route::Several`]'s code: most signals belong to one part.
    single: Vec<u32>,
}

/// Where one event goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Route {
    /// To no part.
    None,
    /// To one part, at one bit.
    One(u16, u8),
    /// To several parts ([`Routes::of`]).
    Several,
}

impl Routes {
    const NONE: u32 = u32::MAX;
    const SEVERAL: u32 = u32::MAX - 1;

    /// The routes of `plant`'s signals to `parts`.
    pub(crate) fn new(plant: &Plant, parts: &[PartRun]) -> Self {
        let mut per_signal = vec![Vec::new(); plant.signals.len()];
        for (p, r) in parts.iter().enumerate() {
            for (bit, s) in r.engine.part.signals.iter().enumerate() {
                if let Some(route) = per_signal.get_mut(s.index()) {
                    route.push((p as u16, bit as u8));
                }
            }
        }
        let mut spans = Vec::new();
        let mut from = 0u32;
        for r in &per_signal {
            spans.push((from, from + r.len() as u32));
            from += r.len() as u32;
        }
        let single = per_signal
            .iter()
            .map(|r| match r[..] {
                [] => Self::NONE,
                [(part, bit)] => u32::from(part) << 8 | u32::from(bit),
                _ => Self::SEVERAL,
            })
            .collect();
        Routes {
            spans,
            routes: per_signal.concat(),
            single,
        }
    }

    /// The parts that read signal `s`, and at which bit (none for a signal
    /// of no part, or not of the plant).
    #[inline(always)]
    pub(crate) fn of(&self, s: usize) -> &[(u16, u8)] {
        match self.spans.get(s) {
            Some(&(from, to)) => self.routes.get(from as usize..to as usize).unwrap_or(&[]),
            None => &[],
        }
    }

    /// Where an event of signal `s` goes.
    #[inline(always)]
    pub(crate) fn route(&self, s: usize) -> Route {
        match self.single.get(s).copied().unwrap_or(Self::NONE) {
            Self::NONE => Route::None,
            Self::SEVERAL => Route::Several,
            one => Route::One((one >> 8) as u16, one as u8),
        }
    }
}
