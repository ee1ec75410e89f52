//! Learning the parts of the simulated sorting line, and checking runs against
//! the learned model.

use std::path::PathBuf;

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use diagnoser::model::{Model, PartModel};
use diagnoser::{MS, SECOND, Time, TimeFormat, TimeUnit};
use learning::check::check;
use learning::ingest::{LogFormat, LogStream};
use learning::learn::{LearnOptions, Learner};

fn simulate(duration: Time, seed: u64, faults: &[&str]) -> MemorySink {
    let plant = plant();
    let faults = faults
        .iter()
        .map(|f| Injection::resolve(&f.parse::<FaultSpec>().expect("spec"), &plant).expect("fault"))
        .collect();
    let mut line = SortingLine::new(SortingConfig::default());
    let mut ctl = SynthesisedControl::new(line.ids());
    let cfg = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults,
    };
    let mut sink = MemorySink::default();
    run(&mut line, &mut ctl, &cfg, &mut sink, |_| {}).expect("runs");
    sink
}

fn stream(sink: &MemorySink, name: &str) -> LogStream {
    // Several batches, as from a real file.
    let batches: Vec<_> = sink.events.chunks(1000).map(|c| Ok(c.to_vec())).collect();
    LogStream {
        path: PathBuf::from(name),
        format: LogFormat::EventsCsv,
        time: TimeFormat::Numeric(TimeUnit::Ms),
        start: sink.start,
        initial: sink.initial.clone(),
        batches: Box::new(batches.into_iter()),
        end: Default::default(),
    }
}

fn learn(sinks: &[&MemorySink]) -> Model {
    let plant = plant();
    let mut learner = Learner::new(&plant, LearnOptions::default()).expect("learner");
    for (i, s) in sinks.iter().enumerate() {
        learner
            .learn_log(stream(s, &format!("run{i}")), |_| {})
            .expect("learns");
    }
    learner.finish()
}

fn part<'m>(model: &'m Model, name: &str) -> &'m PartModel {
    model.parts.iter().find(|p| p.name == name).expect("part")
}

#[test]
fn turntable_guards_match_the_seed() {
    let model = learn(&[&simulate(3600 * SECOND, 7, &[])]);
    let tt = part(&model, "turntable");
    for t in &tt.transitions {
        eprintln!(
            "{:>16} clock {:>8} n {:>4} min {:>6} q50 {:>6} max {:>6} guard [{}, {}] timed {}",
            t.event,
            t.clock,
            t.count,
            t.guard.min,
            t.guard.q50,
            t.guard.max,
            t.guard.lo,
            t.guard.hi,
            t.timed
        );
    }
    for e in &tt.estimates {
        eprintln!(
            "{} {:?}",
            e.actuators,
            e.intervals
                .iter()
                .map(|i| (&i.name, i.from, i.to))
                .collect::<Vec<_>>()
        );
        for s in &e.sensors {
            eprintln!("   {} {:?}", s.sensor, s.values);
        }
    }
    for s in &tt.sensor_estimates {
        eprintln!("{} = {}   uncertain {:?}", s.sensor, s.expr, s.uncertain);
    }
    eprintln!("untimed: {:#?}", tt.untimed);
    let guard = |event: &str| {
        tt.transitions
            .iter()
            .find(|t| t.event == event)
            .map(|t| t.guard)
            .expect(event)
    };
    // Seed 002: FE(C4) in [~30, 130], RE(C5) in [2900, 2950] after RE(A4);
    // FE(C5) within 150, RE(C4) in [2880, 2970] after FE(A4). One scan (10 ms)
    // is the default margin.
    let within = |event: &str, lo: f64, hi: f64| {
        let g = guard(event);
        assert!(
            g.min >= lo && g.max <= hi,
            "{event}: learned [{}, {}] not within [{lo}, {hi}]",
            g.min,
            g.max
        );
        assert!(
            (g.lo - (g.min - 10.0)).abs() < 1e-9 && (g.hi - (g.max + 10.0)).abs() < 1e-9,
            "{event}: margin"
        );
    };
    within("FE(C4)", 20.0, 130.0);
    within("RE(C5)", 2900.0, 2950.0);
    within("FE(C5)", 0.0, 150.0);
    within("RE(C4)", 2880.0, 2970.0);
    let est = |s: &str| tt.sensor_estimates.iter().find(|e| e.sensor == s).expect(s);
    assert_eq!(est("C4").expr, "I1 | I2 | I9 | I10");
    assert_eq!(est("C4").uncertain, ["I2", "I9"]);
    assert_eq!(est("C5").expr, "I4 | I5 | I6 | I7");
    assert_eq!(est("C5").uncertain, ["I4", "I7"]);
}

#[test]
fn a_model_accepts_another_normal_run_and_catches_f2() {
    let model = learn(&[&simulate(4 * 3600 * SECOND, 7, &[])]);
    let plant = plant();
    let other = simulate(3600 * SECOND, 8, &[]);
    let violations = check(&model, &plant, stream(&other, "seed8")).expect("checks");
    assert_eq!(violations, vec![], "normal run rejected");

    let onset = 602 * SECOND;
    let f2 = simulate(900 * SECOND, 7, &["F2@602s"]);
    let violations = check(&model, &plant, stream(&f2, "f2")).expect("checks");
    let a4 = plant.signals.id("A4").expect("A4");
    let rise = f2
        .events
        .iter()
        .find(|e| e.signal == a4 && e.value && e.t >= onset)
        .expect("RE(A4)");
    let first = violations
        .iter()
        .find(|v| v.part == "turntable")
        .expect("turntable violation");
    eprintln!("{first:?}");
    assert!(
        first.t > rise.t && first.t <= rise.t + 150 * MS,
        "first violation at {} ms, RE(A4) at {} ms",
        first.t / MS,
        rise.t / MS
    );
    assert!(first.message.contains("FE(C4)"), "{}", first.message);
}
