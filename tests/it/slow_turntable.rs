//! A slow turntable (`slow(P)`) on the simulated sorting line, diagnosed with a
//! model learned from a fault-free run: the turntable leaves normal once a
//! rotation outlasts its window, and its labels keep the slow fault.

use std::path::Path;
use std::sync::OnceLock;

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig};
use datasets::sorting::{PLANT_TOML, plant, simulate_in_memory};
use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::fault::Factor;
use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, TimeFormat, TimeUnit};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;

const MINUTE: i64 = 60 * SECOND;

/// The label the diagnosers give `slow(P)`.
const SLOW: &str = "F13";

/// A run of the sorting line, with `slow(P)` from `onset` at `factor` if any.
fn simulate(seed: u64, duration: i64, slow: Option<(i64, &str)>) -> MemorySink {
    let plant = plant();
    let faults = slow
        .map(|(onset, factor)| {
            let spec = FaultSpec {
                what: "slow(P)".to_string(),
                onset,
                factor: Some(factor.parse::<Factor>().expect("a factor")),
            };
            Injection::resolve(&spec, &plant).expect("the sorting line's turntable")
        })
        .into_iter()
        .collect();
    let config = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults,
    };
    simulate_in_memory(&config).expect("simulation runs").0
}

fn stream(sink: &MemorySink) -> LogStream {
    LogStream::from_events(
        "memory",
        TimeFormat::Numeric(TimeUnit::Ms),
        sink.start,
        sink.initial.clone(),
        sink.events.clone(),
    )
}

/// The sorting plant with `slow(P)` among its faults, and a model learned
/// from two simulated hours of normal operation.
fn setup() -> &'static (Plant, Model) {
    static SETUP: OnceLock<(Plant, Model)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let text = PLANT_TOML.replacen("[faults]\n", "[faults]\nF13 = \"slow(P)\"\n", 1);
        let plant = Plant::parse(&text, Path::new("sorting.toml")).expect("plant parses");
        let sink = simulate(1000, 120 * MINUTE, None);
        let mut learner = Learner::new(&plant, LearnOptions::default()).expect("learner");
        learner
            .learn_log(stream(&sink), |_| {})
            .expect("learning reads the run");
        let model = learner.finish();
        (plant, model)
    })
}

fn diagnose(sink: &MemorySink) -> Vec<Verdict> {
    let (plant, model) = setup();
    let mut d = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default())
        .expect("a diagnoser for the sorting plant");
    let mut out = Vec::new();
    d.start(sink.start, &sink.initial);
    for &e in &sink.events {
        d.push(e, &mut |v| out.push(v));
    }
    let end = sink.events.last().map_or(sink.start, |e| e.t);
    d.finish(end, &mut |v| out.push(v));
    out
}

#[test]
fn the_diagnosers_know_the_slow_turntable() {
    let (plant, model) = setup();
    let d = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default()).expect("diagnoser");
    let turntable = d
        .engines()
        .find(|e| e.part.name == "turntable")
        .expect("turntable");
    assert!(turntable.part.modes.iter().any(|m| m.label == SLOW));
}

/// At x1.5, x2 and x3 from an onset mid-run, the turntable leaves normal
/// after the onset, and every verdict of the turntable and of the plant view
/// that is not normal holds the slow label; the turntable ends certain of it.
#[test]
fn a_slow_turntable_leaves_normal_and_keeps_its_label() {
    let onset = 10 * MINUTE + 1_234 * MS;
    for (seed, factor) in [(41, "x1.5"), (42, "x2"), (43, "x3")] {
        let sink = simulate(seed, onset + 10 * MINUTE, Some((onset, factor)));
        let verdicts = diagnose(&sink);
        let turntable: Vec<&Verdict> = verdicts.iter().filter(|v| v.part == "turntable").collect();
        assert!(
            !turntable.is_empty(),
            "{factor}: the turntable stayed normal"
        );
        for v in &verdicts {
            assert!(v.t >= onset, "{factor}: verdict before the onset: {v:?}");
            let judged = v.part == "turntable" || v.part == PLANT_VIEW;
            if judged && v.verdict != VerdictKind::Normal {
                assert!(
                    v.labels.iter().any(|l| l == SLOW),
                    "{factor}: slow excluded: {v:?}"
                );
            }
        }
        let last = turntable.last().expect("a verdict");
        assert_eq!(last.labels, [SLOW], "{factor}: {last:?}");
    }
}

/// Without the fault, the same runs give no verdict: the test above is not
/// passed by a diagnoser that flags everything.
#[test]
fn the_same_runs_without_the_fault_stay_normal() {
    for seed in [41, 42, 43] {
        let verdicts = diagnose(&simulate(seed, 20 * MINUTE + 1_234 * MS, None));
        assert!(verdicts.is_empty(), "seed {seed}: {:?}", verdicts.first());
    }
}
