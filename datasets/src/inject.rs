//! Fault injection: which fault, from when, and how it bends what the PLC reads
//! and what the actuators do.

use vocabulary::fault::{Factor, FaultTarget};
use vocabulary::{
    Event, FaultTemplate, MS, Plant, SECOND, SignalId, SignalKind, SignalTable, Time, TimeUnit,
    time,
};

use crate::sim::MemorySink;
use serde::Serialize;

/// Width of the spurious pulse of `unexpected_rise` / `unexpected_fall`.
pub const PULSE: Time = 50 * MS;

/// A fault as asked for on the command line: `F2@600s` or `stuck1(C4)@10min`,
/// and for a `slow` fault its factor after the onset: `F40@600s:x3`,
/// `slow(P)@10min:x1.5` (×2 when none is given).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FaultSpec {
    /// A label of the plant file (`F2`) or a template (`stuck1(C4)`).
    pub what: String,
    /// Onset, from the start of the run.
    pub onset: Time,
    /// How much slower a `slow` fault's motions are, if given.
    pub factor: Option<Factor>,
}

impl std::str::FromStr for FaultSpec {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        let (what, at) = text
            .rsplit_once('@')
            .ok_or_else(|| format!("bad fault '{text}': expected LABEL@TIME, e.g. F2@600s"))?;
        if what.trim().is_empty() {
            return Err(format!(
                "bad fault '{text}': missing fault label before '@'"
            ));
        }
        let (at, factor) = match at.split_once(':') {
            Some((at, factor)) => (
                at,
                Some(
                    factor
                        .parse()
                        .map_err(|e| format!("bad fault '{text}': {e}"))?,
                ),
            ),
            None => (at, None),
        };
        let onset = time::parse_duration(at).map_err(|e| format!("bad fault '{text}': {e}"))?;
        Ok(FaultSpec {
            what: what.trim().to_string(),
            onset,
            factor,
        })
    }
}

/// A fault resolved against a plant: ready to inject, and to write to `truth.json`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Injection {
    /// The label (from the plant file, or the template text itself).
    pub label: String,
    /// What goes wrong.
    pub template: FaultTemplate,
    /// From when.
    pub onset: Time,
    /// How much slower a `slow` fault's motions are (`None` for the others).
    pub factor: Option<Factor>,
}

impl Injection {
    /// Resolves a command-line fault against `plant`: a known label, or a template
    /// whose arguments name the plant's signals and elements.
    pub fn resolve(spec: &FaultSpec, plant: &Plant) -> Result<Injection, String> {
        if let Some(def) = plant.fault(&spec.what) {
            return Injection::with_factor(def.label.clone(), def.template.clone(), spec);
        }
        let template: FaultTemplate = spec.what.parse().map_err(|e: String| {
            if spec.what.contains('(') {
                e
            } else {
                let labels: Vec<&str> = plant
                    .faults
                    .iter()
                    .map(|f| f.label.as_str())
                    .take(16)
                    .collect();
                format!(
                    "unknown fault '{}' for plant '{}' (known: {}{})",
                    spec.what,
                    plant.name,
                    labels.join(", "),
                    if plant.faults.len() > 16 { ", …" } else { "" }
                )
            }
        })?;
        let kind = |name: &str| plant.signals.id(name).map(|id| plant.signals.get(id).kind);
        match template.target() {
            FaultTarget::Sensor | FaultTarget::Actuator => {
                let want = if template.target() == FaultTarget::Sensor {
                    SignalKind::Sensor
                } else {
                    SignalKind::Actuator
                };
                let s = template.arguments()[0];
                match kind(s) {
                    None => return Err(format!("unknown signal '{s}' in fault '{template}'")),
                    Some(k) if k != want => {
                        return Err(format!(
                            "'{s}' in fault '{template}' is not {}",
                            want.with_article()
                        ));
                    }
                    Some(_) => {}
                }
            }
            FaultTarget::Motion => {
                let x = template.arguments()[0];
                let element = plant.parts.iter().any(|p| p.element.as_deref() == Some(x));
                if !element && kind(x) != Some(SignalKind::Actuator) {
                    return Err(format!(
                        "'{x}' in fault '{template}' is neither an element nor an actuator"
                    ));
                }
            }
            FaultTarget::Element => {
                let args = template.arguments();
                let Some(part) = plant
                    .parts
                    .iter()
                    .find(|p| p.element.as_deref() == Some(args[0]))
                else {
                    return Err(format!(
                        "unknown element '{}' in fault '{template}'",
                        args[0]
                    ));
                };
                for s in &args[1..] {
                    if !part.sensors.iter().any(|&id| plant.signals.name(id) == *s) {
                        return Err(format!(
                            "'{s}' in fault '{template}' is not a sensor of part '{}'",
                            part.name
                        ));
                    }
                }
            }
        }
        Injection::with_factor(spec.what.clone(), template, spec)
    }

    /// The injection of `template`, with the factor of `spec` where the
    /// template is `slow` (and an error where it is not).
    fn with_factor(
        label: String,
        template: FaultTemplate,
        spec: &FaultSpec,
    ) -> Result<Injection, String> {
        let factor = match (&template, spec.factor) {
            (FaultTemplate::Slow(_), f) => Some(f.unwrap_or(Factor::DEFAULT)),
            (_, None) => None,
            (_, Some(f)) => {
                return Err(format!(
                    "fault '{label}' ({template}) takes no factor ({f}): only slow faults do"
                ));
            }
        };
        Ok(Injection {
            label,
            template,
            onset: spec.onset,
            factor,
        })
    }

    /// An injection of a fault that is not `slow` (no factor).
    pub fn new(label: impl Into<String>, template: FaultTemplate, onset: Time) -> Injection {
        let factor = matches!(template, FaultTemplate::Slow(_)).then_some(Factor::DEFAULT);
        Injection {
            label: label.into(),
            template,
            onset,
            factor,
        }
    }
}

/// One entry of `truth.json`.
#[derive(Debug, Clone, Serialize)]
pub struct TruthEntry {
    /// Fault label.
    pub label: String,
    /// Template text, e.g. `stuck1(C4)`.
    pub template: String,
    /// Onset in the log's time unit.
    pub onset: serde_json::Value,
    /// Whether the fault showed in the log at all: from its onset, what the
    /// PLC saw or ordered differs from the same run without it (an edge
    /// changed, added or missing).
    pub showed: bool,
    /// The first scan where it did, in the log's time unit; `null` if never.
    pub showed_at: serde_json::Value,
    /// A `slow` fault's factor (`3` for ×3); absent for the others.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
}

/// The ground truth of a run, as written to `truth.json`: each fault and when
/// it first showed (`showed[i]` for `faults[i]`, see
/// [`crate::sim::run_with_showing`]).
pub fn truth_json(
    faults: &[Injection],
    showed: &[Option<Time>],
    unit: TimeUnit,
) -> serde_json::Value {
    let entries: Vec<TruthEntry> = faults
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let at = showed.get(i).copied().flatten();
            TruthEntry {
                label: f.label.clone(),
                template: f.template.to_string(),
                onset: time_value(f.onset, unit),
                showed: at.is_some(),
                showed_at: at.map_or(serde_json::Value::Null, |t| time_value(t, unit)),
                factor: f.factor.map(Factor::get),
            }
        })
        .collect();
    serde_json::json!({ "faults": entries })
}

/// A time as a JSON number in `unit`: an integer when exact.
pub fn time_value(t: Time, unit: TimeUnit) -> serde_json::Value {
    if t % unit.nanos() == 0 {
        serde_json::Value::from(t / unit.nanos())
    } else {
        serde_json::Value::from(t as f64 / unit.nanos() as f64)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SensorMode {
    Stuck(bool),
    /// Spurious pulse to this value, at the first scan from onset where the true
    /// value is the opposite; `Some(start)` once it began.
    Pulse(bool, Option<Time>),
}

#[derive(Debug, Clone)]
struct SensorFault {
    index: usize,
    onset: Time,
    mode: SensorMode,
}

/// Applies sensor and actuator faults, scan by scan.
#[derive(Debug, Clone, Default)]
pub struct SensorInjector {
    sensors: Vec<SensorFault>,
    actuators: Vec<(usize, Time, bool)>,
}

impl SensorInjector {
    /// Collects the signal faults of `faults` (element faults are the physics' job).
    pub fn new(signals: &SignalTable, faults: &[Injection]) -> Self {
        let mut out = SensorInjector::default();
        for f in faults {
            out.add(signals, f);
        }
        out
    }

    /// Adds one fault; an element fault is left to the physics.
    pub fn add(&mut self, signals: &SignalTable, f: &Injection) {
        let Some(index) = f
            .template
            .signal()
            .and_then(|s| signals.id(s))
            .map(|id| id.index())
        else {
            return;
        };
        let mode = match &f.template {
            FaultTemplate::Stuck0(_) => SensorMode::Stuck(false),
            FaultTemplate::Stuck1(_) => SensorMode::Stuck(true),
            FaultTemplate::UnexpectedRise(_) => SensorMode::Pulse(true, None),
            FaultTemplate::UnexpectedFall(_) => SensorMode::Pulse(false, None),
            FaultTemplate::ActuatorStuck0(_) => {
                self.actuators.push((index, f.onset, false));
                return;
            }
            FaultTemplate::ActuatorStuck1(_) => {
                self.actuators.push((index, f.onset, true));
                return;
            }
            _ => return,
        };
        self.sensors.push(SensorFault {
            index,
            onset: f.onset,
            mode,
        });
    }

    /// Replaces true sensor values in `io` by what a faulty sensor reports at `t`.
    pub fn apply_sensors(&mut self, t: Time, io: &mut [bool]) {
        for f in &mut self.sensors {
            if t < f.onset {
                continue;
            }
            match &mut f.mode {
                SensorMode::Stuck(v) => io[f.index] = *v,
                SensorMode::Pulse(v, start) => match *start {
                    None if io[f.index] != *v => {
                        *start = Some(t);
                        io[f.index] = *v;
                    }
                    Some(s) if t < s + PULSE => io[f.index] = *v,
                    _ => {}
                },
            }
        }
    }

    /// Replaces orders in `physical` by what a faulty actuator does at `t`.
    pub fn apply_actuators(&self, t: Time, physical: &mut [bool]) {
        for &(index, onset, v) in &self.actuators {
            if t >= onset {
                physical[index] = v;
            }
        }
    }
}

/// A false alarm on purpose: `sink` with one scan that no fault of a part
/// explains. At the first scan from `from` on (scans every `scan`) where none of
/// `sensors` changed within a second, every one of them flips, and one scan
/// later flips back. Returns the run and that time.
///
/// Use it with two sensors or more of one part: a single fault explains one
/// edge, not several at once.
pub fn with_unexplained_scan(
    sink: &MemorySink,
    sensors: &[SignalId],
    from: Time,
    scan: Time,
) -> (MemorySink, Time) {
    let near = |t: Time| {
        sink.events
            .iter()
            .any(|e| sensors.contains(&e.signal) && (e.t - t).abs() < SECOND)
    };
    let mut at = from;
    while near(at) {
        at += scan;
    }
    let mut values = sink.initial.clone();
    for e in sink.events.iter().take_while(|e| e.t < at) {
        values[e.signal.index()] = e.value;
    }
    let mut out = sink.clone();
    for &signal in sensors {
        let v = values[signal.index()];
        out.events.push(Event {
            t: at,
            signal,
            value: !v,
        });
        out.events.push(Event {
            t: at + scan,
            signal,
            value: v,
        });
    }
    out.events.sort_by_key(|e| (e.t, e.signal));
    (out, at)
}
