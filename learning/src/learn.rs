//! The learning pass: one streaming pass over logs builds, for every part, its
//! states, transitions, guard statistics and sensor estimates.
//!
//! Memory holds per-part statistics only (states, transitions, one histogram per
//! transition and clock), never the events themselves, so it does not grow with
//! the length of the logs.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use vocabulary::model::{
    ClockInterval, CommandEstimate, Expectation, LearnSettings, MODEL_VERSION, Model, ModelClock,
    PartModel, Provenance, SensorClass, SensorEstimate, SensorKind, SensorSchedule, StateModel,
    TransitionModel, edge_name,
};
use vocabulary::{Located, Plant, SignalKind, Time};

use crate::replay::PartRoutes;
use hist::{Distribution, Hist};
use logs::LogStream;

mod hist;

/// Settings of learning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnOptions {
    /// Absolute widening of each guard on each side; `None`: one scan period.
    pub margin: Option<Time>,
    /// Relative widening of each side, as a fraction of the learned width.
    pub margin_relative: f64,
    /// Share of samples dropped on each side before widening (outliers); 0 keeps
    /// the learned min and max.
    pub trim: f64,
    /// How many standard deviations of the drift between runs each guard
    /// covers. Runs drift (wear, temperature, supply pressure): a duration's
    /// mean differs from one log to the next. The drift is measured, as a share
    /// of each duration, over every timed transition of the plant and every log
    /// (so three logs already say much), and each guard widened so that a new
    /// run's mean within this many deviations stays inside. With a single log
    /// there is no drift to see, and no widening. 0 turns it off.
    pub drift: f64,
    /// Make the sensors that are wholly inputs (no edge caused by their part)
    /// inputs of their parts, unless the plant file gives the part's `inputs`.
    /// Sensors that are partly inputs never are: declare them by hand.
    pub learn_inputs: bool,
    /// Another edge replaces the command clock as a transition's clock when its
    /// interval is at most this fraction of the command clock's.
    pub tight_ratio: f64,
    /// A transition is timed when its best clock's spread (`q99 - q01`) is at
    /// most this, or at most `timed_relative` of its median; otherwise its timing
    /// follows something the part does not see (usually the product flow).
    pub timed_spread: Time,
    /// See `timed_spread`.
    pub timed_relative: f64,
    /// Fewest occurrences for a transition to be timed, or for another edge to
    /// be chosen as its clock: with fewer, a tight interval may be chance.
    pub min_samples: u64,
}

impl Default for LearnOptions {
    fn default() -> Self {
        LearnOptions {
            margin: None,
            margin_relative: 0.0,
            trim: 0.0,
            drift: 3.0,
            learn_inputs: false,
            tight_ratio: 0.5,
            timed_spread: vocabulary::SECOND,
            timed_relative: 0.2,
            min_samples: 20,
        }
    }
}

/// Learns part models from logs, one log after the other.
pub struct Learner<'p> {
    plant: &'p Plant,
    options: LearnOptions,
    margin: Time,
    parts: Vec<PartLearner>,
    routes: PartRoutes,
    logs: Vec<String>,
    events: u64,
    duration: Time,
}

impl<'p> Learner<'p> {
    /// A learner for the parts of `plant`.
    ///
    /// # Errors
    /// A part with more than 64 signals cannot be learned (its state would not
    /// fit a machine word); the error names it.
    pub fn new(plant: &'p Plant, options: LearnOptions) -> Result<Self, String> {
        let mut routes = PartRoutes::new(plant.signals.len());
        let mut parts = Vec::new();
        for part in &plant.parts {
            let ids: Vec<_> = part
                .actuators
                .iter()
                .chain(&part.sensors)
                .copied()
                .collect();
            if ids.len() > 64 {
                return Err(format!(
                    "part '{}' has {} signals; at most 64 can be learned",
                    part.name,
                    ids.len()
                ));
            }
            routes.add_part(ids.iter().copied());
            let names = ids
                .iter()
                .map(|&id| plant.signals.name(id).to_string())
                .collect();
            parts.push(PartLearner::new(
                part.name.clone(),
                names,
                part.actuators.len(),
            ));
        }
        let margin = options.margin.unwrap_or(plant.scan_period);
        Ok(Learner {
            plant,
            options,
            margin,
            parts,
            routes,
            logs: Vec::new(),
            events: 0,
            duration: 0,
        })
    }

    /// Reads one log to its end. `progress` is called after each batch with the
    /// number of events read so far from this log.
    pub fn learn_log(
        &mut self,
        log: LogStream,
        mut progress: impl FnMut(u64),
    ) -> Result<(), Located> {
        self.logs.push(log.path.display().to_string());
        let mut states = self.routes.states(&log.initial);
        for (part, &state) in self.parts.iter_mut().zip(&states) {
            part.start_log(self.logs.len() - 1, state);
        }
        let parts = &mut self.parts;
        let (read, last_t) = self.routes.replay(
            log.batches,
            log.start,
            &mut states,
            |t, changes| {
                for c in changes {
                    parts[c.part].transition(t, c.from, c.changed);
                }
            },
            &mut progress,
        )?;
        for part in &mut self.parts {
            part.end_log(last_t);
        }
        self.events += read;
        self.duration += last_t - log.start;
        Ok(())
    }

    /// Turns the statistics into a model.
    pub fn finish(self) -> Model {
        let unit = self.plant.time_unit;
        let scale = unit.nanos() as f64;
        let sigma = self.drift_sigma();
        let settings = LearnSettings {
            margin: self.margin as f64 / scale,
            margin_relative: self.options.margin_relative,
            trim: self.options.trim,
            drift: self.options.drift,
            drift_sigma: sigma,
        };
        let widening = Widening {
            margin: self.margin,
            drift: self.options.drift * sigma,
        };
        let parts = self
            .parts
            .iter()
            .zip(&self.plant.parts)
            .map(|(p, part)| {
                let declared = part.inputs.as_ref().map(|ids| {
                    ids.iter()
                        .map(|&s| self.plant.signals.name(s).to_string())
                        .collect()
                });
                p.model(&self.options, widening, scale, declared)
            })
            .collect();
        Model {
            version: MODEL_VERSION,
            plant: self.plant.name.clone(),
            plant_digest: Some(self.plant.learning_digest()),
            time_unit: unit,
            scan_period: self.plant.scan_period as f64 / scale,
            learned_from: Provenance {
                logs: self.logs,
                events: self.events,
                duration: self.duration as f64 / scale,
            },
            settings,
            parts,
        }
    }

    /// The drift between runs, as a relative standard deviation of a duration's
    /// mean from one log to the next: pooled over the timed transitions of every
    /// part (each weighted by its squared mean, so that long, precisely measured
    /// motions count most), 0 with fewer than two logs.
    fn drift_sigma(&self) -> f64 {
        let (mut squares, mut weight) = (0.0, 0.0);
        for acc in self.parts.iter().flat_map(|p| {
            let act = p.act_mask();
            p.trans.iter().filter(move |t| t.changed & !act != 0)
        }) {
            let h = acc.command.distribution();
            let means = h.log_means();
            if means.len() < 2 || h.n < self.options.min_samples || !h.tight(&self.options) {
                continue;
            }
            let k = means.len() as f64;
            let mean = means.iter().sum::<f64>() / k;
            squares += means.iter().map(|m| (m - mean).powi(2)).sum::<f64>();
            weight += (k - 1.0) * mean * mean;
        }
        if weight > 0.0 {
            (squares / weight).sqrt()
        } else {
            0.0
        }
    }

    /// Names of the plant's sensors that belong to no part (never learned).
    pub fn unassigned_sensors(&self) -> Vec<&str> {
        self.plant
            .signals
            .iter()
            .filter(|(id, s)| s.kind == SignalKind::Sensor && self.routes.is_unrouted(*id))
            .map(|(_, s)| s.name.as_str())
            .collect()
    }
}

// ----- statistics -----

/// A cheap hasher for small integer keys (state vectors, edge counts).
#[derive(Default)]
struct IntHasher(u64);

impl Hasher for IntHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(5) ^ u64::from(b)).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
        }
    }
    fn write_u64(&mut self, n: u64) {
        self.0 = (self.0.rotate_left(5) ^ n).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, n: i64) {
        self.write_u64(n as u64);
    }
}

type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<IntHasher>>;

/// How a learned interval is widened into a guard.
#[derive(Debug, Clone, Copy)]
struct Widening {
    /// On each side, in nanoseconds.
    margin: Time,
    /// The drift between runs to cover: relative standard deviation times the
    /// number of deviations ([`LearnOptions::drift`]).
    drift: f64,
}

#[derive(Debug, Clone)]
struct TransAcc {
    from: usize,
    to: usize,
    changed: u64,
    to_vec: u64,
    count: u64,
    command: Hist,
    /// One histogram per reference edge (bit · 2 + rising) of the part.
    refs: Vec<Hist>,
    /// The reference edges (bit `r` for `refs[r]`) that preceded every
    /// occurrence so far: the others can never be the clock, and their
    /// histograms are left alone.
    candidates: u128,
}

/// Edges of one sensor after one command, up to the next command.
#[derive(Debug, Clone, Default)]
struct EstAcc {
    episodes: u64,
    v0_ones: u64,
    /// Episodes by number of edges, in the order the numbers first came (the
    /// order of insertion into the map that [`schedule`] reads).
    counts: Vec<(usize, u64)>,
    /// For the k-th edge (k < 4): min and max time since the command.
    kth: [(Time, Time, u64); 4],
    /// Longest episode with exactly c edges (c < 4): was it cut short by the next command?
    longest_with: [Time; 4],
}

/// The time from one command to the next, as the part's sensors saw it. One
/// value per part, reused by every command: commands are frequent.
#[derive(Debug, Clone)]
struct Episode {
    /// Whether a command opened it and it has not been closed yet.
    open: bool,
    act: u64,
    t0: Time,
    /// Sensor bits at the end of the command's scan.
    v0: u64,
    /// Per sensor bit: its edge count and the times since t0 of its first
    /// edges (the first `min(count, 4)` are set).
    edges: Vec<(usize, [Time; 4])>,
}

struct PartLearner {
    name: String,
    /// Index of the log being read.
    log: usize,
    names: Vec<String>,
    n_act: usize,
    origin: Option<Time>,
    /// Last time of each edge, indexed bit · 2 + rising.
    last_edge: Vec<Option<Time>>,
    state_ids: FastMap<u64, usize>,
    /// By state id: the state vector and its visits.
    states: Vec<(u64, u64)>,
    /// By state id: the transitions out of the state, as (target vector,
    /// index in `trans`). A state has few: a scan is cheaper than hashing.
    out: Vec<Vec<(u64, usize)>>,
    /// The id of the state the part is in.
    current: usize,
    trans: Vec<TransAcc>,
    episode: Episode,
    /// Actuator states in order of first command, with their per-sensor statistics.
    est: Vec<(u64, Vec<EstAcc>)>,
}

impl PartLearner {
    fn new(name: String, names: Vec<String>, n_act: usize) -> Self {
        let n = names.len();
        PartLearner {
            name,
            log: 0,
            names,
            n_act,
            origin: None,
            last_edge: vec![None; 2 * n],
            state_ids: FastMap::default(),
            states: Vec::new(),
            out: Vec::new(),
            current: 0,
            trans: Vec::new(),
            episode: Episode {
                open: false,
                act: 0,
                t0: 0,
                v0: 0,
                edges: vec![(0, [0; 4]); n - n_act],
            },
            est: Vec::new(),
        }
    }

    fn act_mask(&self) -> u64 {
        if self.n_act >= 64 {
            u64::MAX
        } else {
            (1u64 << self.n_act) - 1
        }
    }

    fn state_id(&mut self, v: u64) -> usize {
        if let Some(&id) = self.state_ids.get(&v) {
            return id;
        }
        let id = self.states.len();
        self.states.push((v, 0));
        self.out.push(Vec::new());
        self.state_ids.insert(v, id);
        id
    }

    fn start_log(&mut self, log: usize, state: u64) {
        self.log = log;
        self.origin = None;
        self.last_edge.iter_mut().for_each(|e| *e = None);
        self.episode.open = false;
        let id = self.state_id(state);
        self.states[id].1 += 1;
        self.current = id;
    }

    fn end_log(&mut self, t: Time) {
        self.close_episode(t);
    }

    fn transition(&mut self, t: Time, from_vec: u64, changed: u64) {
        let to_vec = from_vec ^ changed;
        // The part leaves the state it is in; the lookup is for safety only.
        let from = match self.states.get(self.current) {
            Some(&(v, _)) if v == from_vec => self.current,
            _ => self.state_id(from_vec),
        };
        let idx = match self.out[from].iter().find(|&&(v, _)| v == to_vec) {
            Some(&(_, i)) => i,
            None => self.new_transition(from, from_vec, changed),
        };
        let acc = &mut self.trans[idx];
        self.current = acc.to;
        self.states[acc.to].1 += 1;
        acc.count += 1;
        if let Some(o) = self.origin {
            acc.command.add(t - o, self.log);
        }
        let mut candidates = acc.candidates;
        while candidates != 0 {
            let r = candidates.trailing_zeros() as usize;
            match self.last_edge[r] {
                Some(l) => acc.refs[r].add(t - l, self.log),
                None => acc.candidates &= !(1 << r),
            }
            candidates &= candidates - 1;
        }
        let mut bits = changed;
        while bits != 0 {
            let bit = bits.trailing_zeros() as usize;
            let rising = to_vec >> bit & 1 == 1;
            self.last_edge[2 * bit + usize::from(rising)] = Some(t);
            bits &= bits - 1;
        }
        if changed & self.act_mask() != 0 {
            self.close_episode(t);
            self.origin = Some(t);
            let (act, v0) = (to_vec & self.act_mask(), to_vec >> self.n_act);
            let ep = &mut self.episode;
            (ep.open, ep.act, ep.t0, ep.v0) = (true, act, t, v0);
            ep.edges.iter_mut().for_each(|(count, _)| *count = 0);
        } else if self.episode.open {
            let ep = &mut self.episode;
            let mut sensor_changes = changed >> self.n_act;
            while sensor_changes != 0 {
                let (count, times) = &mut ep.edges[sensor_changes.trailing_zeros() as usize];
                if *count < times.len() {
                    times[*count] = t - ep.t0;
                }
                *count += 1;
                sensor_changes &= sensor_changes - 1;
            }
        }
    }

    /// Adds the transition from state `from` (vector `from_vec`) by the edges
    /// `changed`; returns its index.
    fn new_transition(&mut self, from: usize, from_vec: u64, changed: u64) -> usize {
        let to_vec = from_vec ^ changed;
        let to = self.state_id(to_vec);
        let i = self.trans.len();
        // Only a sensor edge may take another edge as its clock.
        let (refs, candidates) = if changed & !self.act_mask() != 0 {
            let n = 2 * self.names.len();
            (vec![Hist::default(); n], u128::MAX >> (128 - n))
        } else {
            (Vec::new(), 0)
        };
        self.trans.push(TransAcc {
            from,
            to,
            changed,
            to_vec,
            count: 0,
            command: Hist::default(),
            refs,
            candidates,
        });
        self.out[from].push((to_vec, i));
        i
    }

    fn close_episode(&mut self, t: Time) {
        let ep = &mut self.episode;
        if !ep.open {
            return;
        }
        ep.open = false;
        let slot = match self.est.iter().position(|(a, _)| *a == ep.act) {
            Some(i) => i,
            None => {
                self.est
                    .push((ep.act, vec![EstAcc::default(); ep.edges.len()]));
                self.est.len() - 1
            }
        };
        let duration = t - ep.t0;
        for (s, ((count, times), acc)) in ep.edges.iter().zip(&mut self.est[slot].1).enumerate() {
            let count = *count;
            acc.episodes += 1;
            acc.v0_ones += ep.v0 >> s & 1;
            match acc.counts.iter_mut().find(|(c, _)| *c == count) {
                Some((_, n)) => *n += 1,
                None => acc.counts.push((count, 1)),
            }
            for (e, &tau) in acc.kth.iter_mut().zip(&times[..count.min(4)]) {
                if e.2 == 0 {
                    *e = (tau, tau, 1);
                } else {
                    e.0 = e.0.min(tau);
                    e.1 = e.1.max(tau);
                    e.2 += 1;
                }
            }
            if count < 4 {
                acc.longest_with[count] = acc.longest_with[count].max(duration);
            }
        }
    }

    fn event_name(&self, changed: u64, to_vec: u64) -> String {
        let mut parts = Vec::new();
        for (bit, name) in self.names.iter().enumerate() {
            if changed >> bit & 1 == 1 {
                parts.push(edge_name(name, to_vec >> bit & 1 == 1));
            }
        }
        parts.join(" ")
    }

    fn ref_name(&self, r: usize) -> String {
        let clock = ModelClock::Edge {
            signal: self.names[r / 2].clone(),
            rising: r % 2 == 1,
        };
        clock.to_string()
    }

    fn model(
        &self,
        options: &LearnOptions,
        widening: Widening,
        scale: f64,
        declared_inputs: Option<Vec<String>>,
    ) -> PartModel {
        let mut untimed = Vec::new();
        // Whether each transition keeps a regular time on its clock (for an
        // order alone: whether it is a timer of the control).
        let (mut transitions, regular): (Vec<TransitionModel>, Vec<bool>) = self
            .trans
            .iter()
            .enumerate()
            .map(|(id, acc)| self.transition_model(id, acc, options, widening, scale, &mut untimed))
            .unzip();
        // Before the rules below untime whole states: whether each transition's
        // own timing follows a clock of the part.
        let own_timing: Vec<bool> = transitions.iter().map(|t| t.timed).collect();
        let (inputs, sensor_classes) = self.sensor_classes(declared_inputs, &own_timing, options);
        self.untime_outside_edges(
            &mut transitions,
            &own_timing,
            options.min_samples,
            &mut untimed,
        );
        self.untime_reactions_beside_orders(&mut transitions);
        untime_exits_beside_product_flow(&mut transitions, self.states.len(), &mut untimed);
        let states = self.state_models(&transitions, &regular);
        let (estimates, sensor_estimates) = self.estimates(widening.margin, scale, &mut untimed);
        PartModel {
            name: self.name.clone(),
            signals: self.names.clone(),
            actuators: self.n_act,
            states,
            transitions,
            estimates,
            sensor_estimates,
            untimed,
            inputs,
            sensor_classes,
        }
    }

    /// Transition `id` as learned: its clock, guard and whether it is timed
    /// on its own, and whether it keeps a regular time on that clock. Why it is
    /// not timed goes to `untimed`.
    fn transition_model(
        &self,
        id: usize,
        acc: &TransAcc,
        options: &LearnOptions,
        widening: Widening,
        scale: f64,
        untimed: &mut Vec<String>,
    ) -> (TransitionModel, bool) {
        let event = self.event_name(acc.changed, acc.to_vec);
        let command = acc.changed & self.act_mask() != 0;
        // A sensor edge with a command in the same scan is the control
        // reacting to the plant: its timing is the sensor's, and is learned
        // when the state is left by nothing else (see below).
        let sensed = acc.changed & !self.act_mask() != 0;
        // The clock: the command clock, unless an edge of the part that
        // preceded every occurrence gives a much tighter interval.
        let command_hist = acc.command.distribution();
        let command_width = command_hist.width();
        let refs: Vec<(usize, Distribution)> = acc
            .refs
            .iter()
            .enumerate()
            .filter(|(_, h)| h.n >= options.min_samples && h.n == acc.count)
            .map(|(r, h)| (r, h.distribution()))
            .collect();
        let best_ref = refs.iter().min_by_key(|(_, h)| h.width());
        let use_ref = sensed
            && best_ref.is_some_and(|(_, h)| {
                command_hist.n < acc.count
                    || (h.width() as f64) <= options.tight_ratio * command_width as f64
            });
        let (clock, hist) = match best_ref {
            Some((r, h)) if use_ref => (self.ref_name(*r), h),
            _ => (ModelClock::Command.to_string(), &command_hist),
        };
        if hist.n == 0 {
            untimed.push(format!(
                "{event}: never preceded by a command or another edge of the part"
            ));
        }
        let guard = hist.guard(options, widening, scale);
        let tight = hist.n >= options.min_samples && hist.tight(options);
        let regular = tight && hist.light_tails(widening.margin);
        let timed = sensed && regular;
        if sensed && hist.n > 0 && hist.n < options.min_samples {
            untimed.push(format!(
                "{event}: only {} occurrence(s), too few to time",
                hist.n
            ));
        } else if sensed && tight && !timed {
            untimed.push(format!(
                "{event}: q01–q99 = {:.0}–{:.0} on its best clock ({clock}), but {:.0}–{:.0} in all: it sometimes waits for the product flow",
                guard.q01, guard.q99, guard.min, guard.max
            ));
        } else if sensed && hist.n > 0 && !timed {
            untimed.push(format!(
                "{event}: q01–q99 = {:.0}–{:.0} on its best clock ({clock}): it follows the product flow, not a command",
                guard.q01, guard.q99
            ));
        }
        let command_guard = if clock != ModelClock::Command.to_string() && command_hist.n > 0 {
            Some(command_hist.guard(options, widening, scale))
        } else {
            None
        };
        (
            TransitionModel {
                id,
                from: acc.from,
                to: acc.to,
                event,
                command,
                count: acc.count,
                clock,
                guard,
                command_guard,
                timed,
            },
            regular,
        )
    }

    /// The part's inputs and each sensor's class: as the plant file declares
    /// them, or else as the edges' timing (`own_timing`) shows.
    fn sensor_classes(
        &self,
        declared_inputs: Option<Vec<String>>,
        own_timing: &[bool],
        options: &LearnOptions,
    ) -> (Vec<String>, Vec<SensorClass>) {
        match declared_inputs {
            Some(names) => {
                let classes = self.names[self.n_act..]
                    .iter()
                    .map(|n| SensorClass {
                        sensor: n.clone(),
                        class: if names.contains(n) {
                            SensorKind::DeclaredInput
                        } else {
                            SensorKind::DeclaredDriven
                        },
                        why: String::new(),
                    })
                    .collect();
                (names, classes)
            }
            None => {
                let classes = self.classify_sensors(own_timing, options);
                let inputs = classes
                    .iter()
                    .filter(|c| options.learn_inputs && c.class == SensorKind::Input)
                    .map(|c| c.sensor.clone())
                    .collect();
                (inputs, classes)
            }
        }
    }

    /// Untimes the reactions (a sensor edge and an order in one scan) out of a
    /// state that an order alone also leaves: they are the control's choice
    /// as much as the plant's.
    fn untime_reactions_beside_orders(&self, transitions: &mut [TransitionModel]) {
        let act_mask = self.act_mask();
        let sensed =
            |t: &TransitionModel| (self.states[t.from].0 ^ self.states[t.to].0) & !act_mask != 0;
        for id in 0..self.states.len() {
            let pure_command = transitions.iter().any(|t| t.from == id && !sensed(t));
            if pure_command {
                for t in transitions.iter_mut() {
                    if t.from == id && t.command && t.timed {
                        t.timed = false;
                    }
                }
            }
        }
    }

    /// Each learned state with the events it expects by a deadline, if it has
    /// one (`regular`: whether each transition keeps a regular time).
    fn state_models(&self, transitions: &[TransitionModel], regular: &[bool]) -> Vec<StateModel> {
        let act_mask = self.act_mask();
        let sensed =
            |t: &TransitionModel| (self.states[t.from].0 ^ self.states[t.to].0) & !act_mask != 0;
        self.states
            .iter()
            .enumerate()
            .map(|(id, &(v, visits))| {
                let out: Vec<&TransitionModel> =
                    transitions.iter().filter(|t| t.from == id).collect();
                // A deadline only where every sensor event out of the state is
                // timed: otherwise the state also stands for "waiting for a
                // product", which may last any time.
                // Reactions count as sensor events where they are timed.
                let sensor_out: Vec<&&TransitionModel> = out
                    .iter()
                    .filter(|t| !t.command || (t.timed && sensed(t)))
                    .collect();
                // A control that may also leave the state by itself (a timer),
                // or react to an edge whose time follows the product (an untimed
                // reaction), may do so as late as it was seen to: the state's
                // deadline waits for that order too. An order alone at no
                // regular time waits for something outside the part (the next
                // machine, a workpiece upstream), for as long as that takes:
                // the state has no deadline.
                let timeouts = out.iter().filter(|t| t.command && (!sensed(t) || !t.timed));
                let waits = out
                    .iter()
                    .any(|t| t.command && !sensed(t) && !regular[t.id]);
                let expected =
                    if !waits && sensor_out.iter().all(|t| t.timed) && !sensor_out.is_empty() {
                        sensor_out
                            .iter()
                            .copied()
                            .chain(timeouts)
                            .map(|t| Expectation {
                                transition: t.id,
                                event: t.event.clone(),
                                clock: t.clock.clone(),
                                by: t.guard.hi,
                            })
                            .collect()
                    } else {
                        Vec::new()
                    };
                StateModel {
                    id,
                    values: (0..self.names.len()).map(|b| v >> b & 1 == 1).collect(),
                    visits,
                    stable: sensor_out.is_empty(),
                    expected,
                }
            })
            .collect()
    }

    /// How many times the sensor at `bit` rose (`rising`) or fell, and how
    /// many of those followed a clock of the part (`own_timing`, by transition).
    fn edge_timing(&self, bit: usize, rising: bool, own_timing: &[bool]) -> (u64, u64) {
        let (mut seen, mut timed) = (0u64, 0u64);
        for (acc, &own) in self.trans.iter().zip(own_timing) {
            if acc.changed >> bit & 1 == 1 && (acc.to_vec >> bit & 1 == 1) == rising {
                seen += acc.count;
                if own {
                    timed += acc.count;
                }
            }
        }
        (seen, timed)
    }

    /// Untimes the transitions whose sensor edges all come, in most of their
    /// occurrences or in enough of them to judge (`min_samples`), at no
    /// regular time on any clock of the part: such an edge is the product
    /// flow's (a workpiece arriving), and where it came regularly in the
    /// learning logs, that regularity was the flow's too (an upstream machine
    /// that had a workpiece ready), which the part cannot promise. A late or
    /// early one may be one of those that came from outside (a magazine
    /// refilled just then).
    fn untime_outside_edges(
        &self,
        transitions: &mut [TransitionModel],
        own_timing: &[bool],
        min_samples: u64,
        untimed: &mut Vec<String>,
    ) {
        let act_mask = self.act_mask();
        let outside = |bit: usize, rising: bool| {
            let (seen, timed) = self.edge_timing(bit, rising, own_timing);
            timed * 2 < seen || seen - timed >= min_samples
        };
        for (t, acc) in transitions.iter_mut().zip(&self.trans) {
            let sensed = acc.changed & !act_mask;
            if !t.timed || sensed == 0 {
                continue;
            }
            let all_outside = (0..self.names.len())
                .filter(|&b| sensed >> b & 1 == 1)
                .all(|b| outside(b, acc.to_vec >> b & 1 == 1));
            if all_outside {
                t.timed = false;
                untimed.push(format!(
                    "{}: its edges often follow no clock of the part: it follows the product flow",
                    t.event
                ));
            }
        }
    }

    /// How each sensor of the part looks in the logs. For each edge (rises,
    /// falls) seen often enough to judge, it is *caused* when more than one in
    /// ten of its occurrences follow a clock of the part (a timed transition),
    /// else it comes from outside the part's motion: an operator, a workpiece,
    /// another machine. A sensor with no caused edge is an input; one with both
    /// kinds (a place sensor: a workpiece arrives when it comes, and leaves when
    /// the part takes it) is partly one.
    fn classify_sensors(&self, own_timing: &[bool], options: &LearnOptions) -> Vec<SensorClass> {
        let mut classes = Vec::new();
        for bit in self.n_act..self.names.len() {
            let (mut outside, mut caused) = (Vec::new(), Vec::new());
            for rising in [true, false] {
                let (seen, timed) = self.edge_timing(bit, rising, own_timing);
                let edge = if rising { "rises" } else { "falls" };
                let text = format!("{timed} of {seen} {edge}");
                if seen >= options.min_samples && timed * 10 <= seen {
                    outside.push(text);
                } else if seen > 0 {
                    caused.push(text);
                }
            }
            let (class, why) = match (outside.is_empty(), caused.is_empty()) {
                (false, true) => (
                    SensorKind::Input,
                    format!(
                        "{} follow a clock of the part: an operator, a workpiece or another machine moves it",
                        outside.join(", ")
                    ),
                ),
                (false, false) => (
                    SensorKind::PartlyInput,
                    format!(
                        "{} follow a clock of the part, but {} do",
                        outside.join(", "),
                        caused.join(", ")
                    ),
                ),
                (true, true) => (SensorKind::Driven, "it never changed".to_string()),
                (true, false) => (
                    SensorKind::Driven,
                    format!("{} follow a clock of the part", caused.join(", ")),
                ),
            };
            classes.push(SensorClass {
                sensor: self.names[bit].clone(),
                class,
                why,
            });
        }
        classes
    }

    fn estimates(
        &self,
        margin: Time,
        scale: f64,
        untimed: &mut Vec<String>,
    ) -> (Vec<CommandEstimate>, Vec<SensorEstimate>) {
        let sensors = self.names.len() - self.n_act;
        let mut estimates = Vec::new();
        // Per sensor: (interval name, value) over all actuator states.
        let mut per_sensor: Vec<Vec<(String, &'static str)>> = vec![Vec::new(); sensors];
        let mut estimable = vec![true; sensors];
        // Whether the sensor changed after some command: one that never did
        // (a limit switch never reached while learning) has no temporal
        // estimate, and the filter reads it as possibly anything.
        let mut moved = vec![false; sensors];
        let mut next_name = 1;
        for (act, accs) in &self.est {
            // Each estimable sensor: initial value, then uncertain windows.
            let mut schedules: Vec<Option<Schedule>> = Vec::new();
            for (s, acc) in accs.iter().enumerate() {
                let sensor = &self.names[self.n_act + s];
                let actuators = self.act_label(*act);
                match schedule(acc) {
                    Ok(sched) => schedules.push(Some(sched)),
                    Err(why) => {
                        if estimable[s] {
                            untimed.push(format!("estimate of {sensor} after {actuators}: {why}"));
                        }
                        estimable[s] = false;
                        schedules.push(None);
                    }
                }
            }
            let mut cuts: Vec<Time> = Vec::new();
            for (_, windows) in schedules.iter().flatten() {
                for &(a, b) in windows {
                    cuts.push((a - margin).max(0));
                    cuts.push(b + margin + 1);
                }
            }
            cuts.retain(|&c| c > 0);
            cuts.sort_unstable();
            cuts.dedup();
            let mut bounds = vec![0];
            bounds.extend(cuts);
            let intervals: Vec<ClockInterval> = bounds
                .iter()
                .enumerate()
                .map(|(i, &from)| {
                    let name = format!("I{}", next_name + i);
                    ClockInterval {
                        name,
                        from: from as f64 / scale,
                        to: bounds.get(i + 1).map(|&to| to as f64 / scale),
                    }
                })
                .collect();
            next_name += intervals.len();
            let mut sensor_rows = Vec::new();
            for (s, sched) in schedules.iter().enumerate() {
                let Some((v0, windows)) = sched else { continue };
                moved[s] |= !windows.is_empty();
                let values: Vec<&'static str> = bounds
                    .iter()
                    .map(|&from| {
                        let mut v = *v0;
                        for &(a, b) in windows {
                            let (a, b) = ((a - margin).max(0), b + margin + 1);
                            if from >= a && from < b {
                                return "uncertain";
                            }
                            if from >= b {
                                v = !v;
                            }
                        }
                        if v { "1" } else { "0" }
                    })
                    .collect();
                for (iv, v) in intervals.iter().zip(&values) {
                    per_sensor[s].push((iv.name.clone(), v));
                }
                sensor_rows.push(SensorSchedule {
                    sensor: self.names[self.n_act + s].clone(),
                    values: values.iter().map(|v| v.to_string()).collect(),
                });
            }
            estimates.push(CommandEstimate {
                actuators: self.act_label(*act),
                intervals,
                sensors: sensor_rows,
            });
        }
        for s in (0..sensors).filter(|&s| estimable[s] && !moved[s]) {
            untimed.push(format!(
                "estimate of {}: it never changed after a command in the logs",
                self.names[self.n_act + s]
            ));
        }
        let sensor_estimates = (0..sensors)
            .filter(|&s| estimable[s] && moved[s] && !per_sensor[s].is_empty())
            .map(|s| {
                let ones: Vec<&str> = per_sensor[s]
                    .iter()
                    .filter(|(_, v)| *v != "0")
                    .map(|(n, _)| n.as_str())
                    .collect();
                SensorEstimate {
                    sensor: self.names[self.n_act + s].clone(),
                    expr: if ones.is_empty() {
                        "0".to_string()
                    } else {
                        ones.join(" | ")
                    },
                    uncertain: per_sensor[s]
                        .iter()
                        .filter(|(_, v)| *v == "uncertain")
                        .map(|(n, _)| n.clone())
                        .collect(),
                }
            })
            .collect();
        (estimates, sensor_estimates)
    }

    fn act_label(&self, act: u64) -> String {
        (0..self.n_act)
            .map(|b| format!("{}={}", self.names[b], act >> b & 1))
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// A sensor's value at a command, and the windows of the command clock in which
/// each of its following edges came.
type Schedule = (bool, Vec<(Time, Time)>);

/// A sensor's behaviour after one actuator state is commanded: its initial value
/// and, for each of its edges, the window of the command clock in which it came.
/// Fails (with the reason) when episodes disagree: the sensor then follows
/// something other than the command.
fn schedule(acc: &EstAcc) -> Result<Schedule, String> {
    if acc.episodes == 0 {
        return Err("never commanded".into());
    }
    // Which disagreement is reported follows the order of a map filled one
    // number at a time, as they first came (no capacity reserved ahead).
    let mut counts: FastMap<usize, u64> = FastMap::default();
    for &(c, n) in &acc.counts {
        counts.insert(c, n);
    }
    if acc.v0_ones != 0 && acc.v0_ones != acc.episodes {
        return Err(format!(
            "its value at the command varies ({} of {} episodes at 1)",
            acc.v0_ones, acc.episodes
        ));
    }
    let (&k, _) = counts
        .iter()
        .max_by_key(|&(&c, &n)| (n, std::cmp::Reverse(c)))
        .ok_or("no episode")?;
    if k >= 4 {
        return Err(format!("it changes {k} times per command"));
    }
    for (&c, &n) in &counts {
        if c > k || (c < k && c < 4 && acc.longest_with[c] >= acc.kth[c].0) {
            return Err(format!(
                "the number of its edges per command varies ({n} of {} episodes with {c} instead of {k}): it follows the product flow",
                acc.episodes
            ));
        }
    }
    let windows: Vec<(Time, Time)> = acc.kth[..k].iter().map(|&(a, b, _)| (a, b)).collect();
    if windows.windows(2).any(|w| w[0].1 >= w[1].0) {
        return Err("its edge windows overlap".into());
    }
    Ok((acc.v0_ones > 0, windows))
}

/// Untimes every exit of a state that an untimed event may also leave: such a
/// state also stands for "waiting for the product", and the time of its other
/// exits depends on the product too.
fn untime_exits_beside_product_flow(
    transitions: &mut [TransitionModel],
    states: usize,
    untimed: &mut Vec<String>,
) {
    for id in 0..states {
        let exits: Vec<usize> = transitions
            .iter()
            .filter(|t| t.from == id && (!t.command || t.timed))
            .map(|t| t.id)
            .collect();
        if exits.iter().any(|&i| !transitions[i].timed) {
            for i in exits {
                if transitions[i].timed {
                    transitions[i].timed = false;
                    untimed.push(format!(
                        "{}: leaves a state that is also left by untimed events (the product flow)",
                        transitions[i].event
                    ));
                }
            }
        }
    }
}
