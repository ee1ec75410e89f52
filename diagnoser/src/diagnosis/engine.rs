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
//! The replay's hot path ([`Engine::scan_at`], [`Engine::advance_at`],
//! [`Engine::next_timer`]) reads the clocks from their origins and the present
//! time, and finds a state's transitions in the state's own sorted table: no
//! hashing and no allocation once the transition is known.

use std::collections::HashMap;

use super::part::{Hypothesis, PartDiagnoser, Readings};
use crate::Time;

/// What a set of hypotheses says: the verdict's ingredients.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
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
    /// Per state, the clocks its region reads and its timers, flattened.
    clocking: Vec<Clocking>,
    /// Per state, its transitions computed so far.
    moves: Vec<Moves>,
}

/// A state's thresholds in the form the replay reads them: only the clocks
/// that have any, each with its slice of one flat array.
#[derive(Debug, Clone, Default)]
struct Clocking {
    /// Per clock with thresholds: the clock, and how many thresholds it has.
    region: Box<[(u16, u16)]>,
    /// The thresholds of `region`, clock after clock.
    region_at: Box<[Time]>,
    /// Per clock with timers: the clock, and how many.
    timers: Box<[(u16, u16)]>,
    /// The timers of `timers`, clock after clock.
    timers_at: Box<[Time]>,
}

impl Clocking {
    fn new(thresholds: &[Box<[Time]>], timers: &[Box<[Time]>]) -> Self {
        let flatten = |per_clock: &[Box<[Time]>]| {
            let clocks: Box<[(u16, u16)]> = per_clock
                .iter()
                .enumerate()
                .filter(|(_, th)| !th.is_empty())
                .map(|(c, th)| (c as u16, th.len() as u16))
                .collect();
            let flat: Box<[Time]> = per_clock.iter().flat_map(|th| th.iter().copied()).collect();
            (clocks, flat)
        };
        let (region, region_at) = flatten(thresholds);
        let (timers, timers_at) = flatten(timers);
        Clocking {
            region,
            region_at,
            timers,
            timers_at,
        }
    }
}

/// A state's transitions, each sorted by its key for a binary search: most
/// states have a handful.
#[derive(Debug, Clone, Default)]
struct Moves {
    /// (changed bits, region before the scan) to the state after the scan.
    on_scan: Vec<((u32, u64), u32)>,
    /// Region to the state after time has passed.
    on_time: Vec<(u64, u32)>,
}

/// The value for `key` in a table sorted by key.
#[inline]
fn find<K: Ord + Copy>(table: &[(K, u32)], key: K) -> Option<u32> {
    // A state has a handful of transitions: a plain scan beats a binary search.
    if table.len() <= 8 {
        return table.iter().find(|(k, _)| *k == key).map(|&(_, v)| v);
    }
    table
        .binary_search_by(|(k, _)| k.cmp(&key))
        .ok()
        .map(|i| table[i].1)
}

/// Adds `key` to a table sorted by key.
fn insert<K: Ord + Copy>(table: &mut Vec<(K, u32)>, key: K, value: u32) {
    if let Err(i) = table.binary_search_by(|(k, _)| k.cmp(&key)) {
        table.insert(i, (key, value));
    }
}

/// The readings at `t` of clocks started at `origins`.
fn readings_at(origins: &[Option<Time>], t: Time) -> Vec<Option<Time>> {
    origins.iter().map(|o| o.map(|o| t - o)).collect()
}

impl Engine {
    /// An engine with no state yet.
    pub fn new(part: PartDiagnoser) -> Self {
        Engine {
            part,
            states: Vec::new(),
            index: HashMap::new(),
            labels: Vec::new(),
            label_index: HashMap::new(),
            clocking: Vec::new(),
            moves: Vec::new(),
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

    /// Transitions computed so far (on scans, on time).
    pub fn transitions(&self) -> (usize, usize) {
        self.moves.iter().fold((0, 0), |(s, t), m| {
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
        let label_id = match self.label_index.get(&labels) {
            Some(&i) => i,
            None => {
                self.labels.push(labels.clone());
                let i = (self.labels.len() - 1) as u32;
                self.label_index.insert(labels, i);
                i
            }
        };
        let (all, timers) = self.part.thresholds(&key.1);
        let id = self.states.len() as u32;
        let thresholds: Vec<Box<[Time]>> = all.into_iter().map(Vec::into_boxed_slice).collect();
        let timers: Vec<Box<[Time]>> = timers.into_iter().map(Vec::into_boxed_slice).collect();
        self.clocking.push(Clocking::new(&thresholds, &timers));
        self.moves.push(Moves::default());
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

    fn compute_labels(&self, hyps: &[Hypothesis]) -> Labels {
        let normal = hyps.iter().any(|h| h.mode == 0);
        if normal {
            return Labels {
                normal,
                modes: Vec::new(),
                flags: 0,
                suspects: 0,
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
        }
    }

    /// The region of the clock readings for state `id`: which of its thresholds
    /// they have passed.
    pub fn region(&self, id: u32, readings: &Readings) -> u64 {
        self.region_of(id, |c| readings.get(c).copied().flatten())
    }

    /// The region at `t` of the clocks started at `origins`: as
    /// [`Engine::region`] with the readings `t - origin`.
    #[inline]
    pub fn region_at(&self, id: u32, origins: &[Option<Time>], t: Time) -> u64 {
        self.region_of(id, |c| origins.get(c).copied().flatten().map(|o| t - o))
    }

    #[inline]
    fn region_of(&self, id: u32, reading: impl Fn(usize) -> Option<Time>) -> u64 {
        let clocking = &self.clocking[id as usize];
        let mut region = 0u64;
        let mut from = 0;
        for &(c, n) in &clocking.region {
            let th = &clocking.region_at[from..from + n as usize];
            from += n as usize;
            let idx = match reading(c as usize) {
                Some(v) => th.partition_point(|&x| x <= v) as u64,
                None => th.len() as u64 + 1,
            };
            region = region.wrapping_mul(th.len() as u64 + 2).wrapping_add(idx);
        }
        region
    }

    /// The state after time has passed up to `readings`.
    pub fn advance(&mut self, id: u32, readings: &Readings) -> u32 {
        let region = self.region(id, readings);
        match find(&self.moves[id as usize].on_time, region) {
            Some(next) => next,
            None => self.advance_new(id, region, readings),
        }
    }

    /// The state after time has passed up to `t`, for clocks started at
    /// `origins`: as [`Engine::advance`] with the readings `t - origin`.
    #[inline]
    pub fn advance_at(&mut self, id: u32, origins: &[Option<Time>], t: Time) -> u32 {
        let region = self.region_at(id, origins, t);
        match find(&self.moves[id as usize].on_time, region) {
            Some(next) => next,
            None => self.advance_new(id, region, &readings_at(origins, t)),
        }
    }

    /// Computes and keeps a transition on time not taken before.
    #[cold]
    fn advance_new(&mut self, id: u32, region: u64, readings: &Readings) -> u32 {
        let st = &self.states[id as usize];
        let obs = st.obs;
        let mut hyps = st.hyps.to_vec();
        self.part.close(obs, &mut hyps, readings);
        let next = self.intern(obs, hyps);
        insert(&mut self.moves[id as usize].on_time, region, next);
        next
    }

    /// The state after a scan that changed the observed bits `changed`;
    /// `before` are the clock readings before the scan, `after` once it has reset
    /// the clocks of its edges. `id` must already be advanced to `before`.
    pub fn scan(&mut self, id: u32, changed: u32, before: &Readings, after: &Readings) -> u32 {
        let region = self.region(id, before);
        let stepped = match find(&self.moves[id as usize].on_scan, (changed, region)) {
            Some(s) => s,
            None => self.scan_new(id, changed, region, before),
        };
        self.advance(stepped, after)
    }

    /// The state right after a scan at `t` that changed the observed bits
    /// `changed`, for clocks started at `origins` before the scan: as
    /// [`Engine::scan`] before time passes. [`Engine::advance_at`] with the
    /// origins the scan's edges restarted completes it.
    #[inline]
    pub fn scan_at(&mut self, id: u32, changed: u32, origins: &[Option<Time>], t: Time) -> u32 {
        let region = self.region_at(id, origins, t);
        match find(&self.moves[id as usize].on_scan, (changed, region)) {
            Some(s) => s,
            None => self.scan_new(id, changed, region, &readings_at(origins, t)),
        }
    }

    /// Computes and keeps a transition on a scan not taken before.
    #[cold]
    fn scan_new(&mut self, id: u32, changed: u32, region: u64, before: &Readings) -> u32 {
        let st = &self.states[id as usize];
        let obs = st.obs;
        let hyps = self.part.step(obs, changed, &st.hyps, before);
        let s = self.intern(obs ^ changed, hyps);
        insert(&mut self.moves[id as usize].on_scan, (changed, region), s);
        s
    }

    /// When time alone will next change state `id`, given the clocks' origins
    /// (`None`: not yet observed) and the present time `now`.
    #[inline]
    pub fn next_timer(&self, id: u32, origins: &[Option<Time>], now: Time) -> Option<Time> {
        let clocking = &self.clocking[id as usize];
        let mut next: Option<Time> = None;
        let mut from = 0;
        for &(c, n) in &clocking.timers {
            let th = &clocking.timers_at[from..from + n as usize];
            from += n as usize;
            let Some(Some(o)) = origins.get(c as usize) else {
                continue;
            };
            let v = now - o;
            let i = th.partition_point(|&x| x <= v);
            if let Some(&x) = th.get(i) {
                let at = o + x;
                next = Some(next.map_or(at, |n: Time| n.min(at)));
            }
        }
        next
    }
}
