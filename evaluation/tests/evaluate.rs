//! The benchmark's machinery on real generated plants: branched faulty runs
//! are the runs with the fault from the start, and one plant goes through the
//! whole chain with sensible figures.

use datasets::generated::{Family, GeneratedPlant, Size};
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
        .map(|i| {
            Injection::new(
                plant.faults[i].label.clone(),
                plant.faults[i].template.clone(),
                onsets[i],
            )
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

fn memory(log: &evaluation::runs::Log) -> MemorySink {
    let mut sink = MemorySink::default();
    sink.start = log.start;
    sink.initial = log.initial.clone();
    sink.events = log.events.clone();
    sink
}

fn as_log(sink: &MemorySink, end: diagnoser::Time) -> evaluation::runs::Log {
    evaluation::runs::Log {
        start: sink.start,
        initial: sink.initial.clone(),
        events: sink.events.clone(),
        end,
    }
}

/// A false alarm on purpose on a generated plant (an unexplained scan), then
/// a real stuck sensor of the same part five minutes later: the part is
/// `unknown` for an episode, raises no flag, is back to normal before the
/// fault, and ends on the same verdict as without the false alarm. Tried on
/// the first stuck sensors, of parts with two sensors or more, that the
/// diagnosers isolate without the false alarm.
#[test]
fn on_a_generated_plant_a_fault_after_an_unknown_episode_is_still_labelled() {
    use diagnoser::diagnosis::{PlantDiagnoser, VerdictKind};
    use evaluation::judge::{part_of, replay};

    let onset = 900 * SECOND;
    let mut tried = 0;
    for seed in 1..=12 {
        let g = GeneratedPlant::generate(seed, Size::Small).expect("a plant");
        let plant = g.plant();
        let mut diagnoser = learned_diagnoser(&g, 3);
        let stuck: Vec<Injection> = plant
            .faults
            .iter()
            .filter(|f| f.template.to_string().starts_with("stuck"))
            .map(|f| Injection::new(f.label.clone(), f.template.clone(), onset))
            .collect();
        faulty_runs(&g, FAULT_SEED, &stuck, 300 * SECOND, |run| {
            let part_name = part_of(plant, &run.fault.template).expect("a part");
            let part = plant
                .parts
                .iter()
                .find(|p| p.name == part_name)
                .expect("part");
            if part.sensors.len() < 2 || tried >= 3 {
                return;
            }
            let own = |log: &evaluation::runs::Log, d: &mut PlantDiagnoser| {
                let all = replay(d, log);
                all.into_iter()
                    .filter(|v| v.part == part_name)
                    .collect::<Vec<_>>()
            };
            let plain = own(&run.log, &mut diagnoser);
            let isolated = plain.first().is_some_and(|v| v.t >= onset)
                && plain.last().is_some_and(|v| {
                    v.verdict == VerdictKind::Certain && v.labels == [run.fault.label.clone()]
                });
            if !isolated {
                return;
            }
            let (sink, at) = datasets::inject::with_unexplained_scan(
                &memory(&run.log),
                &part.sensors,
                onset - 300 * SECOND,
                plant.scan_period,
            );
            let verdicts = own(&as_log(&sink, run.log.end), &mut diagnoser);
            // A fault may explain the flips, e.g. a stuck order that moves the
            // part into a state the model never saw, where it cannot judge the
            // sensors: those scans are not ones that no fault explains, so they
            // test nothing here.
            if !verdicts
                .iter()
                .any(|v| v.labels == ["unknown"] && v.t <= at + plant.scan_period)
            {
                return;
            }
            tried += 1;
            let what = format!("plant {seed}, {} at {at}: {verdicts:#?}", run.fault.label);
            // The flipped sensors may first read as a fault; flipping back is
            // explained by none.
            assert_eq!(verdicts.first().map(|v| v.t), Some(at), "{what}");
            let unknown = verdicts
                .iter()
                .find(|v| v.labels == ["unknown"])
                .unwrap_or_else(|| panic!("no unknown episode: {what}"));
            assert!(unknown.t <= at + plant.scan_period, "{what}");
            let back = verdicts
                .iter()
                .find(|v| v.verdict == VerdictKind::Normal)
                .unwrap_or_else(|| panic!("never back to normal: {what}"));
            assert!(back.t < onset, "{what}");
            assert!(
                verdicts
                    .iter()
                    .filter(|v| v.t < onset)
                    .all(|v| v.flags.is_empty()),
                "{what}"
            );
            let (last, expected) = (
                verdicts.last().expect("verdicts"),
                plain.last().expect("verdicts"),
            );
            assert_eq!(
                (&last.labels, &last.flags),
                (&expected.labels, &expected.flags),
                "{what}"
            );
        })
        .expect("runs");
        if tried >= 3 {
            return;
        }
    }
    panic!("only {tried} isolated stuck sensors found to try");
}

/// A healthy plant's sensor that bounces once (a splash on a level switch, a
/// contact that chatters), something the learning logs never showed: the
/// part may leave normal, but it raises no `def_` flag, and it is back to
/// normal after a cycle. Nothing but elimination would make a fault certain.
#[test]
fn on_a_healthy_generated_plant_an_unseen_glitch_gives_no_flag() {
    use diagnoser::diagnosis::VerdictKind;
    use diagnoser::{Event, Time};
    use evaluation::judge::replay;

    let mut tried = std::collections::HashMap::new();
    let plants = (1..=8).map(|seed| (Family::Process, seed));
    for (family, seed) in plants.chain((1..=10).map(|seed| (Family::Assembly, seed))) {
        if tried.get(&family).is_some_and(|&n| n >= 2) {
            continue;
        }
        let g = GeneratedPlant::generate_family(seed, Size::Small, family).expect("a plant");
        let plant = g.plant();
        let mut diagnoser = learned_diagnoser(&g, 2);
        let fresh = evaluation::runs::fault_free(&g, 100, 1200 * SECOND).expect("runs");
        let healthy = replay(&mut diagnoser, &fresh);
        if !healthy.is_empty() {
            continue; // a false alarm of its own: not what this tests
        }
        // Each part's busiest sensor bounces for two scans, in the middle of
        // a stretch of at least a second where it keeps its value.
        for part in &plant.parts {
            let Some(&sensor) = part
                .sensors
                .iter()
                .max_by_key(|&&s| fresh.events.iter().filter(|e| e.signal == s).count())
            else {
                continue;
            };
            let edges: Vec<Time> = (fresh.events.iter())
                .filter(|e| e.signal == sensor)
                .map(|e| e.t)
                .collect();
            let Some(at) = edges
                .windows(2)
                .filter(|w| w[1] - w[0] > 2 * SECOND && w[0] > 600 * SECOND)
                .map(|w| (w[0] + w[1]) / 2 / plant.scan_period * plant.scan_period)
                .next()
            else {
                continue;
            };
            let value = (fresh.events.iter())
                .rev()
                .find(|e| e.signal == sensor && e.t < at)
                .map_or(fresh.initial[sensor.index()], |e| e.value);
            let mut glitched = fresh.clone();
            let back = at + 2 * plant.scan_period;
            for (t, v) in [(at, !value), (back, value)] {
                glitched.events.push(Event {
                    t,
                    signal: sensor,
                    value: v,
                });
            }
            glitched.events.sort_by_key(|e| (e.t, e.signal));
            let verdicts = replay(&mut diagnoser, &glitched);
            let own: Vec<_> = verdicts.iter().filter(|v| v.part == part.name).collect();
            let what = format!(
                "{family} plant {seed}, {} bouncing at {at} ns: {own:#?}",
                plant.signals.name(sensor)
            );
            assert!(
                verdicts.iter().all(|v| v.flags.is_empty()),
                "a def_ flag on a healthy plant: {what}"
            );
            if own.is_empty() {
                continue; // the bounce fitted the model
            }
            *tried.entry(family).or_insert(0) += 1;
            let last = own.last().expect("verdicts");
            assert_eq!(last.verdict, VerdictKind::Normal, "{what}");
            assert!(last.reason.starts_with("back to normal"), "{what}");
        }
    }
    for family in [Family::Process, Family::Assembly] {
        let n = tried.get(&family).copied().unwrap_or(0);
        assert!(
            n >= 2,
            "only {n} bounces left normal on {family} plants: too few tried"
        );
    }
}

/// Every fault a generated plant of any family declares is judged on a
/// part: `slow` of an actuator as well as of an element.
#[test]
fn every_declared_fault_has_its_part() {
    use datasets::generated::Family;
    use evaluation::judge::part_of;
    for family in Family::ALL {
        for seed in 1..=4 {
            let g = GeneratedPlant::generate_family(seed, Size::Small, family).expect("a plant");
            for f in &g.plant().faults {
                assert!(
                    part_of(g.plant(), &f.template).is_some(),
                    "{family} plant {seed}: {} has no part",
                    f.label
                );
            }
        }
    }
}

/// The diagnosers of `g` learned from `runs` fault-free hours (run seeds 1, 2, …).
fn learned_diagnoser(g: &GeneratedPlant, runs: u64) -> diagnoser::diagnosis::PlantDiagnoser {
    use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
    use learning::learn::{LearnOptions, Learner};
    use logs::LogStream;

    let mut learner = Learner::new(g.plant(), LearnOptions::default()).expect("learner");
    for run_seed in 1..=runs {
        let log = evaluation::runs::fault_free(g, run_seed, 3600 * SECOND).expect("runs");
        let stream = LogStream::from_events(
            "memory",
            diagnoser::TimeFormat::Numeric(diagnoser::TimeUnit::Ms),
            log.start,
            log.initial,
            log.events,
        );
        learner.learn_log(stream, |_| {}).expect("learns");
    }
    let model = learner.finish();
    PlantDiagnoser::new(g.plant(), &model, &DiagnoserOptions::default()).expect("diagnoser")
}
