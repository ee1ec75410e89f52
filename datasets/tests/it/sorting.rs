//! Behaviour of the simulated sorting line: normal operation, the damage monitor,
//! and the visible effect of each of seed 002's turntable faults.

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{Controller, MemorySink, SimConfig, SimReport, run};
use datasets::sorting::{SortingConfig, SortingIds, SortingLine, SynthesisedControl, plant};
use vocabulary::{Event, MS, SECOND, Time};

fn simulate<C: Controller>(
    duration: Time,
    seed: u64,
    faults: &[&str],
    control: impl FnOnce(SortingIds) -> C,
) -> (SimReport, MemorySink) {
    let plant = plant();
    let faults = faults
        .iter()
        .map(|f| {
            let spec: FaultSpec = f.parse().expect("valid fault spec");
            Injection::resolve(&spec, &plant).expect("known fault")
        })
        .collect();
    let mut line = SortingLine::new(SortingConfig::default());
    let mut ctl = control(line.ids());
    let cfg = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults,
    };
    let mut sink = MemorySink::default();
    let report = run(&mut line, &mut ctl, &cfg, &mut sink, |_| {}).expect("in-memory run");
    (report, sink)
}

fn counter(report: &SimReport, name: &str) -> u64 {
    report
        .counters
        .iter()
        .find(|(n, _)| n == name)
        .map_or(0, |(_, v)| *v)
}

fn events_of<'a>(sink: &'a MemorySink, name: &str) -> impl Iterator<Item = &'a Event> {
    let id = plant().signals.id(name).expect("signal exists");
    sink.events.iter().filter(move |e| e.signal == id)
}

#[test]
fn eight_hours_of_default_control_cause_no_damage_and_sort_both_ways() {
    let (report, _) = simulate(8 * 3600 * SECOND, 7, &[], SynthesisedControl::new);
    assert_eq!(report.damage, vec![], "damage under the default control");
    let (left, right) = (
        counter(&report, "delivered_left"),
        counter(&report, "delivered_right"),
    );
    assert!(left > 1000 && right > 1000, "left {left}, right {right}");
    // Alternating sides: the two counts differ by at most one box.
    assert!(left.abs_diff(right) <= 1, "left {left}, right {right}");
    assert_eq!(counter(&report, "boxes_lost"), 0);
}

#[test]
fn same_seed_same_log_and_different_seed_different_log() {
    let (_, a) = simulate(600 * SECOND, 11, &[], SynthesisedControl::new);
    let (_, b) = simulate(600 * SECOND, 11, &[], SynthesisedControl::new);
    let (_, c) = simulate(600 * SECOND, 12, &[], SynthesisedControl::new);
    assert_eq!(a.events, b.events);
    assert_ne!(a.events, c.events);
}

#[test]
fn turntable_timing_follows_the_seed() {
    let (_, sink) = simulate(3600 * SECOND, 3, &[], SynthesisedControl::new);
    let p = plant();
    let id = |n: &str| p.signals.id(n).expect("signal");
    let (a4, c4, c5) = (id("A4"), id("C4"), id("C5"));
    let mut order: Option<(bool, Time)> = None;
    let mut checked = 0;
    for e in &sink.events {
        if e.signal == a4 {
            order = Some((e.value, e.t));
            continue;
        }
        let Some((rising, t0)) = order else { continue };
        let dt = (e.t - t0) / MS;
        match (rising, e.signal == c4, e.signal == c5, e.value) {
            (true, true, _, false) => {
                assert!((30..=130).contains(&dt), "FE(C4) {dt} ms after RE(A4)")
            }
            (true, _, true, true) => {
                assert!((2900..=2950).contains(&dt), "RE(C5) {dt} ms after RE(A4)")
            }
            (false, _, true, false) => {
                assert!((1..=150).contains(&dt), "FE(C5) {dt} ms after FE(A4)")
            }
            (false, true, _, true) => {
                assert!((2880..=2970).contains(&dt), "RE(C4) {dt} ms after FE(A4)")
            }
            _ => continue,
        }
        checked += 1;
    }
    assert!(checked > 400, "only {checked} turntable edges checked");
}

/// Runs the rollers (A2) whenever the turntable is between its two positions.
struct RollersInTransit(SynthesisedControl, SortingIds);

impl Controller for RollersInTransit {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        self.0.scan(t, io);
        let ids = self.1;
        if !io[ids.c[4]] && !io[ids.c[5]] {
            io[ids.a[2]] = true;
        }
    }
}

#[test]
fn damage_monitor_fires_when_rollers_run_during_rotation() {
    let (report, _) = simulate(120 * SECOND, 7, &[], |ids| {
        RollersInTransit(SynthesisedControl::new(ids), ids)
    });
    let first = report.damage.first().expect("damage recorded");
    assert_eq!(first.cause, "rollers_in_transit");
    assert!(first.t > 0);
}

/// Releases the rotation order as soon as a box reaches the right conveyor (CSs10).
struct EarlyRelease(SynthesisedControl, SortingIds);

impl Controller for EarlyRelease {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        self.0.scan(t, io);
        if io[self.1.c[7]] {
            io[self.1.a[4]] = false;
        }
    }
}

#[test]
fn damage_monitor_fires_when_the_turntable_turns_with_a_box_half_on_it() {
    let (report, _) = simulate(300 * SECOND, 7, &[], |ids| {
        EarlyRelease(SynthesisedControl::new(ids), ids)
    });
    assert!(
        report
            .damage
            .iter()
            .any(|d| d.cause == "rotation_with_box_straddling"),
        "{:?}",
        report.damage
    );
}

/// Runs the intermediate conveyor whatever the turntable does (CSs2).
struct AlwaysFeed(SynthesisedControl, SortingIds);

impl Controller for AlwaysFeed {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        self.0.scan(t, io);
        io[self.1.a[0]] = true;
        io[self.1.a[1]] = true;
    }
}

#[test]
fn damage_monitor_sees_falls_and_collisions() {
    let (report, _) = simulate(600 * SECOND, 7, &[], |ids| {
        AlwaysFeed(SynthesisedControl::new(ids), ids)
    });
    let causes: Vec<&str> = report.damage.iter().map(|d| d.cause).collect();
    assert!(causes.contains(&"fell_off_end"), "{causes:?}");
}

/// A moment after `after` when the turntable has just come back to the loading
/// position in the normal run of `seed`: faults injected then start from a known state.
fn quiet_onset(seed: u64, after: Time) -> Time {
    let (_, normal) = simulate(after + 120 * SECOND, seed, &[], SynthesisedControl::new);
    let back = events_of(&normal, "C4")
        .find(|e| e.value && e.t >= after)
        .expect("the turntable returns");
    back.t + 100 * MS
}

#[test]
fn f2_keeps_c4_at_one_while_the_turntable_still_reaches_c5() {
    let onset = quiet_onset(7, 600 * SECOND);
    let (_, sink) = simulate(
        900 * SECOND,
        7,
        &[&format!("F2@{}ms", onset / MS)],
        SynthesisedControl::new,
    );
    let rise = events_of(&sink, "A4")
        .find(|e| e.value && e.t >= onset)
        .expect("a rotation after onset");
    assert_eq!(
        events_of(&sink, "C4").filter(|e| e.t >= onset).count(),
        0,
        "C4 changed after onset"
    );
    let c5 = events_of(&sink, "C5")
        .find(|e| e.value && e.t > rise.t)
        .expect("C5 rises");
    let dt = (c5.t - rise.t) / MS;
    assert!((2900..=2950).contains(&dt), "RE(C5) {dt} ms after RE(A4)");
}

#[test]
fn every_turntable_fault_changes_the_log_after_its_onset_only() {
    let onset = 300 * SECOND;
    let (_, normal) = simulate(600 * SECOND, 5, &[], SynthesisedControl::new);
    for label in [
        "F1", "F2", "F3", "F4", "F5", "F6", "F7", "F8", "F9", "F10", "F11", "F12",
    ] {
        let (_, faulty) = simulate(
            600 * SECOND,
            5,
            &[&format!("{label}@300s")],
            SynthesisedControl::new,
        );
        let before = |s: &MemorySink| {
            s.events
                .iter()
                .filter(|e| e.t < onset)
                .copied()
                .collect::<Vec<_>>()
        };
        assert_eq!(
            before(&normal),
            before(&faulty),
            "{label} changed the log before its onset"
        );
        assert_ne!(
            normal.events, faulty.events,
            "{label} left no trace in the log"
        );
    }
}

#[test]
fn blocked_turntable_faults_freeze_the_position_sensors() {
    // F5: stuck at loading, C5 never rises after onset.
    let (_, s) = simulate(900 * SECOND, 7, &["F5@600s"], SynthesisedControl::new);
    assert!(events_of(&s, "C5").all(|e| e.t < 600 * SECOND + 3 * SECOND));
    // F11: blocked on the way to unloading, both position sensors end at 0.
    let (_, s) = simulate(900 * SECOND, 7, &["F11@600s"], SynthesisedControl::new);
    let last = |name: &str| events_of(&s, name).last().map(|e| e.value);
    assert_eq!((last("C4"), last("C5")), (Some(false), Some(false)));
}

#[test]
fn unknown_faults_are_refused_with_the_known_labels() {
    let spec: FaultSpec = "F13@10s".parse().expect("well-formed");
    let err = Injection::resolve(&spec, &plant()).expect_err("F13 does not exist");
    assert!(
        err.contains("unknown fault 'F13'") && err.contains("F1"),
        "{err}"
    );
    assert!("F2@soon".parse::<FaultSpec>().is_err());
    let spec: FaultSpec = "stuck1(C44)@1s".parse().expect("well-formed");
    assert!(Injection::resolve(&spec, &plant()).is_err());
}

/// The time from each RE(A4) to the next RE(C5), for orders given from `from` on.
fn turns_to_unloading(sink: &MemorySink, from: Time) -> Vec<Time> {
    let p = plant();
    let (a4, c5) = (p.signals.id("A4"), p.signals.id("C5"));
    let mut order = None;
    let mut turns = Vec::new();
    for e in &sink.events {
        if Some(e.signal) == a4 && e.value {
            order = Some(e.t).filter(|&t| t >= from);
        } else if Some(e.signal) == c5
            && e.value
            && let Some(t0) = order.take()
        {
            turns.push(e.t - t0);
        }
    }
    turns
}

#[test]
fn a_slow_turntable_turns_factor_times_slower_from_the_onset() {
    let onset = 600 * SECOND;
    for (fault, lo, hi) in [
        ("slow(P)@600s:x2", 5780, 5900),
        ("slow(A4)@600s:x1.5", 4335, 4425),
        ("slow(P)@600s", 5780, 5900),
    ] {
        let (report, s) = simulate(1200 * SECOND, 7, &[fault], SynthesisedControl::new);
        let before = turns_to_unloading(&s, 0);
        assert!(before.iter().take(3).all(|&d| d <= 2960 * MS), "{before:?}");
        let after = turns_to_unloading(&s, onset);
        assert!(after.len() > 5, "{fault}: {after:?}");
        for d in after {
            assert!((lo * MS..=hi * MS).contains(&d), "{fault}: {} ms", d / MS);
        }
        assert_eq!(report.damage, vec![], "{fault}");
    }
    let spec: FaultSpec = "slow(C4)@1s".parse().expect("well-formed");
    assert!(Injection::resolve(&spec, &plant()).is_err());
}
