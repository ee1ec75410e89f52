//! The physics of a generated plant: axes, grippers, conveyors, magazines and
//! the workpieces they move, and the surroundings (an operator refilling
//! magazines, an upstream machine feeding, a next machine taking workpieces).
//!
//! Positions are fractions. An axis runs from end 0 to end 1, its switches on
//! within [`AT_END`] of each end; a stroke's duration is the component's
//! nominal time, scaled by a drift drawn once per run and a jitter drawn per
//! stroke. A workpiece is at a place, pushed by a rod (it moves with the rod
//! tip once the rod reaches it), on a belt (it moves with the belt, queueing
//! behind the one ahead), or carried (in a gripper, or in a rotary table's
//! nest). Sensors read these positions; the program sees them through any
//! injected sensor fault.
//!
//! Every component draws its randomness from its own stream, seeded from the
//! run's seed, so that what happens in one station does not change the draws
//! of another: two runs that differ only by a fault differ only where the
//! fault's effects reach.
//!
//! Damage: `collision` when a rod meets a swivel arm, or a table turns with a
//! rod in its nest; `workpiece_dropped` when a gripper lets go between
//! positions or a workpiece is pushed onto a table that is not there;
//! `workpiece_jam` when a workpiece is delivered onto an occupied place.
//!
//! Tanks and positioning cells keep their own state and damage
//! ([`super::process`], [`super::positioning`]). A `slow` fault stretches the
//! nominal times of the component it names, from the stroke under way on.

use std::sync::Arc;

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use vocabulary::{FaultTemplate, Plant, Time, fault::Factor};

use super::layout::{DRIFT, Hazard, Layout, Middle, PlaceKind, Stage};
use super::positioning::{CarriageBlock, CellState};
use super::process::TankState;
use crate::sim::{Damage, Physics};

/// Distance from an end within which an end switch is on.
pub const AT_END: f64 = 0.02;
/// Rod position at which it reaches the workpiece it pushes.
const CONTACT: f64 = 0.05;
/// Share of a belt a workpiece takes; also the entry sensor's field.
const WORKPIECE: f64 = 0.1;
/// Belt position from which the end-stop sensor sees a workpiece.
const AT_STOP: f64 = 0.97;
/// Half-width of the field of a sensor half-way along a belt.
const MIDDLE_FIELD: f64 = 0.06;
/// Gripper level at which it holds (or lets go of) a workpiece.
const GRIPS: f64 = 0.5;
/// Gripper level from which its sensor reports a held workpiece.
const SENSES: f64 = 0.8;

/// An element fault of one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Block {
    /// Cannot leave end `end` (once there).
    At { end: bool },
    /// Freezes half-way on its next stroke towards `towards`; `frozen` once it has.
    Between { towards: bool, frozen: bool },
}

#[derive(Debug, Clone)]
struct AxisState {
    r: f64,
    /// The end the valve drives it to.
    valve: bool,
    /// Speed of the current stroke, position per nanosecond.
    speed: f64,
    drift: f64,
    block: Option<Block>,
    /// A `slow` fault's factor on its strokes.
    slow: Option<Factor>,
    rng: ChaCha8Rng,
}

#[derive(Debug, Clone)]
struct GripperState {
    level: f64,
    drift: f64,
    slow: Option<Factor>,
    /// The workpiece held, by index.
    holding: Option<usize>,
}

#[derive(Debug, Clone)]
struct ConveyorState {
    /// Belt speed, position per nanosecond, drawn per run and per start.
    speed: f64,
    drift: f64,
    running: bool,
    slow: Option<Factor>,
    rng: ChaCha8Rng,
}

#[derive(Debug, Clone)]
struct MagazineState {
    count: u32,
    refill_at: Option<Time>,
    rng: ChaCha8Rng,
}

/// Where a workpiece is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Loc {
    At(usize),
    Pushed {
        axis: usize,
        q: f64,
    },
    Belt {
        conveyor: usize,
        x: f64,
    },
    /// In the gripper on an arm (by the arm's axis): at no place.
    Held(usize),
    /// In a rotary table's nest: at the place where the table is.
    Nest(usize),
    Gone,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Workpiece {
    loc: Loc,
    metallic: bool,
}

/// Which places an axis or conveyor links, precomputed from the stages.
#[derive(Debug, Clone, Default)]
struct Geometry {
    /// Per axis: the places at its ends it carries a workpiece between (arm
    /// with gripper, table nest).
    carries: Vec<Option<(usize, usize)>>,
    /// Per axis: the places it pushes from and to.
    pushes: Vec<Option<(usize, usize)>>,
    /// Per conveyor: entry and end-stop places.
    belts: Vec<(usize, usize)>,
    /// Per gripper: its arm.
    arm_of: Vec<usize>,
    /// Per place: the station whose output it is.
    output_of: Vec<Option<usize>>,
    /// The place the upstream machine feeds, if any.
    feed: Option<usize>,
}

impl Geometry {
    fn new(layout: &Layout) -> Geometry {
        let mut g = Geometry {
            carries: vec![None; layout.axes.len()],
            pushes: vec![None; layout.axes.len()],
            belts: vec![(0, 0); layout.conveyors.len()],
            arm_of: layout.grippers.iter().map(|g| g.arm).collect(),
            output_of: vec![None; layout.places.len()],
            feed: None,
        };
        for (k, s) in layout.stations.iter().enumerate() {
            g.output_of[s.output] = Some(k);
            for stage in &s.stages {
                match *stage {
                    Stage::Push { axis, from, to } => g.pushes[axis] = Some((from, to)),
                    Stage::Carry { conveyor, from, to } => g.belts[conveyor] = (from, to),
                    Stage::PickPlace { arm, from, to, .. } => g.carries[arm] = Some((from, to)),
                    Stage::Rotate { table, from, to } => g.carries[table] = Some((from, to)),
                    Stage::Process { .. } => {}
                }
            }
        }
        if let Some(first) = layout.stations.first() {
            let input = &layout.places[first.input];
            if !matches!(input.kind, PlaceKind::Outlet(_)) {
                g.feed = Some(first.input);
            }
        }
        g
    }
}

/// The state of the surroundings and the counters.
#[derive(Debug, Clone, Default)]
struct Environment {
    feed_at: Option<Time>,
    busy_until: Option<Time>,
    feed_rng: Option<ChaCha8Rng>,
    downstream_rng: Option<ChaCha8Rng>,
    delivered: u64,
    lost: u64,
    refills: u64,
    cycles: Vec<u64>,
}

/// A generated plant's physics.
#[derive(Debug, Clone)]
pub struct GeneratedPhysics {
    layout: Arc<Layout>,
    plant: Arc<Plant>,
    toml: Arc<str>,
    geometry: Arc<Geometry>,
    axes: Vec<AxisState>,
    grippers: Vec<GripperState>,
    conveyors: Vec<ConveyorState>,
    magazines: Vec<MagazineState>,
    workpieces: Vec<Workpiece>,
    around: Environment,
    tanks: Vec<TankState>,
    cells: Vec<CellState>,
    /// Per hazard: whether it is being recorded already (one record per incident).
    latched: Vec<bool>,
    last_t: Option<Time>,
    seeded: bool,
    /// Axis positions before this scan's moves (kept to avoid an allocation).
    before: Vec<f64>,
}

fn seeded(base: u64, stream: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(base ^ stream.wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

fn drift(rng: &mut ChaCha8Rng) -> f64 {
    rng.random_range(1.0 - DRIFT..=1.0 + DRIFT)
}

impl GeneratedPhysics {
    /// The plant at rest: axes at their rest ends, magazines not yet filled
    /// (they are filled at the first scan, from the run's seed).
    pub fn new(layout: Arc<Layout>, plant: Arc<Plant>, toml: Arc<str>) -> GeneratedPhysics {
        let zero = ChaCha8Rng::seed_from_u64(0);
        let axes = layout
            .axes
            .iter()
            .map(|a| {
                let rest = a.role.rest();
                AxisState {
                    r: if rest { 1.0 } else { 0.0 },
                    valve: rest,
                    speed: 0.0,
                    drift: 1.0,
                    block: None,
                    slow: None,
                    rng: zero.clone(),
                }
            })
            .collect();
        GeneratedPhysics {
            geometry: Arc::new(Geometry::new(&layout)),
            axes,
            grippers: vec![
                GripperState {
                    level: 0.0,
                    drift: 1.0,
                    slow: None,
                    holding: None
                };
                layout.grippers.len()
            ],
            conveyors: vec![
                ConveyorState {
                    speed: 0.0,
                    drift: 1.0,
                    running: false,
                    slow: None,
                    rng: zero.clone(),
                };
                layout.conveyors.len()
            ],
            magazines: vec![
                MagazineState {
                    count: 0,
                    refill_at: None,
                    rng: zero.clone(),
                };
                layout.magazines.len()
            ],
            workpieces: Vec::new(),
            tanks: layout
                .tanks
                .iter()
                .map(|_| TankState::new(zero.clone()))
                .collect(),
            cells: layout
                .cells
                .iter()
                .map(|c| CellState::new(c, zero.clone()))
                .collect(),
            around: Environment {
                cycles: vec![0; layout.stations.len()],
                ..Environment::default()
            },
            latched: vec![false; layout.hazards.len()],
            last_t: None,
            seeded: false,
            before: Vec::new(),
            layout,
            plant,
            toml,
        }
    }

    /// Workpieces delivered to the output of each station so far.
    pub fn cycles(&self) -> &[u64] {
        &self.around.cycles
    }

    /// Draws each component's stream, drift and the magazines' first fill.
    fn seed(&mut self, rng: &mut ChaCha8Rng) {
        let base = rng.next_u64();
        let mut stream = 0u64;
        let mut next = || {
            stream += 1;
            seeded(base, stream)
        };
        for a in &mut self.axes {
            a.rng = next();
            a.drift = drift(&mut a.rng);
        }
        for g in &mut self.grippers {
            let mut r = next();
            g.drift = drift(&mut r);
        }
        for c in &mut self.conveyors {
            c.rng = next();
            c.drift = drift(&mut c.rng);
        }
        let (lo, hi) = self.layout.surroundings.refill_count;
        for m in &mut self.magazines {
            m.rng = next();
            m.count = m.rng.random_range(lo..=hi);
        }
        self.around.feed_rng = Some(next());
        self.around.downstream_rng = Some(next());
        // Tanks and cells draw after the line, so that a line keeps its draws.
        for t in &mut self.tanks {
            t.seed(next());
        }
        for c in &mut self.cells {
            c.seed(next());
        }
        self.seeded = true;
    }

    fn move_axes(&mut self, dt: f64, act: &[bool]) {
        for (a, spec) in self.axes.iter_mut().zip(&self.layout.axes) {
            let valve = match spec.back {
                None => act[spec.out],
                Some(back) => match (act[spec.out], act[back]) {
                    (true, false) => true,
                    (false, true) => false,
                    _ => a.valve,
                },
            };
            if valve != a.valve || a.speed == 0.0 {
                a.valve = valve;
                let mut nominal = if valve { spec.out_time } else { spec.back_time };
                if let Some(f) = a.slow {
                    nominal = f.stretch(nominal);
                }
                let jitter = a.rng.random_range(-spec.jitter..=spec.jitter);
                a.speed = 1.0 / (nominal as f64 * a.drift * (1.0 + jitter));
            }
            let old = a.r;
            let mut new = if valve {
                (old + a.speed * dt).min(1.0)
            } else {
                (old - a.speed * dt).max(0.0)
            };
            match &mut a.block {
                Some(Block::At { end }) => {
                    let at = if *end {
                        old >= 1.0 - AT_END
                    } else {
                        old <= AT_END
                    };
                    if at {
                        new = old;
                    }
                }
                Some(Block::Between { towards, frozen }) => {
                    if *frozen {
                        new = old;
                    } else if *towards == valve && old != new && (old - 0.5) * (new - 0.5) <= 0.0 {
                        *frozen = true;
                        new = 0.5;
                    }
                }
                None => {}
            }
            a.r = new;
        }
    }

    fn at_end(&self, axis: usize) -> Option<bool> {
        let r = self.axes[axis].r;
        if r <= AT_END {
            Some(false)
        } else if r >= 1.0 - AT_END {
            Some(true)
        } else {
            None
        }
    }

    /// The place a workpiece is at, if it is at one.
    fn place_of(&self, loc: Loc) -> Option<usize> {
        match loc {
            Loc::At(p) => Some(p),
            Loc::Belt { conveyor, x } => {
                let (entry, stop) = self.geometry.belts[conveyor];
                if x <= WORKPIECE {
                    Some(entry)
                } else if x >= AT_STOP {
                    Some(stop)
                } else {
                    None
                }
            }
            Loc::Nest(axis) => {
                let (p0, p1) = self.geometry.carries[axis]?;
                self.at_end(axis).map(|e| if e { p1 } else { p0 })
            }
            Loc::Pushed { .. } | Loc::Held(_) | Loc::Gone => None,
        }
    }

    fn at_place(&self, place: usize) -> Option<usize> {
        self.workpieces
            .iter()
            .position(|w| self.place_of(w.loc) == Some(place))
    }

    fn occupied(&self, place: usize) -> bool {
        self.at_place(place).is_some()
    }

    fn lose(
        &mut self,
        w: usize,
        t: Time,
        cause: &'static str,
        detail: String,
        damage: &mut Vec<Damage>,
    ) {
        self.workpieces[w].loc = Loc::Gone;
        self.around.lost += 1;
        damage.push(Damage { t, cause, detail });
    }

    /// Puts workpiece `w` at `place`, or records what went wrong.
    fn deliver(&mut self, w: usize, place: usize, t: Time, damage: &mut Vec<Damage>) {
        if let Some(station) = self.geometry.output_of[place] {
            self.around.cycles[station] += 1;
        }
        let name = self.layout.places[place].name.clone();
        let kind = self.layout.places[place].kind;
        if kind == PlaceKind::Downstream {
            if self.around.busy_until.is_some() {
                let detail = format!("a workpiece was pushed into {name} while it was busy");
                return self.lose(w, t, "workpiece_jam", detail, damage);
            }
            self.workpieces[w].loc = Loc::Gone;
            self.around.delivered += 1;
            let (lo, hi) = self.layout.surroundings.downstream;
            let rng = self
                .around
                .downstream_rng
                .get_or_insert_with(|| seeded(0, 0));
            self.around.busy_until = Some(t + rng.random_range(lo..=hi));
            return;
        }
        if self.occupied(place) {
            let detail = format!("a workpiece was delivered onto {name}, which was occupied");
            return self.lose(w, t, "workpiece_jam", detail, damage);
        }
        self.workpieces[w].loc = match kind {
            PlaceKind::BeltEntry(conveyor) => Loc::Belt { conveyor, x: 0.0 },
            PlaceKind::Nest { table, end } => {
                if self.at_end(table) != Some(end) {
                    let detail =
                        format!("a workpiece was pushed onto {name}, but the table was not there");
                    return self.lose(w, t, "workpiece_dropped", detail, damage);
                }
                Loc::Nest(table)
            }
            _ => Loc::At(place),
        };
    }

    /// Rods reach the workpiece they push, and push it on to their target.
    fn push(&mut self, before: &[f64], t: Time, damage: &mut Vec<Damage>) {
        for (axis, &r_before) in before.iter().enumerate().take(self.axes.len()) {
            let Some((from, to)) = self.geometry.pushes[axis] else {
                continue;
            };
            let r = self.axes[axis].r;
            if r > r_before
                && r_before <= CONTACT
                && r > CONTACT
                && let Some(w) = self.at_place(from)
            {
                self.workpieces[w].loc = Loc::Pushed { axis, q: r };
            }
            for w in 0..self.workpieces.len() {
                if let Loc::Pushed { axis: a, q } = self.workpieces[w].loc {
                    if a != axis {
                        continue;
                    }
                    let q = q.max(r);
                    self.workpieces[w].loc = Loc::Pushed { axis, q };
                    if q >= 1.0 - AT_END {
                        self.deliver(w, to, t, damage);
                    }
                }
            }
        }
    }

    fn run_belts(&mut self, dt: f64, act: &[bool]) {
        for c in 0..self.conveyors.len() {
            let on = act[self.layout.conveyors[c].motor];
            let state = &mut self.conveyors[c];
            if on && !state.running {
                let jitter = state.rng.random_range(-0.02..=0.02);
                let mut travel = self.layout.conveyors[c].travel_time;
                if let Some(f) = state.slow {
                    travel = f.stretch(travel);
                }
                let travel = travel as f64 * state.drift * (1.0 + jitter);
                state.speed = (1.0 - WORKPIECE) / travel;
            }
            state.running = on;
            if !on {
                continue;
            }
            let step = state.speed * dt;
            // Front first: each workpiece queues behind the one ahead.
            let mut on_belt: Vec<(usize, f64)> = self
                .workpieces
                .iter()
                .enumerate()
                .filter_map(|(i, w)| match w.loc {
                    Loc::Belt { conveyor, x } if conveyor == c => Some((i, x)),
                    _ => None,
                })
                .collect();
            on_belt.sort_by(|a, b| b.1.total_cmp(&a.1));
            let mut limit = 1.0;
            for (i, x) in on_belt {
                let x = (x + step).min(limit).max(x);
                self.workpieces[i].loc = Loc::Belt { conveyor: c, x };
                limit = x - WORKPIECE;
            }
        }
    }

    fn grip(&mut self, dt: f64, act: &[bool], t: Time, damage: &mut Vec<Damage>) {
        let layout = Arc::clone(&self.layout);
        for (g, spec) in layout.grippers.iter().enumerate() {
            let on = act[spec.order];
            let state = &mut self.grippers[g];
            let mut time = if on {
                spec.grip_time
            } else {
                spec.release_time
            };
            if let Some(f) = state.slow {
                time = f.stretch(time);
            }
            let time = time as f64 * state.drift;
            state.level = if on {
                (state.level + dt / time).min(1.0)
            } else {
                (state.level - dt / time).max(0.0)
            };
            let (level, holding) = (state.level, state.holding);
            let arm = spec.arm;
            let Some((pick, place)) = self.geometry.carries[arm] else {
                continue;
            };
            let end = self.at_end(arm);
            match holding {
                None if level >= GRIPS => {
                    let here = match end {
                        Some(true) => place,
                        Some(false) => pick,
                        None => continue,
                    };
                    if let Some(w) = self.at_place(here) {
                        self.workpieces[w].loc = Loc::Held(arm);
                        self.grippers[g].holding = Some(w);
                    }
                }
                Some(w) if level < GRIPS => {
                    self.grippers[g].holding = None;
                    self.workpieces[w].loc = Loc::Gone;
                    match end {
                        Some(end) => self.deliver(w, if end { place } else { pick }, t, damage),
                        None => {
                            let detail = format!(
                                "gripper {} let go of a workpiece while arm {} was between positions",
                                spec.tag, layout.axes[arm].tag
                            );
                            self.lose(w, t, "workpiece_dropped", detail, damage);
                        }
                    }
                }
                _ => {}
            }
        }
    }

    /// The operator, the upstream machine and the next machine.
    fn surroundings(&mut self, t: Time) {
        let s = self.layout.surroundings;
        for m in 0..self.magazines.len() {
            let outlet = self.layout.magazines[m].outlet;
            let outlet_free = !self.occupied(outlet);
            let state = &mut self.magazines[m];
            // The operator refills first: a refill shows on the sensor only once
            // a workpiece has dropped into the outlet, in the same instant.
            match state.refill_at {
                None if state.count == 0 && outlet_free => {
                    state.refill_at = Some(t + state.rng.random_range(s.refill.0..=s.refill.1));
                }
                Some(at) if t >= at => {
                    state.count += state.rng.random_range(s.refill_count.0..=s.refill_count.1);
                    state.refill_at = None;
                    self.around.refills += 1;
                }
                _ => {}
            }
            let pusher = self
                .geometry
                .pushes
                .iter()
                .position(|p| p.is_some_and(|p| p.0 == outlet));
            let rod_back = pusher.is_none_or(|a| self.axes[a].r <= CONTACT);
            let state = &mut self.magazines[m];
            if state.count > 0 && outlet_free && rod_back {
                state.count -= 1;
                let metallic = state.rng.random_bool(s.metallic);
                self.workpieces.push(Workpiece {
                    loc: Loc::At(outlet),
                    metallic,
                });
            }
        }
        if let Some(feed) = self.geometry.feed {
            self.feed(feed, t);
        }
        if self.around.busy_until.is_some_and(|u| t >= u) {
            self.around.busy_until = None;
        }
    }

    fn feed(&mut self, feed: usize, t: Time) {
        let s = self.layout.surroundings;
        let free = !self.occupied(feed);
        let rng = self.around.feed_rng.get_or_insert_with(|| seeded(0, 0));
        match self.around.feed_at {
            None if free => self.around.feed_at = Some(t + rng.random_range(s.feed.0..=s.feed.1)),
            Some(at) if t >= at && free => {
                let metallic = rng.random_bool(s.metallic);
                self.around.feed_at = None;
                let loc = match self.layout.places[feed].kind {
                    PlaceKind::BeltEntry(conveyor) => Loc::Belt { conveyor, x: 0.0 },
                    _ => Loc::At(feed),
                };
                self.workpieces.push(Workpiece { loc, metallic });
            }
            _ => {}
        }
    }

    fn check_hazards(&mut self, t: Time, damage: &mut Vec<Damage>) {
        for (k, h) in self.layout.hazards.iter().enumerate() {
            let (now, detail) = match *h {
                Hazard::RodVsArm { rod, arm, end } => {
                    let near = (self.axes[arm].r - if end { 1.0 } else { 0.0 }).abs() < 0.5;
                    (self.axes[rod].r > 0.5 && near, (rod, arm, "hit swivel arm"))
                }
                Hazard::RodInNest { rod, table, end } => {
                    let away = (self.axes[table].r - if end { 1.0 } else { 0.0 }).abs() > AT_END;
                    (
                        self.axes[rod].r > 0.3 && away,
                        (rod, table, "was in the nest of rotary table"),
                    )
                }
                _ => continue,
            };
            if now && !self.latched[k] {
                let (a, b, what) = detail;
                damage.push(Damage {
                    t,
                    cause: "collision",
                    detail: format!(
                        "the rod of {} {} {what} {}",
                        self.layout.axes[a].role.noun(),
                        self.layout.axes[a].tag,
                        self.layout.axes[b].tag
                    ),
                });
            }
            self.latched[k] = now;
        }
    }

    /// Work done by each unit so far: workpieces delivered by each station,
    /// then batches of each tank and workpieces of each cell.
    pub fn unit_cycles(&self) -> Vec<u64> {
        let mut out = self.around.cycles.clone();
        out.extend(self.tanks.iter().map(TankState::batches));
        out.extend(self.cells.iter().map(CellState::delivered));
        out
    }

    /// A blocking fault of a cell's carriage; `None` if `template` names no
    /// carriage.
    fn inject_carriage_fault(&mut self, template: &FaultTemplate) -> Option<Result<(), String>> {
        let (element, ends) = match template {
            FaultTemplate::BlockedAt { element, at } => (element, vec![at]),
            FaultTemplate::BlockedBetween { element, from, to } => (element, vec![from, to]),
            _ => return None,
        };
        let k = self.layout.cells.iter().position(|c| &c.tag == element)?;
        let cell = &self.layout.cells[k];
        let mut at = Vec::new();
        for name in ends {
            let position = self
                .layout
                .signals
                .iter()
                .position(|s| &s.name == name)
                .and_then(|s| cell.position_of(s));
            match position {
                Some(p) => at.push(p),
                None => {
                    return Some(Err(format!(
                        "{name} is not a cam switch of axis {}",
                        cell.tag
                    )));
                }
            }
        }
        let block = match at.as_slice() {
            [p] => CarriageBlock::At(*p),
            [a, b] if a != b => CarriageBlock::Between {
                from: *a,
                to: *b,
                frozen: false,
            },
            _ => return Some(Err(format!("{template}: the two positions must differ"))),
        };
        self.cells[k].block(block);
        Some(Ok(()))
    }

    fn axis_of_element(&self, element: &str) -> Result<usize, String> {
        self.layout
            .axes
            .iter()
            .position(|a| a.tag == element)
            .ok_or_else(|| format!("plant '{}' has no element {element}", self.layout.name))
    }

    fn end_of(&self, axis: usize, sensor: &str) -> Result<bool, String> {
        let a = &self.layout.axes[axis];
        let name = |s: Option<usize>| s.map(|s| self.layout.signals[s].name.as_str());
        if name(a.at0) == Some(sensor) {
            Ok(false)
        } else if name(a.at1) == Some(sensor) {
            Ok(true)
        } else {
            Err(format!("{sensor} is not an end switch of {}", a.tag))
        }
    }
}

impl Physics for GeneratedPhysics {
    fn plant(&self) -> &Plant {
        &self.plant
    }

    fn plant_toml(&self) -> &str {
        &self.toml
    }

    fn advance(&mut self, t: Time, act: &[bool], rng: &mut ChaCha8Rng, damage: &mut Vec<Damage>) {
        if !self.seeded {
            self.seed(rng);
        }
        let Some(last) = self.last_t.replace(t) else {
            self.surroundings(t);
            return;
        };
        let dt = (t - last) as f64;
        let mut before = std::mem::take(&mut self.before);
        before.clear();
        before.extend(self.axes.iter().map(|a| a.r));
        self.move_axes(dt, act);
        self.push(&before, t, damage);
        self.before = before;
        self.run_belts(dt, act);
        self.grip(dt, act, t, damage);
        self.surroundings(t);
        self.check_hazards(t, damage);
        for (state, tank) in self.tanks.iter_mut().zip(&self.layout.tanks) {
            state.advance(tank, t, dt, act, damage);
        }
        for (state, cell) in self.cells.iter_mut().zip(&self.layout.cells) {
            let clamp = self.axes[cell.clamp].r;
            state.advance(cell, (t, dt), act, clamp, damage);
        }
        self.workpieces.retain(|w| w.loc != Loc::Gone);
        for g in &mut self.grippers {
            // Indices shift when workpieces are removed: find the held one again.
            g.holding = None;
        }
        for (i, w) in self.workpieces.iter().enumerate() {
            if let Loc::Held(axis) = w.loc
                && let Some(g) = self.geometry.arm_of.iter().position(|&a| a == axis)
            {
                self.grippers[g].holding = Some(i);
            }
        }
    }

    fn read_sensors(&self, io: &mut [bool]) {
        for (a, spec) in self.axes.iter().zip(&self.layout.axes) {
            if let Some(s) = spec.at0 {
                io[s] = a.r <= AT_END;
            }
            if let Some(s) = spec.at1 {
                io[s] = a.r >= 1.0 - AT_END;
            }
        }
        for (g, spec) in self.grippers.iter().zip(&self.layout.grippers) {
            if let Some(s) = spec.holding {
                io[s] = g.holding.is_some() && g.level >= SENSES;
            }
        }
        for (c, spec) in self.layout.conveyors.iter().enumerate() {
            let xs = self.workpieces.iter().filter_map(|w| match w.loc {
                Loc::Belt { conveyor, x } if conveyor == c => Some((x, w.metallic)),
                _ => None,
            });
            let (mut entry, mut middle, mut exit) = (false, false, false);
            for (x, metallic) in xs {
                entry |= x <= WORKPIECE;
                exit |= x >= AT_STOP;
                let passing = (x - 0.5).abs() <= MIDDLE_FIELD;
                middle |= match spec.middle {
                    Some(Middle::Metal(_)) => passing && metallic,
                    _ => passing,
                };
            }
            io[spec.entry] = entry;
            io[spec.exit] = exit;
            if let Some(Middle::Metal(s) | Middle::Presence(s)) = spec.middle {
                io[s] = middle;
            }
        }
        for (m, spec) in self.magazines.iter().zip(&self.layout.magazines) {
            io[spec.empty] = m.count == 0 && !self.occupied(spec.outlet);
        }
        for (state, tank) in self.tanks.iter().zip(&self.layout.tanks) {
            state.read(tank, io);
        }
        for (state, cell) in self.cells.iter().zip(&self.layout.cells) {
            state.read(cell, io);
        }
        for (p, place) in self.layout.places.iter().enumerate() {
            let Some(s) = place.sensor else { continue };
            match place.kind {
                PlaceKind::Downstream => io[s] = self.around.busy_until.is_none(),
                PlaceKind::BeltEntry(_) | PlaceKind::BeltExit(_) => {}
                _ => io[s] = self.occupied(p),
            }
        }
    }

    fn inject_element_fault(&mut self, template: &FaultTemplate) -> Result<(), String> {
        if let Some(result) = self.inject_carriage_fault(template) {
            return result;
        }
        let block = match template {
            FaultTemplate::BlockedAt { element, at } => {
                let axis = self.axis_of_element(element)?;
                (
                    axis,
                    Block::At {
                        end: self.end_of(axis, at)?,
                    },
                )
            }
            FaultTemplate::BlockedBetween { element, from, to } => {
                let axis = self.axis_of_element(element)?;
                let (from, to) = (self.end_of(axis, from)?, self.end_of(axis, to)?);
                if from == to {
                    return Err(format!("{template}: the two positions must differ"));
                }
                (
                    axis,
                    Block::Between {
                        towards: to,
                        frozen: false,
                    },
                )
            }
            other => return Err(format!("{other} is not an element fault")),
        };
        self.axes[block.0].block = Some(block.1);
        Ok(())
    }

    fn inject_slow(&mut self, target: &str, factor: Factor) -> Result<(), String> {
        let layout = Arc::clone(&self.layout);
        let signal = layout.signals.iter().position(|s| s.name == target);
        let is = |s: usize| signal == Some(s);
        if let Some(k) = layout
            .axes
            .iter()
            .position(|a| a.tag == target || is(a.out) || a.back.is_some_and(is))
        {
            let a = &mut self.axes[k];
            a.slow = Some(factor);
            // The stroke under way slows down too.
            a.speed /= factor.get();
            return Ok(());
        }
        if let Some(k) = layout
            .grippers
            .iter()
            .position(|g| g.tag == target || is(g.order))
        {
            self.grippers[k].slow = Some(factor);
            return Ok(());
        }
        if let Some(k) = layout
            .conveyors
            .iter()
            .position(|c| c.tag == target || is(c.motor))
        {
            let c = &mut self.conveyors[k];
            c.slow = Some(factor);
            c.speed /= factor.get();
            return Ok(());
        }
        if let Some(s) = signal {
            for (state, tank) in self.tanks.iter_mut().zip(&layout.tanks) {
                if state.slow(tank, s, factor) {
                    return Ok(());
                }
            }
        }
        if let Some(k) = layout
            .cells
            .iter()
            .position(|c| c.tag == target || c.orders().into_iter().any(is))
        {
            self.cells[k].slow(factor);
            return Ok(());
        }
        Err(format!(
            "plant '{}' has no element or actuator {target} that moves",
            layout.name
        ))
    }

    fn counters(&self) -> Vec<(String, u64)> {
        let mut out = vec![
            ("workpieces_delivered".to_string(), self.around.delivered),
            ("workpieces_lost".to_string(), self.around.lost),
            ("refills".to_string(), self.around.refills),
        ];
        for (k, n) in self.around.cycles.iter().enumerate() {
            out.push((format!("station{}_cycles", k + 1), *n));
        }
        for (state, tank) in self.tanks.iter().zip(&self.layout.tanks) {
            out.push((format!("unit{}_batches", tank.number), state.batches()));
        }
        for (state, cell) in self.cells.iter().zip(&self.layout.cells) {
            out.push((format!("unit{}_delivered", cell.number), state.delivered()));
        }
        out
    }
}
