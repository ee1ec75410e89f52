//! Timed models of plant parts, as learned from logs (`model.json`).
//!
//! A part's model is an automaton over the observed vectors of the part's signals
//! (its *states*), whose *transitions* are the observed events (one or several
//! edges in one scan), each with an interval *guard* measured on a *clock*: by
//! default the part's command clock (time since the last edge of one of its
//! actuators), or the time since another edge of the part when that gives a much
//! tighter interval. The model also carries each sensor's *temporal estimate*: its
//! value as a function of the command clock and of the actuators' state.
//!
//! All times in a model are in its `time_unit`.

use serde::{Deserialize, Serialize};

pub mod validity;

use crate::error::{Located, Location};
use crate::{Plant, Time, TimeUnit};

/// Version of the `model.json` schema written by this build.
pub const MODEL_VERSION: u32 = 1;

/// A learned model of every part of a plant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Model {
    /// Schema version ([`MODEL_VERSION`]).
    pub version: u32,
    /// Plant name.
    pub plant: String,
    /// [`Plant::learning_digest`] of the plant file it was learned with;
    /// absent from models learned before it was written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plant_digest: Option<String>,
    /// Unit of every time in this model.
    pub time_unit: TimeUnit,
    /// PLC scan period, in `time_unit`.
    pub scan_period: f64,
    /// What it was learned from.
    pub learned_from: Provenance,
    /// The settings that widened the guards.
    pub settings: LearnSettings,
    /// One model per part.
    pub parts: Vec<PartModel>,
}

impl Model {
    /// Whether this model was learned for `plant` as it is: the same name,
    /// and the same signals and parts (the digest, when the model has one).
    pub fn fits(&self, plant: &Plant) -> Result<(), String> {
        if self.plant != plant.name {
            return Err(format!(
                "the model was learned for plant '{}', not '{}'",
                self.plant, plant.name
            ));
        }
        match &self.plant_digest {
            Some(digest) if *digest != plant.learning_digest() => Err(format!(
                "the model was learned with another plant file '{}': its signals or parts differ (learn the model again)",
                plant.name
            )),
            _ => Ok(()),
        }
    }
}

/// The logs a model was learned from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// Log files, as given.
    pub logs: Vec<String>,
    /// Events read.
    pub events: u64,
    /// Total logged time, in `time_unit`.
    pub duration: f64,
}

/// How learned intervals were turned into guards.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LearnSettings {
    /// Absolute widening on each side, in `time_unit`.
    pub margin: f64,
    /// Relative widening on each side, as a fraction of the learned width.
    pub margin_relative: f64,
    /// Share of samples trimmed on each side before widening (outliers).
    pub trim: f64,
    /// Standard deviations of the drift between runs that each guard covers.
    #[serde(default)]
    pub drift: f64,
    /// The drift between the learning logs: the relative standard deviation of
    /// a duration's mean from one log to the next (0 from a single log).
    #[serde(default)]
    pub drift_sigma: f64,
}

impl Model {
    /// Reads a `model.json` file, checking its schema version.
    pub fn from_path(path: &std::path::Path) -> Result<Model, Located> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Located::new(Location::new(path, 0, 0), format!("cannot read: {e}")))?;
        Model::parse(&text, path)
    }

    /// Parses the text of a `model.json` file and checks what it means (see
    /// [`validity`]); `path` names it in errors.
    pub fn parse(text: &str, path: &std::path::Path) -> Result<Model, Located> {
        // Check the version first: a model from another schema fails on it, not
        // on whichever field changed.
        #[derive(Deserialize)]
        struct Versioned {
            version: Option<u32>,
        }
        let at = |e: &serde_json::Error| Location::new(path, e.line(), e.column());
        let v: Versioned = serde_json::from_str(text)
            .map_err(|e| Located::new(at(&e), format!("not a model file: {e}")))?;
        match v.version {
            Some(MODEL_VERSION) => {}
            Some(other) => {
                return Err(Located::new(
                    Location::new(path, 1, 1).with_field("version"),
                    format!(
                        "model schema version {other}; this build reads version {MODEL_VERSION} (learn the model again)"
                    ),
                ));
            }
            None => {
                return Err(Located::new(
                    Location::new(path, 1, 1).with_field("version"),
                    "not a model file: no schema version",
                ));
            }
        }
        let model: Model = serde_json::from_str(text).map_err(|e| {
            let msg = e.to_string();
            let msg = msg.split(" at line ").next().unwrap_or(&msg).to_string();
            Located::new(at(&e), msg)
        })?;
        validity::validate(&model).map_err(|why| Located::new(Location::new(path, 0, 0), why))?;
        Ok(model)
    }
}

/// The model of one part.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartModel {
    /// Part name, from the plant file.
    pub name: String,
    /// The part's signals, actuators first: the order of every state vector.
    pub signals: Vec<String>,
    /// How many of `signals` are actuators.
    pub actuators: usize,
    /// Observed states.
    pub states: Vec<StateModel>,
    /// Observed transitions.
    pub transitions: Vec<TransitionModel>,
    /// The partition of the command clock into intervals `I1`, `I2`, … per actuator
    /// state, and each sensor's value in them.
    pub estimates: Vec<CommandEstimate>,
    /// Each estimable sensor's estimate over all actuator states, in the form of
    /// seed 002: e.g. `Ĉ4 = I1 | I2 | I9 | I10`.
    pub sensor_estimates: Vec<SensorEstimate>,
    /// What could not be timed, and why.
    pub untimed: Vec<String>,
    /// The part's input sensors: the plant file's `inputs`, or those learned
    /// with `learn --learn-inputs`. Their edges are allowed in any state.
    #[serde(default)]
    pub inputs: Vec<String>,
    /// How each sensor looks in the logs (driven by the part's orders, or an
    /// input), and why.
    #[serde(default)]
    pub sensor_classes: Vec<SensorClass>,
}

/// How a sensor of a part looks in the learning logs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorClass {
    /// Sensor name.
    pub sensor: String,
    /// What its edges follow.
    pub class: SensorKind,
    /// The counts behind it, in words.
    pub why: String,
}

/// Whether a sensor's edges follow the part's orders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    /// Its edges follow clocks of the part.
    Driven,
    /// None of its edges does: an operator, a workpiece or another machine.
    Input,
    /// One of its edges does, the other not (a place sensor).
    PartlyInput,
    /// An input because the plant file's `inputs` says so.
    DeclaredInput,
    /// Not an input because the plant file's `inputs` leaves it out.
    DeclaredDriven,
}

impl SensorKind {
    /// In words, as `learn` reports it.
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::Driven => "driven",
            SensorKind::Input => "input",
            SensorKind::PartlyInput => "partly an input",
            SensorKind::DeclaredInput => "input, as the plant file's `inputs` says",
            SensorKind::DeclaredDriven => "driven, as the plant file's `inputs` says",
        }
    }
}

/// A state: one observed vector of the part's signals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateModel {
    /// Index in `states`.
    pub id: usize,
    /// Values of the part's signals, in `PartModel::signals` order.
    pub values: Vec<bool>,
    /// Times the state was entered.
    pub visits: u64,
    /// True when the part waits here for a command: every transition out of it
    /// starts with an actuator edge.
    pub stable: bool,
    /// Sensor events expected here, each by a deadline on its clock.
    pub expected: Vec<Expectation>,
}

/// A sensor event expected in a state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Expectation {
    /// Index of the transition.
    pub transition: usize,
    /// The event, e.g. `FE(C4)`.
    pub event: String,
    /// Clock the deadline is measured on (see [`TransitionModel::clock`]).
    pub clock: String,
    /// Latest time on that clock: the transition guard's upper bound, for
    /// readers of the file. The model check and the diagnosers read the
    /// guard itself ([`Guard::window`]).
    pub by: f64,
}

/// A transition between two states.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransitionModel {
    /// Index in `transitions`.
    pub id: usize,
    /// Source state.
    pub from: usize,
    /// Target state.
    pub to: usize,
    /// The edges of the scan, e.g. `RE(A4)` or `FE(C4) RE(C5)`.
    pub event: String,
    /// Whether the event includes an actuator edge (a command).
    pub command: bool,
    /// Occurrences.
    pub count: u64,
    /// Clock of the guard: `command` (time since the part's last actuator edge) or
    /// an edge such as `FE(C1)` (time since its last occurrence).
    pub clock: String,
    /// The interval guard.
    pub guard: Guard,
    /// The same statistics on the command clock, when `clock` is another edge.
    pub command_guard: Option<Guard>,
    /// False when even the best clock leaves the timing spread wide (it follows
    /// the product flow, not a command): the guard is then informative only.
    pub timed: bool,
}

/// Learned timing of a transition, and the widened interval actually used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Guard {
    /// Samples.
    pub n: u64,
    /// Smallest sample.
    pub min: f64,
    /// 1 % quantile.
    pub q01: f64,
    /// Median.
    pub q50: f64,
    /// 99 % quantile.
    pub q99: f64,
    /// Largest sample.
    pub max: f64,
    /// Lower bound of the guard used (after trimming and widening).
    pub lo: f64,
    /// Upper bound of the guard used.
    pub hi: f64,
}

impl Guard {
    /// The guard used, in the log's time. The diagnosers and the model check
    /// both read a guard through this, so they agree to the nanosecond.
    pub fn window(&self, unit: TimeUnit) -> Window {
        let scale = unit.nanos() as f64;
        let to_ns = |x: f64| (x * scale).round() as Time;
        Window {
            lo: to_ns(self.lo),
            hi: to_ns(self.hi),
        }
    }
}

/// When a transition may come: `[lo, hi]` on its clock, both ends included.
/// Past `hi`, an expected transition is late.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// Earliest clock reading.
    pub lo: Time,
    /// Latest clock reading.
    pub hi: Time,
}

impl Window {
    /// Whether the transition may come `elapsed` after its clock's origin.
    pub fn admits(&self, elapsed: Time) -> bool {
        self.lo <= elapsed && elapsed <= self.hi
    }
}

/// The temporal estimates of a part's sensors after one actuator state is
/// commanded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CommandEstimate {
    /// The actuators' values after the command, e.g. `A4=1`.
    pub actuators: String,
    /// Intervals of the command clock, in order, partitioning `[0, ∞)`.
    pub intervals: Vec<ClockInterval>,
    /// For each sensor that could be estimated, its value in each interval.
    pub sensors: Vec<SensorSchedule>,
}

/// A named interval of the command clock, `[from, to[` (`to` = `None`: unbounded).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClockInterval {
    /// Name, `I1`, `I2`, … numbered across the part's estimates.
    pub name: String,
    /// Start, included.
    pub from: f64,
    /// End, excluded; `None` for the last interval.
    pub to: Option<f64>,
}

/// A sensor's estimated value over the intervals of a [`CommandEstimate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorSchedule {
    /// Sensor name.
    pub sensor: String,
    /// One value per interval: `"1"`, `"0"` or `"uncertain"` (the edge may
    /// already have happened).
    pub values: Vec<String>,
}

/// A sensor's temporal estimate as a disjunction of clock intervals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorEstimate {
    /// Sensor name.
    pub sensor: String,
    /// Intervals where the sensor is 1 or may already be 1, e.g. `I1 | I2 | I9 | I10`.
    pub expr: String,
    /// Of those, the ones where its edge may or may not have happened yet.
    pub uncertain: Vec<String>,
}

impl SensorEstimate {
    /// The intervals where the sensor is or may be 1, in order: `expr` read
    /// as the list it is.
    ///
    /// ```
    /// use vocabulary::model::SensorEstimate;
    ///
    /// let c4 = SensorEstimate {
    ///     sensor: "C4".into(),
    ///     expr: "I1 | I2 | I9 | I10".into(),
    ///     uncertain: vec!["I2".into(), "I9".into()],
    /// };
    /// assert_eq!(c4.intervals(), ["I1", "I2", "I9", "I10"]);
    /// ```
    pub fn intervals(&self) -> Vec<&str> {
        // `0`, the empty union: the sensor is 0 whatever the time.
        (self.expr.split('|'))
            .map(str::trim)
            .filter(|s| !s.is_empty() && *s != "0")
            .collect()
    }
}

/// An edge of `signal` as the model names it, in events and clocks: `RE(C5)`
/// when it rises, `FE(C5)` when it falls.
pub fn edge_name(signal: &str, rising: bool) -> String {
    format!("{}({signal})", if rising { "RE" } else { "FE" })
}

/// A clock of the model, as `model.json` names it in guards and deadlines:
/// `command` (time since the part's last actuator edge) or an edge of one of
/// its signals, `RE(C5)` or `FE(C1)` (time since that edge last occurred).
///
/// ```
/// use vocabulary::model::ModelClock;
///
/// let clock = ModelClock::parse("FE(C1)").unwrap();
/// assert_eq!(clock, ModelClock::Edge { signal: "C1".into(), rising: false });
/// assert_eq!(clock.to_string(), "FE(C1)");
/// assert_eq!(ModelClock::parse("command"), Some(ModelClock::Command));
/// assert_eq!(ModelClock::Command.since(), "the last command");
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum ModelClock {
    /// Time since the part's last actuator edge.
    Command,
    /// Time since the last rising or falling edge of `signal`.
    Edge {
        /// The signal's name.
        signal: String,
        /// `RE` (rising) or `FE` (falling).
        rising: bool,
    },
}

impl ModelClock {
    /// The clock named `text`, if it is one.
    pub fn parse(text: &str) -> Option<ModelClock> {
        if text == "command" {
            return Some(ModelClock::Command);
        }
        let (edge, signal) = text.strip_suffix(')')?.split_once('(')?;
        let rising = match edge {
            "RE" => true,
            "FE" => false,
            _ => return None,
        };
        Some(ModelClock::Edge {
            signal: signal.to_string(),
            rising,
        })
    }

    /// What the clock counts from, for sentences: "the last command", or the
    /// edge.
    pub fn since(&self) -> String {
        match self {
            ModelClock::Command => "the last command".to_string(),
            edge => edge.to_string(),
        }
    }
}

impl std::fmt::Display for ModelClock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ModelClock::Command => f.write_str("command"),
            ModelClock::Edge { signal, rising } => f.write_str(&edge_name(signal, *rising)),
        }
    }
}
