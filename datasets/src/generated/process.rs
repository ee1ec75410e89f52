//! Process units: a tank filled from a supply through an inlet valve or pump,
//! with level switches (low, high, optionally overflow), a batch that ends on
//! the high level probe or on a weight switch, an optional heater or cooler
//! with a thermostat, and an outlet valve or pump draining the batch into the
//! next process, which then stays busy for a while.
//!
//! The physics integrates the level and the temperature scan by scan. A valve
//! passes a flow proportional to the square root of the head above it: the
//! supply's head for the inlet, which drifts over a run, and the tank's own
//! level for the outlet, so that draining slows down as the tank empties. A
//! pump delivers a steady flow. Heating (or cooling) time follows the load
//! (the level) and the ambient temperature, which drifts too; the fresh
//! liquid comes in at ambient temperature.
//!
//! Damage: `tank_overflow` (the level reaches the rim), `dry_heating` (the
//! heater or cooler runs with its element above the liquid, under the low
//! switch), `pump_dry_run` (the outlet pump runs on an empty tank), `spill`
//! (a batch is drained into the next process while it is busy).

use std::f64::consts::TAU;

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use vocabulary::{SECOND, Time, fault::Factor};

use super::layout::{Builder, DRIFT, Element, Layout, PartSpec, log_uniform};
use super::program::{ChainWriter, Op, StepChain};
use crate::sim::Damage;

/// Level of the low switch (fraction of the tank's height).
pub const LOW: f64 = 0.2;
/// Level of the high switch.
pub const HIGH: f64 = 0.8;
/// Level of the overflow switch.
pub const OVERFLOW: f64 = 0.93;
/// Level at the start of a run: a heel under the low switch.
const HEEL: f64 = 0.1;
/// Ambient temperature around which the day drifts, °C.
const AMBIENT: f64 = 20.0;
/// Thermostat hysteresis, K.
const HYSTERESIS: f64 = 1.0;

/// How liquid is moved in or out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TankFeed {
    /// A valve: the flow follows the square root of the head above it.
    Valve,
    /// A pump: a steady flow.
    Pump,
}

/// A heater or cooler with its thermostat.
#[derive(Debug, Clone, PartialEq)]
pub struct Thermal {
    /// Heats, or else cools.
    pub heating: bool,
    /// Order: heater (cooler) on.
    pub order: usize,
    /// Sensor: the setpoint is reached (at or above it heating, at or below
    /// it cooling).
    pub thermostat: usize,
    /// Setpoint's distance from the nominal ambient temperature, K.
    pub delta: f64,
    /// Nominal time to bring a full batch from ambient to the setpoint.
    pub time: Time,
    /// Time constant of the losses to ambient.
    pub loss: Time,
}

/// A tank of a process unit.
#[derive(Debug, Clone, PartialEq)]
pub struct Tank {
    /// Its tag, e.g. `T41`.
    pub tag: String,
    /// Its unit's number (as a station's, in tags).
    pub number: usize,
    /// What the unit does, for people.
    pub name: String,
    /// Order: inlet valve open / inlet pump on.
    pub inlet: usize,
    /// How the inlet moves liquid.
    pub inlet_kind: TankFeed,
    /// Order: outlet valve open / outlet pump on.
    pub outlet: usize,
    /// How the outlet moves liquid.
    pub outlet_kind: TankFeed,
    /// Sensor: level above the low switch (the heater is covered).
    pub low: usize,
    /// Sensor: level above the high switch.
    pub high: usize,
    /// Sensor: level at the overflow switch, if there is one.
    pub overflow: Option<usize>,
    /// Sensor: a weight switch ending the batch below the high switch, if the
    /// batch is dosed by weight.
    pub weight: Option<usize>,
    /// Level a batch is filled to.
    pub batch: f64,
    /// Sensor: the next process is ready for a batch.
    pub ready: usize,
    /// Heater or cooler, if any.
    pub thermal: Option<Thermal>,
    /// Nominal time to fill a batch from the low switch.
    pub fill_time: Time,
    /// Nominal time to drain a batch down to the low switch.
    pub drain_time: Time,
    /// Batch-to-batch relative jitter of the flows.
    pub jitter: f64,
}

impl Tank {
    /// The sensor that ends a fill.
    pub fn full(&self) -> usize {
        self.weight.unwrap_or(self.high)
    }

    /// The switch that must never be reached while filling.
    pub fn guard(&self) -> usize {
        match (self.overflow, self.weight) {
            (Some(o), _) => o,
            (None, _) => self.high,
        }
    }

    /// Its orders, inlet first.
    pub fn orders(&self) -> Vec<usize> {
        let mut out = vec![self.inlet, self.outlet];
        out.extend(self.thermal.as_ref().map(|h| h.order));
        out
    }
}

impl Builder {
    /// Draws a process unit around a tank: one part.
    pub(super) fn tank(&mut self) {
        let number = self.layout.units() + 1;
        let thermal = self.rng.random_bool(0.7).then(|| self.rng.random_bool(0.7));
        let weight = self.rng.random_bool(0.4);
        self.unit_name = match (thermal, weight) {
            (Some(true), _) => "heating tank",
            (Some(false), _) => "cooling tank",
            (None, true) => "dosing tank",
            (None, false) => "buffer tank",
        }
        .to_string();
        let label = self.label(number);
        let tag = self.tag('T', number);
        let kind = |pump: bool| {
            if pump {
                TankFeed::Pump
            } else {
                TankFeed::Valve
            }
        };
        let inlet_kind = kind(self.rng.random_bool(0.4));
        let outlet_kind = kind(self.rng.random_bool(0.5));
        let inlet = match inlet_kind {
            TankFeed::Valve => self.signal(
                'Y',
                number,
                false,
                format!("open the inlet valve of tank {tag} from the supply header ({label})"),
            ),
            TankFeed::Pump => self.signal(
                'M',
                number,
                false,
                format!("inlet pump of tank {tag} on ({label})"),
            ),
        };
        let high = self.sensor(
            number,
            format!("tank {tag} level above the high switch ({label})"),
        );
        let overflow = self.rng.random_bool(0.5).then(|| {
            self.sensor(
                number,
                format!("tank {tag} level at the overflow switch ({label})"),
            )
        });
        let weight = weight.then(|| {
            self.sensor(
                number,
                format!(
                    "tank {tag} batch weight reached: weight switch of its load cells ({label})"
                ),
            )
        });
        let outlet = match outlet_kind {
            TankFeed::Valve => self.signal(
                'Y',
                number,
                false,
                format!("open the outlet valve of tank {tag} to the next process ({label})"),
            ),
            TankFeed::Pump => self.signal(
                'M',
                number,
                false,
                format!("outlet pump of tank {tag} on, to the next process ({label})"),
            ),
        };
        let low = self.sensor(
            number,
            format!("tank {tag} level above the low switch ({label})"),
        );
        let ready = self.sensor(
            number,
            format!("next process ready for a batch of tank {tag} ({label})"),
        );
        let thermal = thermal.map(|heating| self.thermal(number, &tag, &label, heating));
        let batch = if weight.is_some() {
            self.rng.random_range(0.55..0.72)
        } else {
            HIGH
        };
        let fill_time = log_uniform(&mut self.rng, 3 * SECOND, 60 * SECOND);
        let drain_time = log_uniform(&mut self.rng, 3 * SECOND, 60 * SECOND);
        let jitter = self.rng.random_range(0.01..0.04);
        let tank = Tank {
            tag,
            number,
            name: self.unit_name.clone(),
            inlet,
            inlet_kind,
            outlet,
            outlet_kind,
            low,
            high,
            overflow,
            weight,
            batch,
            ready,
            thermal,
            fill_time,
            drain_time,
            jitter,
        };
        self.tank_parts(&tank);
        self.layout.tanks.push(tank);
    }

    /// The part of a tank: its orders, its switches, its thermostat and the
    /// next process's "ready".
    fn tank_parts(&mut self, tank: &Tank) {
        // One part: the level switches follow both the inlet and the outlet,
        // and the thermostat the heater and the fresh liquid.
        let mut sensors = vec![tank.low, tank.high];
        sensors.extend(tank.overflow);
        sensors.extend(tank.weight);
        sensors.extend(tank.thermal.as_ref().map(|h| h.thermostat));
        sensors.push(tank.ready);
        self.layout.parts.push(PartSpec {
            name: format!("st{}_tank", tank.number),
            actuators: tank.orders(),
            sensors,
            element: None::<Element>,
            inputs: vec![tank.ready],
        });
    }

    /// A heater (or cooler) of tank `tag` with its thermostat.
    fn thermal(&mut self, number: usize, tag: &str, label: &str, heating: bool) -> Thermal {
        let (what, reached) = if heating {
            ("heater", "at or above")
        } else {
            ("cooler", "at or below")
        };
        let order = self.signal(
            'E',
            number,
            false,
            format!("{what} of tank {tag} on ({label})"),
        );
        let thermostat = self.sensor(
            number,
            format!("thermostat: tank {tag} {reached} its setpoint ({label})"),
        );
        Thermal {
            heating,
            order,
            thermostat,
            delta: if heating {
                self.rng.random_range(15.0..50.0)
            } else {
                self.rng.random_range(5.0..12.0)
            },
            time: log_uniform(&mut self.rng, 5 * SECOND, 90 * SECOND),
            loss: log_uniform(&mut self.rng, 600 * SECOND, 3600 * SECOND),
        }
    }
}

/// A tank's cycle: fill a batch, heat or cool it to the thermostat, wait for
/// the next process, drain down to the low switch, and again.
pub(super) fn chain(layout: &Layout, tank: &Tank) -> StepChain {
    let mut w = ChainWriter::default();
    let start = w.op(Op::wait("start".into(), 0));
    let limit = |nominal: Time| Some(nominal * 3 + 5 * SECOND);
    let mut fill = Op::until(format!("fill tank {}", tank.tag), tank.full(), true);
    fill.enter = vec![(tank.inlet, true)];
    fill.exit = vec![(tank.inlet, false)];
    fill.timeout = limit(tank.fill_time);
    let fill = w.then(start, &[], vec![fill]);
    let mut ops = Vec::new();
    if let Some(h) = &tank.thermal {
        let verb = if h.heating { "heat" } else { "cool" };
        let mut op = Op::until(format!("{verb} tank {}", tank.tag), h.thermostat, true);
        op.enter = vec![(h.order, true)];
        op.exit = vec![(h.order, false)];
        op.timeout = limit(h.time);
        ops.push(op);
    }
    ops.push(Op::until(
        format!("wait: next process ready for tank {}", tank.tag),
        tank.ready,
        true,
    ));
    let mut drain = Op::until(format!("drain tank {}", tank.tag), tank.low, false);
    drain.enter = vec![(tank.outlet, true)];
    drain.exit = vec![(tank.outlet, false)];
    drain.timeout = limit(tank.drain_time);
    ops.push(drain);
    let last = w.then(fill, &[], ops);
    w.link(last, fill, &[]);
    let stop = tank.orders().into_iter().map(|o| (o, false)).collect();
    w.finish(tank.number - 1, start, stop, layout.timeouts)
}

/// The safety constraints of a tank, each with why.
pub(super) fn constraints(layout: &Layout, tank: &Tank, out: &mut Vec<(String, String)>) {
    let sig = |s: usize| layout.signals[s].name.as_str();
    let guard = if Some(tank.guard()) == tank.overflow {
        "the overflow switch"
    } else {
        "the high switch"
    };
    out.push((
        format!(
            "tank {} must not be filled once its level is at {guard}",
            tank.tag
        ),
        format!("{} & {}", sig(tank.inlet), sig(tank.guard())),
    ));
    if let Some(h) = &tank.thermal {
        out.push((
            format!(
                "the {} of tank {} must not run unless the liquid covers it (low switch)",
                if h.heating { "heater" } else { "cooler" },
                tank.tag
            ),
            format!("{} & !{}", sig(h.order), sig(tank.low)),
        ));
    }
    if tank.outlet_kind == TankFeed::Pump {
        out.push((
            format!(
                "the outlet pump of tank {} must not run dry (under the low switch)",
                tank.tag
            ),
            format!("{} & !{}", sig(tank.outlet), sig(tank.low)),
        ));
    }
    out.push((
        format!(
            "tank {} must not be drained while the next process is not ready",
            tank.tag
        ),
        format!("{} & !{}", sig(tank.outlet), sig(tank.ready)),
    ));
}

/// The unit in words, for the plant file's header.
pub(super) fn words(layout: &Layout, tank: &Tank) -> String {
    let sig = |s: usize| layout.signals[s].name.as_str();
    let feed = |k: TankFeed, order: usize| match k {
        TankFeed::Valve => format!("a valve ({})", sig(order)),
        TankFeed::Pump => format!("a pump ({})", sig(order)),
    };
    let mut text = format!(
        "Unit {}, {}: tank {} is filled from a supply header whose flow drifts, through {}, ",
        tank.number,
        tank.name,
        tank.tag,
        feed(tank.inlet_kind, tank.inlet)
    );
    match tank.weight {
        Some(w) => text.push_str(&format!(
            "until its weight switch ({}) says the batch is in",
            sig(w)
        )),
        None => text.push_str(&format!("up to its high switch ({})", sig(tank.high))),
    }
    if let Some(o) = tank.overflow {
        text.push_str(&format!(", under an overflow switch ({})", sig(o)));
    }
    if let Some(h) = &tank.thermal {
        text.push_str(&format!(
            "; a {} ({}) brings it to its thermostat ({}), in a time that follows the load and the ambient temperature",
            if h.heating { "heater" } else { "cooler" },
            sig(h.order),
            sig(h.thermostat)
        ));
    }
    text.push_str(&format!(
        "; once the next process is ready ({}), {} drains it down to the low switch ({}), {}, and the next process is then busy for a while.",
        sig(tank.ready),
        feed(tank.outlet_kind, tank.outlet),
        sig(tank.low),
        match tank.outlet_kind {
            TankFeed::Valve => "slower as the level falls",
            TankFeed::Pump => "at a steady flow",
        }
    ));
    text
}

/// A sine drift over a run: `1 + amplitude · sin(2πt/period + phase)`.
#[derive(Debug, Clone, Copy, Default)]
struct Drift {
    amplitude: f64,
    period: f64,
    phase: f64,
}

impl Drift {
    fn draw(rng: &mut ChaCha8Rng, amplitude: (f64, f64), period: (Time, Time)) -> Drift {
        Drift {
            amplitude: rng.random_range(amplitude.0..amplitude.1),
            period: rng.random_range(period.0 as f64..period.1 as f64),
            phase: rng.random_range(0.0..TAU),
        }
    }

    fn at(&self, t: Time) -> f64 {
        if self.period <= 0.0 {
            return 0.0;
        }
        self.amplitude * (TAU * t as f64 / self.period + self.phase).sin()
    }
}

/// A tank during a run.
#[derive(Debug, Clone)]
pub(super) struct TankState {
    level: f64,
    temperature: f64,
    thermostat: bool,
    /// Relative change of the supply's head over the run.
    supply: Drift,
    /// Ambient temperature's change over the run, K.
    ambient: Drift,
    /// The supply's relative head and the ambient temperature now, and until
    /// when they hold.
    drifts_now: (f64, f64),
    drifts_until: Time,
    /// Per-run drift of each flow and of the heating power.
    drift: [f64; 3],
    /// This batch's jitter of the inlet and outlet flows.
    jitter: [f64; 2],
    /// `slow` faults: how much slower the inlet, the outlet, the heater are.
    slow: [f64; 3],
    was_open: [bool; 2],
    /// Level when the outlet last opened.
    drained_from: f64,
    busy_until: Option<Time>,
    batches: u64,
    /// Per damage cause: whether an incident is under way.
    latched: [bool; 4],
    rng: ChaCha8Rng,
}

impl TankState {
    /// A tank at rest: a heel of liquid at ambient temperature.
    pub(super) fn new(rng: ChaCha8Rng) -> TankState {
        TankState {
            level: HEEL,
            temperature: AMBIENT,
            thermostat: false,
            supply: Drift::default(),
            ambient: Drift::default(),
            drifts_now: (1.0, AMBIENT),
            drifts_until: 0,
            drift: [1.0; 3],
            jitter: [0.0; 2],
            slow: [1.0; 3],
            was_open: [false; 2],
            drained_from: HEEL,
            busy_until: None,
            batches: 0,
            latched: [false; 4],
            rng,
        }
    }

    /// Draws the run: drifts of the supply, the ambient and each flow.
    pub(super) fn seed(&mut self, rng: ChaCha8Rng) {
        self.rng = rng;
        self.supply = Drift::draw(&mut self.rng, (0.05, 0.2), (1200 * SECOND, 7200 * SECOND));
        self.ambient = Drift::draw(
            &mut self.rng,
            (1.0, 4.0),
            (3600 * SECOND, 6 * 3600 * SECOND),
        );
        for d in &mut self.drift {
            *d = self.rng.random_range(1.0 - DRIFT..=1.0 + DRIFT);
        }
        self.temperature = AMBIENT + self.ambient.at(0);
    }

    /// Makes the order `signal` of `tank` slower by `factor`; false if it is
    /// none of its orders.
    pub(super) fn slow(&mut self, tank: &Tank, signal: usize, factor: Factor) -> bool {
        let k = if signal == tank.inlet {
            0
        } else if signal == tank.outlet {
            1
        } else if tank.thermal.as_ref().is_some_and(|h| h.order == signal) {
            2
        } else {
            return false;
        };
        self.slow[k] = factor.get();
        true
    }

    /// Advances by `dt` nanoseconds to `t`.
    pub(super) fn advance(
        &mut self,
        tank: &Tank,
        t: Time,
        dt: f64,
        act: &[bool],
        damage: &mut Vec<Damage>,
    ) {
        let (inlet, outlet) = (act[tank.inlet], act[tank.outlet]);
        for (k, open) in [inlet, outlet].into_iter().enumerate() {
            if open && !self.was_open[k] {
                self.jitter[k] = self.rng.random_range(-tank.jitter..=tank.jitter);
                if k == 1 {
                    self.drained_from = self.level;
                }
            }
        }
        // The next process takes the batch once the outlet closes on it.
        if !outlet && self.was_open[1] && self.drained_from - self.level > 0.1 {
            let busy = if self.rng.random_bool(0.8) {
                self.rng.random_range(SECOND..15 * SECOND)
            } else {
                // Now and then it is blocked for longer.
                self.rng.random_range(30 * SECOND..180 * SECOND)
            };
            self.busy_until = Some(t + busy);
            self.batches += 1;
        }
        self.was_open = [inlet, outlet];
        if self.busy_until.is_some_and(|u| t >= u) {
            self.busy_until = None;
        }
        if t >= self.drifts_until {
            // The drifts take minutes: drawn again each second, not each scan.
            self.drifts_now = (1.0 + self.supply.at(t), AMBIENT + self.ambient.at(t));
            self.drifts_until = t + SECOND;
        }
        let (supply, ambient) = self.drifts_now;
        let span = tank.batch - LOW;
        let mut q_in = 0.0;
        if inlet {
            let nominal = span / tank.fill_time as f64;
            let head = match tank.inlet_kind {
                TankFeed::Valve => supply.max(0.0).sqrt(),
                // A pump's flow hardly feels the supply's pressure.
                TankFeed::Pump => 1.0 + (supply - 1.0) / 4.0,
            };
            q_in = nominal * head / (self.drift[0] * (1.0 + self.jitter[0]) * self.slow[0]);
        }
        let mut q_out = 0.0;
        if outlet && self.level > 0.0 {
            let stretch = self.drift[1] * (1.0 + self.jitter[1]) * self.slow[1];
            q_out = match tank.outlet_kind {
                TankFeed::Valve => {
                    // Torricelli: draining from `batch` to `LOW` in drain_time.
                    let c = 2.0 * (tank.batch.sqrt() - LOW.sqrt()) / tank.drain_time as f64;
                    c * self.level.sqrt()
                }
                TankFeed::Pump => span / tank.drain_time as f64,
            } / stretch;
        }
        let old = self.level;
        let added = q_in * dt;
        self.level = (old + added - q_out * dt).clamp(0.0, 1.0);
        if added > 0.0 && old + added > 0.0 {
            // Fresh liquid comes in at ambient temperature.
            self.temperature = (self.temperature * old + ambient * added) / (old + added);
        }
        if let Some(h) = &tank.thermal {
            let sign = if h.heating { 1.0 } else { -1.0 };
            let mut rate = -(self.temperature - ambient) / h.loss as f64;
            if act[h.order] {
                let power = h.delta * tank.batch / (h.time as f64 * self.drift[2] * self.slow[2]);
                rate += sign * power / self.level.max(0.05);
            }
            self.temperature += rate * dt;
            let setpoint = AMBIENT + sign * h.delta;
            let beyond = sign * (self.temperature - setpoint);
            if beyond >= 0.0 {
                self.thermostat = true;
            } else if beyond < -HYSTERESIS {
                self.thermostat = false;
            }
        }
        let pumping = tank.outlet_kind == TankFeed::Pump && outlet;
        let thermal = tank.thermal.as_ref();
        let hazards = [
            (self.level >= 1.0, "tank_overflow", "overflowed"),
            (
                thermal.is_some_and(|h| act[h.order]) && self.level < LOW,
                "dry_heating",
                if thermal.is_some_and(|h| h.heating) {
                    "had its heater on with the liquid under it"
                } else {
                    "had its cooler on with the liquid under it"
                },
            ),
            (
                pumping && self.level <= 0.02,
                "pump_dry_run",
                "had its outlet pump run dry",
            ),
            (
                outlet && self.level > 0.01 && self.busy_until.is_some(),
                "spill",
                "was drained into the next process while it was busy",
            ),
        ];
        for (k, (now, cause, what)) in hazards.into_iter().enumerate() {
            if now && !self.latched[k] {
                // Words only for an incident: this runs every scan.
                let detail = format!("tank {} {what}", tank.tag);
                damage.push(Damage { t, cause, detail });
            }
            self.latched[k] = now;
        }
    }

    /// Writes the tank's sensors.
    pub(super) fn read(&self, tank: &Tank, io: &mut [bool]) {
        io[tank.low] = self.level >= LOW;
        io[tank.high] = self.level >= HIGH;
        if let Some(o) = tank.overflow {
            io[o] = self.level >= OVERFLOW;
        }
        if let Some(w) = tank.weight {
            io[w] = self.level >= tank.batch;
        }
        io[tank.ready] = self.busy_until.is_none();
        if let Some(h) = &tank.thermal {
            io[h.thermostat] = self.thermostat;
        }
    }

    /// Batches handed over to the next process so far.
    pub(super) fn batches(&self) -> u64 {
        self.batches
    }
}
