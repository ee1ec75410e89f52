//! One part's diagnoser: its fault modes, built from the plant's fault templates
//! over the learned model of the part, and the semantics of its hypotheses.
//!
//! A *hypothesis* is a fault mode (normal, or one fault of the part) with the
//! part's physical state in that mode. Under a fault the physical state and the
//! observed one may differ: a stuck sensor reads its stuck value whatever the
//! plant does, a stuck actuator ignores its orders. The physical state follows the
//! learned model's transitions, with their interval guards; the observed one is
//! what the log shows. A diagnoser tracks the set of hypotheses consistent with
//! everything observed, including the passing of time: a state the model says must
//! be left by a deadline is no longer possible once the deadline has passed.
//!
//! Fault onsets are unobservable and may come at any moment (seed 002: a single
//! permanent fault per part), so every fault mode that could have begun silently
//! is carried along as a *shadow* of the normal hypothesis. The verdict is normal
//! as long as the normal hypothesis survives; when it dies, the remaining modes are
//! the candidate labels. Carrying the shadows from the start, rather than guessing
//! the onset when the normal hypothesis dies, is what makes the labels sound: the
//! true fault is never excluded, whenever it began.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use crate::fault::{Factor, FaultTemplate};
use crate::model::{ModelClock, PartModel, SensorKind, edge_name};
use crate::plant::{Part, Plant};
use crate::{SignalId, Time, TimeUnit};

/// Most signals a part may have: states are bit vectors of this width.
pub const MAX_PART_SIGNALS: usize = 16;

/// A clock a guard or a deadline is measured on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Clock {
    /// Time since the part's last actuator edge.
    Command,
    /// Time since the last edge of one of the part's signals, e.g. `FE(C1)`.
    Edge {
        /// Bit of the signal in the part's state vector.
        bit: u8,
        /// Rising (`RE`) or falling (`FE`) edge.
        rising: bool,
    },
}

/// One transition of the learned model, in the form the diagnoser runs.
#[derive(Debug, Clone, Copy)]
pub struct Move {
    /// Index of the transition in the model.
    pub id: usize,
    /// Bits of the part's state vector that change.
    pub changed: u32,
    /// Whether an actuator edge is among them.
    pub command: bool,
    /// Index of the guard's clock in [`PartDiagnoser::clocks`].
    pub clock: u8,
    /// Earliest clock reading, in nanoseconds.
    pub lo: Time,
    /// Latest clock reading, in nanoseconds.
    pub hi: Time,
    /// Whether the guard is enforced (untimed transitions follow the product flow).
    pub timed: bool,
    /// Whether the move was learned in another state and lent to this one
    /// (see `borrow_moves` and `lend_outside_edges`).
    pub lent: bool,
}

/// How a fault mode transforms the part's normal behaviour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModeKind {
    /// No fault.
    Normal,
    /// The sensor at `bit` reads `value` whatever the plant does; its real edges
    /// are hidden.
    SensorStuck {
        /// Bit of the sensor.
        bit: u8,
        /// The value it reads.
        value: bool,
    },
    /// The sensor at `bit` takes `value` when the plant does not explain it, then
    /// goes back to the real value (seed 002's unexpected rise and fall).
    Glitch {
        /// Bit of the sensor.
        bit: u8,
        /// The unexpected value: 1 for a rise, 0 for a fall.
        value: bool,
    },
    /// The actuator at `bit` stays at `value` whatever its order.
    ActuatorStuck {
        /// Bit of the actuator.
        bit: u8,
        /// The value it keeps.
        value: bool,
    },
    /// The element cannot leave the position of the sensor at `bit`: once there,
    /// the sensors it drives no longer change.
    BlockedAt {
        /// Bit of the position's sensor.
        bit: u8,
        /// Bits of the sensors the element drives (the plant file's `drives`).
        drives: u32,
    },
    /// The element stops in transit from the position of `from` to that of `to`:
    /// once it has left `from` towards `to`, the sensors it drives no longer change.
    BlockedBetween {
        /// Bit of the sensor of the position it leaves.
        from: u8,
        /// Bit of the sensor of the position it never reaches.
        to: u8,
        /// Bits of the sensors the element drives.
        drives: u32,
    },
    /// The motions of an element or of what an actuator drives take longer,
    /// by an unknown factor up to [`Factor::MAX`], from an unobserved onset
    /// on: their edges come in the learned order, no sooner than learned, and
    /// up to that factor later.
    Slow {
        /// Bits of the sensors whose rising edges end or mark such a motion.
        rises: u32,
        /// Bits of the sensors whose falling edges do.
        falls: u32,
    },
}

/// A fault mode of a part (or its normal mode).
#[derive(Debug, Clone)]
pub struct Mode {
    /// The label reported: `N`, or the fault's label from the plant file (`F2`).
    pub label: String,
    /// The fault's template, `None` for the normal mode.
    pub template: Option<FaultTemplate>,
    /// How the mode changes the part's behaviour.
    pub kind: ModeKind,
    /// Index of the fault's partition in [`PartDiagnoser::partitions`].
    pub partition: Option<usize>,
}

/// A hypothesis: a mode and the part's physical state in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Hypothesis {
    /// Index in [`PartDiagnoser::modes`] (0 is normal).
    pub mode: u16,
    /// [`Hypothesis::GLITCH`], [`Hypothesis::UNTIMED`], [`Hypothesis::STARTED`],
    /// [`Hypothesis::SOONER`], [`Hypothesis::UNSEEN`] and [`Hypothesis::LATE`].
    pub flags: u8,
    /// While a glitch shows: [`Hypothesis::SEEN`] if it began with an observed
    /// edge, else the model transition it hid as it began (its deadline counts
    /// from that transition's window). 0 otherwise.
    pub since: u16,
    /// The physical state vector (bit `i`: the part's `i`-th signal).
    pub phys: u32,
}

impl Hypothesis {
    /// A glitch mode's sensor currently shows its unexpected value.
    pub const GLITCH: u8 = 1;
    /// The clocks no longer say when the physical state was entered (a stuck
    /// actuator moved the part at an unobserved moment), so guards and deadlines
    /// are not enforced for this hypothesis.
    pub const UNTIMED: u8 = 2;
    /// The control has just given an order the model never saw it give in
    /// this physical state (a fault misled it, e.g. a pulse withdrawn one scan
    /// after it began): the motion that order started may still show its first
    /// edge. Holds until the part's next scan.
    pub const STARTED: u8 = 4;
    /// The control has given an order in transit that the model never saw it
    /// give there alone, so the element may have turned in mid-stroke: its
    /// motions may end sooner than learned, never later. Guards' lower bounds
    /// are not enforced, their upper bounds and deadlines are. Holds until a
    /// sensor edge of the model dates the element again.
    pub const SOONER: u8 = 8;
    /// The hypothesis reached its state from one the model never saw, or by
    /// edges the model's moves do not explain (a blocked element holds a
    /// state where the normal plant only passes; a slide left half-way home
    /// is sent out again): the model may know the state, but not with the
    /// element where it is. The sensors the element does not drive are left
    /// to themselves (see [`PartDiagnoser::astray`]). Holds until a sensor
    /// edge of the model dates the element again.
    pub const UNSEEN: u8 = 16;
    /// A glitch held back a real edge the control waits for, and has just
    /// let it show, with the control's reaction: the reaction came late, and
    /// the element went on meanwhile (to the end of its stroke), so its next
    /// motion may take up to a glitch's longest showing more than learned. Upper bounds and
    /// deadlines are pushed back by that much. Holds until a sensor edge of
    /// the model dates the element again.
    pub const LATE: u8 = 32;
    /// The flags that hold until a sensor edge of the model dates the
    /// element again.
    pub const UNDATED: u8 = Self::SOONER | Self::UNSEEN | Self::LATE;

    /// [`Hypothesis::since`] of a glitch that began with an observed edge.
    pub const SEEN: u16 = u16::MAX;

    fn normal(phys: u32) -> Self {
        Hypothesis {
            mode: 0,
            flags: 0,
            since: 0,
            phys,
        }
    }

    fn has(self, flag: u8) -> bool {
        self.flags & flag != 0
    }
}

/// Clock readings in nanoseconds, indexed like [`PartDiagnoser::clocks`]; `None`
/// while the clock's origin has not been observed.
pub type Readings = [Option<Time>];

/// The static diagnoser of one part: its model in runnable form and its modes.
#[derive(Debug, Clone)]
pub struct PartDiagnoser {
    /// Part name.
    pub name: String,
    /// The part's signals, actuators first (the bits of every state vector).
    pub signals: Vec<SignalId>,
    /// Their names.
    pub names: Vec<String>,
    /// How many of `signals` are actuators.
    pub actuators: usize,
    /// The clocks guards are measured on (index 0 is the command clock).
    pub clocks: Vec<Clock>,
    /// Mode 0 is normal; then one mode per fault of the part.
    pub modes: Vec<Mode>,
    /// Names of the partitions the part's faults belong to (flags `def_<name>`).
    pub partitions: Vec<String>,
    act_mask: u32,
    /// Bits of the part's input sensors: edges that no order causes, allowed in
    /// any state, and not part of the motion state.
    inputs: u32,
    /// Bits of the sensors learning found moved from outside the part (see
    /// `loose_mask`): the control's reaction to their edges may wait for
    /// conditions outside the part.
    loose: u32,
    /// The changes of the model's reactions (orders with sensor edges), each once.
    reactions: Vec<u32>,
    /// Bits of the sensors that no element of the part holds in place: all
    /// of them on a part without an element (a belt), else `undriven`.
    free: u32,
    /// Each learned set of edges of `free` sensors with the state it was
    /// learned in, as (the state's other bits, edge bits, the edge bits'
    /// values before), each once: what the product flow can do with the
    /// actuators and the element where they are.
    free_edges: Vec<(u32, u32, u32)>,
    /// Bits of the sensors that the part's element does not drive, when the
    /// plant file says which it drives (`drives`), its inputs apart; else 0.
    undriven: u32,
    /// Per motion state, the other motion states that differ from it only in
    /// `undriven` bits.
    kin: Vec<Vec<usize>>,
    /// Motion state of each known motion vector (a state vector without its
    /// inputs' bits).
    states: HashMap<u32, usize>,
    /// The state vector of each model state.
    vectors: Vec<u32>,
    /// Transitions out of each model state.
    moves: Vec<Vec<Move>>,
    /// Per model state, indices in `moves[state]` of the sensor events that must
    /// come (the state must be left by the last of their deadlines).
    expected: Vec<Vec<usize>>,
    /// Event names of the model's transitions, by model transition index.
    events: Vec<String>,
    /// Clock, upper bound and timedness of each model transition, by index.
    windows: Vec<(u8, Time, bool)>,
    /// Longest an unexpected edge (a glitch) shows before the sensor reads its
    /// real value again, in nanoseconds.
    glitch_max: Time,
    /// Per clock, the latest lower bound of a timed transition guarded by it:
    /// past it on every clock, [`Hypothesis::SOONER`] changes nothing.
    latest_lo: Vec<Time>,
    /// Whether an order given in transit may turn the element in mid-stroke
    /// ([`Hypothesis::SOONER`]), and a withdrawn order's first edge is read on
    /// any clock (see [`Self::started_motion`]).
    reversals: bool,
    /// Whether the control's reaction to a sensor edge may come later than
    /// the edge, whatever the sensor (see [`Self::with_held_reactions`]).
    held_reactions: bool,
}

/// Why a part's diagnoser cannot be built.
pub type BuildError = String;

impl PartDiagnoser {
    /// Builds the diagnoser of `part` from its learned `model` and the faults of
    /// `plant` that concern it. `unit` is the model's time unit.
    /// `glitch_max` bounds how long an unexpected edge shows (nanoseconds).
    pub fn build(
        plant: &Plant,
        part: &Part,
        model: &PartModel,
        unit: TimeUnit,
        glitch_max: Time,
    ) -> Result<PartDiagnoser, BuildError> {
        let (signals, names) = part_signals(plant, part, model)?;
        let bit_of = |name: &str| names.iter().position(|n| n == name).map(|b| b as u8);
        let act_mask = (1u32 << part.actuators.len()) - 1;
        let mut clocks = ClockTable::new(&part.name);
        let inputs = input_mask(plant, part, model, &bit_of);
        // The model's states as learned (`learned`), and the motion states the
        // diagnoser runs on: the learned ones with the inputs' bits cleared, so
        // that an input's edge may come in any of them.
        let learned = learned_vectors(part, model, names.len())?;
        let (states, vectors, motion_state) = motion_states(&learned, inputs);
        let learned_moves = LearnedMoves::build(
            part,
            model,
            &learned,
            &motion_state,
            vectors.len(),
            &mut clocks,
            &bit_of,
            unit,
            inputs,
            act_mask,
        )?;
        let (events, windows, mut moves) = (
            learned_moves.events,
            learned_moves.windows,
            learned_moves.moves,
        );
        let expected = expectations(model, &motion_state, &moves);
        let drives = part
            .drives
            .iter()
            .filter_map(|&s| bit_of(plant.signals.name(s)))
            .fold(0u32, |m, b| m | 1 << b)
            & !inputs;
        let sensors = ((1 << names.len()) - 1) & !act_mask & !inputs;
        let undriven = if drives == 0 { 0 } else { sensors & !drives };
        let free = if part.element.is_none() {
            sensors
        } else {
            undriven
        };
        let loose = loose_mask(model, &bit_of) & !inputs;
        borrow_moves(&vectors, &mut moves, loose);
        lend_outside_edges(&vectors, &states, &mut moves, loose | undriven);
        let reactions = reactions(&moves, act_mask);
        let free_edges = free_edges(&vectors, &moves, act_mask, free);
        let motions = Motions {
            drives,
            element: if drives == 0 { sensors } else { drives },
            orders: (0..part.actuators.len() as u8)
                .map(|a| order_edges(&vectors, &states, &moves, act_mask, a))
                .collect(),
        };
        let (modes, partitions) = fault_modes(plant, part, &motions, &names, &bit_of, &mut clocks)?;
        let clocks = clocks.clocks;
        let latest_lo = latest_lower_bounds(&moves, clocks.len());
        Ok(PartDiagnoser {
            kin: kin_states(&vectors, undriven),
            reversals: true,
            held_reactions: false,
            latest_lo,
            inputs,
            loose,
            reactions,
            free,
            free_edges,
            undriven,
            name: part.name.clone(),
            signals,
            names,
            actuators: part.actuators.len(),
            clocks,
            modes,
            partitions,
            act_mask,
            states,
            vectors,
            moves,
            expected,
            events,
            windows,
            glitch_max,
        })
    }

    /// The same diagnoser, where every order starts a whole stroke and a
    /// withdrawn order's first edge is timed from the order alone: for
    /// explorations where orders come anywhere, which would not end otherwise.
    pub fn without_reversals(&self) -> PartDiagnoser {
        PartDiagnoser {
            reversals: false,
            ..self.clone()
        }
    }

    /// The same diagnoser, where the control's reaction to any sensor edge
    /// (an order the model learned in the edge's scan) may come later: the
    /// orders pass a safety filter that may hold one back, as a coupled
    /// filter does while a sensor is suspected. Commands are never blamed, so
    /// an edge is not judged by the order that did not follow it at once.
    pub fn with_held_reactions(self) -> PartDiagnoser {
        PartDiagnoser {
            held_reactions: true,
            ..self
        }
    }

    /// Bits of the actuators in a state vector.
    pub fn actuator_mask(&self) -> u32 {
        self.act_mask
    }

    /// The model's state vectors.
    pub fn state_vectors(&self) -> &[u32] {
        &self.vectors
    }

    /// A state vector's motion: its bits but the inputs'.
    pub fn motion(&self, vector: u32) -> u32 {
        vector & !self.inputs
    }

    /// The motion state of a state vector, if the model knows it.
    pub fn model_state(&self, vector: u32) -> Option<usize> {
        self.states.get(&self.motion(vector)).copied()
    }

    /// Transitions out of a model state.
    pub fn moves(&self, state: usize) -> &[Move] {
        &self.moves[state]
    }

    /// The moves `h` may take from its model state `s`: the model's, and,
    /// where the control sent the element on from a state the model never
    /// saw ([`Hypothesis::UNSEEN`]), those of the states that differ from `s`
    /// only in sensors the element does not drive and that leave them alone.
    fn moves_from(&self, h: Hypothesis, s: usize) -> impl Iterator<Item = &Move> + '_ {
        let kin: &[usize] = if h.has(Hypothesis::UNSEEN) {
            &self.kin[s]
        } else {
            &[]
        };
        self.moves[s].iter().chain(kin.iter().flat_map(move |&o| {
            self.moves[o]
                .iter()
                .filter(move |m| m.changed & self.undriven == 0)
        }))
    }

    /// The sensor events a model state expects, as indices in [`Self::moves`].
    pub fn expected(&self, state: usize) -> &[usize] {
        &self.expected[state]
    }

    /// The event name of a model transition, e.g. `FE(C4)`.
    pub fn event_name(&self, transition: usize) -> &str {
        self.events.get(transition).map_or("?", String::as_str)
    }

    /// A state vector as `A4=1 C4=0 C5=0`.
    pub fn describe(&self, vector: u32) -> String {
        self.names
            .iter()
            .enumerate()
            .map(|(b, n)| format!("{n}={}", vector >> b & 1))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The edges between two state vectors, e.g. `FE(C4) RE(C5)`.
    pub fn edges(&self, before: u32, changed: u32) -> String {
        let after = before ^ changed;
        self.names
            .iter()
            .enumerate()
            .filter(|(b, _)| changed >> b & 1 == 1)
            .map(|(b, n)| edge_name(n, after >> b & 1 == 1))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// A clock's name: `command` or an edge such as `FE(C1)`.
    pub fn clock_name(&self, clock: u8) -> String {
        let clock = match self.clocks.get(clock as usize) {
            Some(Clock::Edge { bit, rising }) => ModelClock::Edge {
                signal: self
                    .names
                    .get(*bit as usize)
                    .map_or("?", String::as_str)
                    .to_string(),
                rising: *rising,
            },
            _ => ModelClock::Command,
        };
        clock.to_string()
    }

    /// Whether the edges `changed`, after which the part reads `after`,
    /// restart clock `clock`.
    pub fn restarts(&self, clock: Clock, changed: u32, after: u32) -> bool {
        match clock {
            Clock::Command => changed & self.act_mask != 0,
            Clock::Edge { bit, rising } => {
                changed >> bit & 1 == 1 && (after >> bit & 1 == 1) == rising
            }
        }
    }

    /// Per clock, the bits whose rise and whose fall restart it: the replay's
    /// form of [`PartDiagnoser::restarts`], one test per clock and scan.
    pub fn restart_masks(&self) -> Box<[(u32, u32)]> {
        self.clocks
            .iter()
            .map(|&clock| match clock {
                Clock::Command => (self.act_mask, self.act_mask),
                Clock::Edge { bit, rising: true } => (1 << bit, 0),
                Clock::Edge { bit, rising: false } => (0, 1 << bit),
            })
            .collect()
    }

    /// Bits on which a hypothesis's physical state may differ from the observed one.
    fn decoupled(&self, h: Hypothesis) -> u32 {
        match self.modes[h.mode as usize].kind {
            ModeKind::SensorStuck { bit, .. } | ModeKind::ActuatorStuck { bit, .. } => 1 << bit,
            ModeKind::Glitch { bit, .. } if h.has(Hypothesis::GLITCH) => 1 << bit,
            _ => 0,
        }
    }

    /// Whether `h` is a blocked element's hypothesis (blocked or not yet).
    fn frozen(&self, h: Hypothesis) -> bool {
        self.frozen_bits(h) != 0
    }

    /// Bits that cannot change under `h`: the sensors its blocked element drives.
    fn frozen_bits(&self, h: Hypothesis) -> u32 {
        match self.modes[h.mode as usize].kind {
            ModeKind::BlockedAt { drives, .. } | ModeKind::BlockedBetween { drives, .. } => drives,
            _ => 0,
        }
    }

    /// The reading of `clock` as hypothesis `h` sees it: `None` when unknown to it
    /// (not yet observed, untimed hypothesis, or an edge its fault hides).
    pub fn reading(&self, h: Hypothesis, clock: u8, readings: &Readings) -> Option<Time> {
        if !self.sees(h, clock) {
            return None;
        }
        readings.get(clock as usize).copied().flatten()
    }

    /// Whether hypothesis `h` can read `clock` at all: not when it is untimed, nor
    /// when the clock is an edge its fault hides.
    pub fn sees(&self, h: Hypothesis, clock: u8) -> bool {
        if h.has(Hypothesis::UNTIMED) {
            return false;
        }
        match self.clocks.get(clock as usize) {
            Some(Clock::Edge { bit, .. }) => !matches!(
                self.modes[h.mode as usize].kind,
                ModeKind::SensorStuck { bit: b, .. } | ModeKind::Glitch { bit: b, .. } if b == *bit
            ),
            _ => true,
        }
    }

    fn admits(&self, h: Hypothesis, m: &Move, readings: &Readings) -> bool {
        !m.timed
            || self
                .reading(h, m.clock, readings)
                .is_none_or(|c| self.lower_bound(h, m) <= c && c <= self.upper_bound(h, m))
    }

    /// Whether every clock `h` reads is past every lower bound on it.
    fn lower_bounds_passed(&self, h: Hypothesis, readings: &Readings) -> bool {
        (0..self.clocks.len()).all(|c| {
            self.reading(h, c as u8, readings)
                .is_none_or(|r| r >= self.latest_lo[c])
        })
    }

    /// The earliest reading of `m`'s clock at which `h` takes `m`: none when
    /// `h`'s element may have turned in mid-stroke.
    fn lower_bound(&self, h: Hypothesis, m: &Move) -> Time {
        if h.has(Hypothesis::SOONER) { 0 } else { m.lo }
    }

    /// The latest reading of `m`'s clock at which `h` takes `m`, or by which
    /// an expected `m` must have come: later when the control reacted late
    /// ([`Hypothesis::LATE`]).
    fn upper_bound(&self, h: Hypothesis, m: &Move) -> Time {
        let hi = self.slow_bound(h, m);
        if h.has(Hypothesis::LATE) {
            hi + self.glitch_max
        } else {
            hi
        }
    }

    /// `m`'s latest reading under `h`'s mode: stretched by [`Factor::MAX`]
    /// where `h`'s slow element or actuator makes the motion.
    pub(crate) fn slow_bound(&self, h: Hypothesis, m: &Move) -> Time {
        if self.slowed(h, m) {
            // Clamped so that no learned bound overflows.
            Factor::MAX.stretch(m.hi.min(Time::MAX / 1024))
        } else {
            m.hi
        }
    }

    /// Whether `m`, taken from `h`'s physical state, is a motion that `h`'s
    /// slow element or actuator makes: one of its sensor edges is.
    fn slowed(&self, h: Hypothesis, m: &Move) -> bool {
        let ModeKind::Slow { rises, falls } = self.modes[h.mode as usize].kind else {
            return false;
        };
        let sensed = m.changed & !self.act_mask;
        sensed & !h.phys & rises != 0 || sensed & h.phys & falls != 0
    }

    /// Whether `m` cannot follow, in the same scan, the transitions of `h`
    /// that moved the bits `moved`: its guard reads a clock one of them reset
    /// and it never came that soon, or `h` is untimed (its clocks cannot tell
    /// how far apart two timed transitions are, and an element does not cross
    /// a whole stroke in one scan).
    fn too_soon(&self, h: Hypothesis, m: &Move, moved: u32) -> bool {
        if !m.timed || moved == 0 {
            return false;
        }
        if h.has(Hypothesis::UNTIMED) {
            return true;
        }
        let Some(Clock::Edge { bit, rising }) = self.clocks.get(m.clock as usize) else {
            return false;
        };
        self.lower_bound(h, m) > 0 && moved >> bit & 1 == 1 && (h.phys >> bit & 1 == 1) == *rising
    }

    fn may_have_happened(&self, h: Hypothesis, m: &Move, readings: &Readings) -> bool {
        !m.timed
            || self
                .reading(h, m.clock, readings)
                .is_none_or(|c| self.lower_bound(h, m) <= c)
    }

    /// Whether `h` has outstayed its state: every expected event's deadline passed.
    /// An expected order is the control's timeout: the state may last until the
    /// latest it was seen to come.
    /// A blocked element waits for ever where an expected event moves it, but
    /// the part's other sensors keep their deadlines. A state reached from
    /// one the model never saw, or by edges its moves do not explain, does
    /// not wait for the sensors the element does not drive
    /// ([`Hypothesis::UNSEEN`]).
    fn expired(&self, h: Hypothesis, readings: &Readings) -> bool {
        if let Some((clock, limit)) = self.glitch_deadline(h)
            && readings
                .get(clock as usize)
                .copied()
                .flatten()
                .is_some_and(|c| c > limit)
        {
            return true;
        }
        let Some(s) = self.model_state(h.phys) else {
            return false;
        };
        let exp = &self.expected[s];
        let frozen = self.frozen_bits(h);
        let free = if h.has(Hypothesis::UNSEEN) {
            self.undriven
        } else {
            0
        };
        !exp.is_empty()
            && exp.iter().all(|&k| {
                let m = &self.moves[s][k];
                (m.timed || m.command)
                    && m.changed & frozen == 0
                    && (free == 0 || m.changed & !self.act_mask & !free != 0)
                    && self
                        .reading(h, m.clock, readings)
                        .is_some_and(|c| c > self.upper_bound(h, m))
            })
    }

    /// Whether `h` is a glitch that has shown longer than a glitch may.
    pub fn glitch_expired(&self, h: Hypothesis, readings: &Readings) -> bool {
        self.glitch_deadline(h).is_some_and(|(clock, limit)| {
            readings
                .get(clock as usize)
                .copied()
                .flatten()
                .is_some_and(|c| c > limit)
        })
    }

    /// Longest a glitch shows, in nanoseconds.
    pub fn glitch_max(&self) -> Time {
        self.glitch_max
    }

    /// The deadline of a showing glitch: (clock, latest reading).
    fn glitch_deadline(&self, h: Hypothesis) -> Option<(u8, Time)> {
        if !h.has(Hypothesis::GLITCH) {
            return None;
        }
        let ModeKind::Glitch { bit, value } = self.modes[h.mode as usize].kind else {
            return None;
        };
        if h.since == Hypothesis::SEEN {
            let edge = Clock::Edge { bit, rising: value };
            let clock = self.clocks.iter().position(|&c| c == edge)?;
            Some((clock as u8, self.glitch_max))
        } else {
            let &(clock, hi, timed) = self.windows.get(h.since as usize)?;
            timed.then_some((clock, hi + self.glitch_max))
        }
    }

    /// Fault modes that may begin now, from the normal hypothesis `h`, without
    /// anything observable at the onset.
    fn silent_onsets(&self, h: Hypothesis, out: &mut Vec<Hypothesis>) {
        let bit = |b: u8| h.phys >> b & 1 == 1;
        for (m, mode) in self.modes.iter().enumerate().skip(1) {
            let mode_id = m as u16;
            let onset = match mode.kind {
                ModeKind::Normal | ModeKind::Glitch { .. } => None,
                ModeKind::SensorStuck { bit: b, value } => (bit(b) == value).then_some(h.phys),
                ModeKind::ActuatorStuck { bit: b, value } => {
                    if bit(b) == value {
                        Some(h.phys)
                    } else {
                        // The part starts (or stops) moving at an unobserved moment.
                        out.push(Hypothesis {
                            mode: mode_id,
                            flags: Hypothesis::UNTIMED,
                            since: 0,
                            phys: h.phys ^ (1 << b),
                        });
                        None
                    }
                }
                ModeKind::BlockedAt { bit: b, .. } => bit(b).then_some(h.phys),
                ModeKind::BlockedBetween { from, to, .. } => {
                    let in_transit = !bit(from)
                        && !bit(to)
                        && self.model_state(h.phys).is_some_and(|s| {
                            self.moves[s]
                                .iter()
                                .any(|mv| (mv.changed & !self.act_mask) >> to & 1 == 1)
                        });
                    in_transit.then_some(h.phys)
                }
                ModeKind::Slow { .. } => {
                    // Nothing differs at the onset but the bounds to come,
                    // so the hypothesis keeps what normal allows for.
                    out.push(Hypothesis { mode: mode_id, ..h });
                    None
                }
            };
            if let Some(phys) = onset {
                out.push(Hypothesis {
                    mode: mode_id,
                    flags: 0,
                    since: 0,
                    phys,
                });
            }
        }
    }

    /// Brings a set of hypotheses up to the present: adds the fault modes that may
    /// have begun silently and the hidden transitions that may have happened, and
    /// drops the hypotheses whose deadlines have passed. `obs` is the observed state.
    pub fn close(&self, obs: u32, hyps: &mut Vec<Hypothesis>, readings: &Readings) {
        let mut i = 0;
        let mut extra = Vec::new();
        while i < hyps.len() {
            let h = hyps[i];
            i += 1;
            extra.clear();
            if h.mode == 0 {
                self.silent_onsets(h, &mut extra);
            }
            if !self.frozen(h) {
                let dec = self.decoupled(h);
                if let Some(s) = self.model_state(h.phys) {
                    for m in &self.moves[s] {
                        if !self.may_have_happened(h, m, readings) {
                            continue;
                        }
                        if m.command {
                            // The control's reaction to a sensor edge it cannot
                            // see does not come; the edge itself still happens.
                            let sensed = m.changed & !self.act_mask;
                            if sensed != 0 && sensed & !dec == 0 {
                                extra.push(Hypothesis {
                                    phys: h.phys ^ sensed,
                                    ..h
                                });
                            } else if sensed.count_ones() == 1 {
                                self.hidden_by_glitch(h, m.id, sensed, &mut extra);
                            }
                        } else if m.changed & !dec == 0 {
                            extra.push(Hypothesis {
                                phys: h.phys ^ m.changed,
                                ..h
                            });
                        } else if m.changed.count_ones() == 1 {
                            self.hidden_by_glitch(h, m.id, m.changed, &mut extra);
                        }
                    }
                }
            }
            for mut e in extra.drain(..) {
                self.normalise(obs, &mut e);
                if !hyps.contains(&e) {
                    hyps.push(e);
                }
            }
        }
        hyps.retain(|&h| !self.expired(h, readings));
        for h in hyps.iter_mut() {
            if h.has(Hypothesis::SOONER) && self.lower_bounds_passed(*h, readings) {
                h.flags &= !Hypothesis::SOONER;
            }
        }
        hyps.sort_unstable();
        hyps.dedup();
    }

    /// A real edge of a sensor that a glitch hides as it starts: the reading
    /// keeps the old value, which is the glitch's value (seed 002's unexpected
    /// rise or fall, beginning just as the real value leaves it). `changed` is
    /// the sensor's bit, moved by transition `id`; when that transition also
    /// holds the control's reaction, the reaction does not come, since the
    /// control reads the glitch.
    fn hidden_by_glitch(&self, h: Hypothesis, id: usize, changed: u32, out: &mut Vec<Hypothesis>) {
        for (mode, _) in self.glitches_hiding(h, changed) {
            out.push(Hypothesis {
                mode,
                flags: h.flags | Hypothesis::GLITCH,
                since: id as u16,
                phys: h.phys ^ changed,
            });
        }
    }

    /// The glitch modes that may begin now under `h` by hiding the real edge
    /// of one of the sensors `edges`, with that sensor's bit: the reading
    /// keeps the old value, which is the glitch's.
    fn glitches_hiding(&self, h: Hypothesis, edges: u32) -> impl Iterator<Item = (u16, u8)> + '_ {
        let own = self.modes[h.mode as usize].kind;
        self.modes.iter().enumerate().filter_map(move |(m, mode)| {
            let ModeKind::Glitch { bit, value } = mode.kind else {
                return None;
            };
            let may_start = (h.mode == 0 || (own == mode.kind && !h.has(Hypothesis::GLITCH)))
                && edges >> bit & 1 == 1
                && (h.phys >> bit & 1 == 1) == value;
            may_start.then_some((m as u16, bit))
        })
    }

    /// The edges of transition `m` that show while a glitch beginning now hides
    /// one of them, as in [`Self::hidden_by_glitch`] but among other edges
    /// (the arm reaches its end switch as the workpiece leaves). The control
    /// reads the glitch, so its reaction in `m` does not come.
    #[allow(clippy::too_many_arguments)]
    fn hidden_amid(
        &self,
        h: Hypothesis,
        m: &Move,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        let sensed = m.changed & !self.act_mask;
        if sensed & self.frozen_bits(h) != 0
            || !self.admits(h, m, readings)
            || self.too_soon(h, m, moved)
        {
            return;
        }
        let dec = self.decoupled(h);
        for (mode, bit) in self.glitches_hiding(h, sensed) {
            let visible = sensed & !(1 << bit) & !dec;
            if visible != 0 && visible & !rest == 0 {
                let next = Hypothesis {
                    mode,
                    flags: (h.flags | Hypothesis::GLITCH) & !Hypothesis::UNDATED,
                    since: m.id as u16,
                    phys: h.phys ^ sensed,
                };
                self.explain(next, rest & !visible, moved | sensed, after, readings, out);
            }
        }
    }

    /// A glitch is over once the real value has caught up with the shown one.
    fn normalise(&self, obs: u32, h: &mut Hypothesis) {
        if let ModeKind::Glitch { bit, .. } = self.modes[h.mode as usize].kind
            && h.has(Hypothesis::GLITCH)
            && (h.phys ^ obs) >> bit & 1 == 0
        {
            h.flags &= !Hypothesis::GLITCH;
            h.since = 0;
        }
    }

    /// The hypotheses after the scan that changed the observed bits `changed`
    /// from the observed state `obs`, with the clocks read before the scan.
    /// The result is not closed (see [`Self::close`]).
    pub fn step(
        &self,
        obs: u32,
        changed: u32,
        hyps: &[Hypothesis],
        readings: &Readings,
    ) -> Vec<Hypothesis> {
        let sensors = changed & !self.act_mask;
        let orders = changed & self.act_mask;
        let after = obs ^ changed;
        let mut out = Vec::new();
        let mut sensed = Vec::new();
        for &h in hyps {
            self.reactions(h, obs, changed, readings, &mut out);
            sensed.clear();
            self.explain(h, sensors, 0, after, readings, &mut sensed);
            let astray = self.astray(h, obs) & sensors;
            if astray != 0 {
                let r = Hypothesis {
                    phys: h.phys ^ astray,
                    ..h
                };
                self.explain(r, sensors & !astray, astray, after, readings, &mut sensed);
            }
            for mut r in sensed.drain(..) {
                r.flags &= !Hypothesis::STARTED;
                if r.has(Hypothesis::LATE)
                    && !h.has(Hypothesis::LATE)
                    && !self.reacts_to_late_edge(r, orders)
                {
                    // A late edge the control did not react to changed
                    // nothing of the element's motion.
                    r.flags &= !Hypothesis::LATE;
                }
                if orders != 0 {
                    let applied = self.apply_orders(&mut r, orders);
                    if r.mode != 0 && !self.frozen(r) && applied != 0 {
                        r.flags |= self.misled(r, applied, after);
                    }
                    r.phys ^= applied;
                }
                self.normalise(after, &mut r);
                out.push(r);
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The sensors left to themselves under `h` in the observed state `obs`:
    /// where a stuck actuator holds the element away from where the control
    /// sent it, or the control sent it on from a state the model never saw
    /// ([`Hypothesis::UNSEEN`]), the part is in a state the model never
    /// judged, and the sensors the element does not drive (a workpiece
    /// arriving) keep whatever moves them, as under a blocked element.
    fn astray(&self, h: Hypothesis, obs: u32) -> u32 {
        if self.held_astray(h, obs) || h.has(Hypothesis::UNSEEN) {
            self.undriven
        } else {
            0
        }
    }

    /// Whether `h`'s stuck actuator holds its element away from where the
    /// control sends it in the observed state `obs`.
    fn held_astray(&self, h: Hypothesis, obs: u32) -> bool {
        matches!(self.modes[h.mode as usize].kind,
            ModeKind::ActuatorStuck { bit, .. } if (obs ^ h.phys) >> bit & 1 == 1)
    }

    /// The scan `changed` from `obs` as the control's reaction to some of its
    /// sensor edges (a transition of the model with the scan's orders and
    /// those edges), the scan's other edges explained by the model before or
    /// after it: a workpiece leaves the entry of a belt in the scan the belt
    /// stops at its end. The reaction's edges happen even where the order they
    /// prompted does not reach the plant.
    fn reactions(
        &self,
        h: Hypothesis,
        obs: u32,
        changed: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        let orders = changed & self.act_mask;
        let sensors = changed & !self.act_mask;
        if orders == 0
            || self.motion(sensors) == 0
            || self.decoupled(h) & sensors != 0
            || self.frozen_bits(h) & changed != 0
        {
            return;
        }
        let after = obs ^ changed;
        let mut before = Vec::new();
        let mut others = Vec::new();
        for edges in self.reaction_edges(orders, sensors) {
            // The other edges first, then the reaction.
            let rest = sensors & !edges;
            before.clear();
            if rest == 0 {
                before.push(h);
            } else {
                self.explain(h, rest, 0, after, readings, &mut before);
            }
            for &b in &before {
                let moved = b.phys ^ h.phys;
                out.extend(self.reacted(b, orders | edges, moved, readings));
            }
            // The reaction first, then the other edges.
            if rest == 0 {
                continue;
            }
            for r in self.reacted(h, orders | edges, 0, readings) {
                others.clear();
                self.explain(r, rest, edges, after, readings, &mut others);
                out.append(&mut others);
            }
        }
    }

    /// The sets of sensor edges among `sensors` that the control reacts to
    /// with `orders` somewhere in the model.
    fn reaction_edges(&self, orders: u32, sensors: u32) -> impl Iterator<Item = u32> + '_ {
        self.reactions
            .iter()
            .filter(move |&&r| r & self.act_mask == orders && r & !orders & !sensors == 0)
            .map(move |&r| r & !orders)
    }

    /// `h` after the model's transition that changes exactly `changed` (orders
    /// and sensor edges) from its state, in the same scan as the transitions
    /// that moved `moved`.
    fn reacted<'a>(
        &'a self,
        h: Hypothesis,
        changed: u32,
        moved: u32,
        readings: &'a Readings,
    ) -> impl Iterator<Item = Hypothesis> + 'a {
        let orders = changed & self.act_mask;
        self.model_state(h.phys)
            .into_iter()
            .flat_map(move |s| self.moves_from(h, s))
            .filter(move |m| {
                m.changed == self.motion(changed)
                    && self.admits(h, m, readings)
                    && !self.too_soon(h, m, moved)
            })
            .map(move |_| {
                let mut r = Hypothesis {
                    phys: h.phys ^ (changed & !orders),
                    flags: h.flags & !(Hypothesis::STARTED | Hypothesis::UNDATED),
                    ..h
                };
                r.phys ^= self.apply_orders(&mut r, orders);
                r
            })
    }

    /// Explains the observed sensor edges `rest` from hypothesis `h`: by the
    /// model's transitions (their visible part), or by the fault's own effects.
    /// `moved`: the bits the scan's earlier transitions changed.
    fn explain(
        &self,
        h: Hypothesis,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        if rest == 0 {
            out.push(h);
            return;
        }
        let dec = self.decoupled(h);
        // An input's edge comes whatever the part's motion (a refill, a workpiece
        // arriving); a fault of the input itself is still explained below.
        let free = rest & self.inputs & !dec;
        if free != 0 {
            let next = Hypothesis {
                phys: h.phys ^ free,
                ..h
            };
            self.explain(next, rest & !free, moved | free, after, readings, out);
        }
        let frozen = self.frozen_bits(h);
        if rest & frozen == 0 {
            self.explain_by_moves(h, rest, moved, after, readings, out);
            if h.has(Hypothesis::STARTED) {
                self.started_motion(h, rest, moved, after, readings, out);
            }
            if self.held_astray(h, after) {
                self.astray_motion(h, rest, moved, after, readings, out);
            }
            // A blocked element holds its state where the normal plant only
            // passes: the learned moves of that state cannot judge the sensors
            // it does not drive, which keep whatever moves them (a workpiece
            // arriving, the next machine).
            if frozen != 0 && rest & dec == 0 {
                out.push(Hypothesis {
                    phys: h.phys ^ rest,
                    flags: (h.flags & !Hypothesis::UNSEEN) | self.unseen_in(h.phys ^ rest, true),
                    ..h
                });
            }
        }
        // The fault's own observable effects, one edge at a time.
        self.explain_by_fault(h, rest, moved, after, readings, out);
    }

    /// Explains the edges `rest` by the learned moves of `h`'s state, or, in a
    /// state the model never saw, as whatever the unusual command made.
    fn explain_by_moves(
        &self,
        h: Hypothesis,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        let dec = self.decoupled(h);
        match self.model_state(h.phys) {
            Some(s) => {
                for m in self.moves_from(h, s) {
                    let sensed = m.changed & !self.act_mask;
                    if sensed.count_ones() >= 2 {
                        self.hidden_amid(h, m, rest, moved, after, readings, out);
                    }
                    // The control's reaction to a sensor edge it cannot see
                    // does not come; the edges themselves still happen, the
                    // hidden ones with the visible ones (as in `close`). Nor
                    // does a reaction the control already shows, on an
                    // actuator stuck where the reaction would put it, nor
                    // one to an element the control did not send where it
                    // is. The reaction to edges from outside the part may
                    // wait for conditions outside it too (a workpiece
                    // arrives before the next machine is ready).
                    let physical = if !m.command {
                        m.changed
                    } else if self.held_reactions
                        || sensed & dec != 0
                        || sensed & !self.loose == 0
                        || self.reaction_shown(h, m, after)
                        || self.held_astray(h, after)
                    {
                        sensed
                    } else {
                        continue;
                    };
                    if let Some(visible) = self.shown_part(h, physical, rest)
                        && self.admits(h, m, readings)
                        && !self.too_soon(h, m, moved)
                    {
                        let phys = h.phys ^ physical;
                        let flags = if m.lent && physical & !self.undriven & !self.act_mask == 0 {
                            // An edge from outside the part, which the model
                            // learned in another state: the state it leads
                            // to was learned with the element elsewhere (a
                            // workpiece arriving after the pusher went by).
                            h.flags | self.unseen_in(phys, false)
                        } else {
                            // The edge dates the element again.
                            h.flags & !Hypothesis::UNDATED
                        };
                        let next = Hypothesis { phys, flags, ..h };
                        let moved = moved | physical;
                        self.explain(next, rest & !visible, moved, after, readings, out);
                    }
                }
            }
            // A state the model never saw (reached by an unusual command):
            // the model cannot judge its sensors.
            None if rest & dec == 0 => out.push(Hypothesis {
                phys: h.phys ^ rest,
                flags: h.flags | self.unseen_in(h.phys ^ rest, false),
                ..h
            }),
            None => {}
        }
    }

    /// Explains the edges `rest` one at a time by the fault's own effects: a
    /// stuck sensor's onset, or a glitch that starts or ends.
    fn explain_by_fault(
        &self,
        h: Hypothesis,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        for bit in 0..self.names.len() as u8 {
            if rest >> bit & 1 == 0 {
                continue;
            }
            let shown = after >> bit & 1 == 1;
            let real = h.phys >> bit & 1 == 1;
            let next_rest = rest & !(1 << bit);
            let own = self.modes[h.mode as usize].kind;
            if h.mode == 0 {
                // A reading that jumps to the value of a fault that begins now:
                // a stuck sensor's onset, or an unexpected edge.
                if shown == real {
                    continue;
                }
                for (m, mode) in self.modes.iter().enumerate().skip(1) {
                    let next = match mode.kind {
                        ModeKind::SensorStuck { bit: b, value } if b == bit && shown == value => {
                            Hypothesis {
                                mode: m as u16,
                                ..h
                            }
                        }
                        ModeKind::Glitch { bit: b, value } if b == bit && shown == value => {
                            Hypothesis {
                                mode: m as u16,
                                flags: h.flags | Hypothesis::GLITCH,
                                since: Hypothesis::SEEN,
                                phys: h.phys,
                            }
                        }
                        _ => continue,
                    };
                    self.explain(next, next_rest, moved, after, readings, out);
                }
            } else if let ModeKind::Glitch { bit: b, value } = own
                && b == bit
            {
                if !h.has(Hypothesis::GLITCH) && shown == value && real != value {
                    let next = Hypothesis {
                        flags: h.flags | Hypothesis::GLITCH,
                        since: Hypothesis::SEEN,
                        ..h
                    };
                    self.explain(next, next_rest, moved, after, readings, out);
                } else if h.has(Hypothesis::GLITCH) && shown == real {
                    // A glitch that hid a real edge lets it show late.
                    let late = if h.since == Hypothesis::SEEN {
                        0
                    } else {
                        Hypothesis::LATE
                    };
                    let next = Hypothesis {
                        flags: (h.flags & !Hypothesis::GLITCH) | late,
                        since: 0,
                        ..h
                    };
                    self.explain(next, next_rest, moved, after, readings, out);
                }
            }
        }
    }

    /// Explains edges among `rest` under a stuck actuator that holds the part
    /// away from where the control sent it. The part then runs in a regime
    /// the control never makes (a belt that goes on running carries several
    /// workpieces at once), which the joint states learned under the control
    /// do not bound: any edge of a sensor that no element holds in place
    /// ([`Self::free`]) that the model learned with the actuators and the
    /// element where they physically are may come, untimed.
    fn astray_motion(
        &self,
        h: Hypothesis,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        let held = h.phys & !self.free;
        for &(key, edges, before) in &self.free_edges {
            if key != held || h.phys & edges != before {
                continue;
            }
            if let Some(visible) = self.shown_part(h, edges, rest) {
                let next = Hypothesis {
                    phys: h.phys ^ edges,
                    flags: h.flags | Hypothesis::UNTIMED,
                    ..h
                };
                self.explain(next, rest & !visible, moved | edges, after, readings, out);
            }
        }
    }

    /// Whether `orders` are a reaction the model learned (in any state) to
    /// edges that include that of `r`'s glitch sensor, which the glitch has
    /// just let show late. The reaction's other edges may have shown on time,
    /// before it (a workpiece pushed off as the pusher reaches its end).
    fn reacts_to_late_edge(&self, r: Hypothesis, orders: u32) -> bool {
        let ModeKind::Glitch { bit, .. } = self.modes[r.mode as usize].kind else {
            return false;
        };
        orders != 0
            && self
                .reactions
                .iter()
                .any(|&c| c & self.act_mask == orders && c >> bit & 1 == 1)
    }

    /// The orders among `orders` that reach the plant under `r`: all but its
    /// stuck actuator's. An ignored order leaves `r` untimed, since the command
    /// clock no longer dates its physical state.
    fn apply_orders(&self, r: &mut Hypothesis, orders: u32) -> u32 {
        let ignored = match self.modes[r.mode as usize].kind {
            ModeKind::ActuatorStuck { bit, .. } => orders & 1 << bit,
            _ => 0,
        };
        if ignored != 0 {
            r.flags |= Hypothesis::UNTIMED;
        }
        orders & !ignored
    }

    /// The part of the edges `physical` that shows, if they can explain some of
    /// the observed edges `rest` under `h`: none of them frozen, at least one
    /// visible, and no visible one outside `rest`.
    fn shown_part(&self, h: Hypothesis, physical: u32, rest: u32) -> Option<u32> {
        let visible = physical & !self.decoupled(h);
        (physical & self.frozen_bits(h) == 0 && visible != 0 && visible & !rest == 0)
            .then_some(visible)
    }

    /// What a fault hypothesis `r` must allow for when the control, misled by
    /// the fault, gives `orders` in `r`'s physical state, the observed state
    /// becoming `after`:
    /// [`Hypothesis::STARTED`] if the model never saw them given there,
    /// [`Hypothesis::SOONER`] if the element may be in transit and the model
    /// never saw them given there without the sensor edges that end the
    /// transit (a cylinder released half-way out, when the control thought it
    /// out), [`Hypothesis::UNTIMED`] if the control reacts to an arrival
    /// from outside the part that only the fault shows (see
    /// [`Self::reacts_to_shown_arrival`]), and [`Hypothesis::UNSEEN`] if the
    /// model never saw the state `phys` at all.
    fn misled(&self, r: Hypothesis, orders: u32, after: u32) -> u8 {
        let phys = r.phys;
        let mut flags = 0;
        if !self.learned_order(phys, orders) {
            flags |= Hypothesis::STARTED;
        }
        let alone = self
            .model_state(phys)
            .is_some_and(|s| self.moves[s].iter().any(|m| m.changed == orders));
        if self.reversals && !alone && self.in_transit(phys) {
            flags |= Hypothesis::SOONER;
        }
        if self.reacts_to_shown_arrival(r, orders, after) {
            flags |= Hypothesis::UNTIMED;
        }
        if self.model_state(phys).is_none() {
            flags |= self.unseen_in(phys ^ orders, false);
        }
        flags
    }

    /// Whether the learning logs showed the control give `orders` in `r`'s
    /// physical state only as its reaction to edges of sensors moved from
    /// outside the part, which `r`'s fault shows in `after` though the plant did not make
    /// them: the control starts a motion for a workpiece that never came (a
    /// belt started by an entry sensor stuck on). The model never saw the part
    /// move without it, so its guards and deadlines no longer apply.
    fn reacts_to_shown_arrival(&self, r: Hypothesis, orders: u32, after: u32) -> bool {
        let shown = self.decoupled(r) & self.loose & (after ^ r.phys);
        let Some(s) = self.model_state(r.phys).filter(|_| shown != 0) else {
            return false;
        };
        let mut reactions = self.moves[s]
            .iter()
            .filter(|m| !m.lent && m.command && m.changed & self.act_mask == orders)
            .peekable();
        reactions.peek().is_some()
            && reactions.all(|m| {
                let sensed = m.changed & !self.act_mask;
                sensed != 0 && sensed & !shown == 0
            })
    }

    /// [`Hypothesis::UNSEEN`] for a hypothesis that reaches the state
    /// `phys` from one the model never saw, or (`blocked`) a blocked element's
    /// by edges the model does not explain, where the flag changes something:
    /// in a state the model knows, when the element does not drive every
    /// sensor, and for a blocked element, which moves no more, only where the
    /// state waits for edges of the sensors it does not drive alone.
    fn unseen_in(&self, phys: u32, blocked: bool) -> u8 {
        let Some(s) = self.model_state(phys).filter(|_| self.undriven != 0) else {
            return 0;
        };
        let waits_alone = || {
            self.expected[s].iter().any(|&k| {
                let sensed = self.moves[s][k].changed & !self.act_mask;
                sensed != 0 && sensed & !self.undriven == 0
            })
        };
        if !blocked || waits_alone() {
            Hypothesis::UNSEEN
        } else {
            0
        }
    }

    /// Whether an element may be between two positions in the physical state
    /// `phys`: the model must see a sensor edge to leave it (alone, or with
    /// the control's reaction to it), or never saw it.
    fn in_transit(&self, phys: u32) -> bool {
        self.model_state(phys).is_none_or(|s| {
            self.expected[s]
                .iter()
                .any(|&k| self.moves[s][k].changed & !self.act_mask != 0)
        })
    }

    /// Whether the model saw the control give `orders` in the physical state `phys`.
    fn learned_order(&self, phys: u32, orders: u32) -> bool {
        self.model_state(phys).is_some_and(|s| {
            self.moves[s]
                .iter()
                .any(|m| m.command && m.changed & self.act_mask == orders)
        })
    }

    /// The first edge of a motion whose order the control withdrew in a state
    /// where it never does (see [`Hypothesis::STARTED`]): the element had
    /// started, and the edge the order leads to first still comes, in its
    /// learned window (any time, if `h` is untimed already).
    /// `h` is back in the state the order was given from; what follows is the
    /// model's no more, so it goes untimed.
    fn started_motion(
        &self,
        h: Hypothesis,
        rest: u32,
        moved: u32,
        after: u32,
        readings: &Readings,
        out: &mut Vec<Hypothesis>,
    ) {
        for a in (0..self.names.len() as u8).filter(|&a| self.act_mask >> a & 1 == 1) {
            let given = h.phys ^ 1 << a;
            let Some(s) = self.model_state(given) else {
                continue;
            };
            if !self.learned_order(h.phys, 1 << a) {
                continue;
            }
            let order = Clock::Edge {
                bit: a,
                rising: given >> a & 1 == 1,
            };
            for m in &self.moves[s] {
                // On whatever clock the model learned it: the order's own, or
                // one the withdrawal restarted (the command clock), which reads
                // less than the time since the order and so only loosens the
                // window's upper bound; the lower one is waived in transit
                // (`Hypothesis::SOONER`). Without reversals, on the order's
                // own clock only.
                let clock = self.clocks.get(m.clock as usize);
                if !m.command
                    && m.timed
                    && (self.reversals || clock == Some(&order))
                    && let Some(visible) = self.shown_part(h, m.changed, rest)
                    && self.admits(h, m, readings)
                {
                    let next = Hypothesis {
                        flags: (h.flags | Hypothesis::UNTIMED) & !Hypothesis::STARTED,
                        phys: h.phys ^ m.changed,
                        ..h
                    };
                    self.explain(
                        next,
                        rest & !visible,
                        moved | m.changed,
                        after,
                        readings,
                        out,
                    );
                }
            }
        }
    }

    /// Whether the control's reaction `m` orders only the actuator that `h`
    /// holds stuck, and the observed order `after` already is what the
    /// reaction would give: the control has nothing to order, and the sensor
    /// edges it reacts to still happen (a valve stuck on turns a table to the
    /// end where the control would have released it).
    fn reaction_shown(&self, h: Hypothesis, m: &Move, after: u32) -> bool {
        let ModeKind::ActuatorStuck { bit, .. } = self.modes[h.mode as usize].kind else {
            return false;
        };
        let orders = m.changed & self.act_mask;
        orders == 1 << bit && (after ^ h.phys ^ m.changed) >> bit & 1 == 0
    }

    /// The initial hypotheses for the observed state `obs`.
    pub fn initial(&self, obs: u32) -> Vec<Hypothesis> {
        vec![Hypothesis::normal(obs)]
    }

    /// The hypotheses to start again from in the observed state `obs`, after
    /// observations that no mode explains: normal there, as at a log's start,
    /// and every stuck sensor that reads its stuck value, whatever the real one
    /// is. Closing the set adds the faults that may have begun unseen.
    pub fn resync(&self, obs: u32) -> Vec<Hypothesis> {
        let mut out = self.initial(obs);
        for (m, mode) in self.modes.iter().enumerate().skip(1) {
            if let ModeKind::SensorStuck { bit, value } = mode.kind
                && (obs >> bit & 1 == 1) == value
            {
                out.push(Hypothesis {
                    mode: m as u16,
                    flags: 0,
                    since: 0,
                    phys: obs ^ (1 << bit),
                });
            }
        }
        out.sort_unstable();
        out
    }

    /// The clock thresholds that matter to a set of hypotheses, per clock: guard
    /// bounds (for events) and the moments time alone changes the set (hidden
    /// transitions becoming possible, deadlines passing). A threshold `θ` is
    /// passed when the reading is `>= θ`. The timers are complete: between two
    /// of them, [`Self::close`] gives the same set, which is what lets a replay
    /// advance a set only when a timer fires.
    pub fn thresholds(&self, hyps: &[Hypothesis]) -> (Vec<Vec<Time>>, Vec<Vec<Time>>) {
        let mut all = vec![Vec::new(); self.clocks.len()];
        let mut timers = vec![Vec::new(); self.clocks.len()];
        let glitches = self
            .modes
            .iter()
            .any(|m| matches!(m.kind, ModeKind::Glitch { .. }));
        for &h in hyps {
            // A glitch ends by its deadline whatever the hypothesis's state.
            if let Some((clock, limit)) = self.glitch_deadline(h) {
                timers[clock as usize].push(limit + 1);
                all[clock as usize].push(limit + 1);
            }
            if h.has(Hypothesis::UNTIMED) {
                continue;
            }
            if h.has(Hypothesis::SOONER) {
                for (c, &l) in self.latest_lo.iter().enumerate() {
                    timers[c].push(l);
                    all[c].push(l);
                }
            }
            let Some(s) = self.model_state(h.phys) else {
                continue;
            };
            let dec = self.decoupled(h);
            let frozen = self.frozen_bits(h);
            for m in &self.moves[s] {
                if !m.timed || !self.sees(h, m.clock) || m.changed & frozen != 0 {
                    continue;
                }
                let c = m.clock as usize;
                all[c].push(m.lo);
                all[c].push(self.upper_bound(h, m) + 1);
                let sensed = m.changed & !self.act_mask;
                // Hidden by the fault, or by a glitch that may start now
                // (see `hidden_by_glitch`).
                let hidden = sensed & !dec == 0
                    || (glitches && !h.has(Hypothesis::GLITCH) && sensed.count_ones() == 1);
                if sensed != 0 && hidden {
                    timers[c].push(m.lo);
                }
            }
            for &k in &self.expected[s] {
                let m = &self.moves[s][k];
                if (m.timed || m.command) && self.sees(h, m.clock) && m.changed & frozen == 0 {
                    let limit = self.upper_bound(h, m) + 1;
                    timers[m.clock as usize].push(limit);
                    all[m.clock as usize].push(limit);
                }
            }
        }
        for v in all.iter_mut().chain(timers.iter_mut()) {
            v.sort_unstable();
            v.dedup();
        }
        (all, timers)
    }
}

/// The part's signals (actuators, then sensors) and their names, checked
/// against the model's.
fn part_signals(
    plant: &Plant,
    part: &Part,
    model: &PartModel,
) -> Result<(Vec<SignalId>, Vec<String>), BuildError> {
    let signals: Vec<SignalId> = part
        .actuators
        .iter()
        .chain(&part.sensors)
        .copied()
        .collect();
    let names: Vec<String> = signals
        .iter()
        .map(|&s| plant.signals.name(s).to_string())
        .collect();
    if names != model.signals || model.actuators != part.actuators.len() {
        return Err(format!(
            "part '{}': the model's signals [{}] are not the plant's [{}] (learned from another plant file?)",
            part.name,
            model.signals.join(", "),
            names.join(", ")
        ));
    }
    if names.len() > MAX_PART_SIGNALS {
        return Err(format!(
            "part '{}' has {} signals; a diagnoser handles at most {MAX_PART_SIGNALS}",
            part.name,
            names.len()
        ));
    }
    Ok((signals, names))
}

/// The part's clocks, numbered in the order they are first named: the command
/// clock first, then the model's clocks, then the glitches' own.
struct ClockTable<'a> {
    part: &'a str,
    clocks: Vec<Clock>,
}

impl<'a> ClockTable<'a> {
    fn new(part: &'a str) -> Self {
        ClockTable {
            part,
            clocks: vec![Clock::Command],
        }
    }

    /// The number of the clock `name` (`command`, `RE(x)` or `FE(x)`).
    fn index(
        &mut self,
        name: &str,
        bit_of: &impl Fn(&str) -> Option<u8>,
    ) -> Result<u8, BuildError> {
        let clock = match ModelClock::parse(name) {
            Some(ModelClock::Command) => Some(Clock::Command),
            Some(ModelClock::Edge { signal, rising }) => {
                bit_of(&signal).map(|bit| Clock::Edge { bit, rising })
            }
            None => None,
        };
        let clock = clock
            .ok_or_else(|| format!("part '{}': unknown clock '{name}' in the model", self.part))?;
        Ok(match self.clocks.iter().position(|&c| c == clock) {
            Some(i) => i as u8,
            None => {
                self.clocks.push(clock);
                (self.clocks.len() - 1) as u8
            }
        })
    }
}

/// Each learned state's values as a bit vector (bit `b`: signal `b`).
fn learned_vectors(part: &Part, model: &PartModel, signals: usize) -> Result<Vec<u32>, BuildError> {
    model
        .states
        .iter()
        .enumerate()
        .map(|(i, s)| {
            if s.values.len() != signals {
                return Err(format!(
                    "part '{}': state {i} has {} values for {signals} signals",
                    part.name,
                    s.values.len(),
                ));
            }
            Ok(s.values
                .iter()
                .enumerate()
                .fold(0u32, |v, (b, &x)| v | (u32::from(x) << b)))
        })
        .collect()
}

/// The motion states: the learned vectors with the inputs' bits cleared, each
/// numbered once (`states`: vector to number, `vectors`: number to vector), and
/// the motion state of each learned state.
fn motion_states(learned: &[u32], inputs: u32) -> (HashMap<u32, usize>, Vec<u32>, Vec<usize>) {
    let mut states = HashMap::new();
    let mut vectors = Vec::new();
    let motion_state: Vec<usize> = learned
        .iter()
        .map(|&v| {
            *states.entry(v & !inputs).or_insert_with(|| {
                vectors.push(v & !inputs);
                vectors.len() - 1
            })
        })
        .collect();
    (states, vectors, motion_state)
}

/// The model's transitions in the diagnoser's form: per transition its event
/// and window, and per motion state the moves out of it.
struct LearnedMoves {
    events: Vec<String>,
    windows: Vec<(u8, Time, bool)>,
    moves: Vec<Vec<Move>>,
}

impl LearnedMoves {
    #[allow(clippy::too_many_arguments)]
    fn build(
        part: &Part,
        model: &PartModel,
        learned: &[u32],
        motion_state: &[usize],
        motion_states: usize,
        clocks: &mut ClockTable<'_>,
        bit_of: &impl Fn(&str) -> Option<u8>,
        unit: TimeUnit,
        inputs: u32,
        act_mask: u32,
    ) -> Result<LearnedMoves, BuildError> {
        let mut moves: Vec<Vec<Move>> = vec![Vec::new(); motion_states];
        let mut events = Vec::with_capacity(model.transitions.len());
        let mut windows = Vec::with_capacity(model.transitions.len());
        for t in &model.transitions {
            let (Some(&from), Some(&to)) = (learned.get(t.from), learned.get(t.to)) else {
                return Err(format!(
                    "part '{}': transition {} joins unknown states",
                    part.name, t.id
                ));
            };
            events.push(t.event.clone());
            let clock = clocks.index(&t.clock, bit_of)?;
            let window = t.guard.window(unit);
            windows.push((clock, window.hi, t.timed));
            let changed = (from ^ to) & !inputs;
            if changed == 0 {
                continue; // an input's edge alone: allowed anywhere
            }
            moves[motion_state[t.from]].push(Move {
                id: t.id,
                changed,
                command: changed & act_mask != 0,
                clock,
                lo: window.lo,
                hi: window.hi,
                timed: t.timed,
                lent: false,
            });
        }
        Ok(LearnedMoves {
            events,
            windows,
            moves,
        })
    }
}

/// The changes of the moves that are the control's reactions: orders given in
/// the same scan as sensor edges.
fn reactions(moves: &[Vec<Move>], act_mask: u32) -> Vec<u32> {
    let mut reactions: Vec<u32> = moves
        .iter()
        .flatten()
        .map(|m| m.changed)
        .filter(|&c| c & act_mask != 0 && c & !act_mask != 0)
        .collect();
    reactions.sort_unstable();
    reactions.dedup();
    reactions
}

/// The normal mode, then one mode per fault of the plant that concerns the
/// part, with the partitions they belong to (numbered in order of first use).
fn fault_modes(
    plant: &Plant,
    part: &Part,
    motions: &Motions,
    names: &[String],
    bit_of: &impl Fn(&str) -> Option<u8>,
    clocks: &mut ClockTable<'_>,
) -> Result<(Vec<Mode>, Vec<String>), BuildError> {
    let mut modes = vec![Mode {
        label: "N".to_string(),
        template: None,
        kind: ModeKind::Normal,
        partition: None,
    }];
    let mut partitions: Vec<String> = Vec::new();
    for f in &plant.faults {
        let Some(kind) = mode_kind(&f.template, part, motions, bit_of) else {
            continue;
        };
        if let ModeKind::Glitch { bit, value } = kind {
            // The glitch's own clock: time since its observed edge.
            let edge = edge_name(&names[bit as usize], value);
            clocks.index(&edge, bit_of)?;
        }
        let partition = plant.partition_of(&f.label).map(|p| {
            match partitions.iter().position(|n| *n == p.name) {
                Some(i) => i,
                None => {
                    partitions.push(p.name.clone());
                    partitions.len() - 1
                }
            }
        });
        modes.push(Mode {
            label: f.label.clone(),
            template: Some(f.template.clone()),
            kind,
            partition,
        });
    }
    if partitions.len() > 32 {
        return Err(format!(
            "part '{}' has {} fault partitions; at most 32 are supported",
            part.name,
            partitions.len()
        ));
    }
    Ok((modes, partitions))
}

/// Per clock, the latest lower bound of a timed move guarded by it.
fn latest_lower_bounds(moves: &[Vec<Move>], clocks: usize) -> Vec<Time> {
    let mut latest_lo = vec![0; clocks];
    for m in moves.iter().flatten().filter(|m| m.timed) {
        let l = &mut latest_lo[m.clock as usize];
        *l = (*l).max(m.lo);
    }
    latest_lo
}

/// Bits of the part's input sensors: the plant file's `inputs` when it gives
/// them, else those the model learned.
fn input_mask(
    plant: &Plant,
    part: &Part,
    model: &PartModel,
    bit_of: &impl Fn(&str) -> Option<u8>,
) -> u32 {
    let names: Vec<&str> = match &part.inputs {
        Some(ids) => ids.iter().map(|&s| plant.signals.name(s)).collect(),
        None => model.inputs.iter().map(String::as_str).collect(),
    };
    names
        .into_iter()
        .filter_map(bit_of)
        .fold(0, |m, b| m | 1 << b)
}

/// Bits of the sensors that learning found moved from outside the part, in
/// one direction or both (`partly_input`, `input`), and that are not inputs:
/// what the rest of the part does cannot depend on their values.
fn loose_mask(model: &PartModel, bit_of: &impl Fn(&str) -> Option<u8>) -> u32 {
    model
        .sensor_classes
        .iter()
        .filter(|c| matches!(c.class, SensorKind::PartlyInput | SensorKind::Input))
        .filter_map(|c| bit_of(&c.sensor))
        .fold(0, |m, b| m | 1 << b)
}

/// Each learned set of sensor edges (a move's sensor part) that are all of
/// `free` sensors, with the bits of the state it leaves outside `free` and the edge bits'
/// values there, each once.
fn free_edges(
    vectors: &[u32],
    moves: &[Vec<Move>],
    act_mask: u32,
    free: u32,
) -> Vec<(u32, u32, u32)> {
    let mut out: Vec<(u32, u32, u32)> = vectors
        .iter()
        .zip(moves)
        .flat_map(|(&v, ms)| {
            ms.iter()
                .filter(|m| !m.lent)
                .map(move |m| m.changed & !act_mask)
                .filter(|&edges| edges != 0 && edges & !free == 0)
                .map(move |edges| (v & !free, edges, v & edges))
        })
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Per motion state, the other motion states whose vectors differ from its
/// own only in the bits `undriven`.
fn kin_states(vectors: &[u32], undriven: u32) -> Vec<Vec<usize>> {
    vectors
        .iter()
        .enumerate()
        .map(|(s, &v)| {
            (0..vectors.len())
                .filter(|&o| o != s && undriven != 0 && (v ^ vectors[o]) & !undriven == 0)
                .collect()
        })
        .collect()
}

/// Lends each motion state the moves of the states that differ from it only in
/// `loose` bits, when the moves leave those bits alone: a workpiece arriving at the entry
/// of a conveyor does not change how the one ahead of it reaches the end stop,
/// even if the learning logs never showed both at once. Lent moves are untimed
/// (their clocks were read in another state) and add no deadline.
fn borrow_moves(vectors: &[u32], moves: &mut [Vec<Move>], loose: u32) {
    if loose == 0 {
        return;
    }
    let own: Vec<Vec<Move>> = moves.to_vec();
    for (s, &v) in vectors.iter().enumerate() {
        for (o, &w) in vectors.iter().enumerate() {
            if o == s || (v ^ w) & !loose != 0 {
                continue;
            }
            for m in own[o].iter().filter(|m| m.changed & (v ^ w) == 0) {
                if !moves[s].iter().any(|n| n.changed == m.changed) {
                    moves[s].push(Move {
                        timed: false,
                        lent: true,
                        ..*m
                    });
                }
            }
        }
    }
}

/// Lends each untimed edge of an `outside` sensor alone (a refill of a
/// magazine, a workpiece taken away) to every motion state where the sensor
/// reads what the edge leaves, when the state it leads to is known: such an
/// edge comes from outside the part, whatever its motion, even if the
/// learning logs only showed it while the part stood still. Outside sensors
/// are those learning found moved from outside the part, and those the
/// part's element does not drive. Lent moves are untimed.
fn lend_outside_edges(
    vectors: &[u32],
    states: &HashMap<u32, usize>,
    moves: &mut [Vec<Move>],
    outside_bits: u32,
) {
    let outside: Vec<(u32, Move)> = moves
        .iter()
        .enumerate()
        .flat_map(|(s, ms)| ms.iter().map(move |&m| (vectors[s], m)))
        .filter(|(_, m)| !m.timed && m.changed.count_ones() == 1 && m.changed & !outside_bits == 0)
        .collect();
    for (s, &v) in vectors.iter().enumerate() {
        for &(from, m) in &outside {
            if v & m.changed == from & m.changed
                && states.contains_key(&(v ^ m.changed))
                && !moves[s].iter().any(|n| n.changed == m.changed)
            {
                moves[s].push(Move { lent: true, ..m });
            }
        }
    }
}

/// Per motion state, the indices in its moves of the events that must come.
/// Several learned states may share a motion state (they differ in inputs): it
/// has deadlines only if each of them has some, and then it is left by the last.
fn expectations(model: &PartModel, motion_state: &[usize], moves: &[Vec<Move>]) -> Vec<Vec<usize>> {
    let mut waits = vec![false; moves.len()];
    let mut expected: Vec<Vec<usize>> = vec![Vec::new(); moves.len()];
    for (i, s) in model.states.iter().enumerate() {
        let m = motion_state[i];
        let found: Vec<usize> = s
            .expected
            .iter()
            .filter_map(|e| moves[m].iter().position(|mv| mv.id == e.transition))
            .collect();
        if s.stable || found.is_empty() {
            waits[m] = true;
        }
        expected[m].extend(found);
    }
    for (m, e) in expected.iter_mut().enumerate() {
        if waits[m] {
            e.clear();
        }
        e.sort_unstable();
        e.dedup();
    }
    expected
}

/// Which sensor edges a part's element and each of its actuators move:
/// what its element and slow faults act on.
struct Motions {
    /// Bits of the sensors the element drives (the plant file's `drives`,
    /// 0 without it).
    drives: u32,
    /// Bits of the sensors the element moves: `drives`, or without it every
    /// sensor of the part but its inputs.
    element: u32,
    /// Per actuator bit, the sensor edges that follow its orders, as
    /// (rising bits, falling bits).
    orders: Vec<(u32, u32)>,
}

/// The sensor edges that follow the orders of actuator `a` in the model, as
/// (rising bits, falling bits): those of the moves out of the states an
/// edge of `a` leads to, and on through sensor edges, until another order
/// starts another motion.
fn order_edges(
    vectors: &[u32],
    states: &HashMap<u32, usize>,
    moves: &[Vec<Move>],
    act_mask: u32,
    a: u8,
) -> (u32, u32) {
    let mut seen = vec![false; vectors.len()];
    let mut queue: Vec<usize> = moves
        .iter()
        .enumerate()
        .flat_map(|(s, ms)| ms.iter().map(move |m| (s, m)))
        .filter(|(_, m)| m.changed >> a & 1 == 1)
        .filter_map(|(s, m)| states.get(&(vectors[s] ^ m.changed)).copied())
        .collect();
    let (mut rises, mut falls) = (0, 0);
    while let Some(s) = queue.pop() {
        if std::mem::replace(&mut seen[s], true) {
            continue;
        }
        for m in &moves[s] {
            let sensed = m.changed & !act_mask;
            rises |= sensed & !vectors[s];
            falls |= sensed & vectors[s];
            if m.changed & act_mask == 0 {
                queue.extend(states.get(&(vectors[s] ^ m.changed)));
            }
        }
    }
    (rises, falls)
}

/// The mode a fault template gives in `part`, if it concerns the part.
fn mode_kind(
    template: &FaultTemplate,
    part: &Part,
    motions: &Motions,
    bit_of: &impl Fn(&str) -> Option<u8>,
) -> Option<ModeKind> {
    let element_is = |e: &str| part.element.as_deref() == Some(e);
    let drives = motions.drives;
    Some(match template {
        FaultTemplate::Stuck0(s) => ModeKind::SensorStuck {
            bit: bit_of(s)?,
            value: false,
        },
        FaultTemplate::Stuck1(s) => ModeKind::SensorStuck {
            bit: bit_of(s)?,
            value: true,
        },
        FaultTemplate::UnexpectedRise(s) => ModeKind::Glitch {
            bit: bit_of(s)?,
            value: true,
        },
        FaultTemplate::UnexpectedFall(s) => ModeKind::Glitch {
            bit: bit_of(s)?,
            value: false,
        },
        FaultTemplate::ActuatorStuck0(a) => ModeKind::ActuatorStuck {
            bit: bit_of(a)?,
            value: false,
        },
        FaultTemplate::ActuatorStuck1(a) => ModeKind::ActuatorStuck {
            bit: bit_of(a)?,
            value: true,
        },
        FaultTemplate::BlockedAt { element, at } if element_is(element) => ModeKind::BlockedAt {
            bit: bit_of(at)?,
            drives,
        },
        FaultTemplate::BlockedBetween { element, from, to } if element_is(element) => {
            ModeKind::BlockedBetween {
                from: bit_of(from)?,
                to: bit_of(to)?,
                drives,
            }
        }
        FaultTemplate::Slow(x) if element_is(x) => ModeKind::Slow {
            rises: motions.element,
            falls: motions.element,
        },
        FaultTemplate::Slow(x) => {
            let &(rises, falls) = motions.orders.get(usize::from(bit_of(x)?))?;
            ModeKind::Slow { rises, falls }
        }
        _ => return None,
    })
}
