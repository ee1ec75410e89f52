//! One part's diagnoser over its own scans and deadlines.
//!
//! A part's verdicts depend on its own events and on time only: the plant's
//! other parts never change them. [`PartRun`] is that part of a replay, with
//! no notion of the plant; [`super::PlantDiagnoser`] feeds every part with its
//! scans in time order and combines their verdicts, and
//! [`super::PartwiseReplay`] runs the parts of a recorded log side by side.

use serde::{Deserialize, Serialize};

use super::engine::{Engine, NEVER, Origins, Restarted, UNEXPLAINED};
use super::part::Hypothesis;
use super::run::PartSummary;
use super::snapshot::PartSnapshot;
use super::verdict::{UNKNOWN_LABEL, Verdict, VerdictKind};
use crate::{Flag, Time, TimeUnit};

/// Where a part stands in a replay: what one step may need to undo.
#[derive(Debug, Clone)]
struct RunState {
    state: u32,
    obs: u32,
    /// When each clock last restarted.
    origins: Origins,
    /// Raised flags, as partition bits (sticky).
    flags: u32,
    /// Labels index of the last verdict given.
    shown: u32,
    /// When time alone next changes the state ([`NEVER`]: never).
    next_timer: Time,
    /// The last command's edges, for explanations.
    last_command: Option<(u32, u32)>,
    /// First time the verdict left normal.
    detected: Option<Time>,
    /// The unknown episode the part is in, if any.
    episode: Option<Episode>,
    /// Normal after a glitch, followed since the normal hypothesis died,
    /// until it is ruled out or the part is back to normal.
    watch: Option<Watch>,
    /// When time alone next changes the state of the part's own automaton
    /// (`next_timer` also counts the watch's).
    main_timer: Time,
    /// The outcome ([`Engine::outcome`]) of a step with nothing to report:
    /// the labels shown, while no episode nor watch is under way; else none.
    quiet: u32,
}

impl RunState {
    /// What [`RunState::quiet`] is, from the labels shown, the episode and
    /// the watch.
    fn quiet(&self) -> u32 {
        match (self.episode, &self.watch) {
            (None, None) => self.shown,
            _ => u32::MAX,
        }
    }
}

/// Normal after a transient glitch, beside the fault hypotheses, from the
/// moment an observation rules the normal hypothesis out.
///
/// Elimination alone is no evidence: one unexplained edge (a splash on a level
/// switch) rules normal out, and later edges may rule every fault out but one
/// that nothing confirmed. So the part also follows a shadow run: it waits
/// while the glitch may still show (`glitch_max`), then starts from what the
/// part reads, normal, with the clocks that the part's edges restarted
/// meanwhile unknown (a glitch's edges date nothing). While that shadow
/// lives, the verdict is `{N, faults…}`, ambiguous, with no `def_` flag. It
/// ends one of two ways:
/// - **back to normal**: the shadow runs a learned cycle (back in the first
///   learned state it was in, after leaving it), or explains what no fault
///   does; the part then goes on from the shadow;
/// - **ruled out**: the shadow dies (a deadline, an edge normal never makes
///   there, or readings in a state the model never saw for longer than a
///   glitch shows), and the faults left explained what it could not: they
///   stand on their own, `certain` with their flag where they lie in one
///   partition.
#[derive(Debug, Clone)]
pub(crate) struct Watch {
    /// When the normal hypothesis died.
    since: Time,
    /// Normal after the glitch, while it lives.
    shadow: Option<Shadow>,
    /// When the shadow died.
    ruled_out: Option<Time>,
}

/// The shadow run of a [`Watch`]: normal restarted after a glitch.
#[derive(Debug, Clone)]
struct Shadow {
    /// Its state in the part's automaton.
    state: u32,
    /// When its clocks restarted.
    origins: Origins,
    /// Its next deadline ([`NEVER`]: none).
    timer: Time,
    /// Since when the readings are in a state the model never saw.
    unseen_since: Option<Time>,
    /// The learned cycle that brings the part back to normal.
    cycle: Episode,
    /// It has run that cycle.
    back: bool,
    /// While the glitch may still show (for `glitch_max` after the
    /// unexplained step), `state` and `origins` are the part's just before
    /// that step, and this says until when, from when, and what the part
    /// read then (see [`PartRun::end_glitch`]).
    pending: Option<Pending>,
}

/// The glitch window of a [`Shadow`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct Pending {
    /// When the glitch is over, at the latest.
    until: Time,
    /// When normal was ruled out.
    at: Time,
    /// What the part read just before.
    obs: u32,
}

impl Shadow {
    /// Time passes to `at`: every deadline of the shadow up to then fires.
    fn catch_up(&mut self, engine: &mut Engine, at: Time) {
        while self.timer <= at {
            let step = engine.fire_at(self.state, &self.origins, self.timer);
            if (step.state, step.timer) == (self.state, self.timer) {
                break;
            }
            (self.state, self.timer) = (step.state, step.timer);
        }
    }
}

/// A [`Watch`] as data, in a [`PartSnapshot`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct WatchSnapshot {
    since: Time,
    ruled_out: Option<Time>,
    /// The shadow, while it lives.
    shadow: Option<ShadowSnapshot>,
    /// The part's own automaton's next deadline.
    main_timer: Option<Time>,
}

/// A [`Shadow`] as data.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
struct ShadowSnapshot {
    /// Its hypotheses (while pending, the part's before the glitch).
    hypotheses: Vec<Hypothesis>,
    origins: Vec<Option<Time>>,
    timer: Option<Time>,
    unseen_since: Option<Time>,
    cycle: Episode,
    pending: Option<Pending>,
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct Episode {
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

/// One part's diagnoser, fed with the part's own scans (the bits that changed)
/// and the deadlines that pass.
#[derive(Debug, Clone)]
pub(crate) struct PartRun {
    /// The part's diagnoser automaton.
    pub(crate) engine: Engine,
    at: RunState,
    unit: TimeUnit,
    /// See [`super::DiagnoserOptions::polled`].
    polled: bool,
    /// Verdict changes given.
    changes: u64,
    /// The clocks the last step restarted, with their origins before it, and
    /// its time: what an explanation reads (as the readings before the step),
    /// only when a verdict changes.
    undo: Restarted,
    before_at: Time,
    /// Scratch readings.
    before: Vec<Option<Time>>,
    after: Vec<Option<Time>>,
    /// Longest a glitch shows (see [`super::DiagnoserOptions::glitch_max`]).
    glitch_max: Time,
}

impl PartRun {
    /// A part's run, not started.
    pub(crate) fn new(engine: Engine, unit: TimeUnit, polled: bool, glitch_max: Time) -> Self {
        PartRun {
            engine,
            at: RunState {
                state: 0,
                obs: 0,
                origins: Origins::new(0),
                flags: 0,
                shown: 0,
                next_timer: NEVER,
                last_command: None,
                detected: None,
                episode: None,
                watch: None,
                main_timer: NEVER,
                quiet: u32::MAX,
            },
            unit,
            polled,
            changes: 0,
            undo: Restarted::default(),
            before_at: Time::MIN,
            before: Vec::new(),
            after: Vec::new(),
            glitch_max,
        }
    }

    /// Starts a replay with every plant signal's `initial` value. Clocks are
    /// unknown until their first edge.
    pub(crate) fn start(&mut self, initial: &[bool]) {
        let e = &mut self.engine;
        let obs = e.part.signals.iter().enumerate().fold(0u32, |v, (b, s)| {
            v | (u32::from(initial.get(s.index()).copied().unwrap_or(false)) << b)
        });
        let origins = Origins::new(e.part.clocks.len());
        let state = e.initial(obs, &origins.readings(0));
        let shown = e.state(state).labels;
        self.at = RunState {
            state,
            obs,
            origins,
            flags: 0,
            shown,
            next_timer: NEVER,
            last_command: None,
            detected: None,
            episode: None,
            watch: None,
            main_timer: NEVER,
            quiet: shown,
        };
        self.changes = 0;
    }

    /// Where the part stands, as data (see [`super::snapshot`]).
    pub(crate) fn snapshot(&self) -> PartSnapshot {
        let (e, run) = (&self.engine, &self.at);
        PartSnapshot {
            part: e.part.name.clone(),
            obs: run.obs,
            hypotheses: e.state(run.state).hyps.to_vec(),
            origins: run.origins.to_vec(),
            flags: run.flags,
            shown: e.labels(run.shown).clone(),
            next_timer: self.next_timer(),
            last_command: run.last_command,
            detected: run.detected,
            episode: run.episode,
            watch: run.watch.as_ref().map(|w| WatchSnapshot {
                since: w.since,
                ruled_out: w.ruled_out,
                shadow: w.shadow.as_ref().map(|sh| ShadowSnapshot {
                    hypotheses: e.state(sh.state).hyps.to_vec(),
                    origins: sh.origins.to_vec(),
                    timer: (sh.timer != NEVER).then_some(sh.timer),
                    unseen_since: sh.unseen_since,
                    cycle: sh.cycle,
                    pending: sh.pending,
                }),
                main_timer: (run.main_timer != NEVER).then_some(run.main_timer),
            }),
            changes: self.changes,
        }
    }

    /// Puts the part where `s` says; an error, and the part left as it was,
    /// when `s` does not fit its diagnoser.
    pub(crate) fn restore(&mut self, s: &PartSnapshot) -> Result<(), String> {
        let e = &mut self.engine;
        let part = &e.part;
        let fail = |what: &str| Err(format!("part '{}': {what} do not fit the model", s.part));
        if s.part != part.name {
            return Err(format!(
                "part '{}' where the model has '{}'",
                s.part, part.name
            ));
        }
        let vector = |v: u32| part.signals.len() >= 32 || v >> part.signals.len() == 0;
        let modes = part.modes.len();
        let partitions =
            |bits: u32| part.partitions.len() >= 32 || bits >> part.partitions.len() == 0;
        if !vector(s.obs)
            || s.hypotheses
                .iter()
                .any(|h| !vector(h.phys) || h.mode as usize >= modes)
        {
            return fail("the state vectors or modes");
        }
        if s.hypotheses.is_empty() || s.hypotheses.windows(2).any(|w| w[0] >= w[1]) {
            return fail("the hypotheses (not sorted, or none)");
        }
        let shown = &s.shown;
        if !partitions(s.flags | shown.flags | shown.suspects)
            || shown.modes.iter().any(|&m| m as usize >= modes)
        {
            return fail("the labels or flags");
        }
        let Some(origins) = Origins::from_slice(part.clocks.len(), &s.origins) else {
            return fail("the clocks");
        };
        let watch = match &s.watch {
            None => None,
            Some(w) => {
                let shadow = match &w.shadow {
                    None => None,
                    Some(sh) => {
                        let origins = Origins::from_slice(part.clocks.len(), &sh.origins);
                        let hyps = &sh.hypotheses;
                        let fits = !hyps.is_empty()
                            && sh.pending.is_none_or(|p| vector(p.obs))
                            && hyps.windows(2).all(|w| w[0] < w[1])
                            && hyps
                                .iter()
                                .all(|h| vector(h.phys) && (h.mode as usize) < modes);
                        let (Some(origins), true) = (origins, fits) else {
                            return fail("the glitch watch's hypotheses or clocks");
                        };
                        let obs = sh.pending.map_or(s.obs, |p| p.obs);
                        let state = e.intern(obs, hyps.clone());
                        Some(Shadow {
                            state,
                            origins,
                            timer: sh.timer.unwrap_or(NEVER),
                            unseen_since: sh.unseen_since,
                            cycle: sh.cycle,
                            back: false,
                            pending: sh.pending,
                        })
                    }
                };
                Some(Watch {
                    since: w.since,
                    shadow,
                    ruled_out: w.ruled_out,
                })
            }
        };
        let state = e.intern(s.obs, s.hypotheses.clone());
        let shown = e.intern_labels(s.shown.clone());
        let next_timer = s.next_timer.unwrap_or(NEVER);
        self.at = RunState {
            state,
            obs: s.obs,
            origins,
            flags: s.flags,
            shown,
            next_timer,
            last_command: s.last_command,
            detected: s.detected,
            episode: s.episode,
            main_timer: match &s.watch {
                Some(w) => w.main_timer.unwrap_or(NEVER),
                None => next_timer,
            },
            watch,
            quiet: u32::MAX,
        };
        self.at.quiet = self.at.quiet();
        self.changes = s.changes;
        Ok(())
    }

    /// The observed state vector.
    pub(crate) fn obs(&self) -> u32 {
        self.at.obs
    }

    /// When time alone next changes the part's state, if ever.
    #[inline]
    pub(crate) fn next_timer(&self) -> Option<Time> {
        (self.at.next_timer != NEVER).then_some(self.at.next_timer)
    }

    /// When time alone next changes the part's state ([`NEVER`]: never).
    #[inline(always)]
    pub(crate) fn deadline(&self) -> Time {
        self.at.next_timer
    }

    /// The deadline at `at` (from [`PartRun::next_timer`]) passes.
    #[inline]
    pub(crate) fn fire(&mut self, at: Time) -> Option<Verdict> {
        self.undo.clear();
        self.before_at = at;
        let previous = self.at.state;
        let mut outcome = self.engine.outcome(previous);
        if self.at.main_timer <= at {
            let step = self.engine.fire_at(self.at.state, &self.at.origins, at);
            (self.at.state, self.at.main_timer) = (step.state, step.timer);
            self.at.next_timer = step.timer;
            outcome = step.outcome;
        }
        if self.at.watch.is_some() {
            self.watch_time(at, at - 1);
        }
        // The deadline itself is the last moment the event could still have come.
        self.settle(at - 1, previous, None, outcome)
    }

    /// The part's scan at `t` changed the bits `changed` (not 0); every
    /// deadline up to `t` has passed.
    #[inline]
    pub(crate) fn scan(&mut self, t: Time, changed: u32) -> Option<Verdict> {
        let previous = self.at.state;
        let obs_before = self.at.obs;
        let outcome = if self.polled {
            self.polled_step(t, changed);
            self.engine.outcome(self.at.state)
        } else {
            self.step(t, changed)
        };
        if self.at.watch.is_some() {
            self.watch_scan(t, changed);
        }
        self.settle(t, previous, Some((obs_before, changed)), outcome)
    }

    /// A polled scan: one step, tried again as two where it is not normal
    /// and the part was (see [`PartRun::split_step`]).
    #[cold]
    fn polled_step(&mut self, t: Time, changed: u32) {
        let previous = self.at.state;
        let saved = self.at.clone();
        self.step(t, changed);
        if !self.is_normal() && self.normal(previous) {
            self.split_step(t, changed, saved);
        }
    }

    /// The part's summary at the end of a replay.
    pub(crate) fn summary(&self) -> PartSummary {
        let v = self.verdict_of(0, String::new());
        PartSummary {
            part: self.engine.part.name.clone(),
            verdict: v.verdict,
            labels: v.labels,
            detected: self.at.detected,
            flags: v.flags,
            changes: self.changes,
        }
    }

    /// The edges `changed` at `t`: their clocks start, and the state moves
    /// on. Gives the outcome of the state reached.
    #[inline(always)]
    fn step(&mut self, t: Time, changed: u32) -> u32 {
        let run = &mut self.at;
        self.before_at = t;
        let obs_before = run.obs;
        let step = self
            .engine
            .scan_step(run.state, changed, &mut run.origins, t, &mut self.undo);
        (run.state, run.next_timer) = (step.state, step.timer);
        run.main_timer = step.timer;
        run.obs ^= changed;
        let acts = self.engine.part.actuator_mask();
        if changed & acts != 0 {
            run.last_command = Some((obs_before, changed & acts));
        }
        step.outcome
    }

    /// A polled scan that one step does not explain as normal: the orders
    /// then the sensors, or the sensors then the orders, as two PLC scans
    /// seen at once. The first split that is normal stands; else the one step.
    fn split_step(&mut self, t: Time, changed: u32, saved: RunState) {
        let acts = self.engine.part.actuator_mask();
        let (orders, sensors) = (changed & acts, changed & !acts);
        if orders == 0 || sensors == 0 {
            return;
        }
        let one_step = (self.at.clone(), self.undo.clone());
        for first in [orders, sensors] {
            self.at = saved.clone();
            self.step(t, first);
            if self.is_normal() {
                self.step(t, changed ^ first);
                if self.is_normal() {
                    return;
                }
            }
        }
        // The one step stands, and its explanation reads the clocks as they
        // were before it.
        (self.at, self.undo) = one_step;
    }

    fn is_normal(&self) -> bool {
        self.normal(self.at.state)
    }

    /// Whether the normal hypothesis lives in `state`.
    fn normal(&self, state: u32) -> bool {
        let e = &self.engine;
        e.labels(e.state(state).labels).normal
    }

    /// The state has just moved on from `previous`: reports what changed,
    /// starts an unknown episode when nothing explains the part any more, and
    /// ends one when the part has run a learned cycle again.
    #[inline(always)]
    fn settle(
        &mut self,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        outcome: u32,
    ) -> Option<Verdict> {
        // The common case: nothing to report, no episode to follow.
        if outcome == self.at.quiet {
            return None;
        }
        let verdict = self.settle_change(t, previous, scan, outcome & UNEXPLAINED != 0);
        self.at.quiet = self.at.quiet();
        verdict
    }

    #[cold]
    #[inline(never)]
    fn settle_change(
        &mut self,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        unknown: bool,
    ) -> Option<Verdict> {
        if self.at.watch.is_some() {
            return self.settle_watch(t, previous, scan, unknown);
        }
        if unknown {
            let v = self.report(t, previous, scan, None);
            self.start_again(t);
            return v;
        }
        let Some(mut episode) = self.at.episode else {
            if !self.is_normal() && self.engine.labels(self.at.shown).normal {
                self.start_watch(t, previous, scan);
                return self.settle_watch(t, previous, scan, false);
            }
            return self.report(t, previous, scan, None);
        };
        if !self.is_normal() {
            return self.report(t, previous, scan, None);
        }
        let (part, obs) = (&self.engine.part, self.at.obs);
        let back = episode.cycled(part.motion(obs), part.model_state(obs).is_some());
        let reason = back.then(|| {
            format!(
                "back to normal: {} is in state {} again after a cycle that the model explains; unknown since {} {}",
                part.name,
                part.describe(obs),
                self.unit.format(episode.since),
                self.unit.name(),
            )
        });
        self.at.episode = (!back).then_some(episode);
        reason.and_then(|reason| self.report(t, previous, scan, Some(reason)))
    }

    /// Starts the diagnosis again from what the part reads at `t`, its clocks
    /// unknown (see [`Episode`]).
    fn start_again(&mut self, t: Time) {
        let (engine, run) = (&mut self.engine, &mut self.at);
        run.origins.clear();
        run.origins.read_into(t, &mut self.after);
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
    }

    /// The labels the part shows: its automaton's, with normal after a
    /// glitch beside them while a [`Watch`] is under way.
    fn labels_now(&mut self) -> u32 {
        let id = self.engine.state(self.at.state).labels;
        let labels = self.engine.labels(id);
        if self.at.watch.is_none() || labels.normal || labels.modes.is_empty() {
            return id;
        }
        let glitch = labels.with_glitch();
        self.engine.intern_labels(glitch)
    }

    /// Starts a [`Watch`] after the step from `previous` (`scan`: what the
    /// part read before it, and what changed), shown at `shown`: a shadow
    /// run that waits while the glitch may still show.
    fn start_watch(&mut self, shown: Time, previous: u32, scan: Option<(u32, u32)>) {
        let t = self.before_at;
        let mut origins = self.at.origins.clone();
        self.undo.undo(&mut origins);
        let obs = scan.map_or(self.at.obs, |(before, _)| before);
        self.at.watch = Some(Watch {
            since: shown,
            shadow: Some(Shadow {
                state: previous,
                origins,
                timer: NEVER,
                unseen_since: None,
                cycle: Episode {
                    since: shown,
                    anchor: None,
                    left: false,
                },
                back: false,
                pending: Some(Pending {
                    until: t.saturating_add(self.glitch_max),
                    at: shown,
                    obs,
                }),
            }),
            ruled_out: None,
        });
        self.update_timer();
    }

    /// The watch's shadow takes the scan at `t` that changed `changed`.
    #[cold]
    fn watch_scan(&mut self, t: Time, changed: u32) {
        if let Some(sh) = self.at.watch.as_mut().and_then(|w| w.shadow.as_mut())
            && sh.pending.is_none()
        {
            let mut undo = Restarted::default();
            let step = (self.engine).scan_step(sh.state, changed, &mut sh.origins, t, &mut undo);
            (sh.state, sh.timer) = (step.state, step.timer);
        }
        self.judge_shadow(t, t);
    }

    /// Once the glitch is over, the shadow is normal as the part was
    /// before it, moved by what the glitch changed for good as one step at
    /// the moment normal was ruled out: a glitch only hides or fakes edges
    /// for a while, so the part must read what normal operation could have
    /// made of it by then.
    fn end_glitch(&mut self) {
        let obs = self.at.obs;
        let Some(sh) = self.at.watch.as_mut().and_then(|w| w.shadow.as_mut()) else {
            return;
        };
        let Some(p) = sh.pending.take() else {
            return;
        };
        let changed = obs ^ p.obs;
        if changed != 0 {
            let mut undo = Restarted::default();
            let step = (self.engine).scan_step(sh.state, changed, &mut sh.origins, p.at, &mut undo);
            sh.state = step.state;
        }
        sh.timer = self.engine.next_timer(sh.state, &sh.origins, p.at);
    }

    /// Time passes to `at` for the watch's shadow (`shown`: the time
    /// verdicts give it, `at - 1` for a deadline).
    #[cold]
    fn watch_time(&mut self, at: Time, shown: Time) {
        let glitch_over = (self.at.watch.as_ref())
            .and_then(|w| w.shadow.as_ref())
            .and_then(|sh| sh.pending)
            .is_some_and(|p| p.until <= at);
        if glitch_over {
            self.end_glitch();
        }
        if let Some(sh) = self.at.watch.as_mut().and_then(|w| w.shadow.as_mut())
            && sh.pending.is_none()
        {
            sh.catch_up(&mut self.engine, at);
        }
        self.judge_shadow(at, shown);
    }

    /// Rules the shadow out at `t` (`shown` in verdicts) if normal no longer
    /// explains the part, or the readings have been in a state the model
    /// never saw for longer than a glitch shows; else notes whether it ran
    /// its cycle.
    fn judge_shadow(&mut self, t: Time, shown: Time) {
        let (engine, obs) = (&self.engine, self.at.obs);
        let Some(w) = self.at.watch.as_mut() else {
            return;
        };
        if let Some(sh) = w.shadow.as_mut().filter(|sh| sh.pending.is_none()) {
            let part = &engine.part;
            let learned = part.model_state(obs).is_some();
            sh.unseen_since = if learned {
                None
            } else {
                Some(sh.unseen_since.unwrap_or(t))
            };
            let normal = engine.labels(engine.state(sh.state).labels).normal;
            let unseen_too_long = sh.unseen_since.is_some_and(|u| t - u > self.glitch_max);
            if !normal || unseen_too_long {
                w.shadow = None;
                w.ruled_out = Some(shown);
            } else if sh.cycle.cycled(part.motion(obs), learned) {
                sh.back = true;
            }
        }
        self.update_timer();
    }

    /// The next time anything of the part changes with time alone: its
    /// automaton's deadline, or the watch's.
    fn update_timer(&mut self) {
        let run = &mut self.at;
        let mut next = run.main_timer;
        if let Some(sh) = run.watch.as_ref().and_then(|w| w.shadow.as_ref()) {
            next = next.min(sh.pending.map_or(sh.timer, |p| p.until));
            if let Some(u) = sh.unseen_since {
                next = next.min(u.saturating_add(self.glitch_max + 1));
            }
        }
        run.next_timer = next;
    }

    /// A step under a [`Watch`]: back to normal, normal after a glitch
    /// ruled out (the faults stand on their own), or the labels with it
    /// beside them.
    fn settle_watch(
        &mut self,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        unknown: bool,
    ) -> Option<Verdict> {
        let unit = self.unit;
        let time = |x: Time| format!("{} {}", unit.format(x), unit.name());
        let w = self.at.watch.as_ref()?;
        let since = w.since;
        let verdict = match (&w.shadow, w.ruled_out) {
            (Some(sh), _) if sh.back || unknown => {
                let sh = self.at.watch.take().and_then(|w| w.shadow)?;
                (self.at.state, self.at.origins, self.at.main_timer) =
                    (sh.state, sh.origins, sh.timer);
                let part = &self.engine.part;
                let reason = if unknown {
                    format!(
                        "back to normal: a glitch at {}, then what no fault explains and normal does",
                        time(since)
                    )
                } else {
                    format!(
                        "back to normal: a glitch at {}, then {} in state {} again after a cycle that the model explains",
                        time(since),
                        part.name,
                        part.describe(self.at.obs)
                    )
                };
                self.report(t, previous, scan, Some(reason))
            }
            (Some(_), _) => self.report(t, previous, scan, None).map(|mut v| {
                v.reason.push_str(&format!(
                    "; or normal after a glitch at {}: no def_ flag while it explains the part",
                    time(since)
                ));
                v
            }),
            (None, _) if unknown => {
                self.at.watch = None;
                let v = self.report(t, previous, scan, None);
                self.start_again(t);
                v
            }
            (None, ruled_out) => {
                // Normal after a glitch could not explain what the faults
                // left do: they stand on their own now, flags included.
                self.at.watch = None;
                let r = ruled_out.unwrap_or(since);
                self.report(t, previous, scan, None).map(|mut v| {
                    if v.reason.is_empty() {
                        v.reason = "no other change".to_string();
                    }
                    v.reason.push_str(&format!(
                        "; normal after a glitch at {} ruled out at {}",
                        time(since),
                        time(r)
                    ));
                    v
                })
            }
        };
        self.update_timer();
        verdict
    }

    /// The verdict at `t` if the labels changed since the last one given;
    /// `reason` replaces the diagnoser's own.
    fn report(
        &mut self,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        reason: Option<String>,
    ) -> Option<Verdict> {
        let now = self.labels_now();
        let (engine, run) = (&self.engine, &mut self.at);
        if now == run.shown {
            return None;
        }
        let labels = engine.labels(now);
        let unknown = !labels.normal && labels.modes.is_empty();
        // The readings before the step: its restarted clocks put back.
        run.origins.read_into(self.before_at, &mut self.before);
        self.undo.put_back(&mut self.before, self.before_at);
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
        self.changes += 1;
        Some(self.verdict_of(t, reason))
    }

    /// The verdict the part last gave, at `t`.
    fn verdict_of(&self, t: Time, reason: String) -> Verdict {
        let (part, run) = (&self.engine.part, &self.at);
        let labels = self.engine.labels(run.shown);
        let names: Vec<String> = if labels.normal {
            vec!["N".to_string()]
        } else if labels.modes.is_empty() {
            vec![UNKNOWN_LABEL.to_string()]
        } else {
            (labels.glitch.then(|| "N".to_string()).into_iter())
                .chain((labels.modes.iter()).map(|&m| part.modes[m as usize].label.clone()))
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
