//! The box-sorting line of seeds 001 and 002 (ITS PLC "tri de caisses").
//!
//! Geometry, in metres along two straight lines:
//! - the *loading line*: feed conveyor `[0, 2)` (A0), intermediate conveyor
//!   `[2, 4)` (A1), and the turntable `[4, 5)` when it is at the loading position;
//! - the *unloading line*, across the turntable at the unloading position: the
//!   right conveyor `(-2.5, -0.5]` (A6, moving towards -2.5), the turntable
//!   `[-0.5, 0.5)` and the left conveyor `[0.5, 2.5)` (A5).
//!
//! A box moves at the speed of whatever supports its centre. Sensors see a box
//! when it covers their point. C0 (1.9) and C1 (2.2) are closer than the smallest
//! box (0.35) is long, which is why the observer 2P exists. C6 sits at 0.25 on
//! the turntable so that a box stopped on it is entirely aboard; C8 is within a
//! box length of C6 and C7 is not, which is why P67 only serves the right exit.
//!
//! The turntable's rotation follows seed 002's timing (see [`TurntableTiming`]).

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use vocabulary::fault::Factor;
use vocabulary::{FaultTemplate, MS, Plant, SignalId, Time};

use crate::sim::{Controller, Damage, MemorySink, Physics, SimConfig, SimReport};

/// The plant file of the sorting line, as shipped.
pub const PLANT_TOML: &str = include_str!("../plants/sorting.toml");

/// Parses the shipped plant file.
pub fn plant() -> Plant {
    match Plant::parse(
        PLANT_TOML,
        std::path::Path::new("datasets/plants/sorting.toml"),
    ) {
        Ok(p) => p,
        // The file is compiled in and covered by tests.
        Err(e) => panic!("shipped sorting plant file is invalid: {e}"),
    }
}

// Loading line (m).
const FEED_END: f64 = 2.0;
const INTER_END: f64 = 4.0;
const TABLE_LEN: f64 = 1.0;
const LOAD_TABLE_CENTRE: f64 = INTER_END + TABLE_LEN / 2.0;
const C0_AT: f64 = 1.9;
const C1_AT: f64 = 2.2;
const C3_AT: f64 = 3.95;
// Turntable frame (m), centred; +u points to the far end when loading, left when unloading.
const HALF: f64 = TABLE_LEN / 2.0;
const C6_AT: f64 = 0.25;
// Unloading line (m).
const C7_AT: f64 = -0.6;
const C8_AT: f64 = 0.55;
const C9_AT: f64 = -2.45;
const C10_AT: f64 = 2.45;
const EVAC_END: f64 = 2.5;
/// Two boxes closer than this (m) are still in contact.
const CONTACT_GAP: f64 = 0.005;
/// Turntable position thresholds: C4 is on at or below P4, C5 at or above P5.
const P4: f64 = 0.02;
const P5: f64 = 0.98;

/// Timing of the turntable, in ms after the order's edge, drawn uniformly per move.
///
/// The defaults are the seed's intervals shifted so that a PLC sampling every
/// 10 ms observes exactly them: after RE(A4), FE(C4) at 30–130 ms and RE(C5) at
/// 2900–2950 ms; after FE(A4), FE(C5) by 150 ms and RE(C4) at 2880–2970 ms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TurntableTiming {
    /// Leaving the loading position (C4 falls) after RE(A4).
    pub leave_loading: (f64, f64),
    /// Reaching the unloading position (C5 rises) after RE(A4).
    pub reach_unloading: (f64, f64),
    /// Leaving the unloading position (C5 falls) after FE(A4).
    pub leave_unloading: (f64, f64),
    /// Reaching the loading position (C4 rises) after FE(A4).
    pub reach_loading: (f64, f64),
}

impl Default for TurntableTiming {
    fn default() -> Self {
        TurntableTiming {
            leave_loading: (21.0, 129.0),
            reach_unloading: (2891.0, 2949.0),
            leave_unloading: (11.0, 149.0),
            reach_loading: (2871.0, 2969.0),
        }
    }
}

/// Settings of the sorting line.
#[derive(Debug, Clone, PartialEq)]
pub struct SortingConfig {
    /// Conveyor and roller speed, m/s.
    pub speed: f64,
    /// Mean time between box arrivals on the feed conveyor, s (exponential).
    pub mean_arrival_s: f64,
    /// Share of large boxes.
    pub large_share: f64,
    /// Length of a small box, m.
    pub small_len: f64,
    /// Length of a large box, m.
    pub large_len: f64,
    /// Turntable timing.
    pub timing: TurntableTiming,
}

impl Default for SortingConfig {
    fn default() -> Self {
        SortingConfig {
            speed: 0.5,
            mean_arrival_s: 12.0,
            large_share: 0.5,
            small_len: 0.35,
            large_len: 0.55,
            timing: TurntableTiming::default(),
        }
    }
}

/// Which straight line a box's coordinate refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Frame {
    /// Feed, intermediate, and the turntable when at the loading position.
    Loading,
    /// Aboard the turntable while it is away from both positions.
    Table,
    /// Right conveyor, turntable at the unloading position, left conveyor.
    Unloading,
}

#[derive(Debug, Clone)]
struct Carton {
    id: u64,
    len: f64,
    large: bool,
    frame: Frame,
    /// Lower end of the box in its frame's coordinate.
    lo: f64,
}

impl Carton {
    fn hi(&self) -> f64 {
        self.lo + self.len
    }
    fn centre(&self) -> f64 {
        self.lo + self.len / 2.0
    }
    fn covers(&self, x: f64) -> bool {
        self.lo <= x && x <= self.hi()
    }
}

#[derive(Debug, Clone, Copy)]
struct Motion {
    /// Direction: +1 towards unloading, -1 towards loading.
    dir: f64,
    t0: Time,
    p0: f64,
    /// End of the slow departure from a position (== t0 when starting mid-way).
    t1: Time,
    p1: f64,
    /// Position units per ns after `t1`.
    speed: f64,
}

impl Motion {
    /// The rest of the motion from `t` on, `factor` times slower.
    fn slowed(self, t: Time, factor: Factor) -> Motion {
        let p = self.position(t);
        let departing = t < self.t1;
        Motion {
            t0: t,
            p0: p,
            t1: if departing {
                t + factor.stretch(self.t1 - t)
            } else {
                t
            },
            p1: if departing { self.p1 } else { p },
            speed: self.speed / factor.get(),
            ..self
        }
    }

    fn position(&self, t: Time) -> f64 {
        if t <= self.t0 {
            self.p0
        } else if t < self.t1 {
            self.p0 + (self.p1 - self.p0) * (t - self.t0) as f64 / (self.t1 - self.t0) as f64
        } else {
            (self.p1 + self.dir * self.speed * (t - self.t1) as f64).clamp(0.0, 1.0)
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Block {
    /// Cannot move while at the position whose sensor is on at `p <= P4` (true) or `p >= P5` (false).
    At { loading: bool },
    /// Freezes mid-way on the next move in direction `dir`.
    Between { dir: f64, frozen: bool },
}

/// Signal ids of the sorting line, resolved once from the plant file.
#[derive(Debug, Clone, Copy)]
pub struct SortingIds {
    /// Sensors C0 to C10.
    pub c: [usize; 11],
    /// Actuators A0 to A6.
    pub a: [usize; 7],
}

impl SortingIds {
    /// Resolves C0..C10 and A0..A6 in `plant`.
    pub fn resolve(plant: &Plant) -> Result<SortingIds, String> {
        let id = |name: String| -> Result<usize, String> {
            plant
                .signals
                .id(&name)
                .map(SignalId::index)
                .ok_or_else(|| format!("plant '{}' has no signal {name}", plant.name))
        };
        let mut c = [0; 11];
        for (i, slot) in c.iter_mut().enumerate() {
            *slot = id(format!("C{i}"))?;
        }
        let mut a = [0; 7];
        for (i, slot) in a.iter_mut().enumerate() {
            *slot = id(format!("A{i}"))?;
        }
        Ok(SortingIds { c, a })
    }
}

/// The physical sorting line.
#[derive(Debug, Clone)]
pub struct SortingLine {
    plant: Plant,
    ids: SortingIds,
    config: SortingConfig,
    boxes: Vec<Carton>,
    next_id: u64,
    /// Arrivals waiting for room at the head of the feed conveyor.
    waiting: u64,
    next_arrival: Option<Time>,
    /// Turntable position: 0 = loading, 1 = unloading.
    p: f64,
    motion: Option<Motion>,
    a4: bool,
    /// Whether the turntable moved in the last step.
    moved: bool,
    block: Option<Block>,
    /// Per actuator (A0 to A6), how much slower what it drives moves: the
    /// turntable for A4, a conveyor or the rollers for the others.
    slow: [Option<Factor>; 7],
    /// A slowdown of the turntable that began during its motion, to apply
    /// to that motion at the next step.
    slowing: Option<Factor>,
    last_t: Option<Time>,
    /// Pairs of boxes in contact at the end of the last step.
    contacts: Vec<(u64, u64)>,
    arrived: u64,
    delivered_left: u64,
    delivered_right: u64,
    lost: u64,
}

impl SortingLine {
    /// A line at rest: turntable at the loading position, no boxes.
    pub fn new(config: SortingConfig) -> SortingLine {
        let plant = plant();
        let ids = match SortingIds::resolve(&plant) {
            Ok(ids) => ids,
            Err(e) => panic!("shipped sorting plant file: {e}"),
        };
        SortingLine {
            plant,
            ids,
            config,
            boxes: Vec::new(),
            next_id: 0,
            waiting: 0,
            next_arrival: None,
            p: 0.0,
            motion: None,
            a4: false,
            moved: false,
            block: None,
            slow: [None; 7],
            slowing: None,
            last_t: None,
            contacts: Vec::new(),
            arrived: 0,
            delivered_left: 0,
            delivered_right: 0,
            lost: 0,
        }
    }

    /// The resolved signal ids.
    pub fn ids(&self) -> SortingIds {
        self.ids
    }

    /// Puts a box on the line at `lo` (its lower end) of the loading line, for tests.
    pub fn place_box(&mut self, large: bool, lo: f64) {
        let len = if large {
            self.config.large_len
        } else {
            self.config.small_len
        };
        self.boxes.push(Carton {
            id: self.next_id,
            len,
            large,
            frame: Frame::Loading,
            lo,
        });
        self.next_id += 1;
    }

    /// Boxes delivered so far, on both sides.
    pub fn delivered(&self) -> u64 {
        self.delivered_left + self.delivered_right
    }

    /// Whether boxes are on the line or waiting to enter it.
    pub fn occupied(&self) -> bool {
        !self.boxes.is_empty() || self.waiting > 0
    }

    /// Stops spontaneous arrivals (boxes then come only from [`Self::place_box`]).
    pub fn without_arrivals(mut self) -> Self {
        self.next_arrival = Some(Time::MAX);
        self
    }

    fn uniform_ms(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> Time {
        let ms = if hi > lo {
            rng.random_range(lo..hi)
        } else {
            lo
        };
        (ms * MS as f64).round() as Time
    }

    fn turntable_order(&mut self, t: Time, a4: bool, rng: &mut ChaCha8Rng) {
        if a4 == self.a4 {
            return;
        }
        self.a4 = a4;
        let timing = self.config.timing;
        let (dir, leave, reach, in_zone, boundary) = if a4 {
            (
                1.0,
                timing.leave_loading,
                timing.reach_unloading,
                self.p <= P4,
                P4,
            )
        } else {
            (
                -1.0,
                timing.leave_unloading,
                timing.reach_loading,
                self.p >= P5,
                P5,
            )
        };
        let leave = Self::uniform_ms(rng, leave);
        let reach = Self::uniform_ms(rng, reach).max(leave + MS);
        let (leave, reach) = match self.slow[4] {
            Some(f) => (f.stretch(leave), f.stretch(reach)),
            None => (leave, reach),
        };
        let speed = (P5 - P4) / (reach - leave) as f64;
        self.motion = Some(if in_zone {
            Motion {
                dir,
                t0: t,
                p0: self.p,
                t1: t + leave,
                p1: boundary + dir * 1e-9,
                speed,
            }
        } else {
            Motion {
                dir,
                t0: t,
                p0: self.p,
                t1: t,
                p1: self.p,
                speed,
            }
        });
    }

    fn move_turntable(&mut self, t: Time) {
        self.moved = false;
        let Some(m) = self.motion else { return };
        let old = self.p;
        let mut new = m.position(t);
        match &mut self.block {
            Some(Block::At { loading }) => {
                let stuck = if *loading { old <= P4 } else { old >= P5 };
                if stuck {
                    new = old;
                }
            }
            Some(Block::Between { dir, frozen }) => {
                if *frozen {
                    new = old;
                } else if *dir == m.dir && (old - 0.5) * (new - 0.5) <= 0.0 && old != new {
                    *frozen = true;
                    new = 0.5;
                }
            }
            None => {}
        }
        self.moved = new != old;
        self.p = new;
        let target = if m.dir > 0.0 { 1.0 } else { 0.0 };
        if self.p == target {
            self.motion = None;
        }
    }

    fn at_loading(&self) -> bool {
        self.p <= P4
    }

    fn at_unloading(&self) -> bool {
        self.p >= P5
    }

    /// Speed of a box given what supports its centre.
    fn velocity(&self, b: &Carton, act: &[bool]) -> f64 {
        // What actuator `i` drives moves at this speed while it is on.
        let v = |i: usize| match self.slow[i] {
            _ if !act[self.ids.a[i]] => 0.0,
            Some(f) => self.config.speed / f.get(),
            None => self.config.speed,
        };
        let rollers = match (act[self.ids.a[2]], act[self.ids.a[3]]) {
            (true, false) => v(2),
            (false, true) => -v(3),
            _ => 0.0,
        };
        let c = b.centre();
        match b.frame {
            Frame::Loading if c < FEED_END => v(0),
            Frame::Loading if c < INTER_END => v(1),
            Frame::Loading => rollers,
            Frame::Table => rollers,
            Frame::Unloading if c >= HALF => v(5),
            Frame::Unloading if c < -HALF => -v(6),
            Frame::Unloading => rollers,
        }
    }

    /// Re-files boxes between frames after the turntable moved; records boxes
    /// caught across a turntable edge.
    fn reframe(&mut self, t: Time, damage: &mut Vec<Damage>) {
        let (load, unload) = (self.at_loading(), self.at_unloading());
        let moving = self.moved;
        let mut lost = Vec::new();
        for b in &mut self.boxes {
            match b.frame {
                Frame::Loading if !load => {
                    let (lo, hi) = (b.lo - LOAD_TABLE_CENTRE, b.hi() - LOAD_TABLE_CENTRE);
                    if lo >= -HALF && hi <= HALF {
                        b.frame = Frame::Table;
                        b.lo = lo;
                    } else if moving && hi > -HALF + 0.01 && lo < HALF {
                        // Half on the table, or sticking out into its sweep: the
                        // rotating table strikes it.
                        damage.push(Damage {
                            t,
                            cause: "rotation_with_box_straddling",
                            detail: format!("box {} was half on the turntable while it rotated away from loading", b.id),
                        });
                        lost.push(b.id);
                    }
                }
                Frame::Unloading if !unload => {
                    if b.lo >= -HALF && b.hi() <= HALF {
                        b.frame = Frame::Table;
                    } else if moving && b.hi() > -HALF + 0.01 && b.lo < HALF - 0.01 {
                        damage.push(Damage {
                            t,
                            cause: "rotation_with_box_straddling",
                            detail: format!("box {} was half on the turntable while it rotated away from unloading", b.id),
                        });
                        lost.push(b.id);
                    }
                }
                Frame::Table if load => {
                    b.frame = Frame::Loading;
                    b.lo += LOAD_TABLE_CENTRE;
                }
                Frame::Table if unload => b.frame = Frame::Unloading,
                _ => {}
            }
        }
        self.remove(&lost);
    }

    /// The gap between two boxes in the same frame (negative if they overlap).
    fn gap(&self, a: u64, b: u64) -> Option<f64> {
        let find = |id| self.boxes.iter().find(|x| x.id == id);
        let (a, b) = (find(a)?, find(b)?);
        (a.frame == b.frame).then(|| (b.lo - a.hi()).max(a.lo - b.hi()))
    }

    fn remove(&mut self, ids: &[u64]) {
        if !ids.is_empty() {
            self.lost += ids.len() as u64;
            self.boxes.retain(|b| !ids.contains(&b.id));
        }
    }

    fn move_boxes(&mut self, t: Time, dt: f64, act: &[bool], damage: &mut Vec<Damage>) {
        let moves: Vec<f64> = self
            .boxes
            .iter()
            .map(|b| self.velocity(b, act) * dt)
            .collect();
        for (b, d) in self.boxes.iter_mut().zip(&moves) {
            b.lo += d;
        }
        // Boxes cannot pass through each other: the one that caught up is held back.
        let mut order: Vec<usize> = (0..self.boxes.len()).collect();
        order.sort_by(|&i, &j| {
            let (a, b) = (&self.boxes[i], &self.boxes[j]);
            (a.frame as u8, a.lo)
                .partial_cmp(&(b.frame as u8, b.lo))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        let mut contacts = Vec::new();
        for w in order.windows(2) {
            let (i, j) = (w[0], w[1]);
            if self.boxes[i].frame != self.boxes[j].frame {
                continue;
            }
            let overlap = self.boxes[i].hi() - self.boxes[j].lo;
            if overlap < -1e-9 {
                continue;
            }
            // Undo the overlap on the box that moved towards the other.
            if moves[i] > moves[j] {
                self.boxes[i].lo -= overlap.max(0.0);
            } else {
                self.boxes[j].lo += overlap.max(0.0);
            }
            let pair = (
                self.boxes[i].id.min(self.boxes[j].id),
                self.boxes[i].id.max(self.boxes[j].id),
            );
            if overlap > 1e-9 && !self.contacts.contains(&pair) {
                damage.push(Damage {
                    t,
                    cause: "box_collision",
                    detail: format!("box {} ran into box {}", pair.0, pair.1),
                });
            }
            contacts.push(pair);
        }
        // Boxes jammed three in a row swap places as neighbours from scan to
        // scan: a pair stays in contact while its boxes stay within a few
        // millimetres, so that one jam counts as one collision per pair.
        for &(a, b) in &self.contacts {
            if !contacts.contains(&(a, b)) && self.gap(a, b).is_some_and(|g| g < CONTACT_GAP) {
                contacts.push((a, b));
            }
        }
        self.contacts = contacts;

        // Ends of lines: falls, deliveries, boxes thrown off a turntable in transit.
        let load = self.at_loading();
        let mut gone = Vec::new();
        for b in &self.boxes {
            let c = b.centre();
            match b.frame {
                Frame::Loading if c >= INTER_END + TABLE_LEN || (!load && c >= INTER_END) => {
                    damage.push(Damage {
                        t,
                        cause: "fell_off_end",
                        detail: if load {
                            format!("box {} was pushed off the far end of the turntable", b.id)
                        } else {
                            format!("box {} fell off the end of the intermediate conveyor (turntable away)", b.id)
                        },
                    });
                    gone.push((b.id, None));
                }
                Frame::Table if b.lo < -HALF || b.hi() > HALF => {
                    damage.push(Damage {
                        t,
                        cause: "rollers_in_transit",
                        detail: format!("box {} was thrown off the turntable: rollers ran while it was rotating", b.id),
                    });
                    gone.push((b.id, None));
                }
                Frame::Unloading if c >= EVAC_END => gone.push((b.id, Some(true))),
                Frame::Unloading if c <= -EVAC_END => gone.push((b.id, Some(false))),
                _ => {}
            }
        }
        for (id, delivered) in gone {
            match delivered {
                Some(true) => self.delivered_left += 1,
                Some(false) => self.delivered_right += 1,
                None => self.lost += 1,
            }
            self.boxes.retain(|b| b.id != id);
        }
    }

    fn arrivals(&mut self, t: Time, rng: &mut ChaCha8Rng) {
        let mean = self.config.mean_arrival_s;
        let next = |rng: &mut ChaCha8Rng, from: Time| -> Time {
            let u: f64 = rng.random_range(f64::EPSILON..1.0);
            from + ((-u.ln()) * mean * 1e9) as Time
        };
        let at = match self.next_arrival {
            Some(at) => at,
            None => {
                let at = next(rng, t);
                self.next_arrival = Some(at);
                at
            }
        };
        if t >= at && at != Time::MAX {
            self.waiting += 1;
            self.next_arrival = Some(next(rng, at));
        }
        if self.waiting == 0 {
            return;
        }
        let large = rng.random_bool(self.config.large_share.clamp(0.0, 1.0));
        let len = if large {
            self.config.large_len
        } else {
            self.config.small_len
        };
        let head_free = self
            .boxes
            .iter()
            .filter(|b| b.frame == Frame::Loading)
            .all(|b| b.lo >= len + 0.1);
        if head_free {
            self.waiting -= 1;
            self.arrived += 1;
            self.boxes.push(Carton {
                id: self.next_id,
                len,
                large,
                frame: Frame::Loading,
                lo: 0.0,
            });
            self.next_id += 1;
        }
    }
}

impl Physics for SortingLine {
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
        if let Some(f) = self.slowing.take() {
            self.motion = self.motion.map(|m| m.slowed(last, f));
        }
        self.turntable_order(last, act[self.ids.a[4]], rng);
        let dt = (t - last) as f64 / 1e9;
        self.move_boxes(t, dt, act, damage);
        self.move_turntable(t);
        self.reframe(t, damage);
        self.arrivals(t, rng);
    }

    fn read_sensors(&self, io: &mut [bool]) {
        let c = &self.ids.c;
        for &i in c {
            io[i] = false;
        }
        io[c[4]] = self.at_loading();
        io[c[5]] = self.at_unloading();
        for b in &self.boxes {
            match b.frame {
                Frame::Loading => {
                    io[c[0]] |= b.covers(C0_AT);
                    io[c[1]] |= b.covers(C1_AT);
                    io[c[2]] |= b.large && b.covers(C1_AT);
                    io[c[3]] |= b.covers(C3_AT);
                    io[c[6]] |= b.covers(LOAD_TABLE_CENTRE + C6_AT);
                }
                Frame::Table => io[c[6]] |= b.covers(C6_AT),
                Frame::Unloading => {
                    io[c[6]] |= b.covers(C6_AT);
                    io[c[7]] |= b.covers(C7_AT);
                    io[c[8]] |= b.covers(C8_AT);
                    io[c[9]] |= b.covers(C9_AT);
                    io[c[10]] |= b.covers(C10_AT);
                }
            }
        }
    }

    fn inject_element_fault(&mut self, template: &FaultTemplate) -> Result<(), String> {
        let zone = |s: &str| match s {
            "C4" => Ok(true),
            "C5" => Ok(false),
            other => Err(format!("the turntable has no position sensed by {other}")),
        };
        self.block = Some(match template {
            FaultTemplate::BlockedAt { element, at } if element == "P" => {
                Block::At { loading: zone(at)? }
            }
            FaultTemplate::BlockedBetween { element, from, to } if element == "P" => {
                let (from, to) = (zone(from)?, zone(to)?);
                if from == to {
                    return Err(format!("{template}: the two positions must differ"));
                }
                Block::Between {
                    dir: if from { 1.0 } else { -1.0 },
                    frozen: false,
                }
            }
            other => return Err(format!("the sorting line cannot simulate {other}")),
        });
        Ok(())
    }

    fn inject_slow(&mut self, x: &str, factor: Factor) -> Result<(), String> {
        // The turntable P is what A4 drives.
        let a = match x {
            "P" => 4,
            _ => (0..7)
                .find(|&i| self.plant.signals.name(SignalId(self.ids.a[i] as u32)) == x)
                .ok_or_else(|| {
                    format!("the sorting line has no element or actuator {x} (P, A0 to A6)")
                })?,
        };
        self.slow[a] = Some(factor);
        if a == 4 {
            self.slowing = Some(factor);
        }
        Ok(())
    }

    fn counters(&self) -> Vec<(String, u64)> {
        vec![
            ("boxes_arrived".into(), self.arrived),
            ("delivered_left".into(), self.delivered_left),
            ("delivered_right".into(), self.delivered_right),
            ("boxes_lost".into(), self.lost),
            ("boxes_waiting".into(), self.waiting),
        ]
    }
}

/// Seed 001's synthesised control law, eq. 68–74, with its observers.
///
/// ```text
/// A0 = !C0 | !2P & (!C3 | C4 & !C6 & !P36)      A3 = C5 & !PC
/// A1 = !C3 | C4 & !C6 & !P36                    A4 = C6 | C8 | C7 | P67
/// A2 = C5 & !C7 & PC | C4 & !C6 & C3 | C4 & P36  A5 = A6 = 1
/// ```
/// Observers (updated from this scan's inputs before the law is evaluated):
/// `2P` set on RE(C0)&C1, reset on FE(C1); `P36` set on FE(C3), reset on RE(C6);
/// `P67` set on FE(C6)&!C8, reset on RE(C7); `PC` toggles on FE(C7)|FE(C8).
#[derive(Debug, Clone)]
pub struct SynthesisedControl {
    ids: SortingIds,
    prev: [bool; 11],
    first: bool,
    /// Observer 2P: two boxes between C0 and C1.
    pub two_p: bool,
    /// Observer P36: a box between C3 and C6.
    pub p36: bool,
    /// Observer P67: a box between C6 and C7.
    pub p67: bool,
    /// Observer PC: the next box goes left.
    pub pc: bool,
}

impl SynthesisedControl {
    /// The control law for a plant with the sorting line's signals.
    pub fn new(ids: SortingIds) -> Self {
        SynthesisedControl {
            ids,
            prev: [false; 11],
            first: true,
            two_p: false,
            p36: false,
            p67: false,
            pc: true,
        }
    }
}

impl Controller for SynthesisedControl {
    fn scan(&mut self, _t: Time, io: &mut [bool]) {
        let mut c = [false; 11];
        for (v, &i) in c.iter_mut().zip(&self.ids.c) {
            *v = io[i];
        }
        if self.first {
            self.prev = c;
            self.first = false;
        }
        let re = |i: usize| c[i] && !self.prev[i];
        let fe = |i: usize| !c[i] && self.prev[i];
        // Observers: reset wins over set.
        if fe(1) {
            self.two_p = false;
        } else if re(0) && c[1] {
            self.two_p = true;
        }
        if re(6) {
            self.p36 = false;
        } else if fe(3) {
            self.p36 = true;
        }
        if re(7) {
            self.p67 = false;
        } else if fe(6) && !c[8] {
            self.p67 = true;
        }
        if fe(7) || fe(8) {
            self.pc = !self.pc;
        }
        self.prev = c;

        let (two_p, p36, p67, pc) = (self.two_p, self.p36, self.p67, self.pc);
        let load_ok = c[4] && !c[6] && !p36;
        let a = &self.ids.a;
        io[a[0]] = !c[0] || !two_p && (!c[3] || load_ok);
        io[a[1]] = !c[3] || load_ok;
        io[a[2]] = c[5] && !c[7] && pc || c[4] && !c[6] && c[3] || c[4] && p36;
        io[a[3]] = c[5] && !pc;
        io[a[4]] = c[6] || c[8] || c[7] || p67;
        io[a[5]] = true;
        io[a[6]] = true;
    }
}

/// Runs the sorting line under its synthesised control (default geometry and
/// timing), keeping the log in memory: for tests, benchmarks and the demo.
pub fn simulate_in_memory(config: &SimConfig) -> std::io::Result<(MemorySink, SimReport)> {
    let mut line = SortingLine::new(SortingConfig::default());
    let mut ctl = SynthesisedControl::new(line.ids());
    let mut sink = MemorySink::default();
    let report = crate::sim::run(&mut line, &mut ctl, config, &mut sink, |_| {})?;
    Ok((sink, report))
}
