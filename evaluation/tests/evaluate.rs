//! The benchmark's machinery on real generated plants: branched faulty runs
//! are the runs with the fault from the start, and one plant goes through the
//! whole chain with sensible figures.

use datasets::generated::{GeneratedPlant, Size};
use datasets::inject::Injection;
use datasets::sim::{MemorySink, SimConfig, run_with_showing};
use diagnoser::{MS, SECOND};
use evaluation::evaluate::{FAULT_SEED, Settings, evaluate, onsets};
use evaluation::runs::faulty_runs;
use evaluation::summary::{disagreements, table};

#[test]
fn branched_runs_are_the_runs_with_the_fault_from_the_start() {
    let g = GeneratedPlant::generate(21, Size::Small).expect("a plant");
    let plant = g.plant();
    let settings = Settings::quick();
    let onsets = onsets(21, plant.faults.len(), &settings);
    // Every fourth fault, so that every template and several onsets are tried.
    let faults: Vec<Injection> = (0..plant.faults.len())
        .step_by(4)
        .map(|i| Injection {
            label: plant.faults[i].label.clone(),
            template: plant.faults[i].template.clone(),
            onset: onsets[i],
        })
        .collect();
    let horizon = 120 * SECOND;
    let mut seen = 0;
    faulty_runs(&g, FAULT_SEED, &faults, horizon, |run| {
        let config = SimConfig {
            duration: run.fault.onset + horizon,
            scan_period: plant.scan_period,
            seed: FAULT_SEED,
            faults: vec![run.fault.clone()],
        };
        let mut straight = MemorySink::default();
        let (_, showed) = run_with_showing(
            &mut g.physics(),
            &mut g.program(),
            &config,
            &mut straight,
            |_| {},
        )
        .expect("runs");
        assert_eq!(run.log.initial, straight.initial, "{}", run.fault.label);
        assert_eq!(run.log.events, straight.events, "{}", run.fault.label);
        assert_eq!(run.showed, showed[0], "{}", run.fault.label);
        seen += 1;
    })
    .expect("runs");
    assert_eq!(seen, faults.len());
}

#[test]
fn a_plant_goes_through_the_whole_chain() {
    let settings = Settings {
        learn_runs: 2,
        learn_duration: 1200 * SECOND,
        normal_duration: 600 * SECOND,
        first_onset: 60 * SECOND,
        onset_window: 120 * SECOND,
        horizon: 120 * SECOND,
        max_faults: Some(16),
    };
    let outcome = evaluate(8, Size::Small, &settings);
    assert_eq!(outcome.error, None);
    assert_eq!(outcome.runs.len(), 16.min(outcome.faults));
    assert!(
        (outcome.normal_hours - 600.0 / 3600.0).abs() < 1e-3,
        "{}",
        outcome.normal_hours
    );
    for r in &outcome.runs {
        assert!(!r.part.is_empty(), "{}: no part", r.label);
        assert!(
            r.check_detectable.is_some(),
            "{}: check said nothing",
            r.label
        );
        assert!(
            r.onset_ms >= 60_000 && r.onset_ms < 180_000,
            "{}",
            r.onset_ms
        );
        assert_eq!(
            r.end_ms * MS,
            (r.onset_ms * MS + 120 * SECOND) / outcome_scan(&outcome) * outcome_scan(&outcome)
        );
        if let (Some(d), Some(s)) = (r.judgement.detected_ms, r.showed_ms) {
            assert!(d >= r.onset_ms as f64 && s >= r.onset_ms as f64, "{r:?}");
        }
        // A fault's own part can only be isolated once it has left normal.
        assert!(
            !r.judgement.isolated || r.judgement.detected_ms.is_some(),
            "{r:?}"
        );
    }
    // Most faults of a small plant show within two minutes.
    let showed = outcome
        .runs
        .iter()
        .filter(|r| r.showed_ms.is_some())
        .count();
    assert!(showed * 2 >= outcome.runs.len(), "only {showed} showed");
    let text = table(std::slice::from_ref(&outcome));
    assert!(
        text.contains("| small: 1 |") && text.contains("| all: 1 |"),
        "{text}"
    );
    for d in disagreements(std::slice::from_ref(&outcome)) {
        assert!(
            outcome
                .runs
                .iter()
                .any(|r| r.label == d.label && r.showed_ms.is_some())
        );
        assert!(
            d.rerun(&settings)
                .starts_with("bash benches/generality-rerun.sh 8 small ")
        );
    }
}

fn outcome_scan(o: &evaluation::PlantOutcome) -> i64 {
    (o.scan_ms * MS as f64).round() as i64
}
