//! The scan loop shared by every simulated plant.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use vocabulary::fault::Factor;
use vocabulary::{FaultTemplate, Plant, Time};

use crate::inject::{Injection, SensorInjector};

/// The PLC program: called once per scan.
///
/// `io` holds one value per signal of the plant, indexed by
/// [`vocabulary::SignalId::index`]: sensors as read in this scan, actuators as
/// ordered in the previous scan. The controller writes its new orders into the
/// actuator entries and must leave the sensor entries alone. The constraint-based
/// safety filter plugs in through this same trait.
pub trait Controller {
    /// Computes the orders of the scan starting at `t`.
    fn scan(&mut self, t: Time, io: &mut [bool]);
}

/// The physical model of a plant.
pub trait Physics {
    /// The plant file describing this plant's signals, parts and faults.
    fn plant(&self) -> &Plant;

    /// The text of that plant file, comments included, as written beside a run.
    fn plant_toml(&self) -> &str;

    /// Advances the plant to time `t`, with the actuators physically at `actuators`
    /// (indexed like the plant's signals; sensor entries are meaningless) since the
    /// previous call. Physical harm is appended to `damage`.
    fn advance(
        &mut self,
        t: Time,
        actuators: &[bool],
        rng: &mut ChaCha8Rng,
        damage: &mut Vec<Damage>,
    );

    /// Writes the true value of every sensor into its entry of `io`.
    fn read_sensors(&self, io: &mut [bool]);

    /// Starts an element fault (`blocked_at`, `blocked_between`) now. Errors name
    /// what this plant cannot simulate.
    fn inject_element_fault(&mut self, template: &FaultTemplate) -> Result<(), String>;

    /// Starts a `slow` fault now: from here on, every motion, flow or heating
    /// of element or actuator `target` takes `factor` times longer. Plants
    /// that cannot simulate it say so.
    fn inject_slow(&mut self, target: &str, factor: Factor) -> Result<(), String> {
        let _ = factor;
        Err(format!(
            "plant '{}' cannot simulate slow({target})",
            self.plant().name
        ))
    }

    /// Throughput counters for the report (e.g. boxes delivered on each side).
    fn counters(&self) -> Vec<(String, u64)>;
}

/// Receives what the PLC saw and ordered in each scan.
pub trait ScanSink {
    /// Records the scan starting at `t`; `values` is indexed like the plant's signals.
    fn scan(&mut self, t: Time, values: &[bool]) -> std::io::Result<()>;
}

/// Physical harm observed by the simulator.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Damage {
    /// When it happened.
    pub t: Time,
    /// Machine-readable cause, e.g. `rollers_in_transit`.
    pub cause: &'static str,
    /// One sentence for people.
    pub detail: String,
}

/// Settings of one simulation run.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Simulated time; scans run at `0, scan, 2·scan, …` up to and including it.
    pub duration: Time,
    /// PLC scan period.
    pub scan_period: Time,
    /// Seed of every random draw (box arrivals, timing jitter).
    pub seed: u64,
    /// Faults to inject.
    pub faults: Vec<Injection>,
}

/// What a run produced besides its log.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct SimReport {
    /// Physical harm, in time order.
    pub damage: Vec<Damage>,
    /// Throughput counters.
    pub counters: Vec<(String, u64)>,
    /// Number of scans run.
    pub scans: u64,
}

/// Runs the scan loop: physics, sensor faults, controller, actuator faults, sink.
pub fn run<P: Physics, C: Controller, S: ScanSink>(
    physics: &mut P,
    controller: &mut C,
    config: &SimConfig,
    sink: &mut S,
    mut progress: impl FnMut(Time),
) -> std::io::Result<SimReport> {
    let mut stepper = Stepper::new(physics.plant(), config);
    while let Some((t, values)) = stepper.step(physics, controller)? {
        sink.scan(t, values)?;
        if stepper.scans().is_multiple_of(65_536) {
            progress(t);
        }
    }
    Ok(stepper.finish(physics))
}

/// Runs the scan loop as [`run`] does, and tells when each injected fault
/// first showed: the first scan, from its onset, where what the PLC saw or
/// ordered differs from the same run without that fault (same seed, the other
/// faults kept). A fault that changes nothing the PLC sees, and delays no
/// edge it would have seen, never shows. `None` for such a fault.
///
/// Each fault costs a second run in lockstep, until the fault shows.
pub fn run_with_showing<P, C, S>(
    physics: &mut P,
    controller: &mut C,
    config: &SimConfig,
    sink: &mut S,
    mut progress: impl FnMut(Time),
) -> std::io::Result<(SimReport, Vec<Option<Time>>)>
where
    P: Physics + Clone,
    C: Controller + Clone,
    S: ScanSink,
{
    let mut twins: Vec<Option<(Stepper, P, C)>> = (0..config.faults.len())
        .map(|i| {
            let mut without = config.clone();
            without.faults.remove(i);
            let stepper = Stepper::new(physics.plant(), &without);
            Some((stepper, physics.clone(), controller.clone()))
        })
        .collect();
    let mut showed = vec![None; config.faults.len()];
    let mut stepper = Stepper::new(physics.plant(), config);
    while let Some((t, values)) = stepper.step(physics, controller)? {
        sink.scan(t, values)?;
        for (i, twin) in twins.iter_mut().enumerate() {
            let Some((s, p, c)) = twin else { continue };
            let same = s.step(p, c)?.is_some_and(|(_, v)| v == values);
            if !same && t >= config.faults[i].onset {
                showed[i] = Some(t);
                *twin = None;
            }
        }
        if stepper.scans().is_multiple_of(65_536) {
            progress(t);
        }
    }
    Ok((stepper.finish(physics), showed))
}

/// The scan loop one scan at a time, for callers that pace the scans
/// themselves (a virtual PLC in real time) or act between them (flags set
/// from outside). [`run`] is this loop run to the end.
#[derive(Debug, Clone)]
pub struct Stepper {
    rng: ChaCha8Rng,
    injector: SensorInjector,
    /// Element faults not started yet, latest first.
    pending_elements: Vec<Injection>,
    /// What the PLC sees and orders in the current scan.
    io: Vec<bool>,
    /// The orders as the actuators carry them out (actuator faults applied).
    physical: Vec<bool>,
    report: SimReport,
    scan: Time,
    duration: Time,
    t: Time,
}

impl Stepper {
    /// A run of `plant` under `config`, before its first scan.
    pub fn new(plant: &Plant, config: &SimConfig) -> Stepper {
        let n = plant.signals.len();
        let mut pending_elements: Vec<Injection> = config
            .faults
            .iter()
            .filter(|f| f.template.signal().is_none())
            .cloned()
            .collect();
        pending_elements.sort_by_key(|f| f.onset);
        pending_elements.reverse();
        Stepper {
            rng: ChaCha8Rng::seed_from_u64(config.seed),
            injector: SensorInjector::new(&plant.signals, &config.faults),
            pending_elements,
            io: vec![false; n],
            physical: vec![false; n],
            report: SimReport::default(),
            scan: config.scan_period.max(1),
            duration: config.duration,
            t: 0,
        }
    }

    /// Adds a fault to the run under way, from its onset on: a run that
    /// takes a fault before its onset is the run that had it from the start.
    /// This lets many faulty runs branch off one fault-free run.
    pub fn inject(&mut self, plant: &Plant, fault: Injection) {
        if fault.template.signal().is_some() {
            self.injector.add(&plant.signals, &fault);
        } else {
            self.pending_elements.push(fault);
            self.pending_elements
                .sort_by_key(|f| std::cmp::Reverse(f.onset));
        }
    }

    /// Time of the next scan, or `None` once the run is over.
    pub fn next_scan(&self) -> Option<Time> {
        (self.t <= self.duration).then_some(self.t)
    }

    /// Runs the next scan: physics, sensor faults, controller, actuator faults.
    /// Returns its time and what the PLC saw and ordered (indexed like the
    /// plant's signals), or `None` once the run is over.
    pub fn step<P: Physics, C: Controller>(
        &mut self,
        physics: &mut P,
        controller: &mut C,
    ) -> std::io::Result<Option<(Time, &[bool])>> {
        let t = self.t;
        if t > self.duration {
            return Ok(None);
        }
        while self.pending_elements.last().is_some_and(|f| f.onset <= t) {
            if let Some(f) = self.pending_elements.pop() {
                // Checked by `Injection::resolve`; a refusal here is a simulator bug.
                let started = match &f.template {
                    FaultTemplate::Slow(x) => {
                        physics.inject_slow(x, f.factor.unwrap_or(Factor::DEFAULT))
                    }
                    other => physics.inject_element_fault(other),
                };
                started.map_err(std::io::Error::other)?;
            }
        }
        physics.advance(t, &self.physical, &mut self.rng, &mut self.report.damage);
        physics.read_sensors(&mut self.io);
        self.injector.apply_sensors(t, &mut self.io);
        controller.scan(t, &mut self.io);
        self.physical.copy_from_slice(&self.io);
        self.injector.apply_actuators(t, &mut self.physical);
        self.report.scans += 1;
        self.t += self.scan;
        Ok(Some((t, &self.io)))
    }

    /// Scans run so far.
    pub fn scans(&self) -> u64 {
        self.report.scans
    }

    /// Physical harm so far, in time order.
    pub fn damage(&self) -> &[Damage] {
        &self.report.damage
    }

    /// Ends the run: its damage, scan count and `physics`' counters.
    pub fn finish<P: Physics>(self, physics: &P) -> SimReport {
        let mut report = self.report;
        report.counters = physics.counters();
        report
    }
}

/// A sink that keeps every scan's changes in memory, for tests and small runs.
#[derive(Debug, Default, Clone)]
pub struct MemorySink {
    /// Values of the first scan.
    pub initial: Vec<bool>,
    /// Time of the first scan.
    pub start: Time,
    /// Every change after the first scan, in order.
    pub events: Vec<vocabulary::Event>,
    last: Vec<bool>,
}

impl ScanSink for MemorySink {
    fn scan(&mut self, t: Time, values: &[bool]) -> std::io::Result<()> {
        if self.last.is_empty() {
            self.initial = values.to_vec();
            self.start = t;
        } else {
            for (i, (&old, &new)) in self.last.iter().zip(values).enumerate() {
                if old != new {
                    self.events.push(vocabulary::Event {
                        t,
                        signal: vocabulary::SignalId(i as u32),
                        value: new,
                    });
                }
            }
        }
        self.last.clear();
        self.last.extend_from_slice(values);
        Ok(())
    }
}
