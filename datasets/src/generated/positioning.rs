//! Positioning cells: an electric axis whose carriage takes a workpiece at the
//! load position, visits work positions as the recipe says, and hands it over
//! at the unload position.
//!
//! The axis has a cam switch at each position and a slow-down cam around every
//! position. The program runs the motor fast, counts the slow-down cams it
//! passes, switches to creep speed on entering the target's slow-down cam and
//! stops, with the brake, on the target's cam switch: a move's duration depends
//! on where it starts and where it ends. A clamp (a pneumatic cylinder on the
//! carriage) holds the workpiece. Workpieces arrive in bursts, the outfeed is
//! now and then blocked for long, and the line controller switches between two
//! recipes (another pattern of moves) at random times.
//!
//! Damage: `overtravel` (the carriage runs into a mechanical end stop),
//! `brake_drag` (the motor runs against the applied brake), `reversing_short`
//! (forward and reverse contactors on together), `workpiece_dropped` (the clamp
//! opens away from the unload position), `workpiece_jam` (a workpiece handed
//! over to a blocked outfeed).

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use vocabulary::{MS, SECOND, Time, fault::Factor};

use super::layout::{AxisRole, Builder, DRIFT, Element, Layout, PartSpec, log_uniform};
use super::physics::AT_END as AT_END_SWITCH;
use super::program::{ChainWriter, Op, StepChain};
use crate::sim::Damage;

/// Half-width of a position's cam switch (fraction of the axis's length).
pub const CAM: f64 = 0.012;
/// Half-width of a position's slow-down cam.
pub const ZONE: f64 = 0.05;

/// One position of an axis.
#[derive(Debug, Clone, PartialEq)]
pub struct CellPosition {
    /// Its cam switch.
    pub cam: usize,
    /// Where it is along the axis (0 to 1).
    pub at: f64,
}

/// A pattern of moves: the work positions visited between load and unload.
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe {
    /// Positions (indices), in the order visited.
    pub stops: Vec<usize>,
    /// Time spent working at each.
    pub dwell: Vec<Time>,
}

/// A positioning cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// The axis's tag, also its carriage's element name, e.g. `X51`.
    pub tag: String,
    /// Its unit's number.
    pub number: usize,
    /// Order: motor forward.
    pub forward: usize,
    /// Order: motor reverse.
    pub reverse: usize,
    /// Order: creep speed instead of fast.
    pub creep: usize,
    /// Order: release the brake (the brake holds when it is off).
    pub brake: usize,
    /// Positions, load first and unload last.
    pub positions: Vec<CellPosition>,
    /// Sensor: the slow-down cam, on near every position.
    pub zone: usize,
    /// Sensor: the line controller selects recipe B (else A), if it can.
    pub recipe: Option<usize>,
    /// Recipe A, and B when there is a selector.
    pub recipes: Vec<Recipe>,
    /// The clamp on the carriage (an axis; end 1: closed).
    pub clamp: usize,
    /// Sensor: a workpiece waits at the load position.
    pub infeed: usize,
    /// Sensor: the outfeed is ready to take a workpiece.
    pub outfeed: usize,
    /// Nominal time for the whole length at fast speed.
    pub stroke_time: Time,
    /// Fast speed over creep speed.
    pub creep_ratio: f64,
    /// Move-to-move relative jitter of the speed.
    pub jitter: f64,
}

impl Cell {
    /// Its orders.
    pub fn orders(&self) -> [usize; 4] {
        [self.forward, self.reverse, self.creep, self.brake]
    }

    /// The position whose cam switch is `sensor`.
    pub fn position_of(&self, sensor: usize) -> Option<usize> {
        self.positions.iter().position(|p| p.cam == sensor)
    }
}

fn position_name(k: usize, n: usize) -> String {
    if k == 0 {
        "the load position".to_string()
    } else if k + 1 == n {
        "the unload position".to_string()
    } else {
        format!("work position {k}")
    }
}

/// Recipe A, and recipe B if there is a `selector`: the work positions
/// between the load (0) and the unload position (`n - 1`), each with a dwell.
fn draw_recipes(rng: &mut ChaCha8Rng, n: usize, selector: bool) -> Vec<Recipe> {
    let draw = |rng: &mut ChaCha8Rng, least: usize| {
        let mut stops: Vec<usize> = (1..n - 1).filter(|_| rng.random_bool(0.6)).collect();
        if stops.len() < least {
            stops.push(rng.random_range(1..n - 1));
        }
        let dwell = stops
            .iter()
            .map(|_| log_uniform(rng, 300 * MS, 3 * SECOND))
            .collect();
        Recipe { stops, dwell }
    };
    let mut recipes = vec![draw(rng, 1)];
    if selector {
        let mut b = draw(rng, 0);
        // Recipe B visits its positions in another order, or others.
        b.stops.reverse();
        if b.stops == recipes[0].stops {
            b.stops.pop();
            b.dwell.pop();
        }
        recipes.push(b);
    }
    recipes
}

impl Builder {
    /// Draws a positioning cell: an axis part and a clamp part.
    pub(super) fn cell(&mut self) {
        let number = self.layout.units() + 1;
        self.unit_name = "positioning cell".to_string();
        let label = self.label(number);
        let tag = self.tag('X', number);
        let n = self.rng.random_range(3..=5usize);
        let forward = self.signal(
            'M',
            number,
            false,
            format!("electric axis {tag} forward ({label})"),
        );
        let reverse = self.signal(
            'M',
            number,
            false,
            format!("electric axis {tag} reverse ({label})"),
        );
        let creep = self.signal(
            'M',
            number,
            false,
            format!("electric axis {tag} at creep speed, else fast ({label})"),
        );
        let brake = self.signal(
            'Y',
            number,
            false,
            format!("release the brake of axis {tag} (it holds when off) ({label})"),
        );
        let spacing = 0.84 / (n - 1) as f64;
        let mut positions = Vec::new();
        for k in 0..n {
            let mut at = 0.08 + spacing * k as f64;
            if k > 0 && k + 1 < n {
                at += self.rng.random_range(-0.03..0.03);
            }
            let cam = self.sensor(
                number,
                format!(
                    "cam switch: axis {tag} at {} ({label})",
                    position_name(k, n)
                ),
            );
            positions.push(CellPosition { cam, at });
        }
        let zone = self.sensor(
            number,
            format!("slow-down cam: axis {tag} near a position ({label})"),
        );
        let recipe = self.rng.random_bool(0.6).then(|| {
            self.sensor(
                number,
                format!("line controller selects recipe B for axis {tag}, else A ({label})"),
            )
        });
        let recipes = draw_recipes(&mut self.rng, n, recipe.is_some());
        let double = self.rng.random_bool(0.3);
        let clamp = self.axis(
            number,
            AxisRole::Clamp,
            double,
            (true, true),
            (50 * MS, 400 * MS),
        );
        let infeed = self.sensor(
            number,
            format!("workpiece waiting at the load position of axis {tag} ({label})"),
        );
        let outfeed = self.sensor(
            number,
            format!("outfeed of axis {tag} ready to take a workpiece ({label})"),
        );
        let cell = Cell {
            tag,
            number,
            forward,
            reverse,
            creep,
            brake,
            positions,
            zone,
            recipe,
            recipes,
            clamp,
            infeed,
            outfeed,
            stroke_time: log_uniform(&mut self.rng, 2 * SECOND, 8 * SECOND),
            creep_ratio: self.rng.random_range(4.0..8.0),
            jitter: self.rng.random_range(0.01..0.03),
        };
        let mut sensors: Vec<usize> = cell.positions.iter().map(|p| p.cam).collect();
        sensors.push(cell.zone);
        sensors.extend(cell.recipe);
        self.layout.parts.push(PartSpec {
            name: format!("st{number}_axis"),
            actuators: cell.orders().to_vec(),
            sensors,
            element: Some(Element::Carriage(self.layout.cells.len())),
            inputs: cell.recipe.into_iter().collect(),
        });
        let part = self.axis_part(clamp, &[cell.infeed, cell.outfeed]);
        // Workpieces arrive and the outfeed frees itself on their own.
        self.layout.parts[part].inputs = vec![cell.infeed, cell.outfeed];
        self.layout.cells.push(cell);
    }
}

/// Orders and the values they are given.
type Orders = Vec<(usize, bool)>;

/// Orders moving the clamp of `cell` (closing or opening), and those to reset
/// once it is there (a double-acting valve's order is released).
fn clamp_orders(layout: &Layout, cell: &Cell, close: bool) -> (Orders, Orders) {
    let a = &layout.axes[cell.clamp];
    match (a.back, close) {
        (None, _) => (vec![(a.out, close)], Vec::new()),
        (Some(back), true) => (vec![(back, false), (a.out, true)], vec![(a.out, false)]),
        (Some(back), false) => (vec![(a.out, false), (back, true)], vec![(back, false)]),
    }
}

/// The steps of a move from position `from` to position `to`: fast until the
/// target's slow-down cam (counting the ones passed), creep to its cam
/// switch, stop and brake.
fn travel(cell: &Cell, from: usize, to: usize) -> Vec<Op> {
    let forward = to > from;
    let motor = if forward { cell.forward } else { cell.reverse };
    let limit = Some(cell.stroke_time * 2 + 5 * SECOND);
    let n = cell.positions.len();
    let tag = &cell.tag;
    let mut leave = Op::until(
        format!("{tag}: leave {}", position_name(from, n)),
        cell.zone,
        false,
    );
    leave.enter = vec![(cell.creep, false), (cell.brake, true), (motor, true)];
    leave.timeout = limit;
    let mut ops = vec![leave];
    let between: Vec<usize> = if forward {
        (from + 1..to).collect()
    } else {
        (to + 1..from).rev().collect()
    };
    for m in between {
        let name = position_name(m, n);
        for (verb, value) in [("reach", true), ("pass", false)] {
            let mut op = Op::until(format!("{tag}: {verb} {name}"), cell.zone, value);
            op.timeout = limit;
            ops.push(op);
        }
    }
    let target = position_name(to, n);
    let mut approach = Op::until(format!("{tag}: approach {target}"), cell.zone, true);
    approach.timeout = limit;
    ops.push(approach);
    let mut creep = Op::until(
        format!("{tag}: creep to {target}"),
        cell.positions[to].cam,
        true,
    );
    creep.enter = vec![(cell.creep, true)];
    creep.exit = vec![(motor, false), (cell.creep, false), (cell.brake, false)];
    creep.timeout = limit;
    ops.push(creep);
    ops
}

/// A recipe's moves from the load position to the unload position.
fn recipe_ops(cell: &Cell, recipe: &Recipe) -> Vec<Op> {
    let mut ops = Vec::new();
    let mut at = 0;
    for (&stop, &dwell) in recipe.stops.iter().zip(&recipe.dwell) {
        ops.extend(travel(cell, at, stop));
        ops.push(Op::wait(
            format!(
                "{}: work at {}",
                cell.tag,
                position_name(stop, cell.positions.len())
            ),
            dwell,
        ));
        at = stop;
    }
    ops.extend(travel(cell, at, cell.positions.len() - 1));
    ops
}

/// A cell's cycle: wait for a workpiece, clamp it, run the recipe selected,
/// wait for the outfeed, unclamp, go back to the load position.
pub(super) fn chain(layout: &Layout, cell: &Cell) -> StepChain {
    let mut w = ChainWriter::default();
    let clamp = &layout.axes[cell.clamp];
    let clamp_limit = Some(clamp.out_time.max(clamp.back_time) * 3 + SECOND);
    let load = w.op(Op::until(
        format!("{}: wait for a workpiece at the load position", cell.tag),
        cell.infeed,
        true,
    ));
    let (enter, exit) = clamp_orders(layout, cell, true);
    let mut close = Op::until(
        format!("close clamp {}", clamp.tag),
        clamp.at1.unwrap_or(cell.infeed),
        true,
    );
    (close.enter, close.exit, close.timeout) = (enter, exit, clamp_limit);
    let closed = w.then(load, &[], vec![close]);
    let outfeed = w.op(Op::until(
        format!("{}: wait for the outfeed", cell.tag),
        cell.outfeed,
        true,
    ));
    for (k, recipe) in cell.recipes.iter().enumerate() {
        let select: Vec<(usize, bool)> = cell.recipe.iter().map(|&s| (s, k == 1)).collect();
        let last = w.then(closed, &select, recipe_ops(cell, recipe));
        w.link(last, outfeed, &[]);
    }
    let (enter, exit) = clamp_orders(layout, cell, false);
    let mut open = Op::until(
        format!("open clamp {}", clamp.tag),
        clamp.at0.unwrap_or(cell.outfeed),
        true,
    );
    (open.enter, open.exit, open.timeout) = (enter, exit, clamp_limit);
    let mut back = vec![open];
    back.extend(travel(cell, cell.positions.len() - 1, 0));
    let last = w.then(outfeed, &[], back);
    w.link(last, load, &[]);
    let mut stop: Vec<(usize, bool)> = cell.orders().iter().map(|&o| (o, false)).collect();
    if let Some(b) = clamp.back {
        stop.extend([(clamp.out, false), (b, false)]);
    }
    w.finish(cell.number - 1, load, stop, layout.timeouts)
}

/// The safety constraints of a cell, each with why.
pub(super) fn constraints(layout: &Layout, cell: &Cell, out: &mut Vec<(String, String)>) {
    let sig = |s: usize| layout.signals[s].name.clone();
    let (f, r, k) = (sig(cell.forward), sig(cell.reverse), sig(cell.brake));
    let first = sig(cell.positions[0].cam);
    let last = sig(cell.positions[cell.positions.len() - 1].cam);
    let tag = &cell.tag;
    out.push((
        format!("axis {tag} must not run forward past the unload position (overtravel)"),
        format!("{f} & {last}"),
    ));
    out.push((
        format!("axis {tag} must not run in reverse past the load position (overtravel)"),
        format!("{r} & {first}"),
    ));
    out.push((
        format!("axis {tag} must not run forward against its brake"),
        format!("{f} & !{k}"),
    ));
    out.push((
        format!("axis {tag} must not run in reverse against its brake"),
        format!("{r} & !{k}"),
    ));
    out.push((
        format!("the forward and reverse contactors of axis {tag} must not be on together"),
        format!("{f} & {r}"),
    ));
    let clamp = &layout.axes[cell.clamp];
    // A spring opens a single-acting clamp when its order falls; a
    // double-acting one opens on its own order.
    let opens = match clamp.back {
        Some(back) => format!("RE({})", sig(back)),
        None => format!("FE({})", sig(clamp.out)),
    };
    out.push((
        format!(
            "clamp {} must not open away from the unload position of axis {tag}",
            clamp.tag
        ),
        format!("{opens} & !{last}"),
    ));
    out.push((
        format!(
            "clamp {} must not hand a workpiece over to a blocked outfeed",
            clamp.tag
        ),
        format!("{opens} & !{}", sig(cell.outfeed)),
    ));
}

/// The cell in words, for the plant file's header.
pub(super) fn words(layout: &Layout, cell: &Cell) -> String {
    let sig = |s: usize| layout.signals[s].name.as_str();
    let n = cell.positions.len();
    let cams: Vec<String> = cell
        .positions
        .iter()
        .enumerate()
        .map(|(k, p)| format!("{} ({})", position_name(k, n), sig(p.cam)))
        .collect();
    let recipe = |r: &Recipe| {
        if r.stops.is_empty() {
            "straight to unload".to_string()
        } else {
            let s: Vec<String> = r.stops.iter().map(|&k| position_name(k, n)).collect();
            s.join(", ")
        }
    };
    let mut text = format!(
        "Unit {}, positioning cell: electric axis {} (forward {}, reverse {}, creep {}, brake release {}) has cam switches at {}, and a slow-down cam ({}) around each; it runs fast, creeps into the target's slow-down cam and stops with its brake on the target's cam. Clamp {} takes a workpiece at the load position ({}; they arrive in bursts); the carriage visits {}",
        cell.number,
        cell.tag,
        sig(cell.forward),
        sig(cell.reverse),
        sig(cell.creep),
        sig(cell.brake),
        cams.join(", "),
        sig(cell.zone),
        layout.axes[cell.clamp].tag,
        sig(cell.infeed),
        recipe(&cell.recipes[0]),
    );
    if let (Some(s), Some(b)) = (cell.recipe, cell.recipes.get(1)) {
        text.push_str(&format!(
            " (recipe A), or {} when the line controller selects recipe B ({})",
            recipe(b),
            sig(s)
        ));
    }
    text.push_str(&format!(
        ", and hands it over at the unload position once the outfeed is ready ({}), which is now and then blocked for long.",
        sig(cell.outfeed)
    ));
    text
}

/// An element fault of a carriage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum CarriageBlock {
    /// Cannot leave position `at` once there.
    At(usize),
    /// Freezes half-way between `from` and `to` on its next move that way.
    Between {
        from: usize,
        to: usize,
        frozen: bool,
    },
}

/// A cell during a run.
#[derive(Debug, Clone)]
pub(super) struct CellState {
    x: f64,
    drift: f64,
    jitter: f64,
    slow: f64,
    moving: Option<bool>,
    block: Option<CarriageBlock>,
    /// A workpiece on the carriage.
    load: bool,
    /// A workpiece waiting at the load position.
    waiting: bool,
    arrival_at: Option<Time>,
    busy_until: Option<Time>,
    recipe_b: bool,
    recipe_at: Option<Time>,
    delivered: u64,
    latched: [bool; 3],
    rng: ChaCha8Rng,
}

impl CellState {
    /// The carriage at the load position, empty.
    pub(super) fn new(cell: &Cell, rng: ChaCha8Rng) -> CellState {
        CellState {
            x: cell.positions[0].at,
            drift: 1.0,
            jitter: 0.0,
            slow: 1.0,
            moving: None,
            block: None,
            load: false,
            waiting: false,
            arrival_at: None,
            busy_until: None,
            recipe_b: false,
            recipe_at: None,
            delivered: 0,
            latched: [false; 3],
            rng,
        }
    }

    /// Draws the run's drift.
    pub(super) fn seed(&mut self, rng: ChaCha8Rng) {
        self.rng = rng;
        self.drift = self.rng.random_range(1.0 - DRIFT..=1.0 + DRIFT);
    }

    /// Workpieces handed over so far.
    pub(super) fn delivered(&self) -> u64 {
        self.delivered
    }

    /// Every move from now on takes `factor` times longer.
    pub(super) fn slow(&mut self, factor: Factor) {
        self.slow = factor.get();
    }

    /// Starts an element fault.
    pub(super) fn block(&mut self, block: CarriageBlock) {
        self.block = Some(block);
    }

    fn near(&self, cell: &Cell, k: usize, width: f64) -> bool {
        (self.x - cell.positions[k].at).abs() <= width
    }

    /// Moves the carriage under the orders `(forward, reverse, creep, brake
    /// released)` for `dt`; true if it ran into an end stop.
    fn drive(
        &mut self,
        cell: &Cell,
        dt: f64,
        (f, r, creep, released): (bool, bool, bool, bool),
    ) -> bool {
        let dir = match (f, r) {
            (true, false) => true,
            (false, true) => false,
            _ => {
                self.moving = None;
                return false;
            }
        };
        if !released {
            self.moving = None;
            return false;
        }
        if self.moving != Some(dir) {
            self.jitter = self.rng.random_range(-cell.jitter..=cell.jitter);
        }
        self.moving = Some(dir);
        let mut v = 1.0 / (cell.stroke_time as f64 * self.drift * (1.0 + self.jitter) * self.slow);
        if creep {
            v /= cell.creep_ratio;
        }
        let old = self.x;
        let mut new = if dir { old + v * dt } else { old - v * dt };
        match &mut self.block {
            Some(CarriageBlock::At(k)) if (old - cell.positions[*k].at).abs() <= CAM => new = old,
            Some(CarriageBlock::Between { frozen: true, .. }) => new = old,
            Some(CarriageBlock::Between { from, to, frozen }) => {
                let (a, b) = (cell.positions[*from].at, cell.positions[*to].at);
                let mid = (a + b) / 2.0;
                if (b > a) == dir && (old - mid) * (new - mid) <= 0.0 && old != new {
                    *frozen = true;
                    new = mid;
                }
            }
            _ => {}
        }
        self.x = new.clamp(0.0, 1.0);
        new <= 0.0 || new >= 1.0
    }

    /// Advances by `dt` nanoseconds to `t`; `clamp` is the clamp's position
    /// (0 open, 1 closed).
    pub(super) fn advance(
        &mut self,
        cell: &Cell,
        (t, dt): (Time, f64),
        act: &[bool],
        clamp: f64,
        damage: &mut Vec<Damage>,
    ) {
        let (f, r, released) = (act[cell.forward], act[cell.reverse], act[cell.brake]);
        let against_stop = self.drive(cell, dt, (f, r, act[cell.creep], released));
        let hazards = [
            (
                f && r,
                "reversing_short",
                "its forward and reverse contactors were on together",
            ),
            (
                f != r && !released,
                "brake_drag",
                "its motor ran against the applied brake",
            ),
            (
                against_stop,
                "overtravel",
                "its carriage ran into a mechanical end stop",
            ),
        ];
        for (k, (now, cause, what)) in hazards.into_iter().enumerate() {
            if now && !self.latched[k] {
                damage.push(Damage {
                    t,
                    cause,
                    detail: format!("axis {}: {what}", cell.tag),
                });
            }
            self.latched[k] = now;
        }
        self.handle(cell, t, clamp, damage);
        self.surroundings(cell, t);
    }

    /// The clamp takes the waiting workpiece at the load position, and lets
    /// go of it wherever it opens.
    fn handle(&mut self, cell: &Cell, t: Time, clamp: f64, damage: &mut Vec<Damage>) {
        let n = cell.positions.len();
        if clamp >= 1.0 - AT_END_SWITCH && self.waiting && !self.load && self.near(cell, 0, CAM) {
            self.load = true;
            self.waiting = false;
        }
        if self.load && clamp < 0.5 {
            self.load = false;
            if !self.near(cell, n - 1, CAM) {
                damage.push(Damage {
                    t,
                    cause: "workpiece_dropped",
                    detail: format!("the clamp of axis {} opened between positions", cell.tag),
                });
            } else if self.busy_until.is_some() {
                damage.push(Damage {
                    t,
                    cause: "workpiece_jam",
                    detail: format!(
                        "axis {} handed a workpiece over to a blocked outfeed",
                        cell.tag
                    ),
                });
            } else {
                self.delivered += 1;
                let busy = if self.rng.random_bool(0.85) {
                    self.rng.random_range(300 * MS..5 * SECOND)
                } else {
                    self.rng.random_range(20 * SECOND..120 * SECOND)
                };
                self.busy_until = Some(t + busy);
            }
        }
    }

    /// The outfeed frees itself, workpieces arrive in bursts, and the line
    /// controller switches recipes.
    fn surroundings(&mut self, cell: &Cell, t: Time) {
        if self.busy_until.is_some_and(|u| t >= u) {
            self.busy_until = None;
        }
        match self.arrival_at {
            None if !self.waiting => {
                // Bursts: most workpieces follow closely, now and then a gap.
                let gap = if self.rng.random_bool(0.75) {
                    self.rng.random_range(200 * MS..3 * SECOND)
                } else {
                    self.rng.random_range(15 * SECOND..90 * SECOND)
                };
                self.arrival_at = Some(t + gap);
            }
            Some(at) if t >= at => {
                self.waiting = true;
                self.arrival_at = None;
            }
            _ => {}
        }
        if cell.recipe.is_some() {
            match self.recipe_at {
                None => {
                    self.recipe_at = Some(t + self.rng.random_range(120 * SECOND..1200 * SECOND))
                }
                Some(at) if t >= at => {
                    self.recipe_b = !self.recipe_b;
                    self.recipe_at = None;
                }
                _ => {}
            }
        }
    }

    /// Writes the cell's sensors.
    pub(super) fn read(&self, cell: &Cell, io: &mut [bool]) {
        let mut zone = false;
        for (k, p) in cell.positions.iter().enumerate() {
            io[p.cam] = self.near(cell, k, CAM);
            zone |= self.near(cell, k, ZONE);
        }
        io[cell.zone] = zone;
        if let Some(s) = cell.recipe {
            io[s] = self.recipe_b;
        }
        io[cell.infeed] = self.waiting;
        io[cell.outfeed] = self.busy_until.is_none();
    }
}
