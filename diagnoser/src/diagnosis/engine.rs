//! The diagnoser automaton of one part, built on the fly.
//!
//! Its states are sets of hypotheses (with the observed state vector); its
//! transitions are taken on an observed scan (the bits that changed) or on the
//! passing of time, and depend on the clocks only through which thresholds they
//! have passed (the *region*). Each transition is computed once, from
//! [`PartDiagnoser::step`] and [`PartDiagnoser::close`], then looked up: a
//! replay costs a region computation and one or two hash lookups per scan, and
//! the part of the automaton a log visits is exactly seed 002's diagnoser
//! (Fig. 12), states labelled with their fault labels.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use super::part::{Hypothesis, PartDiagnoser, Readings};
use crate::Time;

/// A fast hasher for the small integer keys of the transition tables.
#[derive(Default, Clone, Copy)]
pub struct IntHasher(u64);

impl Hasher for IntHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u32(&mut self, n: u32) {
        self.write_u64(u64::from(n));
    }

    fn write_u64(&mut self, n: u64) {
        self.0 = (self.0.rotate_left(26) ^ n).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

type IntMap<K, V> = HashMap<K, V, BuildHasherDefault<IntHasher>>;

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
    on_scan: IntMap<(u32, u32, u64), u32>,
    on_time: IntMap<(u32, u64), u32>,
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
            on_scan: IntMap::default(),
            on_time: IntMap::default(),
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
        (self.on_scan.len(), self.on_time.len())
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
        self.states.push(DiagnoserState {
            obs,
            hyps: key.1.clone(),
            labels: label_id,
            thresholds: all.into_iter().map(Vec::into_boxed_slice).collect(),
            timers: timers.into_iter().map(Vec::into_boxed_slice).collect(),
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
        let st = &self.states[id as usize];
        let mut region = 0u64;
        for (c, th) in st.thresholds.iter().enumerate() {
            if th.is_empty() {
                continue;
            }
            let idx = match readings.get(c).copied().flatten() {
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
        if let Some(&next) = self.on_time.get(&(id, region)) {
            return next;
        }
        let st = &self.states[id as usize];
        let obs = st.obs;
        let mut hyps = st.hyps.to_vec();
        self.part.close(obs, &mut hyps, readings);
        let next = self.intern(obs, hyps);
        self.on_time.insert((id, region), next);
        next
    }

    /// The state after a scan that changed the observed bits `changed`;
    /// `before` are the clock readings before the scan, `after` once it has reset
    /// the clocks of its edges. `id` must already be advanced to `before`.
    pub fn scan(&mut self, id: u32, changed: u32, before: &Readings, after: &Readings) -> u32 {
        let region = self.region(id, before);
        let stepped = match self.on_scan.get(&(id, changed, region)) {
            Some(&s) => s,
            None => {
                let st = &self.states[id as usize];
                let obs = st.obs;
                let hyps = self.part.step(obs, changed, &st.hyps, before);
                let s = self.intern(obs ^ changed, hyps);
                self.on_scan.insert((id, changed, region), s);
                s
            }
        };
        self.advance(stepped, after)
    }

    /// When time alone will next change state `id`, given the clocks' origins
    /// (`None`: not yet observed) and the present time `now`.
    pub fn next_timer(&self, id: u32, origins: &[Option<Time>], now: Time) -> Option<Time> {
        let st = &self.states[id as usize];
        let mut next: Option<Time> = None;
        for (c, th) in st.timers.iter().enumerate() {
            let Some(Some(o)) = origins.get(c) else {
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
