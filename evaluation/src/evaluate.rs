//! One generated plant through the whole chain: learn from fault-free logs,
//! replay fresh fault-free logs and every declared fault, run `check`, and
//! judge each replay against the ground truth.

use std::collections::HashMap;
use std::time::Instant;

use datasets::generated::{Family, GeneratedPlant, Size};
use datasets::inject::Injection;
use diagnoser::diagnosis::compile::Compiled;
use diagnoser::diagnosis::diagnosability::check;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::{FaultTemplate, MS, SECOND, Time, TimeFormat, TimeUnit};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::judge::{Alarm, Judgement, alarms, judge, ms, part_of, replay};
use crate::runs::{Log, fault_free, faulty_runs};

/// Run seeds: the learning logs use 1, 2, …; the fresh fault-free log and
/// the faulty runs use their own.
pub const NORMAL_SEED: u64 = 100;
/// Run seed of the fault-free run the faulty runs branch off.
pub const FAULT_SEED: u64 = 200;

/// How much to simulate per plant.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Fault-free logs to learn from, with run seeds 1, 2, …
    pub learn_runs: u64,
    /// Length of each.
    pub learn_duration: Time,
    /// Length of the fresh fault-free log replayed for false alarms.
    pub normal_duration: Time,
    /// Earliest onset of a fault.
    pub first_onset: Time,
    /// Onsets are drawn in `[first_onset, first_onset + onset_window)`.
    pub onset_window: Time,
    /// How long a faulty run goes on after its onset.
    pub horizon: Time,
    /// Replay at most this many of each plant's faults (spread over its list).
    pub max_faults: Option<usize>,
}

impl Settings {
    /// The full benchmark: three hours of learning, two fresh hours, every
    /// fault for five minutes.
    pub fn full() -> Settings {
        Settings {
            learn_runs: 3,
            learn_duration: 3600 * SECOND,
            normal_duration: 7200 * SECOND,
            first_onset: 120 * SECOND,
            onset_window: 600 * SECOND,
            horizon: 300 * SECOND,
            max_faults: None,
        }
    }

    /// A short run for continuous integration.
    pub fn quick() -> Settings {
        Settings {
            learn_runs: 2,
            learn_duration: 1800 * SECOND,
            normal_duration: 1800 * SECOND,
            first_onset: 60 * SECOND,
            onset_window: 300 * SECOND,
            horizon: 180 * SECOND,
            max_faults: Some(24),
        }
    }
}

/// One faulty run and how the diagnosers did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultOutcome {
    /// The fault's label.
    pub label: String,
    /// Its template.
    pub template: String,
    /// A `slow` fault's factor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
    /// Its part.
    pub part: String,
    /// Onset, in ms from the start of the run.
    pub onset_ms: i64,
    /// End of the run, in ms.
    pub end_ms: i64,
    /// When the fault first showed in the log, in ms (`None`: never).
    pub showed_ms: Option<f64>,
    /// Whether its part made the same edges in the same order as without the
    /// fault, at other times only.
    pub timing_only: bool,
    /// The replay judged against the truth.
    #[serde(flatten)]
    pub judgement: Judgement,
    /// What `check` says: detectable.
    pub check_detectable: Option<bool>,
    /// What `check` says: isolable under the learned control, also if it
    /// waits for ever.
    pub check_isolable: Option<bool>,
    /// What `check` says: isolable while the plant keeps running.
    pub check_isolable_running: Option<bool>,
}

/// Seconds spent on each step of a plant.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Seconds {
    /// Simulating the learning logs and learning.
    pub learn: f64,
    /// Simulating and replaying the fresh fault-free log.
    pub normal: f64,
    /// `check`.
    pub check: f64,
    /// Simulating and replaying the faulty runs.
    pub faults: f64,
}

/// Everything measured on one plant.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlantOutcome {
    /// Plant seed.
    pub seed: u64,
    /// Its size.
    pub size: &'static str,
    /// Its family.
    pub family: &'static str,
    /// Its name.
    pub name: String,
    /// Parts.
    pub parts: usize,
    /// Signals.
    pub signals: usize,
    /// Declared faults.
    pub faults: usize,
    /// PLC scan period, ms.
    pub scan_ms: f64,
    /// Whether its program has timeouts.
    pub timeouts: bool,
    /// Hours of fresh fault-free log replayed.
    pub normal_hours: f64,
    /// Parts leaving normal on it.
    pub false_alarms: Vec<Alarm>,
    /// `def_` flags raised on it: each would have switched a healthy sensor
    /// to its estimate, or stopped a healthy part.
    pub false_flags: Vec<String>,
    /// Each faulty run.
    pub runs: Vec<FaultOutcome>,
    /// Time spent.
    pub seconds: Seconds,
    /// What stopped the evaluation of this plant, if anything.
    pub error: Option<String>,
}

fn stream(log: Log) -> LogStream {
    LogStream::from_events(
        "memory",
        TimeFormat::Numeric(TimeUnit::Ms),
        log.start,
        log.initial,
        log.events,
    )
}

/// The onset of each fault: in whole milliseconds, drawn from the plant seed.
pub fn onsets(seed: u64, count: usize, settings: &Settings) -> Vec<Time> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x005e_7a11);
    let window = (settings.onset_window / MS).max(1);
    (0..count)
        .map(|_| settings.first_onset + rng.random_range(0..window) * MS)
        .collect()
}

/// The faults replayed: all, or at most `max_faults` spread over the list.
fn chosen(plant: &diagnoser::Plant, settings: &Settings) -> Vec<usize> {
    let n = plant.faults.len();
    match settings.max_faults {
        Some(k) if k < n => (0..k).map(|i| i * n / k).collect(),
        _ => (0..n).collect(),
    }
}

/// The factors every `slow` fault is replayed at: a degradation caught
/// early (×1.5), halfway (×2) and late (×3).
pub const SLOW_FACTORS: [&str; 3] = ["x1.5", "x2", "x3"];

/// The runs of one declared fault: once, or once per factor of
/// [`SLOW_FACTORS`] for a `slow` fault.
fn injections(label: &str, template: &FaultTemplate, onset: Time) -> Vec<Injection> {
    let one = Injection::new(label, template.clone(), onset);
    if !matches!(template, FaultTemplate::Slow(_)) {
        return vec![one];
    }
    SLOW_FACTORS
        .iter()
        .filter_map(|f| f.parse().ok())
        .map(|f| Injection {
            factor: Some(f),
            ..one.clone()
        })
        .collect()
}

/// Evaluates assembly plant `seed` of `size`.
pub fn evaluate(seed: u64, size: Size, settings: &Settings) -> PlantOutcome {
    evaluate_family(seed, size, Family::Assembly, settings)
}

/// Evaluates plant `seed` of `size` and `family`.
pub fn evaluate_family(seed: u64, size: Size, family: Family, settings: &Settings) -> PlantOutcome {
    let mut out = PlantOutcome {
        seed,
        size: size.name(),
        family: family.name(),
        name: String::new(),
        parts: 0,
        signals: 0,
        faults: 0,
        scan_ms: 0.0,
        timeouts: false,
        normal_hours: 0.0,
        false_alarms: Vec::new(),
        false_flags: Vec::new(),
        runs: Vec::new(),
        seconds: Seconds::default(),
        error: None,
    };
    if let Err(e) = run(seed, size, family, settings, &mut out) {
        out.error = Some(e);
    }
    out
}

fn run(
    seed: u64,
    size: Size,
    family: Family,
    settings: &Settings,
    out: &mut PlantOutcome,
) -> Result<(), String> {
    let g = GeneratedPlant::generate_family(seed, size, family)?;
    let plant = g.plant();
    out.name = plant.name.clone();
    out.parts = plant.parts.len();
    out.signals = plant.signals.len();
    out.faults = plant.faults.len();
    out.scan_ms = ms(plant.scan_period);
    out.timeouts = g.layout().timeouts;

    let clock = Instant::now();
    let mut learner = Learner::new(plant, LearnOptions::default())?;
    for run_seed in 1..=settings.learn_runs {
        let log = fault_free(&g, run_seed, settings.learn_duration).map_err(|e| e.to_string())?;
        learner
            .learn_log(stream(log), |_| {})
            .map_err(|e| e.to_string())?;
    }
    let model = learner.finish();
    let mut diagnoser = PlantDiagnoser::new(plant, &model, &DiagnoserOptions::default())?;
    out.seconds.learn = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let log = fault_free(&g, NORMAL_SEED, settings.normal_duration).map_err(|e| e.to_string())?;
    out.normal_hours = (log.end - log.start) as f64 / (3600 * SECOND) as f64;
    let fault_free_verdicts = replay(&mut diagnoser, &log);
    out.false_alarms = alarms(&fault_free_verdicts);
    for v in &fault_free_verdicts {
        for f in &v.flags {
            if !out.false_flags.contains(f) {
                out.false_flags.push(f.clone());
            }
        }
    }
    out.seconds.normal = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let mut verdicts: HashMap<String, (bool, bool, bool)> = HashMap::new();
    for engine in diagnoser.engines() {
        let mut engine = engine.clone();
        let compiled = Compiled::explore(&mut engine, 2);
        for v in check(&mut engine, &compiled, model.time_unit) {
            verdicts.insert(v.label, (v.detectable, v.isolable_when_waiting, v.isolable));
        }
    }
    out.seconds.check = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let chosen = chosen(plant, settings);
    let onsets = onsets(seed, plant.faults.len(), settings);
    let faults: Vec<Injection> = chosen
        .iter()
        .flat_map(|&i| injections(&plant.faults[i].label, &plant.faults[i].template, onsets[i]))
        .collect();
    faulty_runs(&g, FAULT_SEED, &faults, settings.horizon, |run| {
        let part = part_of(plant, &run.fault.template).unwrap_or_default();
        let verdicts_of_run = replay(&mut diagnoser, &run.log);
        let judgement = judge(&verdicts_of_run, &part, &run.fault.label, run.fault.onset);
        let check = verdicts.get(&run.fault.label);
        out.runs.push(FaultOutcome {
            label: run.fault.label.clone(),
            template: run.fault.template.to_string(),
            factor: run.fault.factor.map(|f| f.get()),
            part,
            onset_ms: run.fault.onset / MS,
            end_ms: run.log.end / MS,
            showed_ms: run.showed.map(ms),
            timing_only: run.timing_only,
            judgement,
            check_detectable: check.map(|c| c.0),
            check_isolable: check.map(|c| c.1),
            check_isolable_running: check.map(|c| c.2),
        });
    })
    .map_err(|e| e.to_string())?;
    out.seconds.faults = clock.elapsed().as_secs_f64();
    Ok(())
}
