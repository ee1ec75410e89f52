//! A plant's diagnosers saved between two scans (`PlantDiagnoser::snapshot`,
//! as JSON) and restored into diagnosers built afresh go on with the verdict
//! lines of an uninterrupted run: on generated plants under faults, and on
//! the shipped F2 run of the sorting line, wherever the cuts fall.
//!
//! This is what a fleet worker's checkpoint and another worker's takeover
//! rest on.

use std::sync::OnceLock;

use datasets::generated::{GeneratedPlant, Size};
use datasets::inject::Injection;
use datasets::sim::{MemorySink, SimConfig};
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Snapshot};
use diagnoser::model::Model;
use diagnoser::{Event, Plant, SECOND, TimeFormat};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use proptest::prelude::*;

use crate::support::repo;

/// One plant's case: its plant and model, a log, and the lines of an
/// uninterrupted run on it.
struct Case {
    plant: Plant,
    model: Model,
    start: i64,
    initial: Vec<bool>,
    /// The log's scans: the events at one time.
    scans: Vec<Vec<Event>>,
    lines: Vec<String>,
}

impl Case {
    fn new(plant: Plant, model: Model, log: MemorySink) -> Case {
        let mut scans: Vec<Vec<Event>> = Vec::new();
        for e in log.events {
            match scans.last_mut() {
                Some(s) if s[0].t == e.t => s.push(e),
                _ => scans.push(vec![e]),
            }
        }
        let mut case = Case {
            plant,
            model,
            start: log.start,
            initial: log.initial,
            scans,
            lines: Vec::new(),
        };
        case.lines = case.run(&[]);
        case
    }

    fn diagnoser(&self) -> PlantDiagnoser {
        PlantDiagnoser::new(&self.plant, &self.model, &DiagnoserOptions::default())
            .expect("the model fits")
    }

    /// The verdict lines of a run fed scan by scan, as the monitor feeds it
    /// (deadlines before the scan, the scan, deadlines at its time), whose
    /// diagnosers are saved and replaced by restored ones after each scan
    /// index in `cuts`.
    fn run(&self, cuts: &[usize]) -> Vec<String> {
        let time = TimeFormat::Numeric(self.plant.time_unit);
        let mut lines = Vec::new();
        let mut d = self.diagnoser();
        d.start(self.start, &self.initial);
        for (i, scan) in self.scans.iter().enumerate() {
            let t = scan[0].t;
            let mut out = |v: diagnoser::diagnosis::Verdict| lines.push(v.json_line(time, None));
            d.advance_to(t - 1, &mut out);
            for &e in scan {
                d.push(e, &mut out);
            }
            d.advance_to(t, &mut out);
            if cuts.contains(&i) {
                let saved = serde_json::to_string(&d.snapshot().expect("between scans"))
                    .expect("a snapshot serialises");
                let snapshot: Snapshot = serde_json::from_str(&saved).expect("and reads back");
                d = self.diagnoser();
                d.restore(&snapshot).expect("the snapshot fits");
            }
        }
        lines
    }
}

/// A generated plant, its model learned on two fault-free hours, and an hour
/// with its first two faults from 20 and 40 minutes.
fn generated(seed: u64) -> Case {
    let g = GeneratedPlant::generate(seed, Size::Small).expect("a plant");
    let plant = g.plant().clone();
    let config = |seed, faults| SimConfig {
        duration: 3600 * SECOND,
        scan_period: plant.scan_period,
        seed,
        faults,
    };
    let mut learner = Learner::new(&plant, LearnOptions::default()).expect("learnable");
    for run in 1..=2 {
        let (log, _) = g
            .simulate_in_memory(&config(run, Vec::new()))
            .expect("runs");
        learner
            .learn_log(stream(&plant, log), |_| {})
            .expect("a valid log");
    }
    let model = learner.finish();
    let faults = plant
        .faults
        .iter()
        .take(2)
        .zip([1200, 2400])
        .map(|(f, s)| Injection::new(f.label.clone(), f.template.clone(), s * SECOND))
        .collect();
    let (log, _) = g.simulate_in_memory(&config(7, faults)).expect("runs");
    Case::new(plant, model, log)
}

fn stream(plant: &Plant, log: MemorySink) -> LogStream {
    let time = TimeFormat::Numeric(plant.time_unit);
    LogStream::from_events("generated", time, log.start, log.initial, log.events)
}

/// The shipped F2 run of the sorting line, with the model of the fixtures.
fn shipped_f2() -> Case {
    let plant =
        Plant::from_path(repo("datasets/data/sorting/F2/plant.toml").as_ref()).expect("a plant");
    let model =
        Model::from_path(repo("diagnoser/tests/fixtures/diagnosis/sorting-model.json").as_ref())
            .expect("a model");
    let path = repo("datasets/data/sorting/F2/events.csv");
    let log = logs::open(path.as_ref(), &plant, &logs::IngestOptions::default())
        .expect("the shipped log");
    let mut sink = MemorySink::default();
    (sink.start, sink.initial) = (log.start, log.initial.clone());
    for batch in log.batches {
        sink.events.extend(batch.expect("a valid log"));
    }
    Case::new(plant, model, sink)
}

fn cases() -> &'static [Case] {
    static CASES: OnceLock<Vec<Case>> = OnceLock::new();
    CASES.get_or_init(|| {
        let mut cases = vec![shipped_f2()];
        cases.extend([3, 12, 17].map(generated));
        for c in &cases {
            assert!(
                c.lines.iter().any(|l| !l.contains("\"normal\"")),
                "{}: the case never leaves normal, so it tests little",
                c.plant.name
            );
        }
        cases
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn restored_diagnosers_go_on_with_the_lines_of_an_uninterrupted_run(
        case in 0..4usize,
        cuts in proptest::collection::vec(0.0..1.0f64, 1..64),
    ) {
        let c = &cases()[case];
        let cuts: Vec<usize> = cuts.iter().map(|f| (f * c.scans.len() as f64) as usize).collect();
        let got = c.run(&cuts);
        prop_assert!(got == c.lines, "{}: cut after scans {cuts:?}: the lines differ", c.plant.name);
    }
}

#[test]
fn a_snapshot_of_another_plant_is_refused_and_leaves_the_diagnosers_as_they_were() {
    let [f2, other, ..] = cases() else {
        unreachable!()
    };
    let mut d = other.diagnoser();
    d.start(other.start, &other.initial);
    let before = d.snapshot();
    let mut theirs = f2.diagnoser();
    theirs.start(f2.start, &f2.initial);
    let err = d
        .restore(&theirs.snapshot().expect("between scans"))
        .expect_err("the parts differ");
    assert!(err.contains("parts") || err.contains("part '"), "{err}");
    assert_eq!(d.snapshot(), before);
}

#[test]
fn diagnosers_restored_after_every_scan_give_the_lines_of_an_uninterrupted_run() {
    for c in cases() {
        let every: Vec<usize> = (0..c.scans.len()).collect();
        assert!(
            c.run(&every) == c.lines,
            "{}: the lines differ",
            c.plant.name
        );
    }
}
