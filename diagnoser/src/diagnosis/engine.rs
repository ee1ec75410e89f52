//! The diagnoser automaton of one part, built on the fly.
//!
//! Its states are sets of hypotheses (with the observed state vector); its
//! transitions are taken on an observed scan (the bits that changed) or on the
//! passing of time, and depend on the clocks only through which thresholds they
//! have passed (the *region*). Each transition is computed once, from
//! [`PartDiagnoser::step`] and [`PartDiagnoser::close`], then looked up: a
//! replay costs a region computation and one or two lookups per scan, and
//! the part of the automaton a log visits is exactly seed 002's diagnoser
//! (Fig. 12), states labelled with their fault labels.
//!
//! The replay's hot path (`scan_step`, `fire_at`) reads the clocks from
//! their origins and the present time, and finds a state's transitions in
//! the state's own sorted table: no hashing and no allocation once the
//! transition is known. A scan's move also keeps what follows from its key
//! (the region before the scan): the state once time has passed to the
//! scan's end, and which threshold of each timer clock comes next, when the
//! clocks the scan left running are read by that region with the same
//! thresholds (`region_follows`, `timer_memo`). Most scans then cost one
//! region and one lookup.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::part::{Hypothesis, PartDiagnoser, Readings};
use crate::Time;

/// What a set of hypotheses says: the verdict's ingredients.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Labels {
    /// The normal hypothesis survives: the verdict is normal.
    pub normal: bool,
    /// Modes of the remaining hypotheses, when not normal (empty: no mode of the
    /// model explains the observations).
    pub modes: Vec<u16>,
    /// Partitions (bits, as in [`PartDiagnoser::partitions`]) that hold every
    /// remaining mode: their `def_` flag is set.
    pub flags: u32,
    /// Partitions holding at least one remaining mode.
    pub suspects: u32,
    /// Normal after a transient glitch also explains the observations
    /// (the run's glitch watch, not a hypothesis of the automaton): the
    /// verdict is `{N, modes…}`, ambiguous, and raises no `def_` flag.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub glitch: bool,
}

impl Labels {
    /// These labels with normal after a glitch beside them: no flag yet.
    pub(crate) fn with_glitch(&self) -> Labels {
        Labels {
            normal: false,
            modes: self.modes.clone(),
            flags: 0,
            suspects: self.suspects,
            glitch: true,
        }
    }
}

/// A state of the diagnoser automaton.
#[derive(Debug, Clone)]
pub struct DiagnoserState {
    /// The observed state vector.
    pub obs: u32,
    /// The hypotheses, sorted.
    pub hyps: Box<[Hypothesis]>,
    /// Index of its labels in [`Engine::labels`].
    pub labels: u32,
    /// Per clock, the sorted thresholds that matter to it.
    pub thresholds: Vec<Box<[Time]>>,
    /// Per clock, the thresholds at which time alone changes it.
    pub timers: Vec<Box<[Time]>>,
}

/// The on-the-fly diagnoser automaton of one part.
#[derive(Debug, Clone)]
pub struct Engine {
    /// The part's static diagnoser.
    pub part: PartDiagnoser,
    states: Vec<DiagnoserState>,
    index: HashMap<(u32, Box<[Hypothesis]>), u32>,
    labels: Vec<Labels>,
    label_index: HashMap<Labels, u32>,
    /// Per state, what the replay reads of it: the clocks its region reads,
    /// its timers, its labels, its transitions computed so far.
    tables: Vec<StateTable>,
    /// Per clock, the bits whose rise and whose fall restart it.
    restarts: Box<[(u32, u32)]>,
}

/// Most clocks a part may have: the command clock, and a rising and a
/// falling edge per signal. Sets of clocks are bits of a `u64`.
const MAX_CLOCKS: usize = 1 + 2 * super::part::MAX_PART_SIGNALS;

/// One clock's thresholds in a state: the clock, and its slice of the
/// state's flat array.
#[derive(Debug, Clone, Copy)]
struct ClockSpan {
    clock: u16,
    len: u16,
    from: u32,
}

/// A state in the form the replay reads it: only the clocks that have
/// thresholds, each with its slice of one flat array, its labels, and its
/// transitions, each sorted by its key for a search (most states have a
/// handful).
#[derive(Debug, Clone, Default)]
struct StateTable {
    /// Clocks with thresholds: the region reads them.
    region: Box<[ClockSpan]>,
    /// Clocks with timers.
    timers: Box<[ClockSpan]>,
    /// The thresholds of `region`, then the timers of `timers`.
    at: Box<[Time]>,
    /// The clocks of `region`, as bits.
    region_clocks: u64,
    /// Index of the state's labels, with [`UNEXPLAINED`] when no mode
    /// explains the observations.
    outcome: u32,
    /// By (changed bits, region before the scan).
    on_scan: Vec<ScanMove>,
    /// By region: the state after time has passed.
    on_time: Vec<TimeMove>,
}

impl StateTable {
    fn new(thresholds: &[Box<[Time]>], timers: &[Box<[Time]>], labels: u32, unknown: bool) -> Self {
        let mut at = Vec::new();
        let mut spans = |per_clock: &[Box<[Time]>]| -> (Box<[ClockSpan]>, u64) {
            let mut clocks = 0u64;
            let spans = per_clock
                .iter()
                .enumerate()
                .filter(|(_, th)| !th.is_empty())
                .map(|(c, th)| {
                    clocks |= 1 << c;
                    let from = at.len() as u32;
                    at.extend_from_slice(th);
                    ClockSpan {
                        clock: c as u16,
                        len: th.len() as u16,
                        from,
                    }
                })
                .collect();
            (spans, clocks)
        };
        let (region, region_clocks) = spans(thresholds);
        let (timers, _) = spans(timers);
        StateTable {
            region,
            timers,
            at: at.into_boxed_slice(),
            region_clocks,
            outcome: labels | if unknown { UNEXPLAINED } else { 0 },
            on_scan: Vec::new(),
            on_time: Vec::new(),
        }
    }

    #[inline]
    fn thresholds(&self, span: ClockSpan) -> &[Time] {
        let from = span.from as usize;
        &self.at[from..from + span.len as usize]
    }
}

/// Whether every reading that falls where `v` falls among the sorted
/// thresholds `known` (one region of a clock) falls where `v` falls among
/// `th` too: no threshold of `th` lies strictly inside `v`'s interval of
/// `known`. Always so when `th` is among `known`.
fn same_place(known: &[Time], th: &[Time], v: Time) -> bool {
    let k = passed(known, v);
    // Readings are never negative.
    let lo = if k == 0 { 0 } else { known[k - 1] };
    let hi = known.get(k).copied().unwrap_or(Time::MAX);
    th.iter().all(|&x| x <= lo || x >= hi)
}

/// How many of the sorted thresholds `th` a reading `v` has passed.
#[inline(always)]
fn passed(th: &[Time], v: Time) -> usize {
    // A clock has a handful of thresholds: a walk from the first beats a
    // binary search.
    if th.len() <= 8 {
        th.iter().position(|&x| x > v).unwrap_or(th.len())
    } else {
        th.partition_point(|&x| x <= v)
    }
}

/// A state's transition on one scan, with what the replay may reuse of the
/// passing of time after it.
#[derive(Debug, Clone, Copy)]
struct ScanMove {
    /// The bits the scan changed.
    changed: u32,
    /// The region before the scan.
    region: u64,
    /// The state right after the scan, before time passes.
    stepped: u32,
    /// The clocks the scan's edges restart, as bits.
    restarts: u64,
    /// The state once time has passed to the scan's end, when that follows
    /// from the move ([`Engine::region_follows`]); else [`ScanMove::OPEN`].
    settled: u32,
    /// The outcome of `settled` ([`Engine::outcome`]).
    outcome: u32,
    /// The next timer of `settled`, when known.
    timer: TimerMemo,
}

impl ScanMove {
    const OPEN: u32 = u32::MAX;
}

/// A state's transition on time passing.
#[derive(Debug, Clone, Copy)]
struct TimeMove {
    /// The region when time has passed.
    region: u64,
    /// The state then.
    state: u32,
    /// Its outcome ([`Engine::outcome`]).
    outcome: u32,
}

/// The next timer after a scan move, when the move's key (its region)
/// tells which threshold of each clock comes next: then it is the earliest
/// of at most two clocks' origins plus a threshold.
#[derive(Debug, Clone, Copy)]
struct TimerMemo {
    /// How many of `clocks`, or [`TimerMemo::OPEN`].
    count: u8,
    clocks: [u8; 2],
    after: [Time; 2],
}

impl TimerMemo {
    /// Not told by the move: read again each time.
    const OPEN: u8 = 255;

    const fn of(count: u8) -> Self {
        TimerMemo {
            count,
            clocks: [0; 2],
            after: [0; 2],
        }
    }

    /// Adds clock `c`'s next threshold `x`; `false` if full.
    fn push(&mut self, c: u8, x: Time) -> bool {
        let k = self.count as usize;
        if k >= self.clocks.len() {
            return false;
        }
        (self.clocks[k], self.after[k]) = (c, x);
        self.count += 1;
        true
    }

    /// The next timer, for clocks started at `origins`; `None` unless
    /// worked out.
    #[inline(always)]
    fn next(&self, origins: &Origins) -> Option<Time> {
        let n = self.count as usize;
        let (clocks, after) = (self.clocks.get(..n)?, self.after.get(..n)?);
        let mut next = NEVER;
        for (&c, &x) in clocks.iter().zip(after) {
            next = next.min(origins.of(usize::from(c)) + x);
        }
        Some(next)
    }
}

/// Where the move on `region` is in a table of time moves sorted by region.
#[inline(always)]
fn find_time(table: &[TimeMove], region: u64) -> Result<usize, usize> {
    // A state has a handful of transitions: a plain scan beats a binary search.
    if table.len() <= 8
        && let Some(i) = table.iter().position(|m| m.region == region)
    {
        return Ok(i);
    }
    table.binary_search_by(|m| m.region.cmp(&region))
}

/// Where the move on `key` is in a table of scan moves sorted by key.
#[inline]
fn find_scan(table: &[ScanMove], key: (u32, u64)) -> Result<usize, usize> {
    if table.len() <= 8
        && let Some(i) = table.iter().position(|m| (m.changed, m.region) == key)
    {
        return Ok(i);
    }
    table.binary_search_by(|m| (m.changed, m.region).cmp(&key))
}

/// The origin of a clock whose first edge has not been seen: its reading
/// is unknown.
pub(crate) const UNSTARTED: Time = Time::MIN;

/// No timer: time alone never changes the state.
pub(crate) const NEVER: Time = Time::MAX;

/// The bit of a state's outcome that says no mode explains the
/// observations (see [`Engine::outcome`]).
pub(crate) const UNEXPLAINED: u32 = 1 << 31;

/// Where one step of a replay leaves a part.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Step {
    /// The state.
    pub(crate) state: u32,
    /// Its next timer ([`NEVER`]: none).
    pub(crate) timer: Time,
    /// Its outcome ([`Engine::outcome`]).
    pub(crate) outcome: u32,
}

/// The reading at `t` of a clock started at `origin`.
#[inline(always)]
fn reading(origin: Time, t: Time) -> Option<Time> {
    (origin != UNSTARTED).then(|| t - origin)
}

/// Room for every clock of a part, a power of two: a clock's index, masked,
/// needs no bounds check.
const CLOCK_ROOM: usize = 64;
const _: () = assert!(MAX_CLOCKS <= CLOCK_ROOM);

/// When each clock of a part last restarted ([`UNSTARTED`]: not yet), by
/// clock index.
#[derive(Debug, Clone)]
pub(crate) struct Origins {
    at: [Time; CLOCK_ROOM],
    clocks: usize,
}

impl Origins {
    /// `clocks` clocks, none started.
    pub(crate) fn new(clocks: usize) -> Self {
        Origins {
            at: [UNSTARTED; CLOCK_ROOM],
            clocks: clocks.min(CLOCK_ROOM),
        }
    }

    /// Clock `c`'s origin.
    #[inline(always)]
    fn of(&self, c: usize) -> Time {
        self.at[c % CLOCK_ROOM]
    }

    /// Every clock unknown again.
    pub(crate) fn clear(&mut self) {
        self.at = [UNSTARTED; CLOCK_ROOM];
    }

    /// Each clock's origin, `None` while unstarted.
    pub(crate) fn to_vec(&self) -> Vec<Option<Time>> {
        self.at[..self.clocks]
            .iter()
            .map(|&o| (o != UNSTARTED).then_some(o))
            .collect()
    }

    /// `clocks` clocks with these origins, if as many are given.
    pub(crate) fn from_slice(clocks: usize, origins: &[Option<Time>]) -> Option<Self> {
        if origins.len() != clocks.min(CLOCK_ROOM) {
            return None;
        }
        let mut o = Origins::new(clocks);
        for (at, &origin) in o.at.iter_mut().zip(origins) {
            *at = origin.unwrap_or(UNSTARTED);
        }
        Some(o)
    }

    /// The readings at `t`.
    pub(crate) fn readings(&self, t: Time) -> Vec<Option<Time>> {
        let mut into = Vec::new();
        self.read_into(t, &mut into);
        into
    }

    /// The readings at `t`, into `into`.
    pub(crate) fn read_into(&self, t: Time, into: &mut Vec<Option<Time>>) {
        into.clear();
        into.extend(self.at[..self.clocks].iter().map(|&o| reading(o, t)));
    }
}

/// The clocks a scan restarted, with their origins before it: what an
/// explanation needs to read the clocks as they were before the step.
#[derive(Debug, Clone)]
pub(crate) struct Restarted {
    clocks: u64,
    before: [Time; CLOCK_ROOM],
}

impl Default for Restarted {
    fn default() -> Self {
        Restarted {
            clocks: 0,
            before: [UNSTARTED; CLOCK_ROOM],
        }
    }
}

impl Restarted {
    /// No clock restarted.
    #[inline]
    pub(crate) fn clear(&mut self) {
        self.clocks = 0;
    }

    /// Puts the restarted clocks' origins back in `origins`: the clocks as
    /// they were before the step.
    pub(crate) fn undo(&self, origins: &mut Origins) {
        let mut left = self.clocks;
        while left != 0 {
            let c = left.trailing_zeros() as usize % CLOCK_ROOM;
            origins.at[c] = self.before[c];
            left &= left - 1;
        }
    }

    /// Restarts `clocks` at `t`, keeping their origins before.
    #[inline(always)]
    fn restart(&mut self, clocks: u64, origins: &mut Origins, t: Time) {
        self.clocks = clocks;
        let mut left = clocks;
        while left != 0 {
            let c = left.trailing_zeros() as usize % CLOCK_ROOM;
            self.before[c] = origins.at[c];
            origins.at[c] = t;
            left &= left - 1;
        }
    }

    /// Puts back into `readings` (at `t`) the restarted clocks' readings
    /// before the restart.
    pub(crate) fn put_back(&self, readings: &mut [Option<Time>], t: Time) {
        let mut left = self.clocks;
        while left != 0 {
            let c = left.trailing_zeros() as usize % CLOCK_ROOM;
            readings[c] = reading(self.before[c], t);
            left &= left - 1;
        }
    }
}

impl Engine {
    /// An engine with no state yet.
    pub fn new(part: PartDiagnoser) -> Self {
        let restarts = part.restart_masks();
        debug_assert!(restarts.len() <= MAX_CLOCKS);
        Engine {
            part,
            states: Vec::new(),
            index: HashMap::new(),
            labels: Vec::new(),
            label_index: HashMap::new(),
            tables: Vec::new(),
            restarts,
        }
    }

    /// The state for the observed vector `obs` at the start of a log, closed for
    /// the clock readings (usually none known).
    pub fn initial(&mut self, obs: u32, readings: &Readings) -> u32 {
        let mut hyps = self.part.initial(obs);
        self.part.close(obs, &mut hyps, readings);
        self.intern(obs, hyps)
    }

    /// The state to start again from in the observed vector `obs` after an
    /// unexplained observation (see [`PartDiagnoser::resync`]), closed for the
    /// clock readings.
    pub fn resync(&mut self, obs: u32, readings: &Readings) -> u32 {
        let mut hyps = self.part.resync(obs);
        self.part.close(obs, &mut hyps, readings);
        self.intern(obs, hyps)
    }

    /// A state by index.
    pub fn state(&self, id: u32) -> &DiagnoserState {
        &self.states[id as usize]
    }

    /// States built so far.
    pub fn states(&self) -> &[DiagnoserState] {
        &self.states
    }

    /// Labels by index.
    pub fn labels(&self, id: u32) -> &Labels {
        &self.labels[id as usize]
    }

    /// State `id`'s labels index, with [`UNEXPLAINED`] when no mode
    /// explains the observations in it: what a replay checks after every
    /// step.
    #[inline(always)]
    pub(crate) fn outcome(&self, id: u32) -> u32 {
        self.tables[id as usize].outcome
    }

    /// Transitions computed so far (on scans, on time).
    pub fn transitions(&self) -> (usize, usize) {
        self.tables.iter().fold((0, 0), |(s, t), m| {
            (s + m.on_scan.len(), t + m.on_time.len())
        })
    }

    /// The state with these hypotheses, added if new.
    pub fn intern(&mut self, obs: u32, hyps: Vec<Hypothesis>) -> u32 {
        let key = (obs, hyps.into_boxed_slice());
        if let Some(&id) = self.index.get(&key) {
            return id;
        }
        let labels = self.compute_labels(&key.1);
        let unknown = !labels.normal && labels.modes.is_empty();
        let label_id = self.intern_labels(labels);
        let (all, timers) = self.part.thresholds(&key.1);
        let id = self.states.len() as u32;
        let thresholds: Vec<Box<[Time]>> = all.into_iter().map(Vec::into_boxed_slice).collect();
        let timers: Vec<Box<[Time]>> = timers.into_iter().map(Vec::into_boxed_slice).collect();
        self.tables
            .push(StateTable::new(&thresholds, &timers, label_id, unknown));
        self.states.push(DiagnoserState {
            obs,
            hyps: key.1.clone(),
            labels: label_id,
            thresholds,
            timers,
        });
        self.index.insert(key, id);
        id
    }

    /// The index of `labels`, added if new (a restored run's labels shown,
    /// which no state built yet may have).
    pub(crate) fn intern_labels(&mut self, labels: Labels) -> u32 {
        if let Some(&i) = self.label_index.get(&labels) {
            return i;
        }
        self.labels.push(labels.clone());
        let i = (self.labels.len() - 1) as u32;
        self.label_index.insert(labels, i);
        i
    }

    fn compute_labels(&self, hyps: &[Hypothesis]) -> Labels {
        let normal = hyps.iter().any(|h| h.mode == 0);
        if normal {
            return Labels {
                normal,
                modes: Vec::new(),
                flags: 0,
                suspects: 0,
                glitch: false,
            };
        }
        let mut modes: Vec<u16> = hyps.iter().map(|h| h.mode).collect();
        modes.sort_unstable();
        modes.dedup();
        let parts: Vec<Option<usize>> = modes
            .iter()
            .map(|&m| self.part.modes[m as usize].partition)
            .collect();
        let suspects = parts.iter().flatten().fold(0u32, |a, &p| a | 1 << p);
        let flags = match parts.first() {
            Some(Some(p)) if parts.iter().all(|q| *q == Some(*p)) => 1 << p,
            _ => 0,
        };
        Labels {
            normal,
            modes,
            flags,
            suspects,
            glitch: false,
        }
    }

    /// The region of the clock readings for state `id`: which of its thresholds
    /// they have passed.
    pub fn region(&self, id: u32, readings: &Readings) -> u64 {
        self.region_of(id, |c| readings.get(c).copied().flatten())
    }

    /// The region at `t` of the clocks started at `origins` ([`UNSTARTED`]:
    /// not yet): as [`Engine::region`] with the readings `t - origin`.
    #[inline(always)]
    pub(crate) fn region_at(&self, id: u32, origins: &Origins, t: Time) -> u64 {
        self.region_of(id, |c| reading(origins.of(c), t))
    }

    #[inline(always)]
    fn region_of(&self, id: u32, reading: impl Fn(usize) -> Option<Time>) -> u64 {
        let table = &self.tables[id as usize];
        let mut region = 0u64;
        for &span in &table.region {
            let th = table.thresholds(span);
            let idx = match reading(span.clock as usize) {
                Some(v) => passed(th, v) as u64,
                None => th.len() as u64 + 1,
            };
            region = region.wrapping_mul(th.len() as u64 + 2).wrapping_add(idx);
        }
        region
    }

    /// The state after time has passed up to `readings`.
    pub fn advance(&mut self, id: u32, readings: &Readings) -> u32 {
        let region = self.region(id, readings);
        let i = self.time_move(id, region, readings);
        self.tables[id as usize].on_time[i].state
    }

    /// A deadline of state `id` at `at` passes (or time passes to `at`), for
    /// clocks started at `origins`.
    #[inline(always)]
    pub(crate) fn fire_at(&mut self, id: u32, origins: &Origins, at: Time) -> Step {
        let region = self.region_at(id, origins, at);
        let table = &self.tables[id as usize];
        let Ok(i) = find_time(&table.on_time, region) else {
            return self.fire_new(id, region, origins, at);
        };
        let mv = table.on_time[i];
        Step {
            state: mv.state,
            timer: self.next_timer(mv.state, origins, at),
            outcome: mv.outcome,
        }
    }

    /// [`Engine::fire_at`] on a region not met before.
    #[cold]
    #[inline(never)]
    fn fire_new(&mut self, id: u32, region: u64, origins: &Origins, at: Time) -> Step {
        let i = self.time_move(id, region, &origins.readings(at));
        let mv = self.tables[id as usize].on_time[i];
        Step {
            state: mv.state,
            timer: self.next_timer(mv.state, origins, at),
            outcome: mv.outcome,
        }
    }

    /// The index of the move of state `id` on time passing to `region`
    /// (`readings`: the clocks then), computed and kept if new.
    fn time_move(&mut self, id: u32, region: u64, readings: &Readings) -> usize {
        match find_time(&self.tables[id as usize].on_time, region) {
            Ok(i) => i,
            Err(i) => {
                self.advance_new(id, region, readings, i);
                i
            }
        }
    }

    /// Computes and keeps, at `i`, a transition on time not taken before.
    #[cold]
    fn advance_new(&mut self, id: u32, region: u64, readings: &Readings, i: usize) {
        let st = &self.states[id as usize];
        let obs = st.obs;
        let mut hyps = st.hyps.to_vec();
        self.part.close(obs, &mut hyps, readings);
        let state = self.intern(obs, hyps);
        let mv = TimeMove {
            region,
            state,
            outcome: self.outcome(state),
        };
        self.tables[id as usize].on_time.insert(i, mv);
    }

    /// The next timer of state `to`, reached from state `from` at `t` by a
    /// scan move whose key is the region of `from` at `t` (the clocks
    /// `restarted` at `t` by it, with origins `origins` after), when every
    /// move with that key gives the same next thresholds: each of `to`'s
    /// timer clocks restarted, or read by `from`'s region with no timer
    /// inside the interval of that region (see [`same_place`]). Else
    /// [`TimerMemo::OPEN`].
    fn timer_memo(
        &self,
        from: u32,
        to: u32,
        restarted: u64,
        origins: &Origins,
        t: Time,
    ) -> TimerMemo {
        let (before, after) = (&self.tables[from as usize], &self.tables[to as usize]);
        let mut memo = TimerMemo::of(0);
        for &span in &after.timers {
            let th = after.thresholds(span);
            let o = origins.of(span.clock as usize);
            if restarted >> span.clock & 1 == 0 {
                let known = before.region.iter().find(|b| b.clock == span.clock);
                let Some(&known) = known else {
                    return TimerMemo::of(TimerMemo::OPEN);
                };
                if o == UNSTARTED {
                    continue;
                }
                if !same_place(before.thresholds(known), th, t - o) {
                    return TimerMemo::of(TimerMemo::OPEN);
                }
            }
            if let Some(&x) = th.get(passed(th, t - o))
                && !memo.push(span.clock as u8, x)
            {
                return TimerMemo::of(TimerMemo::OPEN);
            }
        }
        memo
    }

    /// The state after a scan that changed the observed bits `changed`;
    /// `before` are the clock readings before the scan, `after` once it has reset
    /// the clocks of its edges. `id` must already be advanced to `before`.
    pub fn scan(&mut self, id: u32, changed: u32, before: &Readings, after: &Readings) -> u32 {
        let region = self.region(id, before);
        let i = self.scan_move(id, changed, region, before);
        let stepped = self.tables[id as usize].on_scan[i].stepped;
        self.advance(stepped, after)
    }

    /// A whole scan at `t` in state `id` that changed the observed bits
    /// `changed`, for clocks started at `origins`: the scan's edges restart
    /// their clocks (in `origins`, their origins before kept in `restarted`),
    /// and time passes to `t`. Gives the state then and its next timer, as
    /// a scan, then time passing, then [`Engine::next_timer`] would, but
    /// reads again only what depends on the clocks the scan left running.
    #[inline(always)]
    pub(crate) fn scan_step(
        &mut self,
        id: u32,
        changed: u32,
        origins: &mut Origins,
        t: Time,
        restarted: &mut Restarted,
    ) -> Step {
        let region = self.region_at(id, origins, t);
        let i = match find_scan(&self.tables[id as usize].on_scan, (changed, region)) {
            Ok(i) => i,
            Err(_) => self.scan_move(id, changed, region, &origins.readings(t)),
        };
        let mv = self.tables[id as usize].on_scan[i];
        restarted.restart(mv.restarts, origins, t);
        if mv.settled == ScanMove::OPEN {
            return self.scan_settle(id, i, origins, t);
        }
        let timer = match mv.timer.next(origins) {
            Some(timer) => timer,
            None => self.next_timer(mv.settled, origins, t),
        };
        Step {
            state: mv.settled,
            timer,
            outcome: mv.outcome,
        }
    }

    /// Time passes to the end of the scan move `i` of state `id` at `t`, and
    /// what of it depends only on the restarted clocks is kept in the move.
    #[cold]
    #[inline(never)]
    fn scan_settle(&mut self, id: u32, i: usize, origins: &Origins, t: Time) -> Step {
        let mv = self.tables[id as usize].on_scan[i];
        let step = self.fire_at(mv.stepped, origins, t);
        if self.region_follows(id, mv.stepped, !mv.restarts, origins, t) {
            let timer = self.timer_memo(id, step.state, mv.restarts, origins, t);
            let kept = &mut self.tables[id as usize].on_scan[i];
            kept.settled = step.state;
            kept.outcome = step.outcome;
            kept.timer = timer;
        }
        step
    }

    /// Whether the region of `stepped` right after a scan from `id` at `t`
    /// follows from the region of `id` before it (the move's key): every
    /// clock it reads is restarted (all read 0), or left `running` and read
    /// by `id` too, with none of its thresholds inside the interval of
    /// `id`'s region that the reading lies in (the reading is the same, and
    /// where it falls among them is known). `origins` are the clocks' after
    /// the scan.
    fn region_follows(
        &self,
        id: u32,
        stepped: u32,
        running: u64,
        origins: &Origins,
        t: Time,
    ) -> bool {
        let (before, after) = (&self.tables[id as usize], &self.tables[stepped as usize]);
        if after.region_clocks & running & !before.region_clocks != 0 {
            return false;
        }
        after
            .region
            .iter()
            .filter(|span| running >> span.clock & 1 == 1)
            .all(|&span| {
                let Some(&known) = before.region.iter().find(|b| b.clock == span.clock) else {
                    return false;
                };
                reading(origins.of(span.clock as usize), t)
                    .is_none_or(|v| same_place(before.thresholds(known), after.thresholds(span), v))
            })
    }

    /// The index of the move on a scan that changed `changed` in `region`
    /// of state `id` (`before`: the readings), computed and kept if new.
    fn scan_move(&mut self, id: u32, changed: u32, region: u64, before: &Readings) -> usize {
        match find_scan(&self.tables[id as usize].on_scan, (changed, region)) {
            Ok(i) => i,
            Err(i) => {
                self.scan_new(id, changed, region, before, i);
                i
            }
        }
    }

    /// Computes and keeps, at `i`, a transition on a scan not taken before.
    #[cold]
    fn scan_new(&mut self, id: u32, changed: u32, region: u64, before: &Readings, i: usize) {
        let st = &self.states[id as usize];
        let obs = st.obs;
        let hyps = self.part.step(obs, changed, &st.hyps, before);
        let after = obs ^ changed;
        let (rises, falls) = (changed & after, changed & !after);
        let restarts = self
            .restarts
            .iter()
            .enumerate()
            .filter(|(_, (rise, fall))| rises & rise | falls & fall != 0)
            .fold(0u64, |m, (c, _)| m | 1 << c);
        let stepped = self.intern(after, hyps);
        self.tables[id as usize].on_scan.insert(
            i,
            ScanMove {
                changed,
                region,
                stepped,
                restarts,
                settled: ScanMove::OPEN,
                outcome: 0,
                timer: TimerMemo::of(TimerMemo::OPEN),
            },
        );
    }

    /// When time alone will next change state `id` ([`NEVER`]: never),
    /// given the clocks' origins ([`UNSTARTED`]: not yet observed) and the
    /// present time `now`.
    #[inline(always)]
    pub(crate) fn next_timer(&self, id: u32, origins: &Origins, now: Time) -> Time {
        let table = &self.tables[id as usize];
        let mut next = NEVER;
        for &span in &table.timers {
            let o = origins.of(span.clock as usize);
            if o == UNSTARTED {
                continue;
            }
            let th = table.thresholds(span);
            if let Some(&x) = th.get(passed(th, now - o)) {
                next = next.min(o + x);
            }
        }
        next
    }
}

#[cfg(test)]
mod tests {
    use super::same_place;

    #[test]
    fn a_threshold_outside_the_readings_interval_keeps_its_place() {
        let known = [20, 141];
        // Readings in [20, 141): 2890 and 296001 are passed by none of them.
        assert!(same_place(&known, &[2890, 2961, 296_001], 100));
        assert!(same_place(&known, &[20, 141], 100));
        // 60 lies inside [20, 141): a reading of 30 has not passed it, 100 has.
        assert!(!same_place(&known, &[60], 100));
        // Past the last threshold, any later one may or may not be passed.
        assert!(!same_place(&known, &[2890], 200));
        assert!(same_place(&known, &[141], 200));
        // Before the first: from 0 on.
        assert!(same_place(&known, &[0, 20], 5));
        assert!(!same_place(&known, &[10], 5));
    }
}
