//! Whatever `learn` writes, the other verbs take: on generated plants of
//! every family learned from logs so short that some sensors never change
//! (a limit switch never reached, an overflow switch, a magazine never
//! empty), the model reads back, `check` and `filter rewrite` accept it, and
//! the diagnosers build from it.

use datasets::generated::{Family, GeneratedPlant, Size};
use datasets::sim::SimConfig;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::model::Model;
use diagnoser::{SECOND, TimeFormat, TimeUnit};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use proptest::prelude::*;

use crate::support::gardefou;

/// `plant`'s model learned from `seconds` of one fault-free run, as
/// `model.json` text.
fn learn_briefly(plant: &GeneratedPlant, seconds: i64, run: u64) -> (String, usize) {
    let config = SimConfig {
        duration: seconds * SECOND,
        scan_period: plant.plant().scan_period,
        seed: run,
        faults: Vec::new(),
    };
    let (sink, _) = plant.simulate_in_memory(&config).expect("the plant runs");
    let changed: std::collections::HashSet<usize> =
        sink.events.iter().map(|e| e.signal.index()).collect();
    let still = (0..sink.initial.len())
        .filter(|i| !changed.contains(i))
        .count();
    let stream = LogStream::from_events(
        "memory",
        TimeFormat::Numeric(TimeUnit::Ms),
        sink.start,
        sink.initial.clone(),
        sink.events.clone(),
    );
    let mut learner = Learner::new(plant.plant(), LearnOptions::default()).expect("a learner");
    learner
        .learn_log(stream, |_| {})
        .expect("learning reads the run");
    let model = learner.finish();
    (
        serde_json::to_string_pretty(&model).expect("a model writes"),
        still,
    )
}

/// Every verb that reads a model takes `model`: read back as `model.json`,
/// diagnosers built, `check` and `filter rewrite` run to the end.
fn assert_taken(plant: &GeneratedPlant, model: &str, what: &str) {
    let dir = tempfile::tempdir().expect("temp dir");
    let (plant_path, model_path) = (dir.path().join("plant.toml"), dir.path().join("model.json"));
    std::fs::write(&plant_path, plant.plant_toml()).expect("writes the plant");
    std::fs::write(&model_path, model).expect("writes the model");
    let read = Model::parse(model, &model_path).unwrap_or_else(|e| panic!("{what}: {e}"));
    PlantDiagnoser::new(plant.plant(), &read, &DiagnoserOptions::default())
        .unwrap_or_else(|e| panic!("{what}: the diagnosers refuse the model: {e}"));
    let (p, m) = (plant_path.to_str().unwrap(), model_path.to_str().unwrap());
    for verb in [
        &["check", "--plant", p, "--model", m][..],
        &["filter", "rewrite", "--plant", p, "--model", m],
    ] {
        let o = gardefou(verb);
        assert!(
            o.status.success(),
            "{what}: `{}` refuses the model: {}",
            verb[..2].join(" "),
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, ..ProptestConfig::default() })]

    #[test]
    fn every_verb_takes_the_model_learn_writes(
        seed in 1u64..400,
        family in 0usize..4,
        seconds in 5i64..300,
        run in 1u64..1000,
    ) {
        let family = Family::ALL[family];
        let plant = GeneratedPlant::generate_family(seed, Size::Small, family)
            .expect("a valid plant");
        let (model, _) = learn_briefly(&plant, seconds, run);
        let what = format!("{family} plant {seed}, {seconds} s of run {run}");
        assert_taken(&plant, &model, &what);
    }
}

/// A sensor that never changed while learning gets no temporal estimate:
/// nothing in the logs dates it, so the filter reads it as possibly
/// anything once it is declared failed.
#[test]
fn a_sensor_that_never_changed_gets_no_estimate() {
    let mut seen_still = 0;
    for (seed, family) in (1..=12).zip(Family::ALL.into_iter().cycle()) {
        let plant =
            GeneratedPlant::generate_family(seed, Size::Small, family).expect("a valid plant");
        let (model, still) = learn_briefly(&plant, 20, 7);
        let model: Model = serde_json::from_str(&model).expect("reads");
        seen_still += still;
        for part in &model.parts {
            for e in &part.sensor_estimates {
                assert!(
                    !e.intervals().is_empty(),
                    "plant {seed}: {} has an estimate that is 0 at all times",
                    e.sensor
                );
            }
        }
    }
    assert!(
        seen_still > 0,
        "no plant had a signal that never changed in 20 s"
    );
}
