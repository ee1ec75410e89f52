//! Behaviour of the simulated four-cylinder rig: the plant file, normal operation
//! under seed 001's control by constraints, the damage monitor, and the visible
//! effect of faults.

use datasets::cylinders::{
    ConstraintControl, CylinderConfig, CylinderIds, CylinderRig, PLANT_TOML, Step, plant,
};
use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{Controller, MemorySink, Physics, SimConfig, SimReport, run};
use vocabulary::expr::Expr;
use vocabulary::{MS, SECOND, Time};

fn injections(faults: &[&str]) -> Vec<Injection> {
    let plant = plant();
    faults
        .iter()
        .map(|f| {
            let spec: FaultSpec = f.parse().expect("valid fault spec");
            Injection::resolve(&spec, &plant).expect("known fault")
        })
        .collect()
}

fn simulate_rig<C: Controller>(
    mut rig: CylinderRig,
    duration: Time,
    seed: u64,
    faults: &[&str],
    control: impl FnOnce(CylinderIds) -> C,
) -> (SimReport, MemorySink) {
    let mut ctl = control(rig.ids());
    let cfg = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults: injections(faults),
    };
    let mut sink = MemorySink::default();
    let report = run(&mut rig, &mut ctl, &cfg, &mut sink, |_| {}).expect("in-memory run");
    (report, sink)
}

fn simulate(duration: Time, seed: u64, faults: &[&str]) -> (SimReport, MemorySink) {
    simulate_rig(
        CylinderRig::new(CylinderConfig::default()),
        duration,
        seed,
        faults,
        ConstraintControl::new,
    )
}

fn counter(report: &SimReport, name: &str) -> u64 {
    report
        .counters
        .iter()
        .find(|(n, _)| n == name)
        .map_or(0, |(_, v)| *v)
}

fn id(name: &str) -> usize {
    // Parsed once: `eval` looks names up for every state of an hour-long log.
    static PLANT: std::sync::OnceLock<vocabulary::Plant> = std::sync::OnceLock::new();
    PLANT
        .get_or_init(plant)
        .signals
        .id(name)
        .expect("signal exists")
        .index()
}

/// Calls `f(t, previous values, values)` for the first scan and after each group of
/// simultaneous changes: the log's values between two changes are constant, so this
/// visits every distinct state and every edge.
fn replay(sink: &MemorySink, mut f: impl FnMut(Time, &[bool], &[bool])) {
    let mut values = sink.initial.clone();
    f(sink.start, &values, &values);
    let mut i = 0;
    while i < sink.events.len() {
        let t = sink.events[i].t;
        let before = values.clone();
        while i < sink.events.len() && sink.events[i].t == t {
            values[sink.events[i].signal.index()] = sink.events[i].value;
            i += 1;
        }
        f(t, &before, &values);
    }
}

/// Times at which `signal` rose.
fn rises(sink: &MemorySink, signal: &str) -> Vec<Time> {
    let s = id(signal);
    sink.events
        .iter()
        .filter(|e| e.signal.index() == s && e.value)
        .map(|e| e.t)
        .collect()
}

/// Values of every signal after the last scan.
fn last_values(sink: &MemorySink) -> Vec<bool> {
    let mut values = sink.initial.clone();
    for e in &sink.events {
        values[e.signal.index()] = e.value;
    }
    values
}

/// Evaluates a constraint over signals only, on one scan and the one before.
fn eval(e: &Expr, prev: &[bool], cur: &[bool]) -> bool {
    match e {
        Expr::Const(b) => *b,
        Expr::Var(n) => cur[id(n)],
        Expr::Rise(n) => cur[id(n)] && !prev[id(n)],
        Expr::Fall(n) => !cur[id(n)] && prev[id(n)],
        Expr::Prev(n) => prev[id(n)],
        Expr::Not(x) => !eval(x, prev, cur),
        Expr::And(xs) => xs.iter().all(|x| eval(x, prev, cur)),
        Expr::Or(xs) => xs.iter().any(|x| eval(x, prev, cur)),
    }
}

#[test]
fn shipped_plant_file_parses_with_the_seed_constraints() {
    let p = vocabulary::Plant::parse(PLANT_TOML, std::path::Path::new("cylinders.toml"))
        .expect("valid plant file");
    assert_eq!(p.name, "cylinders");
    assert_eq!(p.scan_period, 10 * MS);
    assert_eq!(p.time_unit, vocabulary::TimeUnit::Ms);
    assert_eq!(p.signals.len(), 16);
    assert_eq!(p.variables, ["X1", "X11", "X21", "X31"]);
    assert_eq!(p.parts.len(), 4);
    let simple = p
        .constraints
        .iter()
        .filter(|c| c.name.starts_with("CSs") && c.priority.is_none())
        .count();
    let combined: Vec<_> = p
        .constraints
        .iter()
        .filter(|c| c.name.starts_with("CSc"))
        .collect();
    assert_eq!((simple, combined.len(), p.constraints.len()), (12, 4, 16));
    assert_eq!(p.functional.len(), 4);
    // The controller applies the priorities the plant file declares.
    let ids = CylinderIds::resolve(&p).expect("the rig's signals");
    assert_eq!(ids.combined, [(0, 1), (1, 2), (2, 3), (3, 0)]);
    assert_eq!(
        combined
            .iter()
            .map(|c| p.signals.name(c.priority.expect("priority")))
            .collect::<Vec<_>>(),
        ["Q9", "Q10", "Q11", "Q12"]
    );
    // Every template kind for cylinder 1, and the four rod faults.
    for template in [
        "stuck0(Se0)",
        "stuck1(Se0)",
        "unexpected_rise(Se1)",
        "unexpected_fall(Se1)",
        "stuck1(I13)",
        "actuator_stuck0(Q9)",
        "actuator_stuck1(Q9)",
        "blocked_at(V1, Se0)",
        "blocked_at(V1, Se1)",
        "blocked_between(V1, Se0, Se1)",
        "blocked_between(V1, Se1, Se0)",
    ] {
        let f = p
            .faults
            .iter()
            .find(|f| f.template.to_string() == template)
            .expect(template);
        assert!(
            p.partition_of(&f.label).is_some(),
            "{template} has no partition"
        );
    }
    assert_eq!(
        p.partition_of("V1.blocked_between.Se0.Se1")
            .map(|x| x.name.as_str()),
        Some("V1")
    );
    assert_eq!(
        p.partition_of("Se0.stuck1").map(|x| x.name.as_str()),
        Some("Se0")
    );
    // Every fault belongs to exactly one partition (the parser rejects duplicates).
    assert!(p.faults.iter().all(|f| p.partition_of(&f.label).is_some()));
}

#[test]
fn an_hour_of_default_control_is_safe_and_moves_objects_round() {
    let started = std::time::Instant::now();
    let (report, sink) = simulate(3600 * SECOND, 7, &[]);
    eprintln!("one simulated hour took {:?}", started.elapsed());
    assert_eq!(report.damage, vec![], "damage under the default control");
    assert_eq!(counter(&report, "objects_lost"), 0);
    let moves = counter(&report, "moves");
    assert!(moves > 1000, "only {moves} moves");
    for s in ["Se1", "Sf1", "Sg1", "Sh1"] {
        let n = rises(&sink, s).len() as u64;
        // The objects go round: every cylinder does about a quarter of the moves.
        assert!(
            n * 4 + 8 >= moves && n * 4 <= moves + 8,
            "{s} rose {n} times for {moves} moves"
        );
    }
    // The control keeps every safety constraint at 0 in every scan.
    let p = plant();
    let mut states = 0;
    replay(&sink, |t, prev, cur| {
        states += 1;
        for c in &p.constraints {
            assert!(
                !eval(&c.expr, prev, cur),
                "{} = {} violated at {} ms",
                c.name,
                c.expr,
                t / MS
            );
        }
    });
    assert!(states > 4000);
}

#[test]
fn stroke_times_follow_the_configuration() {
    let (_, sink) = simulate(600 * SECOND, 5, &[]);
    let (q9, se0, se1) = (id("Q9"), id("Se0"), id("Se1"));
    let mut order: Option<(bool, Time)> = None;
    let mut checked = 0;
    for e in &sink.events {
        if e.signal.index() == q9 {
            order = Some((e.value, e.t));
            continue;
        }
        let Some((on, t0)) = order else { continue };
        let dt = (e.t - t0) / MS;
        // The switches change at 98 % of the stroke, seen at the next 10 ms scan.
        match (on, e.signal.index(), e.value) {
            (true, s, true) if s == se1 => {
                assert!((880..=1090).contains(&dt), "RE(Se1) {dt} ms after RE(Q9)")
            }
            (false, s, true) if s == se0 => {
                assert!((580..=800).contains(&dt), "RE(Se0) {dt} ms after FE(Q9)")
            }
            _ => continue,
        }
        checked += 1;
    }
    assert!(checked > 50, "only {checked} strokes checked");
}

#[test]
fn same_seed_same_log_and_different_seed_different_log() {
    let (_, a) = simulate(300 * SECOND, 11, &[]);
    let (_, b) = simulate(300 * SECOND, 11, &[]);
    let (_, c) = simulate(300 * SECOND, 12, &[]);
    assert_eq!(a.events, b.events);
    assert_ne!(a.events, c.events);
}

#[test]
fn every_placement_of_three_objects_runs_safely() {
    for corners in [[1, 2, 3], [2, 3, 4], [3, 4, 1], [4, 1, 2]] {
        let rig = CylinderRig::new(CylinderConfig::default())
            .with_objects(&corners)
            .expect("valid corners");
        let (report, _) = simulate_rig(rig, 300 * SECOND, 3, &[], ConstraintControl::new);
        assert_eq!(report.damage, vec![], "objects at {corners:?}");
        assert!(
            counter(&report, "moves") > 100,
            "objects at {corners:?}: {:?}",
            report.counters
        );
    }
}

#[test]
fn bad_placements_are_refused() {
    let rig = || CylinderRig::new(CylinderConfig::default());
    assert!(rig().with_objects(&[0]).is_err());
    assert!(rig().with_objects(&[5]).is_err());
    assert!(rig().with_objects(&[2, 2]).is_err());
    let empty = rig().with_objects(&[]).expect("an empty rig is valid");
    assert!(empty.objects().is_empty());
}

/// Orders cylinders 1 and 2 out together, whatever the constraints say.
struct Reckless(CylinderIds);

impl Controller for Reckless {
    fn scan(&mut self, _t: Time, io: &mut [bool]) {
        for (k, &q) in self.0.extend.iter().enumerate() {
            io[q] = k < 2;
        }
    }
}

#[test]
fn damage_monitor_fires_when_constraints_are_ignored() {
    let (report, _) = simulate_rig(
        CylinderRig::new(CylinderConfig::default()),
        10 * SECOND,
        7,
        &[],
        Reckless,
    );
    let causes: Vec<&str> = report.damage.iter().map(|d| d.cause).collect();
    assert!(
        causes.contains(&"rod_collision"),
        "damage: {:?}",
        report.damage
    );
    // Cylinder 2 pushed the object at corner 2 into the one at corner 3.
    assert!(
        causes.contains(&"object_collision"),
        "damage: {:?}",
        report.damage
    );
    assert_eq!(counter(&report, "objects_lost"), 1);
    // Each incident is recorded once, not once per scan.
    assert!(report.damage.len() <= 4, "damage: {:?}", report.damage);
    assert!(report.damage.iter().all(|d| d.t > 0));
}

#[test]
fn grafcet_and_combined_constraints() {
    let rig = CylinderRig::new(CylinderConfig::default());
    let ids = rig.ids();
    let mut ctl = ConstraintControl::new(ids);
    // Every output requested: the priorities form a cycle, each output yields to
    // its upstream neighbour, and all four end off (safe by H3). Figure 3 judges
    // every combined constraint on the requests of the previous pass, so Q12
    // yields to Q11 even though Q11 itself yields to Q10.
    assert_eq!(ctl.combine([true; 4]), [false; 4]);
    assert_eq!(
        ctl.combine([false, true, true, true]),
        [false, true, false, false]
    );
    assert_eq!(
        ctl.combine([true, false, true, false]),
        [true, false, true, false]
    );
    assert_eq!(
        ctl.combine([false, false, true, true]),
        [false, false, true, false]
    );

    // Objects at corners 1, 2, 3: only cylinder 3 may go (corner 4 is free).
    let mut io = vec![false; rig.plant().signals.len()];
    rig.read_sensors(&mut io);
    ctl.scan(0, &mut io);
    assert_eq!(
        ctl.steps(),
        [Step::Extend, Step::Extend, Step::Extend, Step::Idle]
    );
    assert_eq!(ctl.requested(), [true, true, true, false]);
    assert_eq!(ids.extend.map(|i| io[i]), [false, false, true, false]);
}

#[test]
fn stuck1_on_se0_keeps_it_on_while_the_rod_is_out() {
    let onset = 30 * SECOND;
    let (_, sink) = simulate(120 * SECOND, 7, &["Se0.stuck1@30s"]);
    let (se0, se1) = (id("Se0"), id("Se1"));
    let mut both_before = 0;
    let mut both_after = 0;
    replay(&sink, |t, _, v| {
        if t >= onset {
            assert!(v[se0], "Se0 fell at {} ms despite being stuck at 1", t / MS);
            if v[se1] {
                both_after += 1;
            }
        } else if v[se0] && v[se1] {
            both_before += 1;
        }
    });
    assert_eq!(
        both_before, 0,
        "a healthy Se0 and Se1 are never on together"
    );
    // The rod still moves: ordered out after the onset, it reached Se1.
    let out = *rises(&sink, "Q9")
        .iter()
        .find(|&&t| t >= onset)
        .expect("Q9 ordered after the onset");
    assert!(
        rises(&sink, "Se1").iter().any(|&t| t > out),
        "cylinder 1 never got out after the onset"
    );
    assert!(
        both_after > 0,
        "Se0 and Se1 never seen on together after the onset"
    );
}

#[test]
fn actuator_stuck0_on_q9_means_se1_never_rises_after_q9() {
    // With seed 7, cylinder 1 is at rest at 25 s (a fault in mid-stroke would
    // leave the order on, and no rise of Q9 to look after).
    let onset = 25 * SECOND;
    let (_, sink) = simulate(120 * SECOND, 7, &["Q9.actuator_stuck0@25s"]);
    let q9_rises: Vec<Time> = rises(&sink, "Q9")
        .into_iter()
        .filter(|&t| t >= onset)
        .collect();
    let first = *q9_rises.first().expect("Q9 was ordered after the onset");
    assert!(
        rises(&sink, "Se1").iter().all(|&t| t < first),
        "Se1 rose after Q9 rose at {} ms",
        first / MS
    );
    assert!(
        rises(&sink, "Se1").iter().any(|&t| t < onset),
        "cylinder 1 worked before the onset"
    );
    // CSs3 holds the order: the rig waits for Se1 forever.
    let end = last_values(&sink);
    assert!(end[id("Q9")] && !end[id("Se1")] && end[id("Se0")]);
}

#[test]
fn blocked_between_on_v1_leaves_both_switches_off() {
    let onset = 30 * SECOND;
    let (report, sink) = simulate(120 * SECOND, 7, &["V1.blocked_between.Se0.Se1@30s"]);
    let first = *rises(&sink, "Q9")
        .iter()
        .find(|&&t| t >= onset)
        .expect("Q9 was ordered after the onset");
    let (se0, se1) = (id("Se0"), id("Se1"));
    // From about half a stroke after the order on, the rod is stuck half-way.
    let settled = first + 600 * MS;
    replay(&sink, |t, _, v| {
        if t >= settled {
            assert!(
                !v[se0] && !v[se1],
                "a switch of cylinder 1 is on at {} ms",
                t / MS
            );
        }
    });
    let end = last_values(&sink);
    assert!(!end[se0] && !end[se1] && end[id("Q9")]);
    assert_eq!(report.damage, vec![]);
}

#[test]
fn blocked_at_keeps_the_rod_at_its_end() {
    let (_, sink) = simulate(60 * SECOND, 7, &["blocked_at(V3, Sg0)@0s"]);
    // Cylinder 3 is ordered out in the first scan (corner 4 is free) and never
    // leaves its retracted end; CSs9 holds the order.
    assert!(sink.initial[id("Q11")] && sink.initial[id("Sg0")]);
    assert!(!sink.events.iter().any(|e| e.signal.index() == id("Sg0")));
    assert!(last_values(&sink)[id("Q11")]);
    let (_, sink) = simulate(60 * SECOND, 7, &["blocked_at(V3, Sg1)@0s"]);
    let end = last_values(&sink);
    assert!(end[id("Sg1")] && !end[id("Sg0")] && !end[id("Q11")]);
}

#[test]
fn rod_faults_on_other_sensors_are_refused() {
    let plant = plant();
    // The plant file accepts it (I13 is a sensor of cylinder 1) but a rod has no
    // position sensed by a presence sensor.
    let spec: FaultSpec = "blocked_at(V1, I13)@1s".parse().expect("spec");
    let fault = Injection::resolve(&spec, &plant).expect("resolves against the plant file");
    let mut rig = CylinderRig::new(CylinderConfig::default());
    let mut ctl = ConstraintControl::new(rig.ids());
    let cfg = SimConfig {
        duration: 2 * SECOND,
        scan_period: 10 * MS,
        seed: 1,
        faults: vec![fault],
    };
    let err =
        run(&mut rig, &mut ctl, &cfg, &mut MemorySink::default(), |_| {}).expect_err("refused");
    assert!(err.to_string().contains("I13"), "{err}");
    let spec: FaultSpec = "blocked_at(V5, Se0)@1s".parse().expect("spec");
    assert!(Injection::resolve(&spec, &plant).is_err());
}

#[test]
fn combined_constraints_come_from_the_plant_file() {
    let flipped = PLANT_TOML.replace(
        "expr = \"Q12 & Q9\"\npriority = \"Q12\"",
        "expr = \"Q12 & Q9\"\npriority = \"Q9\"",
    );
    assert_ne!(flipped, PLANT_TOML);
    let p =
        vocabulary::Plant::parse(&flipped, std::path::Path::new("flipped.toml")).expect("valid");
    let ids = CylinderIds::resolve(&p).expect("resolves");
    assert_eq!(ids.combined, [(0, 1), (1, 2), (2, 3), (0, 3)]);

    let guarded = PLANT_TOML.replace("expr = \"Q12 & Q9\"", "expr = \"Q12 & Q9 & I13\"");
    let p =
        vocabulary::Plant::parse(&guarded, std::path::Path::new("guarded.toml")).expect("valid");
    let err = CylinderIds::resolve(&p).expect_err("the control cannot apply a conditional CSc");
    assert!(err.contains("CSc4"), "{err}");
}

/// Documents the trade-off of CSc4's priority (see the plant file): with a single
/// object, Q9 over Q12 lets cylinder 1 go out while cylinder 4 delivers to corner 1;
/// Q12 over Q9 does not.
#[test]
fn csc4_priority_matters_with_a_single_object() {
    let one = || {
        CylinderRig::new(CylinderConfig::default())
            .with_objects(&[4])
            .expect("valid corner")
    };
    // Shipped priorities (upstream first): a lone object goes round safely.
    let (report, _) = simulate_rig(one(), 600 * SECOND, 1, &[], ConstraintControl::new);
    assert_eq!(report.damage, vec![]);
    assert!(counter(&report, "moves") > 500, "{:?}", report.counters);

    // Priority to Q9 in CSc4 breaks cylinder 4's stroke when the object reaches corner 1.
    let flipped = PLANT_TOML.replace(
        "expr = \"Q12 & Q9\"\npriority = \"Q12\"",
        "expr = \"Q12 & Q9\"\npriority = \"Q9\"",
    );
    assert_ne!(flipped, PLANT_TOML);
    let p =
        vocabulary::Plant::parse(&flipped, std::path::Path::new("flipped.toml")).expect("valid");
    let ids = CylinderIds::resolve(&p).expect("resolves");
    let (report, _) = simulate_rig(one(), 120 * SECOND, 1, &[], |_| ConstraintControl::new(ids));
    assert!(
        report.damage.iter().any(|d| d.cause == "rod_collision"),
        "damage: {:?}",
        report.damage
    );
}

#[test]
fn a_slow_rod_strokes_factor_times_slower_from_the_onset() {
    let onset = 30 * SECOND;
    // Time from each RE(Q9) to the next RE(Se1): a stroke out, 0.9 to 1.1 s.
    let strokes = |sink: &MemorySink, from: Time| -> Vec<Time> {
        let out = rises(sink, "Se1");
        rises(sink, "Q9")
            .into_iter()
            .filter(|&t| t >= from)
            .filter_map(|t| out.iter().find(|&&s| s > t).map(|&s| s - t))
            .collect()
    };
    for fault in ["slow(V1)@30s:x3", "slow(Q9)@30s:x3"] {
        let (_, sink) = simulate(180 * SECOND, 7, &[fault]);
        let after = strokes(&sink, onset);
        assert!(!after.is_empty(), "{fault}: no stroke after the onset");
        for d in after {
            // 0.98 of a stroke of 0.9 to 1.1 s, three times slower, to a scan.
            assert!(
                (2600 * MS..=3260 * MS).contains(&d),
                "{fault}: {} ms",
                d / MS
            );
        }
        let (_, normal) = simulate(180 * SECOND, 7, &[]);
        assert!(strokes(&normal, 0).iter().all(|&d| d <= 1100 * MS));
    }
}
