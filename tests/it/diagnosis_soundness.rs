//! The diagnosers against the simulator's ground truth: sound labels under any
//! single fault at any onset, and no false alarm on normal runs not used for
//! learning.

use std::sync::OnceLock;

use datasets::inject::{FaultSpec, Injection, with_unexplained_scan};
use datasets::sim::{MemorySink, SimConfig};
use datasets::sorting::{plant, simulate_in_memory};
use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, TimeFormat, TimeUnit};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use proptest::prelude::*;

const MINUTE: i64 = 60 * SECOND;

fn simulate(seed: u64, duration: i64, faults: &[(&str, i64)]) -> MemorySink {
    let plant = plant();
    let faults = faults
        .iter()
        .map(|&(label, onset)| {
            Injection::resolve(
                &FaultSpec {
                    what: label.to_string(),
                    onset,
                    factor: None,
                },
                &plant,
            )
            .expect("a fault of the sorting plant")
        })
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

/// The model every test diagnoses with: learned from two simulated hours of
/// normal operation, with a seed no test run uses.
fn model() -> &'static (Plant, Model) {
    static MODEL: OnceLock<(Plant, Model)> = OnceLock::new();
    MODEL.get_or_init(|| {
        let plant = plant();
        let sink = simulate(1000, 120 * MINUTE, &[]);
        let mut learner = Learner::new(&plant, LearnOptions::default()).expect("learner");
        learner
            .learn_log(stream(&sink), |_| {})
            .expect("learning reads the run");
        let model = learner.finish();
        (plant, model)
    })
}

fn diagnose(sink: &MemorySink) -> Vec<Verdict> {
    let (plant, model) = model();
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

/// Checks soundness of one faulty run; returns whether the fault was detected.
fn check_sound(label: &str, onset: i64, seed: u64, after: i64) -> Result<bool, TestCaseError> {
    let sink = simulate(seed, onset + after, &[(label, onset)]);
    let verdicts = diagnose(&sink);
    let mut detected = false;
    for v in &verdicts {
        prop_assert!(
            v.t >= onset,
            "{label}@{onset}: verdict before the onset: {v:?}"
        );
        // Parts that model no fault may deviate as a consequence (their labels
        // are then `unknown`); the turntable and the plant view must be sound.
        let judged = v.part == "turntable" || v.part == PLANT_VIEW;
        if v.verdict != VerdictKind::Normal && judged {
            prop_assert!(
                v.labels.iter().any(|l| l == label),
                "{label}@{onset} (seed {seed}): true label excluded: {v:?}"
            );
            detected = true;
        }
    }
    Ok(detected)
}

const FAULTS: [&str; 12] = [
    "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8", "F9", "F10", "F11", "F12",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, .. ProptestConfig::default() })]

    /// Whatever the fault and its onset, once a verdict leaves normal the true
    /// label is among its labels.
    #[test]
    fn labels_never_exclude_the_true_fault(
        fault in 0usize..FAULTS.len(),
        onset_ms in (3 * 60_000i64)..(25 * 60_000),
        seed in 0u64..1_000,
    ) {
        check_sound(FAULTS[fault], onset_ms * MS, seed, 10 * MINUTE)?;
    }
}

/// Every fault at several onsets, including onsets in the middle of a rotation.
#[test]
fn every_fault_at_several_onsets_is_sound() {
    let mut detected = 0;
    for (i, label) in FAULTS.iter().enumerate() {
        for k in 0..4 {
            let onset = 5 * MINUTE + (i as i64 * 7919 + k * 3_331) * MS;
            match check_sound(label, onset, 20 + k as u64, 10 * MINUTE) {
                Ok(d) => detected += usize::from(d),
                Err(e) => panic!("{e}"),
            }
        }
    }
    // Most faults show within ten minutes; a fault with no effect on this line's
    // cycle (e.g. an unexpected rise of a sensor that already reads 1) may not.
    assert!(
        detected >= 40,
        "only {detected} of 48 faulty runs were detected"
    );
}

/// Ten simulated hours of normal operation, with a seed not used for learning:
/// no part's verdict ever leaves normal.
#[test]
fn ten_normal_hours_give_no_alarm() {
    let sink = simulate(4242, 600 * MINUTE, &[]);
    assert!(sink.events.len() > 50_000, "{} events", sink.events.len());
    let verdicts = diagnose(&sink);
    assert!(verdicts.is_empty(), "false alarms: {verdicts:?}");
}

/// A false alarm on purpose, then a real fault five minutes later: the
/// turntable is `unknown` for an episode, raises no flag, is back to normal
/// after a cycle, and then gives the real fault its label and flag.
#[test]
fn after_an_unknown_episode_a_later_fault_is_still_labelled() {
    let (plant, _) = model();
    let turntable: Vec<_> = ["C4", "C5"]
        .iter()
        .map(|s| plant.signals.id(s).expect("a turntable sensor"))
        .collect();
    let onset = 15 * MINUTE;
    let faulty = simulate(31, onset + 5 * MINUTE, &[("F2", onset)]);
    let (sink, at) = with_unexplained_scan(&faulty, &turntable, onset - 5 * MINUTE, 10 * MS);
    let verdicts: Vec<Verdict> = diagnose(&sink)
        .into_iter()
        .filter(|v| v.part == "turntable")
        .collect();
    let first = verdicts.first().expect("the turntable leaves normal");
    assert_eq!(first.t, at, "{first:?}");
    assert_eq!(first.labels, ["unknown"], "{first:?}");
    assert!(first.flags.is_empty(), "{first:?}");
    let back = verdicts
        .iter()
        .find(|v| v.verdict == VerdictKind::Normal)
        .expect("back to normal");
    assert!(back.t < onset, "back only at {}: {back:?}", back.t);
    assert!(back.reason.contains("back to normal"), "{back:?}");
    for v in verdicts.iter().filter(|v| v.t < onset) {
        assert!(v.flags.is_empty(), "a flag before the real fault: {v:?}");
    }
    let last = verdicts.last().expect("verdicts");
    assert!(last.t >= onset, "{last:?}");
    assert_eq!(last.labels, ["F2"], "{verdicts:?}");
    assert_eq!(last.flags, ["def_C4"], "{verdicts:?}");
}
