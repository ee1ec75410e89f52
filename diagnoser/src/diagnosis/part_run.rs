//! One part's diagnoser over its own scans and deadlines.
//!
//! A part's verdicts depend on its own events and on time only: the plant's
//! other parts never change them. [`PartRun`] is that part of a replay, with
//! no notion of the plant; [`super::PlantDiagnoser`] feeds every part with its
//! scans in time order and combines their verdicts, and
//! [`super::PartwiseReplay`] runs the parts of a recorded log side by side.

use serde::{Deserialize, Serialize};

use super::engine::{Engine, NEVER, Origins, Restarted, UNEXPLAINED};
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
    /// The outcome ([`Engine::outcome`]) of a step with nothing to report:
    /// the labels shown, while no episode is under way; else none.
    quiet: u32,
}

impl RunState {
    /// What [`RunState::quiet`] is, from the labels shown and the episode.
    fn quiet(&self) -> u32 {
        match self.episode {
            None => self.shown,
            Some(_) => u32::MAX,
        }
    }
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
}

impl PartRun {
    /// A part's run, not started.
    pub(crate) fn new(engine: Engine, unit: TimeUnit, polled: bool) -> Self {
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
                quiet: u32::MAX,
            },
            unit,
            polled,
            changes: 0,
            undo: Restarted::default(),
            before_at: Time::MIN,
            before: Vec::new(),
            after: Vec::new(),
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
        let state = e.intern(s.obs, s.hypotheses.clone());
        let shown = e.intern_labels(s.shown.clone());
        self.at = RunState {
            state,
            obs: s.obs,
            origins,
            flags: s.flags,
            shown,
            next_timer: s.next_timer.unwrap_or(NEVER),
            last_command: s.last_command,
            detected: s.detected,
            episode: s.episode,
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
        let step = self.engine.fire_at(self.at.state, &self.at.origins, at);
        (self.at.state, self.at.next_timer) = (step.state, step.timer);
        // The deadline itself is the last moment the event could still have come.
        self.settle(at - 1, previous, None, step.outcome)
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
        if unknown {
            let v = self.report(t, previous, scan, None);
            self.start_again(t);
            return v;
        }
        let Some(mut episode) = self.at.episode else {
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

    /// The verdict at `t` if the labels changed since the last one given;
    /// `reason` replaces the diagnoser's own.
    fn report(
        &mut self,
        t: Time,
        previous: u32,
        scan: Option<(u32, u32)>,
        reason: Option<String>,
    ) -> Option<Verdict> {
        let (engine, run) = (&self.engine, &mut self.at);
        let now = engine.state(run.state).labels;
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
