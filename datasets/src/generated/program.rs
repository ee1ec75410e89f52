//! The control program of a generated plant: one step chain per station, as a
//! PLC programmer writes it in SFC (GRAFCET).
//!
//! A station's cycle is a list of *moves*: each sets some orders and waits for
//! a sensor (an end switch, a vacuum switch, a conveyor's end stop), or for a
//! time when no sensor tells. A move may first wait for a condition: a
//! workpiece at the input, the output free. Moves that only bring a component
//! back to rest (a cylinder retracting after a push, a table turning back) run
//! in a parallel branch when nothing needs that component before later in the
//! cycle; the branch joins the sequence before the first move that does.
//!
//! The program waits for ever for a sensor that never comes, as a real program
//! without timeouts does. With [`Layout::timeouts`], a move that takes much
//! longer than it should sends its station to a safe stop: conveyors and
//! double-acting valves off, the station halted for good.
//!
//! Orders are stored actions: set when a transition fires and kept until
//! another transition changes them.

use vocabulary::{SECOND, Time};

use super::layout::{DRIFT, Hazard, Layout, MAX_JITTER, PlaceKind, Stage};
use crate::sim::Controller;

/// A transition's condition: every literal holds, and the first source step
/// has been active for at least `after`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Condition {
    /// Signals and the value each must read.
    pub literals: Vec<(usize, bool)>,
    /// Time since the first source step became active.
    pub after: Option<Time>,
}

/// A transition between steps: when all of `from` are active and the
/// condition holds, they become inactive, `to` become active and the orders
/// in `actions` are written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transition {
    /// Source steps (several: a join).
    pub from: Vec<usize>,
    /// Target steps (several: a fork).
    pub to: Vec<usize>,
    /// When it fires.
    pub condition: Condition,
    /// Orders written when it fires.
    pub actions: Vec<(usize, bool)>,
    /// A timeout: firing stops the station for good.
    pub timeout: bool,
}

/// One station's step chain.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepChain {
    /// Index of the station.
    pub station: usize,
    /// Step names, for people ("extend A11", "wait: workpiece at the input").
    pub steps: Vec<String>,
    /// Transitions, normal ones before timeouts.
    pub transitions: Vec<Transition>,
    /// Steps active at start.
    pub initial: Vec<usize>,
    /// Orders written by a safe stop.
    pub stop: Vec<(usize, bool)>,
}

/// What a move acts on, for the dependencies between moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Actor {
    Axis(usize),
    Gripper(usize),
    Conveyor(usize),
}

/// One move of a station's cycle.
#[derive(Debug, Clone)]
struct Move {
    name: String,
    actor: Actor,
    /// Conditions to start it.
    pre: Vec<(usize, bool)>,
    /// Orders written when it starts.
    set: Vec<(usize, bool)>,
    /// When it is complete.
    done: Condition,
    /// Orders written when it is complete.
    reset: Vec<(usize, bool)>,
    /// Brings a component back to rest: may run in a parallel branch.
    home: bool,
    /// Longest it may take before a safe stop.
    timeout: Time,
}

/// How much longer than nominal a timed wait lasts: the slowest stroke
/// (drift and jitter) with a quarter more.
fn patient(nominal: Time, scan: Time) -> Time {
    (nominal as f64 * (1.0 + DRIFT) * (1.0 + MAX_JITTER) * 1.25).round() as Time + 2 * scan
}

/// A timeout: twice the slowest stroke, and one second.
fn timeout(nominal: Time) -> Time {
    (nominal as f64 * (1.0 + DRIFT) * (1.0 + MAX_JITTER) * 2.0).round() as Time + SECOND
}

struct MoveBuilder<'a> {
    layout: &'a Layout,
}

impl MoveBuilder<'_> {
    /// Moves axis `axis` to end `end`.
    fn axis(&self, axis: usize, end: bool, home: bool) -> Move {
        let a = &self.layout.axes[axis];
        let (mut set, mut reset) = (Vec::new(), Vec::new());
        match (a.back, end) {
            (None, _) => set.push((a.out, end)),
            (Some(back), true) => {
                set.extend([(back, false), (a.out, true)]);
                reset.push((a.out, false));
            }
            (Some(back), false) => {
                set.extend([(a.out, false), (back, true)]);
                reset.push((back, false));
            }
        }
        let nominal = if end { a.out_time } else { a.back_time };
        let done = match a.switch(end) {
            Some(s) => Condition {
                literals: vec![(s, true)],
                after: None,
            },
            None => Condition {
                literals: Vec::new(),
                after: Some(patient(nominal, self.layout.scan_period)),
            },
        };
        Move {
            name: a.role.order(&a.tag, end),
            actor: Actor::Axis(axis),
            pre: Vec::new(),
            set,
            done,
            reset,
            home,
            timeout: timeout(nominal),
        }
    }

    fn gripper(&self, gripper: usize, grip: bool) -> Move {
        let g = &self.layout.grippers[gripper];
        let nominal = if grip { g.grip_time } else { g.release_time };
        let done = match g.holding {
            Some(s) => Condition {
                literals: vec![(s, grip)],
                after: None,
            },
            None => Condition {
                literals: Vec::new(),
                after: Some(patient(nominal, self.layout.scan_period)),
            },
        };
        Move {
            name: format!("{} {}", if grip { "grip with" } else { "release" }, g.tag),
            actor: Actor::Gripper(gripper),
            pre: Vec::new(),
            set: vec![(g.order, grip)],
            done,
            reset: Vec::new(),
            home: false,
            timeout: timeout(nominal),
        }
    }

    fn carry(&self, conveyor: usize) -> Move {
        let c = &self.layout.conveyors[conveyor];
        Move {
            name: format!("run conveyor {} to its end stop", c.tag),
            actor: Actor::Conveyor(conveyor),
            pre: vec![(c.entry, true)],
            set: vec![(c.motor, true)],
            done: Condition {
                literals: vec![(c.exit, true)],
                after: None,
            },
            reset: vec![(c.motor, false)],
            home: false,
            timeout: timeout(c.travel_time),
        }
    }

    fn dwell(&self, tool: usize, dwell: Time) -> Move {
        Move {
            name: format!("hold {} down", self.layout.axes[tool].tag),
            actor: Actor::Axis(tool),
            pre: Vec::new(),
            set: Vec::new(),
            done: Condition {
                literals: Vec::new(),
                after: Some(dwell),
            },
            reset: Vec::new(),
            home: false,
            timeout: dwell + SECOND,
        }
    }

    /// The literal saying a workpiece waits at `place`, if a sensor tells.
    fn occupied(&self, place: usize) -> Option<(usize, bool)> {
        let p = &self.layout.places[place];
        if let PlaceKind::Outlet(m) = p.kind {
            return Some((self.layout.magazines[m].empty, false));
        }
        p.sensor.map(|s| (s, p.kind != PlaceKind::Downstream))
    }

    /// The literal saying `place` is free to deliver to, if a sensor tells.
    fn free(&self, place: usize) -> Option<(usize, bool)> {
        let p = &self.layout.places[place];
        p.sensor.map(|s| (s, p.kind == PlaceKind::Downstream))
    }

    /// The moves of one cycle of `station`.
    fn cycle(&self, station: usize) -> Vec<Move> {
        let s = &self.layout.stations[station];
        let mut moves = Vec::new();
        let mut returns = Vec::new();
        for &stage in &s.stages {
            match stage {
                Stage::Push { axis, from, to } => {
                    let mut out = self.axis(axis, true, false);
                    out.pre.extend(self.occupied(from));
                    if to == s.output {
                        out.pre.extend(self.free(to));
                    }
                    moves.push(out);
                    moves.push(self.axis(axis, false, true));
                }
                Stage::Carry { conveyor, .. } => moves.push(self.carry(conveyor)),
                Stage::PickPlace {
                    arm, gripper, to, ..
                } => {
                    moves.push(self.axis(arm, false, false));
                    moves.push(self.gripper(gripper, true));
                    let mut place = self.axis(arm, true, false);
                    place.pre.extend(self.free(to));
                    moves.push(place);
                    moves.push(self.gripper(gripper, false));
                }
                Stage::Rotate { table, .. } => {
                    moves.push(self.axis(table, true, false));
                    // Turned back once the workpiece has left its nest: at the
                    // end of the cycle.
                    returns.push(self.axis(table, false, true));
                }
                Stage::Process { tool, dwell, .. } => {
                    moves.push(self.axis(tool, true, false));
                    moves.push(self.dwell(tool, dwell));
                    moves.push(self.axis(tool, false, false));
                }
            }
        }
        moves.append(&mut returns);
        moves
    }
}

/// Components that must not move while the other one is out of its rest.
fn partners(layout: &Layout, a: Actor, b: Actor) -> bool {
    if a == b {
        return true;
    }
    let (Actor::Axis(x), Actor::Axis(y)) = (a, b) else {
        return false;
    };
    layout.hazards.iter().any(|h| match *h {
        Hazard::RodVsArm { rod, arm, .. } => (rod, arm) == (x, y) || (rod, arm) == (y, x),
        Hazard::RodInNest { rod, table, .. } => (rod, table) == (x, y) || (rod, table) == (y, x),
        _ => false,
    })
}

/// Builds every station's step chain, then each tank's and cell's.
pub fn program(layout: &Layout) -> Vec<StepChain> {
    let mut chains: Vec<StepChain> = (0..layout.stations.len())
        .map(|s| chain(layout, s))
        .collect();
    chains.extend(
        layout
            .tanks
            .iter()
            .map(|t| super::process::chain(layout, t)),
    );
    chains.extend(
        layout
            .cells
            .iter()
            .map(|c| super::positioning::chain(layout, c)),
    );
    chains
}

/// One step of a chain written step by step (a tank's, a cell's): the orders
/// written on entering it, what ends it, the orders written on leaving it.
#[derive(Debug, Clone, Default)]
pub(super) struct Op {
    pub(super) name: String,
    pub(super) enter: Vec<(usize, bool)>,
    pub(super) done: Condition,
    pub(super) exit: Vec<(usize, bool)>,
    /// Longest it may take before a safe stop (none for waits on the
    /// surroundings, which may be long).
    pub(super) timeout: Option<Time>,
}

impl Op {
    /// A step ending when `signal` reads `value`.
    pub(super) fn until(name: String, signal: usize, value: bool) -> Op {
        Op {
            name,
            done: Condition {
                literals: vec![(signal, value)],
                after: None,
            },
            ..Op::default()
        }
    }

    /// A step ending after `time`.
    pub(super) fn wait(name: String, time: Time) -> Op {
        Op {
            name,
            done: Condition {
                literals: Vec::new(),
                after: Some(time),
            },
            ..Op::default()
        }
    }
}

/// Writes a chain step by step: sequences, selections on a sensor, loops.
#[derive(Debug, Default)]
pub(super) struct ChainWriter {
    ops: Vec<Op>,
    transitions: Vec<Transition>,
}

impl ChainWriter {
    /// Adds a step; returns it.
    pub(super) fn op(&mut self, op: Op) -> usize {
        self.ops.push(op);
        self.ops.len() - 1
    }

    /// From `from`, once it is done and `extra` holds, into `to`: writes
    /// `from`'s exit orders, then `to`'s entry orders.
    pub(super) fn link(&mut self, from: usize, to: usize, extra: &[(usize, bool)]) {
        let mut condition = self.ops[from].done.clone();
        condition.literals.extend_from_slice(extra);
        let mut actions = self.ops[from].exit.clone();
        actions.extend(self.ops[to].enter.iter().copied());
        self.transitions.push(Transition {
            from: vec![from],
            to: vec![to],
            condition,
            actions,
            timeout: false,
        });
    }

    /// `ops` in sequence after `from` (entered when `extra` holds too);
    /// returns the last step, or `from` when there is none.
    pub(super) fn then(&mut self, from: usize, extra: &[(usize, bool)], ops: Vec<Op>) -> usize {
        let mut last = from;
        for (k, op) in ops.into_iter().enumerate() {
            let step = self.op(op);
            self.link(last, step, if k == 0 { extra } else { &[] });
            last = step;
        }
        last
    }

    /// The chain of `station`, starting in `initial`; with `timeouts`, a step
    /// that outlasts its timeout stops the unit with the orders of `stop`.
    pub(super) fn finish(
        mut self,
        station: usize,
        initial: usize,
        stop: Vec<(usize, bool)>,
        timeouts: bool,
    ) -> StepChain {
        if timeouts {
            for (k, op) in self.ops.iter().enumerate() {
                if let Some(limit) = op.timeout {
                    self.transitions.push(Transition {
                        from: vec![k],
                        to: Vec::new(),
                        condition: Condition {
                            literals: Vec::new(),
                            after: Some(limit),
                        },
                        actions: Vec::new(),
                        timeout: true,
                    });
                }
            }
        }
        StepChain {
            station,
            steps: self.ops.into_iter().map(|o| o.name).collect(),
            transitions: self.transitions,
            initial: vec![initial],
            stop,
        }
    }
}

/// A maximal run of consecutive home moves, run in a parallel branch that
/// joins before move `join`.
struct Branch {
    first: usize,
    last: usize,
    join: usize,
}

fn branches(layout: &Layout, moves: &[Move]) -> Vec<Branch> {
    let n = moves.len();
    let mut out = Vec::new();
    let mut i = 0;
    while i < n {
        if !moves[i].home {
            i += 1;
            continue;
        }
        let first = i;
        while i + 1 < n && moves[i + 1].home {
            i += 1;
        }
        let last = i;
        let actors: Vec<Actor> = moves[first..=last].iter().map(|m| m.actor).collect();
        let join = (1..n)
            .map(|k| (last + k) % n)
            .find(|&j| {
                !(first..=last).contains(&j)
                    && actors.iter().any(|&a| partners(layout, a, moves[j].actor))
            })
            .unwrap_or(first);
        // A branch joining right away is just part of the sequence.
        if join != (last + 1) % n {
            out.push(Branch { first, last, join });
        }
        i += 1;
    }
    out
}

/// Numbers steps and wires transitions for one station.
fn chain(layout: &Layout, station: usize) -> StepChain {
    let moves = MoveBuilder { layout }.cycle(station);
    let branches = branches(layout, &moves);
    let steps = ChainSteps::new(&moves, &branches);
    let mut transitions = main_transitions(&moves, &branches, &steps);
    transitions.extend(branch_transitions(&moves, &branches, &steps));
    if layout.timeouts {
        transitions.extend(timeout_transitions(&moves, &steps));
    }
    // At start every component rests: the first move waits for a workpiece,
    // and branches that join before their own fork count as done.
    let mut initial = vec![steps.entry(0)];
    for (b, branch) in branches.iter().enumerate() {
        if branch.join <= branch.first {
            initial.push(steps.ends[b]);
        }
    }
    StepChain {
        station,
        steps: steps.names,
        transitions,
        initial,
        stop: safe_stop(layout, station),
    }
}

/// The steps of a chain: per move, an optional wait step and its body step;
/// per branch, a step that says it is done.
struct ChainSteps {
    names: Vec<String>,
    wait: Vec<Option<usize>>,
    body: Vec<usize>,
    ends: Vec<usize>,
}

impl ChainSteps {
    fn new(moves: &[Move], branches: &[Branch]) -> ChainSteps {
        let mut names: Vec<String> = Vec::new();
        let mut step = |name: String| {
            names.push(name);
            names.len() - 1
        };
        // Each main move has a wait step when it waits for a condition or a join.
        let mut wait = vec![None; moves.len()];
        let mut body = vec![0; moves.len()];
        for (i, m) in moves.iter().enumerate() {
            if !in_branch(branches, i) && (!m.pre.is_empty() || !joins_at(branches, i).is_empty()) {
                wait[i] = Some(step(format!("wait before: {}", m.name)));
            }
            body[i] = step(m.name.clone());
        }
        let ends = branches
            .iter()
            .map(|b| step(format!("done: {}", moves[b.last].name)))
            .collect();
        ChainSteps {
            names,
            wait,
            body,
            ends,
        }
    }

    /// The step a move's turn starts in.
    fn entry(&self, i: usize) -> usize {
        self.wait[i].unwrap_or(self.body[i])
    }
}

/// Whether move `i` runs in a parallel branch.
fn in_branch(branches: &[Branch], i: usize) -> bool {
    branches.iter().any(|b| (b.first..=b.last).contains(&i))
}

/// The branches that join before move `i`.
fn joins_at(branches: &[Branch], i: usize) -> Vec<usize> {
    branches
        .iter()
        .enumerate()
        .filter(|(_, b)| b.join == i)
        .map(|(k, _)| k)
        .collect()
}

/// The main sequence: out of each move to the next one's entry (and into any
/// branch forking there), and from a wait step, once its branches have
/// joined and its condition holds, into the move.
fn main_transitions(moves: &[Move], branches: &[Branch], steps: &ChainSteps) -> Vec<Transition> {
    let mut transitions = Vec::new();
    let main: Vec<usize> = (0..moves.len())
        .filter(|&i| !in_branch(branches, i))
        .collect();
    for (k, &i) in main.iter().enumerate() {
        let next = main[(k + 1) % main.len()];
        let mut to = vec![steps.entry(next)];
        let mut actions = moves[i].reset.clone();
        if steps.wait[next].is_none() {
            actions.extend(moves[next].set.iter().copied());
        }
        if let Some(b) = branches.iter().find(|b| b.first == (i + 1) % moves.len()) {
            to.push(steps.body[b.first]);
            actions.extend(moves[b.first].set.iter().copied());
        }
        transitions.push(Transition {
            from: vec![steps.body[i]],
            to,
            condition: moves[i].done.clone(),
            actions,
            timeout: false,
        });
        if let Some(w) = steps.wait[i] {
            let mut from = vec![w];
            from.extend(joins_at(branches, i).into_iter().map(|b| steps.ends[b]));
            transitions.push(Transition {
                from,
                to: vec![steps.body[i]],
                condition: Condition {
                    literals: moves[i].pre.clone(),
                    after: None,
                },
                actions: moves[i].set.clone(),
                timeout: false,
            });
        }
    }
    transitions
}

/// Each parallel branch: move by move, then into its done step.
fn branch_transitions(moves: &[Move], branches: &[Branch], steps: &ChainSteps) -> Vec<Transition> {
    let mut transitions = Vec::new();
    for (b, branch) in branches.iter().enumerate() {
        for i in branch.first..=branch.last {
            let (to, mut actions) = if i < branch.last {
                (steps.body[i + 1], moves[i + 1].set.clone())
            } else {
                (steps.ends[b], Vec::new())
            };
            let mut all = moves[i].reset.clone();
            all.append(&mut actions);
            transitions.push(Transition {
                from: vec![steps.body[i]],
                to: vec![to],
                condition: moves[i].done.clone(),
                actions: all,
                timeout: false,
            });
        }
    }
    transitions
}

/// A move that outlasts its timeout sends the station to its safe stop.
fn timeout_transitions(moves: &[Move], steps: &ChainSteps) -> Vec<Transition> {
    moves
        .iter()
        .enumerate()
        .map(|(i, m)| Transition {
            from: vec![steps.body[i]],
            to: Vec::new(),
            condition: Condition {
                literals: Vec::new(),
                after: Some(m.timeout),
            },
            actions: Vec::new(),
            timeout: true,
        })
        .collect()
}

/// A safe stop: conveyors and double-acting valves off; single-acting
/// cylinders and grippers keep their orders, so that nothing drops.
fn safe_stop(layout: &Layout, station: usize) -> Vec<(usize, bool)> {
    let mut out = Vec::new();
    for a in layout.axes.iter().filter(|a| a.station == station) {
        if let Some(back) = a.back {
            out.extend([(a.out, false), (back, false)]);
        }
    }
    for c in layout.conveyors.iter().filter(|c| c.station == station) {
        out.push((c.motor, false));
    }
    out
}

/// The running program: every station's step chain.
#[derive(Debug, Clone)]
pub struct StepChains {
    chains: Vec<Running>,
}

#[derive(Debug, Clone)]
struct Running {
    chain: StepChain,
    /// Per step, the transitions leaving it.
    leaving: Vec<Vec<usize>>,
    active: Vec<bool>,
    since: Vec<Time>,
    /// When a timeout stopped the station, and in which step.
    stopped: Option<(Time, usize)>,
    started: bool,
    /// Transitions firing in this scan (kept to avoid an allocation per scan).
    firing: Vec<usize>,
}

impl StepChains {
    /// The program of `layout`, every chain in its initial steps.
    pub fn new(layout: &Layout) -> StepChains {
        let chains = program(layout)
            .into_iter()
            .map(|chain| {
                let mut leaving = vec![Vec::new(); chain.steps.len()];
                for (k, t) in chain.transitions.iter().enumerate() {
                    for &s in &t.from {
                        leaving[s].push(k);
                    }
                }
                let mut active = vec![false; chain.steps.len()];
                for &s in &chain.initial {
                    active[s] = true;
                }
                Running {
                    since: vec![0; chain.steps.len()],
                    chain,
                    leaving,
                    active,
                    stopped: None,
                    started: false,
                    firing: Vec::new(),
                }
            })
            .collect();
        StepChains { chains }
    }

    /// Stations stopped by a timeout: the station, when, and the step that
    /// took too long.
    pub fn stopped(&self) -> Vec<(usize, Time, &str)> {
        self.chains
            .iter()
            .filter_map(|c| {
                let (t, step) = c.stopped?;
                Some((c.chain.station, t, c.chain.steps[step].as_str()))
            })
            .collect()
    }

    /// The names of each station's active steps.
    pub fn active_steps(&self) -> Vec<Vec<&str>> {
        self.chains
            .iter()
            .map(|c| {
                (0..c.active.len())
                    .filter(|&s| c.active[s])
                    .map(|s| c.chain.steps[s].as_str())
                    .collect()
            })
            .collect()
    }
}

impl Running {
    fn holds(&self, t: Time, tr: &Transition, io: &[bool]) -> bool {
        tr.from.iter().all(|&s| self.active[s])
            && tr.condition.literals.iter().all(|&(s, v)| io[s] == v)
            && tr
                .condition
                .after
                .is_none_or(|d| t - self.since[tr.from[0]] >= d)
    }

    /// One scan: every enabled transition fires once (SFC without search for
    /// stability); a step left by one transition is not left again.
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        if self.stopped.is_some() {
            return;
        }
        if !self.started {
            self.started = true;
            self.since.iter_mut().for_each(|s| *s = t);
        }
        let mut firing = std::mem::take(&mut self.firing);
        firing.clear();
        for s in 0..self.active.len() {
            if !self.active[s] {
                continue;
            }
            for &k in &self.leaving[s] {
                let tr = &self.chain.transitions[k];
                let taken = firing.iter().any(|&f| {
                    self.chain.transitions[f]
                        .from
                        .iter()
                        .any(|x| tr.from.contains(x))
                });
                if !taken && self.holds(t, tr, io) {
                    firing.push(k);
                }
            }
        }
        for &k in &firing {
            let tr = &self.chain.transitions[k];
            if tr.timeout {
                self.stopped = Some((t, tr.from[0]));
                self.active.iter_mut().for_each(|a| *a = false);
                for &(s, v) in &self.chain.stop {
                    io[s] = v;
                }
                break;
            }
            for &s in &tr.from {
                self.active[s] = false;
            }
            for &s in &tr.to {
                self.active[s] = true;
                self.since[s] = t;
            }
            for &(s, v) in &tr.actions {
                io[s] = v;
            }
        }
        self.firing = firing;
    }
}

impl Controller for StepChains {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        for c in &mut self.chains {
            c.scan(t, io);
        }
    }
}
