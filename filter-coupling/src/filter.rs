//! The safety filter as the PLC runs it, once per scan.
//!
//! A scan of the filter:
//! 1. reads the sensors, and the orders written in the previous scan;
//! 2. updates the estimate intervals (`I1`, `I2`, …: the time since each part's
//!    actuators took their present values) and the observers. Observers come
//!    before this scan's orders: one that reads an output sees the order of the
//!    previous scan, and no edge of it. Flags and internal variables set
//!    between scans count from this scan on, with edges like signals;
//! 3. computes the orders, either by seed 001's safe control by constraints
//!    ([`Mode::Control`]: `S'k = !f0k & g1k | f1k`, then the combined constraints)
//!    or by taking the control program's orders as they are ([`Mode::Filter`]);
//! 4. checks every safety constraint on those orders. A violated one is reported
//!    with the literals that made it true, and every order then takes the value
//!    the constraints force, with priority to 0 (the *fallback*, `Sk = f1k`);
//! 5. sends a part to the fallback while one of its actuator or element faults,
//!    or a fault of one of its sensors that has no temporal estimate, is flagged
//!    (`def_<partition>`): its orders are those the constraints force to 1, e.g.
//!    A4 stays on while a box sits on the turntable at the unloading position.
//!
//! With coupling on, the safety constraints are rewritten by [`crate::rewrite`]:
//! a flagged sensor's literals read its temporal estimate, conservatively. The
//! functional constraints read the estimate the other way round (a requirement
//! holds only where it certainly holds): the safety constraints still decide what
//! is allowed, the functional ones only ask for moves.
//!
//! `f0k`, `f1k` and `g1k` are read off each constraint by Shannon cofactors: a
//! constraint `C` forbids `Sk = 1` where `C[Sk:=1] & !C[Sk:=0]`, and `Sk = 0`
//! where `C[Sk:=0] & !C[Sk:=1]`. For seed 001's monomials this is the usual
//! reading (`C3 & !C4 & S1` gives `f01 = C3 & !C4`), and it also covers edges of
//! the outputs (`!C4 & RE(A4)` gives `f04 = !C4 & !prev(A4)`) and the rewritten
//! constraints, which are no longer monomials.

use std::collections::HashMap;
use std::fmt;

use diagnoser::expr::Expr;
use diagnoser::model::Model;
use diagnoser::plant::{Constraint, ObserverRule, Part};
use diagnoser::{FaultTemplate, Plant, SignalId, SignalKind, Time};

use crate::rewrite::{Estimate, RewriteOptions, rewrite};
use crate::synthesis::{CombinedLaw, OutputLaw, output_law};

/// How the filter uses the diagnosers' flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Coupling {
    /// The constraints read the sensors as they are; flags are ignored.
    #[default]
    None,
    /// `def_<partition>` switches a sensor to its estimate, and sends to the
    /// fallback the part of an actuator, element, or sensor with no estimate.
    Flags,
    /// As [`Coupling::Flags`], and on `suspect_<partition>` a sensor reads the
    /// union of its reading and its estimate (safe under every candidate).
    FlagsAndSuspects,
}

impl Coupling {
    /// Short name, as in the demo's table: `none`, `def`, `def+suspect`.
    pub fn name(self) -> &'static str {
        match self {
            Coupling::None => "none",
            Coupling::Flags => "def",
            Coupling::FlagsAndSuspects => "def+suspect",
        }
    }
}

/// Where a scan's orders come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// The control program wrote them into the outputs; the filter checks them.
    Filter,
    /// Safe control by constraints computes them (seed 001 §4).
    Control,
}

/// A safety constraint that held in a scan, with the literals that made it true.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Violation {
    /// Constraint name, e.g. `CSs5`.
    pub constraint: String,
    /// The true literals, e.g. `["!C5", "A3"]`.
    pub literals: Vec<String>,
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.constraint, self.literals.join(" & "))
    }
}

/// What one scan of the filter did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ScanOutcome {
    /// Safety constraints violated by the proposed orders (empty in a normal scan).
    pub violated: Vec<Violation>,
    /// Whether the whole plant was sent to the fallback.
    pub fallback: bool,
    /// Parts sent to the fallback by a flagged fault that stops them (an
    /// actuator or element fault, or a sensor fault with no estimate).
    pub parts_in_fallback: Vec<usize>,
    /// What became of each order asked for with [`Filter::request`]: the
    /// output and the outcome, in the order of the outputs.
    pub requests: Vec<(String, Request)>,
}

/// What a scan did with an order asked for from outside the control (a
/// probing move, see [`Filter::request`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// The output took the requested value.
    Applied,
    /// The requested value would have violated these constraints; the output
    /// kept the value the control computed.
    Refused(Vec<Violation>),
}

/// A compiled expression: names resolved to slots of the filter's variables.
#[derive(Debug, Clone, PartialEq)]
enum Op {
    Const(bool),
    Var(usize),
    Prev(usize),
    Rise(usize),
    Fall(usize),
    Not(Box<Op>),
    And(Vec<Op>),
    Or(Vec<Op>),
}

impl Op {
    fn eval(&self, cur: &[bool], prev: &[bool]) -> bool {
        match self {
            Op::Const(b) => *b,
            Op::Var(i) => cur[*i],
            Op::Prev(i) => prev[*i],
            Op::Rise(i) => cur[*i] && !prev[*i],
            Op::Fall(i) => !cur[*i] && prev[*i],
            Op::Not(e) => !e.eval(cur, prev),
            Op::And(es) => es.iter().all(|e| e.eval(cur, prev)),
            Op::Or(es) => es.iter().any(|e| e.eval(cur, prev)),
        }
    }
}

/// One named interval of a part's clock, `[from, to[` in nanoseconds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Interval {
    /// Its name, e.g. `I3`.
    pub name: String,
    /// Start, included.
    pub from: Time,
    /// End, excluded (`None`: unbounded).
    pub to: Option<Time>,
}

/// The estimate intervals of one part.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PartIntervals {
    /// The part's actuators, whose orders start its clock.
    pub actuators: Vec<String>,
    /// Per estimated state of those actuators (their values, in order): its
    /// intervals of the time since they took it.
    pub states: Vec<(Vec<bool>, Vec<Interval>)>,
}

/// A constraint as the filter evaluates it.
#[derive(Debug, Clone)]
struct Compiled {
    name: String,
    /// The expression read (rewritten when coupled), for reports.
    expr: Expr,
    op: Op,
    /// The outputs it reads (slots).
    outputs: Vec<usize>,
}

/// How one output is computed by safe control.
#[derive(Debug, Clone, Default)]
struct LawSlots {
    slot: usize,
    /// Simple safety constraints reading this output (indices into `safety`).
    safety: Vec<usize>,
    /// Functional constraints reading it (indices into `functional`).
    functional: Vec<usize>,
    /// Whether one of them asks for 1 (reads `!Sk`).
    asks_for_one: bool,
}

/// A combined constraint: when it holds, `other` is set to 0.
#[derive(Debug, Clone)]
struct Combined {
    constraint: usize,
    other: usize,
}

/// The clock of one part's estimates: the time since its actuators took their
/// present values.
#[derive(Debug, Clone)]
struct PartClock {
    actuators: Vec<usize>,
    /// When the present values were written (`None`: they have held since
    /// before the first scan, so every clock reads past its last threshold).
    since: Option<Time>,
    /// One group per estimated actuator state: the values, and its intervals
    /// `(slot, from, to)` in nanoseconds (`to = None`: unbounded).
    groups: Vec<Schedule<usize>>,
}

/// One estimated state of a part's actuators (their values, in order) and its
/// intervals `(variable, from, to)` in nanoseconds (`to = None`: unbounded).
type Schedule<V> = (Vec<bool>, Vec<(V, Time, Option<Time>)>);

/// A part's name and its schedules, with interval names.
type PartSchedules = (String, Vec<Schedule<String>>);

/// The safety filter of a plant.
#[derive(Debug, Clone)]
pub struct Filter {
    names: Vec<String>,
    index: HashMap<String, usize>,
    signals: usize,
    /// Per signal slot: whether it is a sensor (read from `io`).
    sensor: Vec<bool>,
    /// Per slot: whether the caller sets it (flags, internal variables).
    external: Vec<bool>,
    /// What the caller set, for the next scan.
    next: Vec<bool>,
    actuators: Vec<usize>,
    cur: Vec<bool>,
    prev: Vec<bool>,
    observers: Vec<(usize, ObserverOp)>,
    clocks: Vec<PartClock>,
    safety: Vec<Compiled>,
    functional: Vec<Compiled>,
    laws: Vec<LawSlots>,
    combined: Vec<Combined>,
    /// Per part: the flags of its actuator and element partitions, and its actuators.
    /// Per part: the flags of its actuator and element partitions, and its
    /// outputs (indices into `laws`).
    part_fallback: Vec<(Vec<usize>, Vec<usize>)>,
    estimates: Vec<Estimate>,
    coupling: Coupling,
    started: bool,
    /// Orders asked for from outside the control, per output (as `laws`).
    requested: Vec<Option<bool>>,
    /// Scratch: the orders being computed.
    orders: Vec<bool>,
    /// Per sensor a flag can declare failed, its slot and how a functional
    /// program reads it: as the functional constraints do (a failed sensor
    /// reads what its estimate makes certain). The others read as they are.
    certain: Vec<(usize, Op)>,
}

#[derive(Debug, Clone)]
enum ObserverOp {
    SetReset { set: Op, reset: Op },
    Toggle(Op),
}

/// Per sensor with a reading (an estimate, or none: it may read anything),
/// its slot and its reading where it must hold for certain: the rewriting of
/// the functional constraints applied to the sensor alone, which reads no
/// other sensor.
fn certain_sensors(
    index: &HashMap<String, usize>,
    readings: &[Estimate],
    options: RewriteOptions,
) -> Result<Vec<(usize, Op)>, String> {
    readings
        .iter()
        .map(|e| {
            let read = rewrite_certain(&Expr::Var(e.sensor.clone()), readings, options);
            let slot = index
                .get(&e.sensor)
                .ok_or_else(|| format!("no sensor '{}'", e.sensor))?;
            Ok((*slot, compile(&read, index)?))
        })
        .collect()
}

/// The partition holding a sensor fault of `sensor`, else the sensor's name.
pub fn sensor_partition(plant: &Plant, sensor: &str) -> String {
    plant
        .faults
        .iter()
        .filter(|f| f.template.sensor() == Some(sensor))
        .find_map(|f| plant.partition_of(&f.label))
        .map_or_else(|| sensor.to_string(), |p| p.name.clone())
}

/// The learned estimates of every sensor that has one, with the interval names
/// qualified by their part (`turntable_I3`) only where two parts share a name.
fn estimates_and_clocks(
    plant: &Plant,
    model: &Model,
) -> Result<(Vec<Estimate>, Vec<PartSchedules>), String> {
    let unit = model.time_unit.nanos() as f64;
    let parts: Vec<_> = model
        .parts
        .iter()
        .filter(|p| !p.sensor_estimates.is_empty())
        .collect();
    let mut seen: HashMap<&str, usize> = HashMap::new();
    for p in &parts {
        for e in &p.estimates {
            for i in &e.intervals {
                *seen.entry(i.name.as_str()).or_default() += 1;
            }
        }
    }
    let qualify = |part: &str, name: &str| {
        if seen.get(name).copied().unwrap_or(0) > 1 {
            format!("{part}_{name}")
        } else {
            name.to_string()
        }
    };
    let mut estimates = Vec::new();
    let mut clocks = Vec::new();
    for p in parts {
        let mut groups = Vec::new();
        for e in &p.estimates {
            let mut values = Vec::new();
            for pair in e.actuators.split_whitespace() {
                let (name, v) = pair
                    .split_once('=')
                    .ok_or_else(|| format!("part {}: bad actuator state '{pair}'", p.name))?;
                values.push((name.to_string(), v == "1"));
            }
            let intervals = e
                .intervals
                .iter()
                .map(|i| {
                    (
                        qualify(&p.name, &i.name),
                        (i.from * unit).round() as Time,
                        i.to.map(|to| (to * unit).round() as Time),
                    )
                })
                .collect();
            groups.push((values, intervals));
        }
        // Actuator values in the part's declared order.
        let part = plant
            .parts
            .iter()
            .find(|q| q.name == p.name)
            .ok_or_else(|| format!("the model's part '{}' is not in the plant file", p.name))?;
        let mut ordered = Vec::new();
        for (values, intervals) in groups {
            let mut v = Vec::new();
            for a in &part.actuators {
                let name = plant.signals.name(*a);
                let value = values
                    .iter()
                    .find(|(n, _)| n == name)
                    .map(|(_, v)| *v)
                    .ok_or_else(|| format!("part {}: estimate lacks actuator {name}", p.name))?;
                v.push(value);
            }
            ordered.push((v, intervals));
        }
        clocks.push((p.name.clone(), ordered));
        for s in &p.sensor_estimates {
            let partition = sensor_partition(plant, &s.sensor);
            let intervals: Vec<String> = (s.intervals().into_iter())
                .map(|n| qualify(&p.name, n))
                .collect();
            let uncertain: Vec<String> = s.uncertain.iter().map(|n| qualify(&p.name, n)).collect();
            estimates.push(Estimate::from_model(
                &s.sensor, &partition, &intervals, &uncertain,
            )?);
        }
    }
    Ok((estimates, clocks))
}

/// The sensors of the plant's sensor-fault partitions that have no learned
/// estimate: declared failed or suspected, they may read anything.
fn unestimated_sensors(plant: &Plant, learned: &[Estimate]) -> Vec<Estimate> {
    let mut out: Vec<Estimate> = Vec::new();
    for f in &plant.faults {
        let Some(s) = f.template.sensor() else {
            continue;
        };
        let known = |e: &Estimate| e.sensor == s;
        if plant.partition_of(&f.label).is_none()
            || learned.iter().any(known)
            || out.iter().any(known)
        {
            continue;
        }
        out.push(Estimate::any_value(s, &sensor_partition(plant, s)));
    }
    out
}

/// `!rewrite(!e)`: the rewritten expression holds only where it holds whatever
/// the failed sensors' uncertain values are.
fn rewrite_certain(e: &Expr, estimates: &[Estimate], options: RewriteOptions) -> Expr {
    match rewrite(&Expr::Not(Box::new(e.clone())), estimates, options) {
        Expr::Not(inner) => *inner,
        other => Expr::Not(Box::new(other)),
    }
}

/// The filter's variables as they are declared: each name's slot in the
/// scan's value vectors.
#[derive(Debug, Default)]
struct SlotTable {
    names: Vec<String>,
    index: HashMap<String, usize>,
}

impl SlotTable {
    /// The slot of `name`, a new one after the others if it has none yet.
    fn slot(&mut self, name: &str) -> usize {
        if let Some(&i) = self.index.get(name) {
            return i;
        }
        self.names.push(name.to_string());
        self.index.insert(name.to_string(), self.names.len() - 1);
        self.names.len() - 1
    }
}

/// The clocks of the parts with estimates, their intervals given slots (after
/// every other variable, in the model's order).
fn part_clocks(
    plant: &Plant,
    clock_defs: Vec<PartSchedules>,
    slots: &mut SlotTable,
) -> Result<Vec<PartClock>, String> {
    let mut clocks = Vec::new();
    for (part_name, groups) in clock_defs {
        let part = plant
            .parts
            .iter()
            .find(|p| p.name == part_name)
            .ok_or_else(|| format!("no part {part_name}"))?;
        let groups = groups
            .into_iter()
            .map(|(values, intervals)| {
                let iv = intervals
                    .into_iter()
                    .map(|(n, from, to)| (slots.slot(&n), from, to))
                    .collect();
                (values, iv)
            })
            .collect();
        clocks.push(PartClock {
            actuators: part.actuators.iter().map(|a| a.index()).collect(),
            since: None,
            groups,
        });
    }
    Ok(clocks)
}

/// `constraints` as the filter evaluates them: each expression as `read`
/// gives it (rewritten with the estimates when coupled), compiled, with the
/// outputs the original reads.
fn compile_constraints(
    constraints: &[Constraint],
    index: &HashMap<String, usize>,
    actuators: &[usize],
    read: impl Fn(&Expr) -> Expr,
) -> Result<Vec<Compiled>, String> {
    let mut compiled = Vec::new();
    for c in constraints {
        let expr = read(&c.expr);
        let op = compile(&expr, index)?;
        compiled.push(Compiled {
            name: c.name.clone(),
            outputs: outputs_of(&c.expr, index, actuators),
            expr,
            op,
        });
    }
    Ok(compiled)
}

/// The constraints each output's safe law reads, and the combined ones. A
/// safety constraint without priority that reads one output feeds its law;
/// one with a priority output must read exactly one other, which it sends to 0;
/// the others are only checked. Every functional constraint feeds the laws of
/// the outputs it reads.
fn laws_and_combined(
    plant: &Plant,
    safety: &[Compiled],
    functional: &[Compiled],
    actuators: &[usize],
) -> Result<(Vec<LawSlots>, Vec<Combined>), String> {
    let mut laws: Vec<LawSlots> = actuators
        .iter()
        .map(|&slot| LawSlots {
            slot,
            ..LawSlots::default()
        })
        .collect();
    let mut combined = Vec::new();
    for (i, (c, compiled)) in plant.constraints.iter().zip(safety).enumerate() {
        match (&c.priority, compiled.outputs.as_slice()) {
            (None, [k]) => {
                if let Some(law) = laws.iter_mut().find(|l| l.slot == *k) {
                    law.safety.push(i);
                }
            }
            (Some(p), outs) => {
                let p = p.index();
                let others: Vec<usize> = outs.iter().copied().filter(|&o| o != p).collect();
                match others.as_slice() {
                    [other] => combined.push(Combined {
                        constraint: i,
                        other: *other,
                    }),
                    _ => {
                        return Err(format!(
                            "constraint {}: a combined constraint reads its priority output and exactly one other",
                            c.name
                        ));
                    }
                }
            }
            // Read by no output, or by several with no priority: only checked.
            _ => {}
        }
    }
    for (i, c) in functional.iter().enumerate() {
        for k in &c.outputs {
            if let Some(law) = laws.iter_mut().find(|l| l.slot == *k) {
                law.functional.push(i);
                law.asks_for_one |= reads_negated(&c.op, *k);
            }
        }
    }
    Ok((laws, combined))
}

/// The plant's observers, compiled: each one's slot and rule.
fn compile_observers(
    plant: &Plant,
    index: &HashMap<String, usize>,
) -> Result<Vec<(usize, ObserverOp)>, String> {
    let mut observers = Vec::new();
    for o in &plant.observers {
        let s = index[&o.name];
        let op = match &o.rule {
            ObserverRule::SetReset { set, reset } => ObserverOp::SetReset {
                set: compile(set, index)?,
                reset: compile(reset, index)?,
            },
            ObserverRule::Toggle(e) => ObserverOp::Toggle(compile(e, index)?),
        };
        observers.push((s, op));
    }
    Ok(observers)
}

/// Per part: the flags that send it to the fallback (none without coupling)
/// and its outputs (indices into the laws).
fn part_fallbacks(
    plant: &Plant,
    coupling: Coupling,
    index: &HashMap<String, usize>,
    actuators: &[usize],
    estimates: &[Estimate],
) -> Vec<(Vec<usize>, Vec<usize>)> {
    let mut part_fallback = Vec::new();
    for part in &plant.parts {
        let mut flags = Vec::new();
        if coupling != Coupling::None {
            for p in &plant.partitions {
                if p.faults
                    .iter()
                    .any(|label| stops_part(plant, part, label, estimates))
                {
                    flags.push(index[&p.flag().to_string()]);
                }
            }
        }
        let outputs = part
            .actuators
            .iter()
            .filter_map(|a| actuators.iter().position(|&x| x == a.index()))
            .collect();
        part_fallback.push((flags, outputs));
    }
    part_fallback
}

/// Whether the fault `label` stops `part` once declared: a stuck actuator of
/// the part, its element blocked, or a fault of one of its sensors that has no
/// temporal estimate (a slow motion does not stop it) (its edges follow the workpieces, not a command, so
/// nothing can stand in for its reading).
fn stops_part(plant: &Plant, part: &Part, label: &str, estimates: &[Estimate]) -> bool {
    let own = |names: &[SignalId], s: &str| names.iter().any(|x| plant.signals.name(*x) == s);
    plant.faults.iter().any(|f| {
        f.label == label
            && match &f.template {
                FaultTemplate::ActuatorStuck0(a) | FaultTemplate::ActuatorStuck1(a) => {
                    own(&part.actuators, a)
                }
                FaultTemplate::Stuck0(s)
                | FaultTemplate::Stuck1(s)
                | FaultTemplate::UnexpectedRise(s)
                | FaultTemplate::UnexpectedFall(s) => {
                    own(&part.sensors, s) && !estimates.iter().any(|e| &e.sensor == s)
                }
                FaultTemplate::BlockedAt { element, .. }
                | FaultTemplate::BlockedBetween { element, .. } => {
                    part.element.as_deref() == Some(element.as_str())
                }
                // A slow motion still ends: the part goes on, degraded.
                FaultTemplate::Slow(_) => false,
            }
    })
}

/// Per slot: whether the caller sets it between scans (internal variables,
/// `def_` and `suspect_` flags).
fn external_slots(plant: &Plant, index: &HashMap<String, usize>, n: usize) -> Vec<bool> {
    let mut external = vec![false; n];
    for v in &plant.variables {
        external[index[v]] = true;
    }
    for p in &plant.partitions {
        external[index[&p.flag().to_string()]] = true;
        external[index[&p.suspect_flag().to_string()]] = true;
    }
    external
}

impl Filter {
    /// The filter of `plant`. `model` gives the sensors' estimates; without it
    /// (or with [`Coupling::None`]) the constraints are never rewritten.
    pub fn new(plant: &Plant, model: Option<&Model>, coupling: Coupling) -> Result<Filter, String> {
        let mut slots = SlotTable::default();
        for (_, s) in plant.signals.iter() {
            slots.slot(&s.name);
        }
        let signals = slots.names.len();
        let actuators: Vec<usize> = plant
            .signals
            .of_kind(SignalKind::Actuator)
            .map(|a| a.index())
            .collect();
        for v in &plant.variables {
            slots.slot(v);
        }
        for o in &plant.observers {
            slots.slot(&o.name);
        }
        for p in &plant.partitions {
            slots.slot(&p.flag().to_string());
            slots.slot(&p.suspect_flag().to_string());
        }
        let (estimates, clock_defs) = match (model, coupling) {
            (Some(m), c) if c != Coupling::None => estimates_and_clocks(plant, m)?,
            _ => (Vec::new(), Vec::new()),
        };
        let clocks = part_clocks(plant, clock_defs, &mut slots)?;
        let SlotTable { names, index } = slots;
        let options = RewriteOptions {
            use_suspects: coupling == Coupling::FlagsAndSuspects,
        };
        // Learned estimates, then every other sensor a flag can declare failed,
        // which may then read anything.
        let readings: Vec<Estimate> = match coupling {
            Coupling::None => Vec::new(),
            _ => estimates
                .iter()
                .cloned()
                .chain(unestimated_sensors(plant, &estimates))
                .collect(),
        };
        let safety = compile_constraints(&plant.constraints, &index, &actuators, |e| {
            rewrite(e, &readings, options)
        })?;
        let functional = compile_constraints(&plant.functional, &index, &actuators, |e| {
            if readings.is_empty() {
                e.clone()
            } else {
                rewrite_certain(e, &readings, options)
            }
        })?;
        let (laws, combined) = laws_and_combined(plant, &safety, &functional, &actuators)?;
        // Suspicion is the safety constraints' business: a program reading a
        // suspected sensor as it is keeps the timing the diagnosers learned.
        let declared_only = RewriteOptions {
            use_suspects: false,
        };
        let certain = certain_sensors(&index, &readings, declared_only)?;
        let observers = compile_observers(plant, &index)?;
        let part_fallback = part_fallbacks(plant, coupling, &index, &actuators, &estimates);
        let n = names.len();
        let mut cur = vec![false; n];
        for o in &plant.observers {
            cur[index[&o.name]] = o.init;
        }
        let sensor = (0..signals).map(|i| !actuators.contains(&i)).collect();
        let external = external_slots(plant, &index, n);
        Ok(Filter {
            names,
            index,
            signals,
            sensor,
            next: vec![false; n],
            external,
            actuators,
            prev: cur.clone(),
            cur,
            observers,
            clocks,
            safety,
            functional,
            laws,
            combined,
            part_fallback,
            estimates,
            coupling,
            started: false,
            requested: Vec::new(),
            orders: Vec::new(),
            certain,
        })
    }

    /// How it uses the flags.
    pub fn coupling(&self) -> Coupling {
        self.coupling
    }

    /// The sensors' estimates it switches to (empty without coupling).
    pub fn estimates(&self) -> &[Estimate] {
        &self.estimates
    }

    /// The safety constraints as evaluated: `(name, expression)`, rewritten when
    /// coupled.
    pub fn safety_constraints(&self) -> impl Iterator<Item = (&str, &Expr)> {
        self.safety.iter().map(|c| (c.name.as_str(), &c.expr))
    }

    /// The functional constraints as evaluated.
    pub fn functional_constraints(&self) -> impl Iterator<Item = (&str, &Expr)> {
        self.functional.iter().map(|c| (c.name.as_str(), &c.expr))
    }

    /// Raises or lowers a flag (`def_C4`, `suspect_P`) or sets an internal
    /// variable; false if the filter has no such name.
    /// The value counts from the next scan on, so that its edges and
    /// `prev` read like those of a signal.
    pub fn set(&mut self, name: &str, value: bool) -> bool {
        match self.index.get(name) {
            Some(&i) if self.external[i] => {
                self.next[i] = value;
                true
            }
            _ => false,
        }
    }

    /// The value of any variable of the filter (signal, observer, interval,
    /// flag) in the last scan.
    pub fn value(&self, name: &str) -> Option<bool> {
        self.index.get(name).map(|&i| self.cur[i])
    }

    /// The sensors of `io` as a functional program beside the filter should
    /// read them (a GRAFCET whose steps are the plant file's `variables`): as
    /// the functional constraints do, a sensor declared failed (`def_`) reads
    /// 1 only where its estimate makes 1 certain, so that a step waiting for
    /// it moves on no sooner than the sensor would have risen. A sensor only
    /// suspected reads as it is. The estimate's intervals are those of the
    /// last scan; call it before [`Filter::scan`].
    pub fn certain_sensors(&mut self, io: &mut [bool]) {
        for &(i, ref op) in &self.certain {
            // The reading reads its own sensor, as `io` has it, and flags
            // and intervals as the last scan left them.
            let last = std::mem::replace(&mut self.cur[i], io[i]);
            io[i] = op.eval(&self.cur, &self.prev);
            self.cur[i] = last;
        }
    }

    /// Checks a recorded scan against the safety constraints: `io` holds the
    /// sensors and the orders as the PLC wrote them. Nothing is changed; the
    /// violated constraints come back with their literals.
    pub fn violations(&mut self, t: Time, io: &[bool]) -> Vec<Violation> {
        self.begin(t, io);
        for &a in &self.actuators {
            self.cur[a] = io[a];
        }
        let violated = self.violated_now();
        self.note_orders(t);
        violated
    }

    /// The constraints the current scan's values violate.
    fn violated_now(&self) -> Vec<Violation> {
        self.safety
            .iter()
            .filter(|c| c.op.eval(&self.cur, &self.prev))
            .map(|c| Violation {
                constraint: c.name.clone(),
                literals: crate::eval::true_literals(&c.expr, &Slots(self)),
            })
            .collect()
    }

    /// The start of every scan: shift to the previous values, read the
    /// sensors, update the intervals and observers.
    fn begin(&mut self, t: Time, io: &[bool]) {
        // What was current is now previous; then this scan's sensors, flags
        // and variables.
        self.prev.copy_from_slice(&self.cur);
        for (i, &v) in self.next.iter().enumerate() {
            if self.external[i] {
                self.cur[i] = v;
            }
        }
        for (i, &v) in io.iter().enumerate().take(self.signals) {
            if self.sensor[i] {
                self.cur[i] = v;
            }
        }
        if !self.started {
            // No edge at the first scan: the orders in `io` stand for those
            // of the scan before.
            let n = self.signals.min(io.len());
            self.cur[..n].copy_from_slice(&io[..n]);
            self.prev.copy_from_slice(&self.cur);
            self.started = true;
        }
        self.update_intervals(t);
        self.update_observers();
    }

    /// Runs one scan at `t`. `io` is indexed like the plant's signals: sensors as
    /// read now, actuators as proposed by the control program ([`Mode::Filter`])
    /// or ignored ([`Mode::Control`]). The orders are written back into `io`.
    pub fn scan(&mut self, t: Time, io: &mut [bool], mode: Mode) -> ScanOutcome {
        let mut outcome = ScanOutcome::default();
        self.begin(t, io);

        // Orders: proposed, or computed from the constraints.
        self.orders.clear();
        self.orders.extend(self.actuators.iter().map(|&a| io[a]));
        if mode == Mode::Control {
            for k in 0..self.laws.len() {
                let proposed = self.orders[k];
                self.orders[k] = self.safe_order(k, proposed);
            }
            self.apply_combined();
        }
        for (k, &a) in self.actuators.iter().enumerate() {
            self.cur[a] = self.orders[k];
        }
        self.apply_requests(&mut outcome.requests);
        outcome.violated = self.violated_now();
        if !outcome.violated.is_empty() {
            outcome.fallback = true;
            for k in 0..self.laws.len() {
                self.orders[k] = self.forced(k).1;
            }
        } else {
            for p in 0..self.part_fallback.len() {
                if self.part_fallback[p].0.iter().any(|&f| self.cur[f]) {
                    outcome.parts_in_fallback.push(p);
                    for j in 0..self.part_fallback[p].1.len() {
                        let k = self.part_fallback[p].1[j];
                        self.orders[k] = self.forced(k).1;
                    }
                }
            }
        }
        for (k, &a) in self.actuators.iter().enumerate() {
            self.cur[a] = self.orders[k];
            io[a] = self.orders[k];
        }
        self.note_orders(t);
        outcome
    }

    /// Asks for `actuator` at `value` from the next scan on, instead of the
    /// control's order, as long as no safety constraint (as rewritten by the
    /// flags) forbids it; `None` gives the output back to the control. False
    /// if `actuator` is not an output of the filter.
    ///
    /// Each scan checks the requested values in the order of the outputs,
    /// each against every safety constraint with the orders as they stand; a
    /// refused request leaves the control's order, and
    /// [`ScanOutcome::requests`] says which constraints refused it.
    pub fn request(&mut self, actuator: &str, value: Option<bool>) -> bool {
        let Some(k) = self
            .index
            .get(actuator)
            .and_then(|&i| self.actuators.iter().position(|&a| a == i))
        else {
            return false;
        };
        if self.requested.len() < self.actuators.len() {
            self.requested.resize(self.actuators.len(), None);
        }
        self.requested[k] = value;
        true
    }

    /// Applies each requested order where no constraint forbids it.
    fn apply_requests(&mut self, outcome: &mut Vec<(String, Request)>) {
        for k in 0..self.requested.len() {
            let Some(value) = self.requested[k] else {
                continue;
            };
            let a = self.actuators[k];
            let request = if self.orders[k] == value {
                Request::Applied
            } else {
                self.cur[a] = value;
                let violated = self.violated_now();
                if violated.is_empty() {
                    self.orders[k] = value;
                    Request::Applied
                } else {
                    self.cur[a] = self.orders[k];
                    Request::Refused(violated)
                }
            };
            outcome.push((self.names[a].clone(), request));
        }
    }

    /// Restarts each part's clock where its orders changed in this scan.
    fn note_orders(&mut self, t: Time) {
        for c in &mut self.clocks {
            if c.actuators.iter().any(|&a| self.cur[a] != self.prev[a]) {
                c.since = Some(t);
            }
        }
    }

    fn update_intervals(&mut self, t: Time) {
        for c in &self.clocks {
            let elapsed = c.since.map_or(Time::MAX / 2, |s| t.saturating_sub(s));
            for (values, intervals) in &c.groups {
                let here = c
                    .actuators
                    .iter()
                    .zip(values)
                    .all(|(&a, &v)| self.cur[a] == v);
                for &(slot, from, to) in intervals {
                    self.cur[slot] = here && elapsed >= from && to.is_none_or(|to| elapsed < to);
                }
            }
        }
    }

    fn update_observers(&mut self) {
        for (slot, op) in &self.observers {
            let old = self.cur[*slot];
            self.cur[*slot] = match op {
                ObserverOp::SetReset { set, reset } => {
                    if reset.eval(&self.cur, &self.prev) {
                        false
                    } else if set.eval(&self.cur, &self.prev) {
                        true
                    } else {
                        old
                    }
                }
                ObserverOp::Toggle(e) => old ^ e.eval(&self.cur, &self.prev),
            };
        }
    }

    /// `(f0k, f1k)` of output `k` in this scan.
    fn forced(&mut self, k: usize) -> (bool, bool) {
        let law = &self.laws[k];
        let (mut f0, mut f1) = (false, false);
        for &i in &law.safety {
            let (zero, one) = cofactors(&self.safety[i].op, &mut self.cur, &self.prev, law.slot);
            f0 |= one && !zero;
            f1 |= zero && !one;
        }
        (f0, f1)
    }

    /// `S'k = !f0k & g1k | f1k`. `g1k` is the disjunction of the functional
    /// constraints asking for `Sk = 1`; an output that only has constraints
    /// asking for 0 is wanted at 1 elsewhere (seed 001 eq. 14), and one with no
    /// functional constraint keeps the control program's order.
    fn safe_order(&mut self, k: usize, proposed: bool) -> bool {
        let (f0, f1) = self.forced(k);
        let slot = self.laws[k].slot;
        let (mut g1, mut g0) = (false, false);
        let law = &self.laws[k];
        for &i in &law.functional {
            let (zero, one) = cofactors(&self.functional[i].op, &mut self.cur, &self.prev, slot);
            g1 |= zero && !one;
            g0 |= one && !zero;
        }
        let wanted = if law.asks_for_one {
            g1 && !g0
        } else if law.functional.is_empty() {
            proposed
        } else {
            !g0
        };
        !f0 && wanted || f1
    }

    /// Seed 001 figure 3: while a combined constraint holds, its non-priority
    /// output is set to 0.
    fn apply_combined(&mut self) {
        for _ in 0..=self.combined.len() {
            for (k, &a) in self.actuators.iter().enumerate() {
                self.cur[a] = self.orders[k];
            }
            let mut changed = false;
            for c in &self.combined {
                if self.safety[c.constraint].op.eval(&self.cur, &self.prev) && self.cur[c.other] {
                    self.cur[c.other] = false;
                    if let Some(k) = self.actuators.iter().position(|&a| a == c.other) {
                        self.orders[k] = false;
                    }
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
    }

    /// Each output's law and the combined constraints, as expressions (the same
    /// computation as [`Mode::Control`], in closed form).
    pub fn laws(&self) -> (Vec<OutputLaw>, Vec<CombinedLaw>) {
        let laws = self
            .laws
            .iter()
            .map(|l| {
                let safety: Vec<&Expr> = l.safety.iter().map(|&i| &self.safety[i].expr).collect();
                let functional: Vec<&Expr> = l
                    .functional
                    .iter()
                    .map(|&i| &self.functional[i].expr)
                    .collect();
                output_law(&self.names[l.slot], &safety, &functional)
            })
            .collect();
        let combined = self
            .combined
            .iter()
            .map(|c| {
                let outputs = &self.safety[c.constraint].outputs;
                let priority = outputs
                    .iter()
                    .find(|&&o| o != c.other)
                    .copied()
                    .unwrap_or(c.other);
                CombinedLaw {
                    constraint: self.safety[c.constraint].name.clone(),
                    expr: self.safety[c.constraint].expr.clone(),
                    priority: self.names[priority].clone(),
                    other: self.names[c.other].clone(),
                }
            })
            .collect();
        (laws, combined)
    }

    /// The estimate intervals it computes, per part: the part's actuators, and
    /// for each estimated state of them, the intervals of the time since they
    /// took it.
    pub fn intervals(&self) -> Vec<PartIntervals> {
        self.clocks
            .iter()
            .map(|c| PartIntervals {
                actuators: c.actuators.iter().map(|&a| self.names[a].clone()).collect(),
                states: c
                    .groups
                    .iter()
                    .map(|(values, iv)| {
                        (
                            values.clone(),
                            iv.iter()
                                .map(|&(slot, from, to)| Interval {
                                    name: self.names[slot].clone(),
                                    from,
                                    to,
                                })
                                .collect(),
                        )
                    })
                    .collect(),
            })
            .collect()
    }

    /// For each part whose actuator or element faults send it to the fallback:
    /// the flags that do, and its actuators.
    pub fn fallback_parts(&self) -> Vec<(Vec<String>, Vec<String>)> {
        self.part_fallback
            .iter()
            .filter(|(flags, _)| !flags.is_empty())
            .map(|(flags, acts)| {
                (
                    flags.iter().map(|&f| self.names[f].clone()).collect(),
                    acts.iter()
                        .map(|&k| self.names[self.laws[k].slot].clone())
                        .collect(),
                )
            })
            .collect()
    }

    /// Names of the filter's variables, by slot (signals first).
    pub fn names(&self) -> &[String] {
        &self.names
    }
}

/// `op` evaluated with `slot` at 0 and at 1.
fn cofactors(op: &Op, cur: &mut [bool], prev: &[bool], slot: usize) -> (bool, bool) {
    let old = cur[slot];
    cur[slot] = false;
    let zero = op.eval(cur, prev);
    cur[slot] = true;
    let one = op.eval(cur, prev);
    cur[slot] = old;
    (zero, one)
}

/// Whether `op` reads `!slot` (under an odd number of negations).
fn reads_negated(op: &Op, slot: usize) -> bool {
    fn go(op: &Op, slot: usize, negated: bool) -> bool {
        match op {
            Op::Var(i) | Op::Rise(i) | Op::Fall(i) => *i == slot && negated,
            Op::Not(e) => go(e, slot, !negated),
            Op::And(es) | Op::Or(es) => es.iter().any(|e| go(e, slot, negated)),
            Op::Const(_) | Op::Prev(_) => false,
        }
    }
    go(op, slot, false)
}

/// The outputs an expression reads, as slots.
fn outputs_of(e: &Expr, index: &HashMap<String, usize>, actuators: &[usize]) -> Vec<usize> {
    let mut out: Vec<usize> = e
        .names()
        .into_iter()
        .filter_map(|n| index.get(n).copied())
        .filter(|i| actuators.contains(i))
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

fn compile(e: &Expr, index: &HashMap<String, usize>) -> Result<Op, String> {
    let slot = |n: &str| {
        index
            .get(n)
            .copied()
            .ok_or_else(|| format!("the filter has no variable '{n}'"))
    };
    Ok(match e {
        Expr::Const(b) => Op::Const(*b),
        Expr::Var(n) => Op::Var(slot(n)?),
        Expr::Prev(n) => Op::Prev(slot(n)?),
        Expr::Rise(n) => Op::Rise(slot(n)?),
        Expr::Fall(n) => Op::Fall(slot(n)?),
        Expr::Not(e) => Op::Not(Box::new(compile(e, index)?)),
        Expr::And(es) => Op::And(
            es.iter()
                .map(|e| compile(e, index))
                .collect::<Result<_, _>>()?,
        ),
        Expr::Or(es) => Op::Or(
            es.iter()
                .map(|e| compile(e, index))
                .collect::<Result<_, _>>()?,
        ),
    })
}

/// The filter's variables as a [`crate::eval::Scan`], for reports.
struct Slots<'a>(&'a Filter);

impl crate::eval::Scan for Slots<'_> {
    fn value(&self, name: &str) -> bool {
        self.0.index.get(name).is_some_and(|&i| self.0.cur[i])
    }
    fn previous(&self, name: &str) -> bool {
        self.0.index.get(name).is_some_and(|&i| self.0.prev[i])
    }
}
