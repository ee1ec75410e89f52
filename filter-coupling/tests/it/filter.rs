//! The safety filter once per scan, on the sorting line's plant file: violated
//! constraints and their literals, the fallback, a flagged element's part,
//! the estimate intervals, the rewriting switched by flags, and observers.

use std::path::{Path, PathBuf};

use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, Time};
use filter_coupling::filter::{Coupling, Filter, Mode};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn plant() -> Plant {
    Plant::from_path(&root().join("datasets/plants/sorting.toml")).expect("plant")
}

fn model() -> Model {
    Model::from_path(&root().join("diagnoser/tests/fixtures/diagnosis/sorting-model.json"))
        .expect("model")
}

/// A scan's inputs: the named signals at 1, the rest at 0.
fn io(plant: &Plant, on: &[&str]) -> Vec<bool> {
    let mut v = vec![false; plant.signals.len()];
    for n in on {
        v[plant.signals.id(n).expect("signal").index()] = true;
    }
    v
}

fn get(plant: &Plant, io: &[bool], name: &str) -> bool {
    io[plant.signals.id(name).expect("signal").index()]
}

#[test]
fn a_violated_constraint_is_reported_with_its_literals_and_the_plant_falls_back() {
    let p = plant();
    let mut f = Filter::new(&p, None, Coupling::None).expect("filter");
    // Rollers to the right (A3) while the turntable is at loading.
    let mut v = io(&p, &["C4", "C6", "A3", "A5", "A6"]);
    let out = f.scan(0, &mut v, Mode::Filter);
    let names: Vec<&str> = out.violated.iter().map(|v| v.constraint.as_str()).collect();
    assert_eq!(names, ["CSs5"]);
    assert_eq!(out.violated[0].literals, ["!C5", "A3"]);
    assert!(out.fallback);
    // Fallback: every output at the value the constraints force; none is
    // forced to 1 here, so all are 0.
    for a in ["A0", "A1", "A2", "A3", "A4", "A5", "A6"] {
        assert!(!get(&p, &v, a), "{a} should fall back to 0");
    }
}

#[test]
fn the_fallback_keeps_the_outputs_forced_to_one() {
    let p = plant();
    let mut f = Filter::new(&p, None, Coupling::None).expect("filter");
    // A box aboard at the unloading position: CSs8 forces A4 = 1. The control
    // proposes to release A4 and run A3 with C5 = 1 (allowed) and A0 with 2P
    // unknown (allowed): the release violates CSs8.
    let mut v = io(&p, &["C5", "C6", "A3"]);
    let out = f.scan(0, &mut v, Mode::Filter);
    assert!(
        out.violated.iter().any(|x| x.constraint == "CSs8"),
        "{:?}",
        out.violated
    );
    assert!(out.fallback);
    assert!(get(&p, &v, "A4"));
    for a in ["A0", "A1", "A2", "A3", "A5", "A6"] {
        assert!(!get(&p, &v, a), "{a} should fall back to 0");
    }
}

#[test]
fn a_flagged_element_sends_its_part_to_the_fallback_only() {
    let p = plant();
    let m = model();
    let mut f = Filter::new(&p, Some(&m), Coupling::Flags).expect("filter");
    assert_eq!(
        f.fallback_parts(),
        [(vec!["def_P".to_string()], vec!["A4".to_string()])]
    );
    assert!(f.set("def_P", true));
    // At unloading with a box aboard: A4 is forced to 1 and stays on.
    let mut v = io(&p, &["C5", "C6", "A4", "A3", "A5", "A6"]);
    let out = f.scan(0, &mut v, Mode::Filter);
    assert!(out.violated.is_empty(), "{:?}", out.violated);
    assert_eq!(out.parts_in_fallback.len(), 1);
    assert!(get(&p, &v, "A4"));
    // The other parts keep the control's orders.
    assert!(get(&p, &v, "A3") && get(&p, &v, "A5"));
    // The box leaves to the left: C8 still forces A4.
    let mut v = io(&p, &["C5", "C8", "A4", "A5", "A6"]);
    f.scan(10 * MS, &mut v, Mode::Filter);
    assert!(get(&p, &v, "A4"));
    // Box gone: nothing forces A4 any more, so the turntable's order drops.
    let mut v = io(&p, &["C5", "A4", "A5", "A6"]);
    f.scan(20 * MS, &mut v, Mode::Filter);
    assert!(!get(&p, &v, "A4"));
    assert!(get(&p, &v, "A5"));
}

/// With every fault the parts can have: a flagged sensor whose edges follow
/// the workpieces (no learned estimate) stops its part; C4 and C5, which have
/// estimates, switch to them instead and stop nothing.
#[test]
fn a_flagged_sensor_with_no_estimate_stops_its_part() {
    let p = plant().with_every_fault();
    let m = model();
    let mut f = Filter::new(&p, Some(&m), Coupling::Flags).expect("filter");
    let parts = f.fallback_parts();
    let stopped_by = |flag: &str| -> Vec<String> {
        parts
            .iter()
            .filter(|(flags, _)| flags.iter().any(|x| x == flag))
            .flat_map(|(_, outputs)| outputs.clone())
            .collect()
    };
    assert_eq!(stopped_by("def_C0"), ["A0"]);
    assert_eq!(stopped_by("def_C6"), ["A2", "A3"]);
    assert_eq!(stopped_by("def_C9"), ["A6"]);
    assert_eq!(stopped_by("def_P"), ["A4"]);
    assert_eq!(stopped_by("def_A1"), ["A1"]);
    assert!(stopped_by("def_C4").is_empty());
    assert!(stopped_by("def_C5").is_empty());
    // The feed stops; the other parts keep the control's orders.
    assert!(f.set("def_C0", true));
    let mut v = io(&p, &["C4", "A0", "A1", "A5", "A6"]);
    let out = f.scan(0, &mut v, Mode::Filter);
    assert!(out.violated.is_empty(), "{:?}", out.violated);
    assert_eq!(out.parts_in_fallback.len(), 1);
    assert!(!get(&p, &v, "A0"));
    assert!(get(&p, &v, "A1") && get(&p, &v, "A5") && get(&p, &v, "A6"));
}

#[test]
fn intervals_follow_the_time_since_the_order() {
    let p = plant();
    let m = model();
    let mut f = Filter::new(&p, Some(&m), Coupling::Flags).expect("filter");
    let on = |f: &Filter| -> Vec<String> {
        (1..=10)
            .map(|i| format!("I{i}"))
            .filter(|n| f.value(n) == Some(true))
            .collect()
    };
    // Still since before the first scan: A4 = 0 for long, the last interval.
    let mut v = io(&p, &["C4"]);
    f.scan(0, &mut v, Mode::Filter);
    assert_eq!(on(&f), ["I10"]);
    // A4 written at 1 s; its clock starts at that scan.
    let t0: Time = SECOND;
    let mut v = io(&p, &["C4", "C6", "A4"]);
    f.scan(t0, &mut v, Mode::Filter);
    assert!(get(&p, &v, "A4"));
    let mut seen = Vec::new();
    for dt in [10, 100, 1000, 2900, 3000] {
        let mut v = io(&p, &["C6", "A4"]);
        f.scan(t0 + dt * MS, &mut v, Mode::Filter);
        seen.push(on(&f));
    }
    assert_eq!(seen, [["I1"], ["I2"], ["I3"], ["I4"], ["I5"]]);
}

#[test]
fn a_raised_flag_switches_a_failed_sensor_to_its_estimate() {
    let p = plant();
    let m = model();
    for (flag, allowed) in [(false, false), (true, true)] {
        let mut f = Filter::new(&p, Some(&m), Coupling::Flags).expect("filter");
        f.set("def_C4", flag);
        // C4 stuck at 0 while the turntable has been at loading for long (I10):
        // a box at C3 may be loaded only if C4 is read from its estimate.
        let mut v = io(&p, &["C3", "A1", "A2", "A5", "A6"]);
        let out = f.scan(0, &mut v, Mode::Filter);
        assert_eq!(out.violated.is_empty(), allowed, "{:?}", out.violated);
        assert_eq!(get(&p, &v, "A1"), allowed);
    }
}

#[test]
fn observers_follow_their_set_and_reset_conditions() {
    let p = plant();
    let mut f = Filter::new(&p, None, Coupling::None).expect("filter");
    let scan = |f: &mut Filter, t: Time, on: &[&str]| {
        let mut v = io(&p, on);
        f.scan(t, &mut v, Mode::Control);
    };
    scan(&mut f, 0, &["C4", "C3"]);
    assert_eq!(f.value("P36"), Some(false));
    scan(&mut f, 10 * MS, &["C4"]); // FE(C3)
    assert_eq!(f.value("P36"), Some(true));
    scan(&mut f, 20 * MS, &["C4"]);
    assert_eq!(f.value("P36"), Some(true));
    scan(&mut f, 30 * MS, &["C4", "C6"]); // RE(C6)
    assert_eq!(f.value("P36"), Some(false));
    // PC toggles on FE(C8), from its initial 1.
    assert_eq!(f.value("PC"), Some(true));
    scan(&mut f, 40 * MS, &["C5", "C8"]);
    scan(&mut f, 50 * MS, &["C5"]);
    assert_eq!(f.value("PC"), Some(false));
}

#[test]
fn a_program_reads_a_declared_sensor_where_its_estimate_is_certain() {
    let p = plant();
    let m = model();
    // C4 stuck at 0 while the turntable has been at loading for long (I10).
    let read_c4 = |coupling, flag: Option<&str>| {
        let mut f = Filter::new(&p, Some(&m), coupling).expect("filter");
        if let Some(flag) = flag {
            f.set(flag, true);
        }
        let mut v = io(&p, &["A5", "A6"]);
        f.scan(0, &mut v, Mode::Filter);
        let mut sensors = io(&p, &["A5", "A6"]);
        f.certain_sensors(&mut sensors);
        get(&p, &sensors, "C4")
    };
    assert!(
        !read_c4(Coupling::None, Some("def_C4")),
        "no coupling: as read"
    );
    assert!(!read_c4(Coupling::Flags, None), "no flag: as read");
    assert!(
        read_c4(Coupling::Flags, Some("def_C4")),
        "declared: estimated"
    );
    assert!(
        !read_c4(Coupling::FlagsAndSuspects, Some("suspect_C4")),
        "suspected only: as read"
    );

    // C4 stuck at 1 one second into a rotation (A4 on since 1 s): the
    // turntable has left loading, so C4 is not certainly 1.
    let mut f = Filter::new(&p, Some(&m), Coupling::Flags).expect("filter");
    f.set("def_C4", true);
    // A recorded scan: the orders as written, whatever the constraints say.
    f.violations(0, &io(&p, &["C4"]));
    for t in [SECOND, 2 * SECOND] {
        f.violations(t, &io(&p, &["C4", "A4"]));
    }
    let mut sensors = io(&p, &["C4", "A4"]);
    f.certain_sensors(&mut sensors);
    assert!(!get(&p, &sensors, "C4"), "mid-rotation, C4 is not certain");
    assert!(get(&p, &sensors, "A4"), "orders are left as they are");
}
