//! Learning the parts of the simulated sorting line, and checking runs against
//! the learned model.

use std::path::PathBuf;

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use learning::conformance::deviations;
use learning::learn::{LearnOptions, Learner};
use logs::{LogFormat, LogStream};
use vocabulary::model::{Model, PartModel};
use vocabulary::{MS, SECOND, Time, TimeFormat, TimeUnit};

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
    let violations = deviations(&model, &plant, stream(&other, "seed8")).expect("checks");
    assert_eq!(violations, vec![], "normal run rejected");

    let onset = 602 * SECOND;
    let f2 = simulate(900 * SECOND, 7, &["F2@602s"]);
    let violations = deviations(&model, &plant, stream(&f2, "f2")).expect("checks");
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

/// One log of a cylinder `Y`→`B` whose stroke takes `stroke` ms, 40 cycles.
fn cylinder_log(stroke: i64, name: &str, plant: &vocabulary::Plant) -> LogStream {
    let (y, b) = (
        plant.signals.id("Y").expect("Y"),
        plant.signals.id("B").expect("B"),
    );
    let mut events = Vec::new();
    for k in 0..40i64 {
        let t = 1000 + k * 4000;
        for (dt, signal, value) in [
            (0, y, true),
            (stroke, b, true),
            (2000, y, false),
            (2000 + stroke, b, false),
        ] {
            events.push(vocabulary::Event {
                t: (t + dt) * MS,
                signal,
                value,
            });
        }
    }
    LogStream {
        path: PathBuf::from(name),
        format: LogFormat::EventsCsv,
        time: TimeFormat::Numeric(TimeUnit::Ms),
        start: 0,
        initial: vec![false, false],
        batches: Box::new(std::iter::once(Ok(events))),
        end: Default::default(),
    }
}

/// A plant of one cylinder `Y`→`B`, part `cyl`, with no fault declared.
fn cylinder_plant() -> vocabulary::Plant {
    vocabulary::Plant::parse(
        "name = \"c\"\nscan_period_ms = 10\n[signals]\nY = { kind = \"actuator\" }\n\
         B = { kind = \"sensor\" }\n[[parts]]\nname = \"cyl\"\nactuators = [\"Y\"]\nsensors = [\"B\"]\n",
        std::path::Path::new("c.toml"),
    )
    .expect("plant")
}

/// The cylinder's model, learned from one log per stroke.
fn cylinder_model(strokes: &[i64], drift: f64) -> Model {
    let plant = cylinder_plant();
    let options = LearnOptions {
        drift,
        ..LearnOptions::default()
    };
    let mut learner = Learner::new(&plant, options).expect("learner");
    for (i, &s) in strokes.iter().enumerate() {
        learner
            .learn_log(cylinder_log(s, &format!("run{i}"), &plant), |_| {})
            .expect("learns");
    }
    learner.finish()
}

fn stroke_guard(strokes: &[i64], drift: f64) -> vocabulary::model::Guard {
    part(&cylinder_model(strokes, drift), "cyl")
        .transitions
        .iter()
        .find(|t| t.event == "RE(B)")
        .expect("RE(B)")
        .guard
}

#[test]
fn guards_widen_by_the_drift_between_logs() {
    let close = |g: vocabulary::model::Guard, lo: f64, hi: f64| {
        assert!(
            (g.lo - lo).abs() < 0.01 && (g.hi - hi).abs() < 0.01,
            "[{}, {}], expected [{lo}, {hi}]",
            g.lo,
            g.hi
        );
    };
    // One log: one scan period of margin, no drift to see.
    close(stroke_guard(&[500], 3.0), 490.0, 510.0);
    close(stroke_guard(&[500, 520], 0.0), 490.0, 530.0);
    // Two logs 20 ms apart: a relative drift of 20/510/sqrt(2) per run, and a
    // third run's mean within 3 of them (times sqrt(1 + 1/2) for the mean's own
    // error) around 510 ms: 510 ± 51.97 ms.
    close(stroke_guard(&[500, 520], 3.0), 448.03, 571.97);
    // A third log at the same spread says the drift is smaller than two
    // suggested: a narrower guard.
    close(stroke_guard(&[500, 510, 520], 3.0), 465.36, 554.64);
}

/// A part `cyl` of one cylinder (order `Y`, end switch `B`) and one more sensor.
fn cylinder_and_sensor(sensor: &str) -> vocabulary::Plant {
    let text = format!(
        "name = \"c\"\nscan_period_ms = 10\n[signals]\nY = {{ kind = \"actuator\" }}\n\
         B = {{ kind = \"sensor\" }}\n{sensor} = {{ kind = \"sensor\" }}\n[[parts]]\n\
         name = \"cyl\"\nactuators = [\"Y\"]\nsensors = [\"B\", \"{sensor}\"]\n"
    );
    vocabulary::Plant::parse(&text, std::path::Path::new("c.toml")).expect("plant")
}

#[test]
fn a_sensor_no_order_moves_is_classified_an_input() {
    use vocabulary::model::SensorKind;
    let plant = cylinder_and_sensor("R");
    let ids = |n: &str| plant.signals.id(n).expect("signal");
    let (y, b, r) = (ids("Y"), ids("B"), ids("R"));
    let mut events = Vec::new();
    for k in 0..60i64 {
        let t = 1000 + k * 4000;
        // R (the next machine's "ready") toggles at times the cylinder does not set.
        let ready = t + (k * k * 137) % 3900;
        for (at, signal, value) in [
            (t, y, true),
            (t + 500, b, true),
            (t + 2000, y, false),
            (t + 2500, b, false),
            (ready, r, k % 2 == 0),
        ] {
            events.push(vocabulary::Event {
                t: at * MS,
                signal,
                value,
            });
        }
    }
    events.sort_by_key(|e| e.t);
    let learn = |learn_inputs: bool| {
        let options = LearnOptions {
            learn_inputs,
            ..LearnOptions::default()
        };
        let mut learner = Learner::new(&plant, options).expect("learner");
        let log = LogStream {
            path: PathBuf::from("run"),
            format: LogFormat::EventsCsv,
            time: TimeFormat::Numeric(TimeUnit::Ms),
            start: 0,
            initial: vec![false; 3],
            batches: Box::new(std::iter::once(Ok(events.clone()))),
            end: Default::default(),
        };
        learner.learn_log(log, |_| {}).expect("learns");
        learner.finish()
    };
    let model = learn(false);
    let cyl = part(&model, "cyl");
    let class = |s: &str| {
        cyl.sensor_classes
            .iter()
            .find(|c| c.sensor == s)
            .map(|c| c.class)
    };
    assert_eq!(
        class("B"),
        Some(SensorKind::Driven),
        "{:?}",
        cyl.sensor_classes
    );
    assert_eq!(
        class("R"),
        Some(SensorKind::Input),
        "{:?}",
        cyl.sensor_classes
    );
    // Reported, not applied, unless asked.
    assert!(cyl.inputs.is_empty());
    assert_eq!(part(&learn(true), "cyl").inputs, ["R"]);
}

/// A plant of one cylinder part per name pair `(Y, B)`: order `Y` drives the
/// end switch `B`.
fn cylinders_plant(cylinders: &[(&str, &str)]) -> vocabulary::Plant {
    let mut text = String::from("name = \"c\"\nscan_period_ms = 10\n[signals]\n");
    for (y, b) in cylinders {
        text += &format!("{y} = {{ kind = \"actuator\" }}\n{b} = {{ kind = \"sensor\" }}\n");
    }
    for (y, b) in cylinders {
        text += &format!("[[parts]]\nname = \"{y}\"\nactuators = [\"{y}\"]\nsensors = [\"{b}\"]\n");
    }
    vocabulary::Plant::parse(&text, std::path::Path::new("c.toml")).expect("plant")
}

/// One log of timed edges `(ms, signal, value)`, from every signal at 0.
fn log_of(plant: &vocabulary::Plant, name: &str, edges: &[(i64, &str, bool)]) -> LogStream {
    let mut events: Vec<vocabulary::Event> = edges
        .iter()
        .map(|&(t, s, value)| vocabulary::Event {
            t: t * MS,
            signal: plant.signals.id(s).expect("signal"),
            value,
        })
        .collect();
    events.sort_by_key(|e| e.t);
    LogStream {
        path: PathBuf::from(name),
        format: LogFormat::EventsCsv,
        time: TimeFormat::Numeric(TimeUnit::Ms),
        start: 0,
        initial: vec![false; plant.signals.len()],
        batches: Box::new(std::iter::once(Ok(events))),
        end: Default::default(),
    }
}

/// Strokes of cylinder `(y, b)`, one per cycle: out in `s` ms, held 1 s, back
/// in `s` ms, rest 1 s.
fn strokes(y: &'static str, b: &'static str, strokes: &[i64]) -> Vec<(i64, &'static str, bool)> {
    let mut t = 1000;
    let mut edges = Vec::new();
    for &s in strokes {
        edges.extend([(t, y, true), (t + s, b, true), (t + s + 1000, y, false)]);
        edges.push((t + 2 * s + 1000, b, false));
        t += 2 * s + 2000;
    }
    edges
}

fn learn_logs(plant: &vocabulary::Plant, logs: &[Vec<(i64, &str, bool)>]) -> Model {
    let mut learner = Learner::new(plant, LearnOptions::default()).expect("learner");
    for (i, edges) in logs.iter().enumerate() {
        learner
            .learn_log(log_of(plant, &format!("run{i}"), edges), |_| {})
            .expect("learns");
    }
    learner.finish()
}

fn transition<'m>(part: &'m PartModel, event: &str) -> &'m vocabulary::model::TransitionModel {
    part.transitions
        .iter()
        .find(|t| t.event == event)
        .unwrap_or_else(|| panic!("no {event} in {:?}", part.transitions))
}

#[test]
fn a_guard_reaches_beyond_its_extremes_as_far_as_its_tails_do() {
    let plant = cylinders_plant(&[("Y", "B")]);
    // 40 strokes: 470 and 480, 36 at 500, 520 and 530 ms.
    let mut s = vec![470, 480, 520, 530];
    s.extend([500; 36]);
    let model = learn_logs(&plant, &[strokes("Y", "B", &s)]);
    let g = transition(part(&model, "Y"), "RE(B)").guard;
    // The extremes' distance to the next samples (10 ms), and one scan.
    assert_eq!((g.lo, g.hi), (450.0, 550.0), "{g:?}");
}

#[test]
fn a_transition_with_far_outliers_follows_the_product_flow() {
    let plant = cylinders_plant(&[("Y", "B")]);
    let mut s = vec![500; 196];
    s.extend([510, 510, 3000, 3200]);
    let model = learn_logs(&plant, &[strokes("Y", "B", &s)]);
    let cyl = part(&model, "Y");
    let rise = transition(cyl, "RE(B)");
    assert!(!rise.timed, "{rise:?}");
    assert!(
        cyl.untimed
            .iter()
            .any(|u| u.starts_with("RE(B)") && u.contains("waits for the product flow")),
        "{:?}",
        cyl.untimed
    );
    // The same strokes without the outliers keep their time.
    let model = learn_logs(&plant, &[strokes("Y", "B", &[500; 200])]);
    assert!(transition(part(&model, "Y"), "RE(B)").timed);
}

#[test]
fn a_transition_seen_in_one_log_only_drifts_as_the_plants_others_do() {
    let plant = cylinders_plant(&[("Y1", "B1"), ("Y2", "B2")]);
    // Cylinder 1 strokes in 500 ms in one log and 520 in the other: a drift
    // between runs of 20/510/sqrt(2). Cylinder 2 moves in the first log only.
    let mut first = strokes("Y1", "B1", &[500; 40]);
    first.extend(strokes("Y2", "B2", &[500; 40]));
    let second = strokes("Y1", "B1", &[520; 40]);
    let model = learn_logs(&plant, &[first, second]);
    let g = transition(part(&model, "Y2"), "RE(B2)").guard;
    // Three deviations of that drift, times sqrt(2) for the one log's own
    // error, around 500 ms, and one scan: 500 ± (58.81 + 10) ms.
    let half = 3.0 * (200.0f64 / (510.0 * 510.0)).sqrt() * 500.0 * 2f64.sqrt() + 10.0;
    assert!(
        (g.lo - (500.0 - half)).abs() < 0.01 && (g.hi - (500.0 + half)).abs() < 0.01,
        "{g:?}, expected 500 ± {half}"
    );
}

/// Cycles of cylinder `(Y, B)` where the control withdraws the order before
/// the stroke ends at the times `withdrawn` (ms after the order, one cycle
/// each; with `edge`, in the scan a sensor `C` rises), between full strokes of
/// 3 s.
fn withdrawals(withdrawn: &[i64], edge: bool) -> Vec<(i64, &'static str, bool)> {
    let mut t = 1000;
    let mut edges = Vec::new();
    for &w in withdrawn {
        edges.extend(
            strokes("Y", "B", &[3000])
                .iter()
                .map(|&(at, s, v)| (at - 1000 + t, s, v)),
        );
        t += 8000;
        edges.extend([(t, "Y", true), (t + w, "Y", false)]);
        if edge {
            edges.extend([(t + w, "C", true), (t + w + 500, "C", false)]);
        }
        t += 4000;
    }
    edges
}

#[test]
fn an_order_at_no_regular_time_leaves_its_state_without_deadline() {
    let plant = cylinder_and_sensor("C");
    let moving = |model: &Model| {
        let cyl = part(model, "cyl");
        let state = cyl
            .states
            .iter()
            .find(|s| s.values == [true, false, false])
            .expect("the stroke's state");
        state
            .expected
            .iter()
            .map(|e| (e.event.clone(), e.by))
            .collect::<Vec<_>>()
    };
    // Withdrawn at any time from 0.2 to 2.8 s: the control waits for
    // something outside the part.
    let any: Vec<i64> = (0..30).map(|k| 200 + k * 2600 / 29).collect();
    assert_eq!(moving(&learn_logs(&plant, &[withdrawals(&any, false)])), []);
    // Withdrawn by a timer after 1.5 s: the stroke's end, or the timer.
    let timer = learn_logs(&plant, &[withdrawals(&[1500; 30], false)]);
    let expected = moving(&timer);
    assert_eq!(expected.len(), 2, "{expected:?}");
    assert!(
        expected.contains(&("FE(Y)".to_string(), 1510.0)),
        "{expected:?}"
    );
    // Withdrawn at any time, in the scan C rises: the control reacts to an edge
    // of the product flow, as late as it was seen to (2.8 s, and as far again
    // as the 2.71 s before it, and one scan).
    let expected = moving(&learn_logs(&plant, &[withdrawals(&any, true)]));
    assert!(
        expected.contains(&("FE(Y) RE(C)".to_string(), 2900.0)),
        "{expected:?}"
    );
}

/// Cycles of cylinder `(Y, B)` with a workpiece sensor `C` that rises 300 ms
/// after the stroke's end in the cycles `k` where `regular(k)`, and at no
/// regular time while the cylinder rests in the others.
fn arrivals(regular: impl Fn(i64) -> bool) -> Vec<(i64, &'static str, bool)> {
    let mut edges = Vec::new();
    for k in 0..60i64 {
        let t = 1000 + k * 4000;
        edges.extend([(t, "Y", true), (t + 500, "B", true), (t + 1500, "Y", false)]);
        edges.push((t + 2000, "B", false));
        let arrival = if regular(k) {
            t + 800
        } else {
            t + 2100 + (k * k * 137) % 1500
        };
        edges.extend([(arrival, "C", true), (t + 3950, "C", false)]);
    }
    edges
}

#[test]
fn an_edge_that_often_follows_the_product_flow_is_never_timed() {
    let plant = cylinder_and_sensor("C");
    let during_stroke = |model: &Model| {
        let cyl = part(model, "cyl");
        let from = cyl
            .states
            .iter()
            .find(|s| s.values == [true, true, false])
            .expect("the stroke's end")
            .id;
        let t = cyl
            .transitions
            .iter()
            .find(|t| t.from == from && t.event == "RE(C)")
            .expect("a workpiece during the stroke")
            .clone();
        (t, cyl.untimed.clone())
    };
    // One workpiece in three comes 300 ms after the stroke's end, the others
    // whenever they come: that regularity was the flow's.
    let (t, untimed) = during_stroke(&learn_logs(&plant, &[arrivals(|k| k % 3 == 0)]));
    assert!(!t.timed, "{t:?}");
    assert!(
        untimed
            .iter()
            .any(|u| u.starts_with("RE(C)") && u.contains("follows the product flow")),
        "{untimed:?}"
    );
    // Two in three 300 ms after the stroke's end, but the third often enough
    // (20 times) whenever it comes: a late one may be one of those.
    let (t, _) = during_stroke(&learn_logs(&plant, &[arrivals(|k| k % 3 != 0)]));
    assert!(!t.timed, "{t:?}");
    // All but two 300 ms after the stroke's end: too few to judge, timed.
    let (t, _) = during_stroke(&learn_logs(&plant, &[arrivals(|k| k % 30 != 0)]));
    assert!(t.timed, "{t:?}");
    // Every workpiece 300 ms after the stroke's end: the part's own timing.
    let (t, _) = during_stroke(&learn_logs(&plant, &[arrivals(|_| true)]));
    assert!(t.timed, "{t:?}");
}

/// Whether the diagnosers leave "normal" on `log`.
fn diagnosers_object(plant: &vocabulary::Plant, model: &Model, log: LogStream) -> bool {
    use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, VerdictKind};
    let mut diagnoser =
        PlantDiagnoser::new(plant, model, &DiagnoserOptions::default()).expect("diagnoser");
    let mut objected = false;
    let mut out = |v: diagnoser::diagnosis::Verdict| objected |= v.verdict != VerdictKind::Normal;
    diagnoser.start(log.start, &log.initial);
    let mut last = log.start;
    for batch in log.batches {
        for e in batch.expect("events") {
            last = e.t;
            diagnoser.push(e, &mut out);
        }
    }
    diagnoser.finish(last + SECOND, &mut out);
    objected
}

#[test]
fn the_model_check_and_the_diagnosers_agree_on_a_guards_last_nanosecond() {
    // Strokes of 600 ms against guards that end 0.4 ns and 0.6 ns before
    // 600 ms: read in nanoseconds, the first ends at 600 ms (on time), the
    // second 1 ns before (late). Both readers of the model must say the same.
    let plant = cylinder_plant();
    for (hi_ns, late) in [(600e6 - 0.4, false), (600e6 - 0.6, true)] {
        let mut model = cylinder_model(&[500], 3.0);
        for t in &mut model.parts[0].transitions {
            if t.event.ends_with("(B)") {
                t.guard.hi = hi_ns / 1e6;
            }
        }
        let log = || cylinder_log(600, "at the boundary", &plant);
        let deviations = deviations(&model, &plant, log()).expect("checks");
        assert_eq!(!deviations.is_empty(), late, "{:?}", deviations.first());
        assert_eq!(diagnosers_object(&plant, &model, log()), late);
    }
}
