//! The closed loop of the demo: in each scan of a simulated plant (a [`Rig`]:
//! the sorting line or the four-cylinder rig), the plant's functional program,
//! if it has one, sets the plant file's variables (the rig's GRAFCET steps),
//! safe control by constraints computes the orders through the (rewritten)
//! safety filter, the diagnosers read the scan, and their verdicts raise the
//! flags the filter reads from the next scan on.
//!
//! Nothing in the loop is written for one plant: the program reads the sensors
//! as the filter's functional constraints do ([`Filter::certain_sensors`]),
//! and every plant-specific rule is in its plant file.

use datasets::cylinders::{ConstraintControl, CylinderConfig, CylinderIds, CylinderRig};
use datasets::inject::Injection;
use datasets::sim::{Controller, Damage, MemorySink, Physics, ScanSink, SimConfig};
use datasets::sorting::{SortingConfig, SortingLine};
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict};
use diagnoser::fault::{Factor, FaultTarget};
use diagnoser::model::Model;
use diagnoser::{Event, FaultTemplate, Plant, SignalId, Time, TimeFormat, TimeUnit};
use filter_coupling::filter::{Coupling, Filter, Mode, Request};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use rand_chacha::ChaCha8Rng;

use crate::flags::FlagBoard;
use crate::probe::{ProbeRecord, Prober};

/// No delivery for this long while boxes wait counts as halted, beyond it.
pub const HALT_AFTER: Time = 60 * diagnoser::SECOND;

/// One closed-loop run.
#[derive(Debug, Clone)]
pub struct LoopRun {
    /// How the filter uses the flags.
    pub coupling: Coupling,
    /// Seed of the simulation.
    pub seed: u64,
    /// Simulated time.
    pub duration: Time,
    /// The fault, if any.
    pub fault: Option<Injection>,
    /// Where throughput, damage and halts start being counted (the onset).
    pub from: Time,
    /// Whether the coupling may make probing moves ([`crate::probe`]).
    pub probe: bool,
}

/// What a closed-loop run measured, from [`LoopRun::from`] on.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopOutcome {
    /// Boxes delivered on both sides.
    pub delivered: u64,
    /// Physical harm.
    pub damage: Vec<Damage>,
    /// First verdict other than normal, if any.
    pub detected: Option<Time>,
    /// Time spent with boxes on the line and no delivery for over a minute,
    /// beyond that minute.
    pub halted: Time,
    /// Scans in which the filter overrode the computed orders.
    pub fallback_scans: u64,
    /// The flags raised by the end.
    pub flags: Vec<String>,
    /// When each box was delivered, from the start of the run (not only from
    /// [`LoopRun::from`]): a fault-free run counted from any onset.
    pub deliveries: Vec<Time>,
    /// The probing moves made, each with the reason of the verdict it led to.
    pub probes: Vec<ProbeRecord>,
    /// Why no probe was made for an ambiguous, waiting part, once per reason.
    pub no_probe: Vec<String>,
}

impl LoopOutcome {
    /// Boxes delivered from `from` on.
    pub fn delivered_from(&self, from: Time) -> u64 {
        let before = self.deliveries.partition_point(|&t| t < from);
        (self.deliveries.len() - before) as u64
    }
}

/// The PLC of the closed loop: filter-based safe control plus the diagnosers.
#[derive(Clone)]
pub struct CoupledPlc {
    filter: Filter,
    /// The diagnosers (none while recording a run to learn from).
    diagnoser: Option<PlantDiagnoser>,
    /// Values last given to the diagnosers.
    last: Vec<bool>,
    started: bool,
    /// Flags set by the verdicts, and those the filter has been given.
    board: FlagBoard,
    set: Vec<String>,
    detected: Option<Time>,
    from: Time,
    fallback_scans: u64,
    verdicts: Vec<Verdict>,
    /// Probing, when on: the plant and what it watches.
    probing: Option<Prober>,
    /// What the last scan did with the orders requested from outside.
    last_requests: Vec<(String, Request)>,
    /// The functional program beside the filter, and the variables it sets.
    program: Option<(ConstraintControl, Vec<String>)>,
    /// Scratch: the sensors as the program reads them.
    sensors: Vec<bool>,
}

impl CoupledPlc {
    /// Safe control by constraints (`Mode::Control`) through `filter`, with
    /// `diagnoser`'s verdicts raising the filter's flags; fallback scans are
    /// counted from `from` on.
    pub fn new(filter: Filter, diagnoser: Option<PlantDiagnoser>, from: Time) -> CoupledPlc {
        CoupledPlc {
            filter,
            diagnoser,
            last: Vec::new(),
            started: false,
            board: FlagBoard::default(),
            set: Vec::new(),
            detected: None,
            from,
            fallback_scans: 0,
            verdicts: Vec::new(),
            probing: None,
            last_requests: Vec::new(),
            program: None,
            sensors: Vec::new(),
        }
    }

    /// Runs `program` beside the filter: in each scan, it reads the sensors
    /// as the functional constraints do ([`Filter::certain_sensors`]) and
    /// sets `plant`'s variables, in their plant-file order, for the filter's
    /// functional constraints.
    pub fn with_program(mut self, plant: &Plant, program: ConstraintControl) -> CoupledPlc {
        self.program = Some((program, plant.variables.clone()));
        self
    }

    /// Sets the program's variables for this scan.
    fn run_program(&mut self, io: &[bool]) {
        let Some((program, variables)) = self.program.as_mut() else {
            return;
        };
        self.sensors.clear();
        self.sensors.extend_from_slice(io);
        self.filter.certain_sensors(&mut self.sensors);
        for (name, value) in variables.iter().zip(program.evolve(&self.sensors)) {
            self.filter.set(name, value);
        }
    }

    /// Lets the coupling make probing moves on `plant`'s parts ([`crate::probe`]).
    pub fn with_probing(mut self, plant: &Plant) -> CoupledPlc {
        self.probing = Some(Prober::new(plant));
        self
    }

    /// The filter, to set flags from outside the diagnosers (e.g. a Modbus
    /// client of the virtual PLC) between scans.
    pub fn filter_mut(&mut self) -> &mut Filter {
        &mut self.filter
    }

    /// Scans in which the filter overrode the computed orders, from `from` on.
    pub fn fallback_scans(&self) -> u64 {
        self.fallback_scans
    }

    /// What the last scan did with each order requested through
    /// [`Filter::request`] (a probing move asked over Modbus).
    pub fn last_requests(&self) -> &[(String, Request)] {
        &self.last_requests
    }

    fn apply_verdicts(&mut self) {
        if self.verdicts.is_empty() {
            return;
        }
        for v in self.verdicts.drain(..) {
            if v.part == diagnoser::diagnosis::fusion::PLANT_VIEW {
                continue;
            }
            if self.detected.is_none() && v.t >= self.from {
                self.detected = Some(v.t);
            }
            if let Some(p) = self.probing.as_mut() {
                p.note_verdict(&v, &mut self.filter);
            }
            self.board.update(&v);
        }
        let now: Vec<String> = self
            .board
            .raised()
            .iter()
            .chain(self.board.suspects())
            .cloned()
            .collect();
        for f in &self.set {
            if !now.contains(f) {
                self.filter.set(f, false);
            }
        }
        for f in &now {
            if !self.set.contains(f) {
                self.filter.set(f, true);
            }
        }
        self.set = now;
    }
}

impl Controller for CoupledPlc {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        self.apply_verdicts();
        self.run_program(io);
        let outcome = self.filter.scan(t, io, Mode::Control);
        if outcome.fallback || !outcome.parts_in_fallback.is_empty() {
            self.fallback_scans += u64::from(t >= self.from);
        }
        self.last_requests = outcome.requests;
        let Some(diagnoser) = self.diagnoser.as_mut() else {
            return;
        };
        let verdicts = &mut self.verdicts;
        let mut out = |v: Verdict| verdicts.push(v);
        if !self.started {
            diagnoser.start(t, io);
            self.last = io.to_vec();
            self.started = true;
        } else {
            for (i, (&new, old)) in io.iter().zip(self.last.iter_mut()).enumerate() {
                if new != *old {
                    *old = new;
                    diagnoser.push(
                        Event {
                            t,
                            signal: SignalId(i as u32),
                            value: new,
                        },
                        &mut out,
                    );
                }
            }
            diagnoser.advance_to(t, &mut out);
        }
        if let (Some(p), Some(d)) = (self.probing.as_mut(), self.diagnoser.as_ref()) {
            p.scan(t, io, &mut self.filter, d);
        }
    }
}

/// A simulated plant the closed loop can run: its physics, and the
/// functional program that sets the plant file's `variables` each scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rig {
    /// The sorting line: safe control by its constraints alone; work is
    /// boxes delivered on either side.
    Sorting,
    /// The four-cylinder rig: the cylinders' GRAFCETs set X1, X11, X21, X31,
    /// and safe control by constraints computes the orders; work is objects
    /// pushed from one corner to the next.
    Cylinders,
}

impl Rig {
    /// The simulator whose signals `plant` has, and which it must keep: a
    /// plant is run by the simulator it describes.
    pub fn of(plant: &Plant) -> Result<Rig, String> {
        let same = |other: &Plant| {
            let names = |p: &Plant| {
                p.signals
                    .iter()
                    .map(|(_, s)| s.name.clone())
                    .collect::<Vec<_>>()
            };
            names(plant) == names(other)
        };
        if same(&datasets::sorting::plant()) {
            Ok(Rig::Sorting)
        } else if same(&datasets::cylinders::plant()) {
            Ok(Rig::Cylinders)
        } else {
            Err(format!(
                "no simulator for plant '{}': the closed loop runs the sorting line and the \
                 cylinder rig, with their plant files' signals",
                plant.name
            ))
        }
    }

    /// Whether the rig's simulator can make `fault`; if not, why. Sensor and
    /// actuator faults are made on the signals; an element fault needs an
    /// element and the sensors at its ends (a rod is not blocked "at" a
    /// presence sensor); a slow one, an element or actuator whose motions
    /// the simulator times.
    pub fn simulates(self, fault: &FaultTemplate) -> Result<(), String> {
        match fault {
            FaultTemplate::Slow(x) => Watched::new(self, 0).inject_slow(x, Factor::DEFAULT),
            _ if fault.target() == FaultTarget::Element => {
                Watched::new(self, 0).inject_element_fault(fault)
            }
            _ => Ok(()),
        }
    }

    /// What a unit of work is, for tables.
    pub fn work(self) -> &'static str {
        match self {
            Rig::Sorting => "boxes delivered",
            Rig::Cylinders => "objects moved",
        }
    }

    /// The functional program beside the filter for `plant`, if the rig has
    /// one.
    fn program(self, plant: &Plant) -> Result<Option<ConstraintControl>, String> {
        match self {
            Rig::Sorting => Ok(None),
            Rig::Cylinders => Ok(Some(ConstraintControl::new(CylinderIds::resolve(plant)?))),
        }
    }
}

/// The physics of a [`Rig`].
enum Machine {
    Sorting(Box<SortingLine>),
    Cylinders(Box<CylinderRig>),
}

impl Machine {
    fn physics(&self) -> &dyn Physics {
        match self {
            Machine::Sorting(m) => m.as_ref(),
            Machine::Cylinders(m) => m.as_ref(),
        }
    }

    fn physics_mut(&mut self) -> &mut dyn Physics {
        match self {
            Machine::Sorting(m) => m.as_mut(),
            Machine::Cylinders(m) => m.as_mut(),
        }
    }

    /// Work done so far.
    fn work_done(&self) -> u64 {
        match self {
            Machine::Sorting(m) => m.delivered(),
            Machine::Cylinders(m) => m.moves(),
        }
    }

    /// Whether work waits to be done: only then does a pause count as halted.
    fn work_waiting(&self) -> bool {
        match self {
            Machine::Sorting(m) => m.occupied(),
            Machine::Cylinders(m) => m.occupied(),
        }
    }
}

/// A rig, watched for work done and halts.
pub(crate) struct Watched {
    machine: Machine,
    from: Time,
    last_progress: Time,
    halted: Time,
    last_t: Option<Time>,
    deliveries: Vec<Time>,
}

impl Watched {
    /// `rig` in its default configuration; work and halts count from `from` on.
    pub(crate) fn new(rig: Rig, from: Time) -> Watched {
        let machine = match rig {
            Rig::Sorting => Machine::Sorting(Box::new(SortingLine::new(SortingConfig::default()))),
            Rig::Cylinders => {
                Machine::Cylinders(Box::new(CylinderRig::new(CylinderConfig::default())))
            }
        };
        Watched {
            machine,
            from,
            last_progress: 0,
            halted: 0,
            last_t: None,
            deliveries: Vec::new(),
        }
    }

    /// Work done after `from`.
    pub(crate) fn delivered(&self) -> u64 {
        let before = self.deliveries.partition_point(|&t| t <= self.from);
        (self.deliveries.len() - before) as u64
    }
}

impl Physics for Watched {
    fn plant(&self) -> &Plant {
        self.machine.physics().plant()
    }
    fn plant_toml(&self) -> &str {
        self.machine.physics().plant_toml()
    }
    fn advance(&mut self, t: Time, act: &[bool], rng: &mut ChaCha8Rng, damage: &mut Vec<Damage>) {
        let before = self.machine.work_done();
        self.machine.physics_mut().advance(t, act, rng, damage);
        let after = self.machine.work_done();
        for _ in before..after {
            self.deliveries.push(t);
        }
        if t <= self.from || after > before || !self.machine.work_waiting() {
            self.last_progress = t;
        } else if let Some(last) = self.last_t
            && t - self.last_progress > HALT_AFTER
        {
            self.halted += t - last.max(self.last_progress + HALT_AFTER);
        }
        self.last_t = Some(t);
    }
    fn read_sensors(&self, io: &mut [bool]) {
        self.machine.physics().read_sensors(io);
    }
    fn inject_element_fault(&mut self, template: &FaultTemplate) -> Result<(), String> {
        self.machine.physics_mut().inject_element_fault(template)
    }
    fn inject_slow(&mut self, x: &str, factor: Factor) -> Result<(), String> {
        self.machine.physics_mut().inject_slow(x, factor)
    }
    fn counters(&self) -> Vec<(String, u64)> {
        self.machine.physics().counters()
    }
}

struct NoSink;

impl ScanSink for NoSink {
    fn scan(&mut self, _t: Time, _values: &[bool]) -> std::io::Result<()> {
        Ok(())
    }
}

/// Records a fault-free run of `plant`'s rig under safe control by
/// constraints (no coupling), to learn a model from.
pub fn record(plant: &Plant, seed: u64, duration: Time) -> Result<MemorySink, String> {
    let run = LoopRun {
        coupling: Coupling::None,
        seed,
        duration,
        fault: None,
        from: 0,
        probe: false,
    };
    let mut sink = MemorySink::default();
    simulate(plant, None, &run, &mut sink)?;
    Ok(sink)
}

/// A model of `plant` learned from `duration` of fault-free operation under
/// safe control by constraints, seed `seed` ([`record`]).
pub fn learned(plant: &Plant, seed: u64, duration: Time) -> Result<Model, String> {
    let normal = record(plant, seed, duration)?;
    let mut learner = Learner::new(plant, LearnOptions::default())?;
    learner
        .learn_log(
            LogStream::from_events(
                "simulated fault-free run",
                TimeFormat::Numeric(TimeUnit::Ms),
                normal.start,
                normal.initial.clone(),
                normal.events,
            ),
            |_| {},
        )
        .map_err(|e| e.to_string())?;
    Ok(learner.finish())
}

/// Runs `plant`'s rig in closed loop with `model`'s diagnosers and estimates.
pub fn run(plant: &Plant, model: &Model, run: &LoopRun) -> Result<LoopOutcome, String> {
    simulate(plant, Some(model), run, &mut NoSink)
}

fn simulate(
    plant: &Plant,
    model: Option<&Model>,
    run: &LoopRun,
    sink: &mut impl ScanSink,
) -> Result<LoopOutcome, String> {
    let filter = Filter::new(plant, model, run.coupling)?;
    let diagnoser = match model {
        Some(m) => {
            // A coupled filter may hold the control's reaction to an edge back.
            let options = DiagnoserOptions {
                held_reactions: run.coupling != Coupling::None,
                ..DiagnoserOptions::default()
            };
            Some(PlantDiagnoser::new(plant, m, &options)?)
        }
        None => None,
    };
    let mut plc = CoupledPlc::new(filter, diagnoser, run.from);
    if run.probe {
        plc = plc.with_probing(plant);
    }
    let rig = Rig::of(plant)?;
    if let Some(program) = rig.program(plant)? {
        plc = plc.with_program(plant, program);
    }
    let mut physics = Watched::new(rig, run.from);
    let config = SimConfig {
        duration: run.duration,
        scan_period: plant.scan_period,
        seed: run.seed,
        faults: run.fault.iter().cloned().collect(),
    };
    let report = datasets::sim::run(&mut physics, &mut plc, &config, sink, |_| {})
        .map_err(|e| format!("simulation failed: {e}"))?;
    let (probes, no_probe) = plc
        .probing
        .take()
        .map_or_else(Default::default, Prober::into_findings);
    Ok(LoopOutcome {
        delivered: physics.delivered(),
        damage: report
            .damage
            .into_iter()
            .filter(|d| d.t >= run.from)
            .collect(),
        detected: plc.detected,
        halted: physics.halted,
        fallback_scans: plc.fallback_scans,
        flags: plc.board.raised().to_vec(),
        deliveries: physics.deliveries,
        probes,
        no_probe,
    })
}

#[cfg(test)]
mod tests {
    use super::Rig;

    #[test]
    fn the_rigs_simulate_the_slow_motions_they_time() {
        let slow = |x: &str| format!("slow({x})").parse().expect("a template");
        for x in ["P", "A4", "A0"] {
            assert_eq!(Rig::Sorting.simulates(&slow(x)), Ok(()), "{x}");
        }
        for x in ["V1", "Q12"] {
            assert_eq!(Rig::Cylinders.simulates(&slow(x)), Ok(()), "{x}");
        }
        assert!(Rig::Sorting.simulates(&slow("V1")).is_err());
        assert!(Rig::Cylinders.simulates(&slow("P")).is_err());
    }
}
