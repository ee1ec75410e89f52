//! The four-cylinder teaching rig of seed 001 §5 ("système pédagogique").
//!
//! Geometry. Four corners of a square, numbered 1 to 4 clockwise. Cylinder `i`
//! stands at corner `i` and pushes what is in front of it along one side of the
//! square to corner `i+1` (cylinder 4 pushes to corner 1). Three objects start at
//! corners 1, 2 and 3; the free corner moves backwards as they go round.
//!
//! Positions are fractions: the rod of cylinder `i` is at `r` in `[0, 1]` (0 =
//! retracted, 1 = out, its tip then at corner `i+1`), and an object on the side
//! from corner `i` to `i+1` is at progress `q` in `[0, 1]`. The rod pushes the
//! object when it comes from behind and reaches it (`q = max(q, r)`) and leaves it
//! where it is when it returns. Limit switches: `Sx0` at `r <= 0.02`, `Sx1` at
//! `r >= 0.98`. The presence sensor of corner `i` sees an object that has not left
//! it yet (`q < 0.15`) or one about to arrive from corner `i-1` (`q > 0.85`); at
//! `q >= 0.98` the object is at corner `i+1`.
//!
//! Reconstruction choices (the seed gives the constraints and the GRAFCETs, not the
//! rig's dynamics):
//! - the cylinders are single-acting: the order extends the rod, the spring
//!   returns it; stroke times are drawn per stroke (see [`CylinderConfig`]);
//! - no constraint forbids cylinder `i+1` to go out while cylinder `i` is
//!   returning (with three objects it never wants to, but with free corners or
//!   faults it may), so the rig relies on a spring return being faster than an
//!   extension: the default timings bring a returning rod back behind the half-way
//!   point before its neighbour reaches it;
//! - the reading of seed 001 figure 3: see [`ConstraintControl`];
//! - the seed names no priorities for its combined constraints; ours (always the
//!   upstream cylinder, the one delivering into the other's corner) are explained
//!   in `plants/cylinders.toml`.
//!
//! Damage: `rod_collision` when an object pushed to within reach of the next
//! corner meets that corner's rod out (further than 0.05), or when two adjacent
//! rods are both more than half out; `object_collision` when an object is pushed
//! into a corner where another one still sits (the pushed one falls off and counts
//! as lost).

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use vocabulary::expr::Expr;
use vocabulary::fault::Factor;
use vocabulary::{FaultTemplate, MS, Plant, SignalId, Time};

use crate::sim::{Controller, Damage, Physics};

/// The plant file of the four-cylinder rig, as shipped.
pub const PLANT_TOML: &str = include_str!("../plants/cylinders.toml");

/// Parses the shipped plant file.
pub fn plant() -> Plant {
    match Plant::parse(
        PLANT_TOML,
        std::path::Path::new("datasets/plants/cylinders.toml"),
    ) {
        Ok(p) => p,
        // The file is compiled in and covered by tests.
        Err(e) => panic!("shipped cylinders plant file is invalid: {e}"),
    }
}

/// Number of cylinders (and of corners).
pub const CYLINDERS: usize = 4;

/// Rod position at or below which the retracted switch (`Sx0`) is on.
const RETRACTED_AT: f64 = 0.02;
/// Rod position at or above which the extended switch (`Sx1`) is on.
const EXTENDED_AT: f64 = 0.98;
/// A presence sensor sees an object still at its corner below this progress...
const SEEN_LEAVING: f64 = 0.15;
/// ...and one arriving from the previous corner above this one.
const SEEN_ARRIVING: f64 = 0.85;
/// Progress at which an object has reached the next corner.
const ARRIVED: f64 = 0.98;
/// Progress at which an object pushed towards a corner touches what is there.
const CONTACT: f64 = 0.8;
/// A rod further out than this is in the way of an object arriving at its corner.
const ROD_CLEAR: f64 = 0.05;
/// Two adjacent rods both further out than this hit each other; an object that has
/// not been pushed this far still sits on its corner.
const HALF: f64 = 0.5;

/// Stroke times in ms, each drawn uniformly per stroke.
///
/// The slowest return must stay faster than the fastest extension: the seed's
/// constraints let cylinder `i+1` go out as soon as cylinder `i` is released, and
/// the two rods hit each other if both are more than half out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CylinderConfig {
    /// Time for a retracted rod to extend fully, with the order on.
    pub extend_ms: (f64, f64),
    /// Time for an extended rod to retract fully, with the order off (spring).
    pub retract_ms: (f64, f64),
}

impl Default for CylinderConfig {
    fn default() -> Self {
        // A rod is half out at >= 450 ms and half back by <= 400 ms: 50 ms of margin.
        CylinderConfig {
            extend_ms: (900.0, 1100.0),
            retract_ms: (600.0, 800.0),
        }
    }
}

/// Signal ids of the rig, and its combined constraints, resolved once from the
/// plant file; index 0 is cylinder 1 (corner 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CylinderIds {
    /// Retracted switches Se0, Sf0, Sg0, Sh0.
    pub retracted: [usize; CYLINDERS],
    /// Extended switches Se1, Sf1, Sg1, Sh1.
    pub extended: [usize; CYLINDERS],
    /// Presence sensors I13 to I16 (object in front of cylinder 1 to 4).
    pub present: [usize; CYLINDERS],
    /// Extension orders Q9 to Q12.
    pub extend: [usize; CYLINDERS],
    /// The combined constraints (seed 001 eq. 27–30) in file order, each as
    /// (priority, other) cylinder indices: CSc1 = `Q9 & Q10` with priority Q9 is
    /// `(0, 1)`. Read from the plant file so that the control applies the
    /// priorities the file declares.
    pub combined: [(usize, usize); CYLINDERS],
}

impl CylinderIds {
    /// Resolves the rig's sixteen signals in `plant`.
    pub fn resolve(plant: &Plant) -> Result<CylinderIds, String> {
        let id = |name: &str| -> Result<usize, String> {
            plant
                .signals
                .id(name)
                .map(SignalId::index)
                .ok_or_else(|| format!("plant '{}' has no signal {name}", plant.name))
        };
        let four = |names: [&str; CYLINDERS]| -> Result<[usize; CYLINDERS], String> {
            let mut out = [0; CYLINDERS];
            for (slot, name) in out.iter_mut().zip(names) {
                *slot = id(name)?;
            }
            Ok(out)
        };
        let extend = four(["Q9", "Q10", "Q11", "Q12"])?;
        Ok(CylinderIds {
            retracted: four(["Se0", "Sf0", "Sg0", "Sh0"])?,
            extended: four(["Se1", "Sf1", "Sg1", "Sh1"])?,
            present: four(["I13", "I14", "I15", "I16"])?,
            extend,
            combined: Self::resolve_combined(plant, &extend)?,
        })
    }

    /// The constraints with a priority, each of the form `Qa & Qb` (the control
    /// knows no other form: seed 001's CSc here have no condition besides the two
    /// orders).
    fn resolve_combined(
        plant: &Plant,
        extend: &[usize; CYLINDERS],
    ) -> Result<[(usize, usize); CYLINDERS], String> {
        let cylinder = |name: &str| {
            plant
                .signals
                .id(name)
                .and_then(|id| extend.iter().position(|&i| i == id.index()))
        };
        let mut out = Vec::new();
        for c in plant.constraints.iter().filter(|c| c.priority.is_some()) {
            let pair = match &c.expr {
                Expr::And(terms) => match terms.as_slice() {
                    [Expr::Var(a), Expr::Var(b)] => cylinder(a).zip(cylinder(b)),
                    _ => None,
                },
                _ => None,
            };
            let (a, b) = pair.filter(|(a, b)| a != b).ok_or_else(|| {
                format!("combined constraint {} = {} is not of the form Qa & Qb (two orders of the rig)", c.name, c.expr)
            })?;
            let prio = c
                .priority
                .and_then(|id| extend.iter().position(|&i| i == id.index()));
            out.push(if prio == Some(a) { (a, b) } else { (b, a) });
        }
        out.try_into().map_err(|v: Vec<_>| {
            format!(
                "plant '{}' has {} combined constraints; the rig has four (CSc1 to CSc4)",
                plant.name,
                v.len()
            )
        })
    }
}

/// The cylinder after `k` in the flow, i.e. the one at the corner `k` pushes to.
/// The index of rod `element` (V1 is 0).
fn rod_of(element: &str) -> Option<usize> {
    ["V1", "V2", "V3", "V4"].iter().position(|&v| v == element)
}

fn next(k: usize) -> usize {
    (k + 1) % CYLINDERS
}

/// An element fault of one rod.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Block {
    /// Cannot leave the end where the retracted (`true`) or extended switch is on.
    At { retracted: bool },
    /// Freezes half-way on its next stroke out (`true`) or back; `frozen` once it has.
    Between { outwards: bool, frozen: bool },
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Rod {
    /// Position: 0 retracted, 1 out.
    r: f64,
    /// The physical order it follows (after actuator faults).
    order: bool,
    /// Speed of the current stroke, position units per ns.
    speed: f64,
    block: Option<Block>,
    /// How much slower its strokes are, from a `slow` fault's onset on.
    slow: Option<Factor>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Object {
    id: u64,
    /// Index of the corner it is at or is leaving (0 = corner 1).
    corner: usize,
    /// Progress towards the next corner.
    q: f64,
    /// Damage already recorded for this trip, so that an incident counts once.
    hit_rod: bool,
}

/// The physical rig: four rods and the objects they push round.
#[derive(Debug, Clone)]
pub struct CylinderRig {
    plant: Plant,
    ids: CylinderIds,
    config: CylinderConfig,
    rods: [Rod; CYLINDERS],
    objects: Vec<Object>,
    last_t: Option<Time>,
    /// Pairs (k, k+1) of rods currently both more than half out.
    rods_touching: [bool; CYLINDERS],
    moves: u64,
    lost: u64,
}

impl CylinderRig {
    /// The rig at rest: every rod retracted, objects at corners 1, 2 and 3.
    pub fn new(config: CylinderConfig) -> CylinderRig {
        let plant = plant();
        let ids = match CylinderIds::resolve(&plant) {
            Ok(ids) => ids,
            Err(e) => panic!("shipped cylinders plant file: {e}"),
        };
        // At rest: each stroke draws its speed when its order changes.
        let rod = Rod {
            r: 0.0,
            order: false,
            speed: 0.0,
            block: None,
            slow: None,
        };
        let mut rig = CylinderRig {
            plant,
            ids,
            config,
            rods: [rod; CYLINDERS],
            objects: Vec::new(),
            last_t: None,
            rods_touching: [false; CYLINDERS],
            moves: 0,
            lost: 0,
        };
        rig.place(&[1, 2, 3]);
        rig
    }

    /// Whether any object is still on the rig (none: nothing left to move).
    pub fn occupied(&self) -> bool {
        !self.objects.is_empty()
    }

    /// Objects pushed from one corner to the next so far.
    pub fn moves(&self) -> u64 {
        self.moves
    }

    /// Replaces the objects by one at each of `corners` (numbered 1 to 4, each at
    /// most once), for tests and other scenarios.
    pub fn with_objects(mut self, corners: &[usize]) -> Result<CylinderRig, String> {
        for (i, &c) in corners.iter().enumerate() {
            if !(1..=CYLINDERS).contains(&c) {
                return Err(format!(
                    "corner {c} does not exist (corners are 1 to {CYLINDERS})"
                ));
            }
            if corners[..i].contains(&c) {
                return Err(format!("two objects at corner {c}"));
            }
        }
        self.place(corners);
        Ok(self)
    }

    fn place(&mut self, corners: &[usize]) {
        self.objects = corners
            .iter()
            .enumerate()
            .map(|(i, &c)| Object {
                id: i as u64 + 1,
                corner: c - 1,
                q: 0.0,
                hit_rod: false,
            })
            .collect();
    }

    /// The resolved signal ids.
    pub fn ids(&self) -> CylinderIds {
        self.ids
    }

    /// Rod positions of cylinders 1 to 4 (0 = retracted, 1 = out).
    pub fn rods(&self) -> [f64; CYLINDERS] {
        self.rods.map(|r| r.r)
    }

    /// Each object as (corner it is at or leaving, 1 to 4; progress towards the next).
    pub fn objects(&self) -> Vec<(usize, f64)> {
        self.objects.iter().map(|o| (o.corner + 1, o.q)).collect()
    }

    fn draw_ms(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
        let ms = if hi > lo {
            rng.random_range(lo..hi)
        } else {
            lo
        };
        ms.max(1.0)
    }

    fn move_rods(&mut self, dt: f64, act: &[bool], rng: &mut ChaCha8Rng) {
        for (rod, &a) in self.rods.iter_mut().zip(&self.ids.extend) {
            let order = act[a];
            if order != rod.order {
                // A new stroke (possibly reversing mid-way) draws its own duration.
                rod.order = order;
                let range = if order {
                    self.config.extend_ms
                } else {
                    self.config.retract_ms
                };
                rod.speed = 1.0 / (Self::draw_ms(rng, range) * MS as f64);
            }
            let old = rod.r;
            let speed = rod.slow.map_or(rod.speed, |f| rod.speed / f.get());
            let mut new = if order {
                (old + speed * dt).min(1.0)
            } else {
                (old - speed * dt).max(0.0)
            };
            match &mut rod.block {
                Some(Block::At { retracted }) => {
                    let stuck = if *retracted {
                        old <= RETRACTED_AT
                    } else {
                        old >= EXTENDED_AT
                    };
                    if stuck {
                        new = old;
                    }
                }
                Some(Block::Between { outwards, frozen }) => {
                    if *frozen {
                        new = old;
                    } else if *outwards == order && old != new && (old - HALF) * (new - HALF) <= 0.0
                    {
                        *frozen = true;
                        new = HALF;
                    }
                }
                None => {}
            }
            rod.r = new;
        }
    }

    fn move_objects(&mut self, t: Time, before: [f64; CYLINDERS], damage: &mut Vec<Damage>) {
        let rods = self.rods();
        for o in &mut self.objects {
            // Only a rod coming from behind pushes: an object that lands in front of
            // a rod already out stays put (and the arrival is recorded as a collision).
            if before[o.corner] <= o.q && rods[o.corner] > o.q {
                o.q = rods[o.corner];
            }
        }
        // Contacts at the corner ahead, judged on everyone's new position.
        let mut lost = Vec::new();
        for i in 0..self.objects.len() {
            let o = self.objects[i];
            if o.q < CONTACT {
                continue;
            }
            let to = next(o.corner);
            if rods[to] > ROD_CLEAR && !o.hit_rod {
                damage.push(Damage {
                    t,
                    cause: "rod_collision",
                    detail: format!(
                        "object {} pushed by cylinder {} hit the rod of cylinder {} (not retracted)",
                        o.id,
                        o.corner + 1,
                        to + 1
                    ),
                });
                self.objects[i].hit_rod = true;
            }
            let sitting = self
                .objects
                .iter()
                .find(|p| p.id != o.id && p.corner == to && p.q < HALF);
            if let Some(p) = sitting {
                damage.push(Damage {
                    t,
                    cause: "object_collision",
                    detail: format!(
                        "object {} pushed by cylinder {} ran into object {} at corner {} and fell off",
                        o.id,
                        o.corner + 1,
                        p.id,
                        to + 1
                    ),
                });
                // The pushed object is knocked off the table: at most one object
                // per corner, and each collision is recorded once.
                lost.push(o.id);
            }
        }
        if !lost.is_empty() {
            self.lost += lost.len() as u64;
            self.objects.retain(|o| !lost.contains(&o.id));
        }
        for o in &mut self.objects {
            if o.q >= ARRIVED {
                o.corner = next(o.corner);
                o.q = 0.0;
                o.hit_rod = false;
                self.moves += 1;
            }
        }
    }

    fn check_rods(&mut self, t: Time, damage: &mut Vec<Damage>) {
        for k in 0..CYLINDERS {
            let touching = self.rods[k].r > HALF && self.rods[next(k)].r > HALF;
            if touching && !self.rods_touching[k] {
                damage.push(Damage {
                    t,
                    cause: "rod_collision",
                    detail: format!(
                        "the rods of cylinders {} and {} were both more than half out",
                        k + 1,
                        next(k) + 1
                    ),
                });
            }
            self.rods_touching[k] = touching;
        }
    }
}

impl Physics for CylinderRig {
    fn plant(&self) -> &Plant {
        &self.plant
    }

    fn plant_toml(&self) -> &str {
        PLANT_TOML
    }

    fn advance(&mut self, t: Time, act: &[bool], rng: &mut ChaCha8Rng, damage: &mut Vec<Damage>) {
        let Some(last) = self.last_t.replace(t) else {
            return;
        };
        // The orders in `act` were written at `last` and have acted since.
        let before = self.rods();
        self.move_rods((t - last) as f64, act, rng);
        self.move_objects(t, before, damage);
        self.check_rods(t, damage);
    }

    fn read_sensors(&self, io: &mut [bool]) {
        let ids = &self.ids;
        for (k, rod) in self.rods.iter().enumerate() {
            io[ids.retracted[k]] = rod.r <= RETRACTED_AT;
            io[ids.extended[k]] = rod.r >= EXTENDED_AT;
            io[ids.present[k]] = false;
        }
        for o in &self.objects {
            if o.q < SEEN_LEAVING {
                io[ids.present[o.corner]] = true;
            }
            if o.q > SEEN_ARRIVING {
                io[ids.present[next(o.corner)]] = true;
            }
        }
    }

    fn inject_element_fault(&mut self, template: &FaultTemplate) -> Result<(), String> {
        let element = match template {
            FaultTemplate::BlockedAt { element, .. }
            | FaultTemplate::BlockedBetween { element, .. } => element,
            other => return Err(format!("{other} is not an element fault")),
        };
        let k = rod_of(element).ok_or_else(|| {
            format!("the cylinder rig has no element {element} (rods are V1 to V4)")
        })?;
        let names =
            |ids: &[usize; CYLINDERS]| self.plant.signals.name(SignalId(ids[k] as u32)).to_string();
        let (s0, s1) = (names(&self.ids.retracted), names(&self.ids.extended));
        // true for the retracted end, false for the extended end.
        let end = |s: &str| -> Result<bool, String> {
            if s == s0 {
                Ok(true)
            } else if s == s1 {
                Ok(false)
            } else {
                Err(format!(
                    "rod {element} has no end sensed by {s} (its ends are {s0} and {s1})"
                ))
            }
        };
        self.rods[k].block = Some(match template {
            FaultTemplate::BlockedAt { at, .. } => Block::At {
                retracted: end(at)?,
            },
            FaultTemplate::BlockedBetween { from, to, .. } => {
                let (from, to) = (end(from)?, end(to)?);
                if from == to {
                    return Err(format!("{template}: the two positions must differ"));
                }
                Block::Between {
                    outwards: from,
                    frozen: false,
                }
            }
            other => return Err(format!("the cylinder rig cannot simulate {other}")),
        });
        Ok(())
    }

    fn inject_slow(&mut self, x: &str, factor: Factor) -> Result<(), String> {
        // A rod, or the valve Q9 to Q12 that drives it.
        let k = rod_of(x)
            .or_else(|| {
                self.ids
                    .extend
                    .iter()
                    .position(|&a| self.plant.signals.name(SignalId(a as u32)) == x)
            })
            .ok_or_else(|| {
                format!("the cylinder rig has no rod or valve {x} (V1 to V4, Q9 to Q12)")
            })?;
        self.rods[k].slow = Some(factor);
        Ok(())
    }

    fn counters(&self) -> Vec<(String, u64)> {
        vec![
            ("moves".into(), self.moves),
            ("objects_lost".into(), self.lost),
        ]
    }
}

/// A step of the functional GRAFCET of one cylinder (seed 001 figure 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Initial step: waiting for an object in front of a retracted cylinder.
    Idle,
    /// Extend (X1, X11, X21, X31): the functional requirement `g1k` is 1.
    Extend,
    /// Wait for the spring to bring the rod back.
    Retract,
}

/// Seed 001's control by constraints: four functional GRAFCETs, then the safety
/// constraints.
///
/// Per cylinder `k` with successor `j` (the cylinder it delivers to) the GRAFCET
/// goes Idle → Extend on `I_k & Sx0_k`, Extend → Retract on `Sx1_k`, Retract →
/// Idle on `Sx0_k`, and `g1k` is "Extend is active". The simple safety constraints
/// give, with `Qk*` the previous scan's order (eq. 35–38):
/// `f0k = !Sx0_j | !Qk* & I_j` (must be 0) and `f1k = !Sx1_k & Qk*` (must be 1), so
/// `S'k = !f0k & g1k | f1k` (eq. 39). Then the loop of figure 3 over the combined
/// constraints ([`CylinderIds::combined`]): each violated one switches its
/// non-priority output off, until none is violated.
///
/// Figure 3 evaluates every combined constraint on the `S'` of the previous pass;
/// where two constraints would write the same output in one pass (one "Sk = S'k",
/// the other "Sl = 0"), the 0 wins. Read literally, the later write would win and
/// the loop could cycle forever (e.g. on `S' = 0111`). With zeros winning, a pass
/// only switches orders off and one pass settles it; the loop is kept as in the
/// figure. It may switch off more than needed: on `0111`, Q12 yields to Q11 even
/// though Q11 itself yields to Q10.
#[derive(Debug, Clone)]
pub struct ConstraintControl {
    ids: CylinderIds,
    steps: [Step; CYLINDERS],
}

impl ConstraintControl {
    /// The control law for a plant with the rig's signals; every GRAFCET in its
    /// initial step.
    pub fn new(ids: CylinderIds) -> Self {
        ConstraintControl {
            ids,
            steps: [Step::Idle; CYLINDERS],
        }
    }

    /// The active step of each cylinder's GRAFCET (index 0 = cylinder 1).
    pub fn steps(&self) -> [Step; CYLINDERS] {
        self.steps
    }

    /// The functional requirements `g1k`: the plant file's variables X1, X11, X21, X31.
    pub fn requested(&self) -> [bool; CYLINDERS] {
        self.steps.map(|s| s == Step::Extend)
    }

    /// One scan of the four GRAFCETs on the sensors of `io` (at most one
    /// transition each); the functional requirements `g1k` that follow, the
    /// plant file's variables X1, X11, X21, X31 in order.
    pub fn evolve(&mut self, io: &[bool]) -> [bool; CYLINDERS] {
        let ids = self.ids;
        for (k, step) in self.steps.iter_mut().enumerate() {
            let retracted = io[ids.retracted[k]];
            *step = match *step {
                Step::Idle if io[ids.present[k]] && retracted => Step::Extend,
                Step::Extend if io[ids.extended[k]] => Step::Retract,
                Step::Retract if retracted => Step::Idle,
                s => s,
            };
        }
        self.requested()
    }

    /// Applies the combined constraints to the intermediate orders `s` (figure 3).
    pub fn combine(&self, mut s: [bool; CYLINDERS]) -> [bool; CYLINDERS] {
        let combined = &self.ids.combined;
        loop {
            let mut out = s;
            for &(_, other) in combined.iter().filter(|&&(p, o)| s[p] && s[o]) {
                out[other] = false;
            }
            let violated = combined.iter().any(|&(p, o)| out[p] && out[o]);
            s = out;
            if !violated {
                return s;
            }
        }
    }
}

impl Controller for ConstraintControl {
    fn scan(&mut self, _t: Time, io: &mut [bool]) {
        let ids = self.ids;
        let retracted = ids.retracted.map(|i| io[i]);
        let extended = ids.extended.map(|i| io[i]);
        let present = ids.present.map(|i| io[i]);
        // The actuator entries still hold the previous scan's orders: Qk*.
        let before = ids.extend.map(|i| io[i]);
        let g1 = self.evolve(io);

        let mut s = [false; CYLINDERS];
        for (k, out) in s.iter_mut().enumerate() {
            let j = next(k);
            let f0 = !retracted[j] || !before[k] && present[j];
            let f1 = !extended[k] && before[k];
            *out = !f0 && g1[k] || f1;
        }
        for (&i, v) in ids.extend.iter().zip(self.combine(s)) {
            io[i] = v;
        }
    }
}
