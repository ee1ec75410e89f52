//! Running every part's diagnoser over a stream of events.

use serde::Serialize;

use super::engine::Engine;
use super::fusion::Coordinator;
use super::part::PartDiagnoser;
use super::verdict::{UNKNOWN_LABEL, Verdict, VerdictKind};
use crate::model::Model;
use crate::{Event, Flag, Plant, Time, TimeUnit};

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

/// Per part, the state of the replay.
#[derive(Debug, Clone)]
struct PartRun {
    state: u32,
    obs: u32,
    origins: Vec<Option<Time>>,
    /// Raised flags, as partition bits (sticky).
    flags: u32,
    /// Labels index of the last verdict given.
    shown: u32,
    next_timer: Option<Time>,
    /// The last command's edges, for explanations.
    last_command: Option<(u32, u32)>,
    /// First time the verdict left normal.
    detected: Option<Time>,
    /// The unknown episode the part is in, if any.
    episode: Option<Episode>,
}

/// An unknown episode: from observations that no mode of the part explains
/// until the part runs a learned cycle again.
///
/// `unknown` is not the end of a part's diagnosis. The diagnoser starts again
/// from what the part reads now, with its clocks unknown, as at a log's start,
/// and keeps diagnosing. The episode ends, and the part is reported normal
/// again, once it has come back to the first learned state it was seen in
/// since, after leaving it: one cycle that the model explains. A fault found
/// meanwhile is reported, but raises no `def_` flag until the episode is over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Episode {
    /// When the observations stopped fitting.
    since: Time,
    /// The first learned state the part was seen in after starting again.
    anchor: Option<u32>,
    /// Whether it has left the anchor since.
    left: bool,
}

impl Episode {
    /// Notes the observed state `obs` (`learned`: a state of the model); true
    /// once the part is back in its anchor after leaving it.
    fn cycled(&mut self, obs: u32, learned: bool) -> bool {
        match self.anchor {
            None => {
                if learned {
                    self.anchor = Some(obs);
                }
                false
            }
            Some(a) if a != obs => {
                self.left = true;
                false
            }
            Some(_) => self.left,
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
    engines: Vec<Engine>,
    runs: Vec<PartRun>,
    /// Per plant signal, the parts that read it and at which bit.
    routes: Vec<Vec<(u16, u8)>>,
    pending: Vec<(u16, u32)>,
    scan: Option<Time>,
    /// Time of the last scan or of the start: deadlines before it have fired.
    now: Time,
    earliest: Option<Time>,
    unit: TimeUnit,
    changes: Vec<u64>,
    before: Vec<Option<Time>>,
    after: Vec<Option<Time>>,
    coordinator: Coordinator,
    /// See [`DiagnoserOptions::polled`].
    polled: bool,
}

impl PlantDiagnoser {
    /// Builds the diagnosers of every part of `plant` that `model` has learned.
    pub fn new(plant: &Plant, model: &Model, options: &DiagnoserOptions) -> Result<Self, String> {
        model.fits(plant)?;
        let mut engines = Vec::new();
        for part in &plant.parts {
            let Some(pm) = model.parts.iter().find(|p| p.name == part.name) else {
                return Err(format!("the model has no part '{}'", part.name));
            };
            let built = PartDiagnoser::build(plant, part, pm, model.time_unit, options.glitch_max)?;
            engines.push(Engine::new(if options.held_reactions {
                built.with_held_reactions()
            } else {
                built
            }));
        }
        let mut routes = vec![Vec::new(); plant.signals.len()];
        for (p, e) in engines.iter().enumerate() {
            for (bit, s) in e.part.signals.iter().enumerate() {
                if let Some(r) = routes.get_mut(s.index()) {
                    r.push((p as u16, bit as u8));
                }
            }
        }
        let coordinator = Coordinator::new(
            plant,
            engines
                .iter()
                .map(|e| {
                    let labels = e.part.modes[1..].iter().map(|m| m.label.clone()).collect();
                    (e.part.name.clone(), labels)
                })
                .collect(),
        );
        Ok(PlantDiagnoser {
            coordinator,
            runs: Vec::new(),
            changes: vec![0; engines.len()],
            engines,
            routes,
            pending: Vec::new(),
            scan: None,
            now: Time::MIN,
            earliest: None,
            unit: model.time_unit,
            before: Vec::new(),
            after: Vec::new(),
            polled: options.polled,
        })
    }

    /// The parts' engines.
    pub fn engines(&self) -> &[Engine] {
        &self.engines
    }

    /// Starts a replay at `t0` (the time of the first record) with every
    /// signal's initial value. Clocks are unknown until their first edge.
    pub fn start(&mut self, t0: Time, initial: &[bool]) {
        self.runs.clear();
        self.pending.clear();
        self.scan = None;
        self.earliest = None;
        self.changes.iter_mut().for_each(|c| *c = 0);
        self.coordinator.reset();
        for e in &mut self.engines {
            let obs = e.part.signals.iter().enumerate().fold(0u32, |v, (b, s)| {
                v | (u32::from(initial.get(s.index()).copied().unwrap_or(false)) << b)
            });
            let origins = vec![None; e.part.clocks.len()];
            let state = e.initial(obs, &origins);
            let shown = e.state(state).labels;
            self.runs.push(PartRun {
                state,
                obs,
                origins,
                flags: 0,
                shown,
                next_timer: None,
                last_command: None,
                detected: None,
                episode: None,
            });
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
            let now = (self.runs[part as usize].obs ^ self.pending[i].1) & mask != 0;
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
        self.runs
            .iter()
            .zip(&self.engines)
            .zip(&self.changes)
            .map(|((run, e), &changes)| {
                let v = self.verdict_of(e, run, 0, String::new());
                PartSummary {
                    part: e.part.name.clone(),
                    verdict: v.verdict,
                    labels: v.labels,
                    detected: run.detected,
                    flags: v.flags,
                    changes,
                }
            })
            .collect()
    }

    /// The coordinator's plant view of the parts' latest verdicts.
    pub fn plant_view(&mut self, t: Time) -> Verdict {
        self.coordinator.view(t)
    }

    /// The plant view at `t` as a summary row after the parts' `summaries`
    /// (from [`Self::finish`]): detected when the first part was.
    pub fn plant_summary(&mut self, t: Time, summaries: &[PartSummary]) -> PartSummary {
        let view = self.plant_view(t);
        PartSummary {
            part: view.part,
            verdict: view.verdict,
            labels: view.labels,
            detected: summaries.iter().filter_map(|p| p.detected).min(),
            flags: view.flags,
            changes: 0,
        }
    }

    fn fire_timers(&mut self, t: Time, out: &mut impl FnMut(Verdict)) {
        while let Some(at) = self.earliest {
            if at > t {
                return;
            }
            // Fire the earliest timer of all parts, then look again.
            let mut first: Option<(usize, Time)> = None;
            for (p, run) in self.runs.iter().enumerate() {
                if let Some(x) = run.next_timer
                    && first.is_none_or(|(_, f)| x < f)
                {
                    first = Some((p, x));
                }
            }
            match first {
                Some((p, x)) if x <= t => self.fire(p, x, out),
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

    fn fire(&mut self, p: usize, at: Time, out: &mut impl FnMut(Verdict)) {
        let (engine, run) = (&mut self.engines[p], &mut self.runs[p]);
        read(&run.origins, at, &mut self.before);
        let previous = run.state;
        run.state = engine.advance(run.state, &self.before);
        run.next_timer = engine.next_timer(run.state, &run.origins, at);
        self.earliest = earliest(&self.runs);
        // The deadline itself is the last moment the event could still have come.
        self.settle(p, at - 1, previous, None, out);
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
            let previous = self.runs[p].state;
            let obs_before = self.runs[p].obs;
            // A copy to try again from, only where scans may have merged.
            let saved = self.polled.then(|| self.runs[p].clone());
            self.step(p, t, changed);
            if let Some(saved) = saved
                && !self.is_normal(p)
                && normal(&self.engines[p], previous)
            {
                self.split_step(p, t, changed, &saved);
            }
            let (engine, run) = (&mut self.engines[p], &mut self.runs[p]);
            run.next_timer = engine.next_timer(run.state, &run.origins, t);
            if let Some(x) = run.next_timer
                && self.earliest.is_none_or(|e| x < e)
            {
                self.earliest = Some(x);
            }
            self.settle(p, t, previous, Some((obs_before, changed)), out);
        }
        pending.clear();
        self.pending = pending;
    }

    /// Part `p` takes the edges `changed` at `t`: their clocks start, and its
    /// state moves on.
    fn step(&mut self, p: usize, t: Time, changed: u32) {
        let (engine, run) = (&mut self.engines[p], &mut self.runs[p]);
        read(&run.origins, t, &mut self.before);
        let previous = run.state;
        let obs_before = run.obs;
        let after_obs = run.obs ^ changed;
        let acts = engine.part.actuator_mask();
        for (c, clock) in engine.part.clocks.iter().enumerate() {
            if engine.part.restarts(*clock, changed, after_obs) {
                run.origins[c] = Some(t);
            }
        }
        read(&run.origins, t, &mut self.after);
        run.state = engine.scan(previous, changed, &self.before, &self.after);
        run.obs = after_obs;
        if changed & acts != 0 {
            run.last_command = Some((obs_before, changed & acts));
        }
    }

    /// A polled scan that one step does not explain as normal: the orders
    /// then the sensors, or the sensors then the orders, as two PLC scans
    /// seen at once. The first split that is normal stands; else the one step.
    fn split_step(&mut self, p: usize, t: Time, changed: u32, saved: &PartRun) {
        let acts = self.engines[p].part.actuator_mask();
        let (orders, sensors) = (changed & acts, changed & !acts);
        if orders == 0 || sensors == 0 {
            return;
        }
        let one_step = self.runs[p].clone();
        for first in [orders, sensors] {
            self.runs[p] = saved.clone();
            self.step(p, t, first);
            if self.is_normal(p) {
                self.step(p, t, changed ^ first);
                if self.is_normal(p) {
                    return;
                }
            }
        }
        self.runs[p] = one_step;
    }

    fn is_normal(&self, p: usize) -> bool {
        normal(&self.engines[p], self.runs[p].state)
    }

    /// Part `p`'s state has just moved on from `previous`: reports what changed,
    /// starts an unknown episode when nothing explains the part any more, and
    /// ends one when the part has run a learned cycle again.
    fn settle(
        &mut self,
        p: usize,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        out: &mut impl FnMut(Verdict),
    ) {
        let (engine, run) = (&self.engines[p], &self.runs[p]);
        let labels = engine.labels(engine.state(run.state).labels);
        if !labels.normal && labels.modes.is_empty() {
            self.report(p, t, previous, scan, None, out);
            self.start_again(p, t);
            return;
        }
        let Some(mut episode) = run.episode else {
            self.report(p, t, previous, scan, None, out);
            return;
        };
        if !labels.normal {
            self.report(p, t, previous, scan, None, out);
            return;
        }
        let obs = run.obs;
        let back = episode.cycled(
            engine.part.motion(obs),
            engine.part.model_state(obs).is_some(),
        );
        let reason = back.then(|| {
            format!(
                "back to normal: {} is in state {} again after a cycle that the model explains; unknown since {} {}",
                engine.part.name,
                engine.part.describe(obs),
                self.unit.format(episode.since),
                self.unit.name(),
            )
        });
        self.runs[p].episode = (!back).then_some(episode);
        if let Some(reason) = reason {
            self.report(p, t, previous, scan, Some(reason), out);
        }
    }

    /// Starts part `p`'s diagnosis again from what it reads at `t`, its clocks
    /// unknown (see [`Episode`]).
    fn start_again(&mut self, p: usize, t: Time) {
        let (engine, run) = (&mut self.engines[p], &mut self.runs[p]);
        run.origins.iter_mut().for_each(|o| *o = None);
        read(&run.origins, t, &mut self.after);
        run.state = engine.resync(run.obs, &self.after);
        run.next_timer = engine.next_timer(run.state, &run.origins, t);
        let mut episode = run.episode.unwrap_or(Episode {
            since: t,
            anchor: None,
            left: false,
        });
        if episode.anchor.is_none() {
            episode.cycled(
                engine.part.motion(run.obs),
                engine.part.model_state(run.obs).is_some(),
            );
        }
        run.episode = Some(episode);
        self.earliest = earliest(&self.runs);
    }

    /// Emits a verdict if part `p`'s labels changed since the last one given;
    /// `reason` replaces the diagnoser's own.
    fn report(
        &mut self,
        p: usize,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        reason: Option<String>,
        out: &mut impl FnMut(Verdict),
    ) {
        let (engine, run) = (&self.engines[p], &mut self.runs[p]);
        let now = engine.state(run.state).labels;
        if now == run.shown {
            return;
        }
        let labels = engine.labels(now);
        let unknown = !labels.normal && labels.modes.is_empty();
        let mut reason = reason.unwrap_or_else(|| {
            super::explain::reason(
                engine,
                previous,
                run.state,
                scan,
                &self.before,
                run.last_command,
                self.unit,
            )
        });
        // No flag while the part is unknown, nor until it has run a learned
        // cycle since.
        let new_flags = match run.episode {
            Some(e) if labels.flags != 0 => {
                reason.push_str(&format!(
                    "; no def_ flag: unknown since {} {}, no learned cycle yet",
                    self.unit.format(e.since),
                    self.unit.name()
                ));
                run.flags
            }
            Some(_) => run.flags,
            None => run.flags | labels.flags,
        };
        if unknown && run.episode.is_none() {
            reason.push_str(
                "; diagnosis starts again from the present readings, back to normal after a learned cycle",
            );
        }
        run.flags = new_flags;
        run.shown = now;
        if !labels.normal && run.detected.is_none() {
            run.detected = Some(t);
        }
        self.changes[p] += 1;
        let mut v = self.verdict_of(engine, &self.runs[p], t, reason);
        v.t = t;
        let view = self.coordinator.update(p, &v);
        out(v);
        if let Some(view) = view {
            out(view);
        }
    }

    fn verdict_of(&self, engine: &Engine, run: &PartRun, t: Time, reason: String) -> Verdict {
        let part = &engine.part;
        let labels = engine.labels(run.shown);
        let names: Vec<String> = if labels.normal {
            vec!["N".to_string()]
        } else if labels.modes.is_empty() {
            vec![UNKNOWN_LABEL.to_string()]
        } else {
            labels
                .modes
                .iter()
                .map(|&m| part.modes[m as usize].label.clone())
                .collect()
        };
        let verdict = if labels.normal {
            VerdictKind::Normal
        } else if names.len() == 1 {
            VerdictKind::Certain
        } else {
            VerdictKind::Ambiguous
        };
        let bits = |mask: u32| -> Vec<String> {
            part.partitions
                .iter()
                .enumerate()
                .filter(|(i, _)| mask >> i & 1 == 1)
                .map(|(_, n)| n.clone())
                .collect()
        };
        Verdict {
            t,
            part: part.name.clone(),
            verdict,
            labels: names,
            flags: bits(run.flags)
                .into_iter()
                .map(|n| Flag::def(n).to_string())
                .collect(),
            suspects: bits(labels.suspects),
            reason,
        }
    }
}

/// Whether the normal hypothesis lives in `state`.
fn normal(engine: &Engine, state: u32) -> bool {
    engine.labels(engine.state(state).labels).normal
}

fn read(origins: &[Option<Time>], t: Time, into: &mut Vec<Option<Time>>) {
    into.clear();
    into.extend(origins.iter().map(|o| o.map(|o| t - o)));
}

fn earliest(runs: &[PartRun]) -> Option<Time> {
    runs.iter().filter_map(|r| r.next_timer).min()
}
