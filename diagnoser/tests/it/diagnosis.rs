//! The diagnosers on the shipped turntable runs, with a model learned from the
//! shipped normal run (`fixtures/diagnosis/sorting-model.json`, written by
//! `gardefou learn --plant datasets/plants/sorting.toml
//! datasets/data/sorting/normal/events.csv`), and the coordinator's rules on
//! hand-made verdicts.

use std::path::{Path, PathBuf};

use diagnoser::diagnosis::compile::Compiled;
use diagnoser::diagnosis::diagnosability::{check, separate_under_any_order};
use diagnoser::diagnosis::fusion::Coordinator;
use diagnoser::diagnosis::{DiagnoserOptions, Engine, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::model::Model;
use diagnoser::{Plant, TimeUnit};
use logs::read_events;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn setup() -> (Plant, Model) {
    let plant = Plant::from_path(&repo("datasets/plants/sorting.toml")).expect("plant");
    let model = Model::from_path(&repo(
        "diagnoser/tests/fixtures/diagnosis/sorting-model.json",
    ))
    .expect("model");
    (plant, model)
}

fn replay(plant: &Plant, model: &Model, run: &str) -> Vec<Verdict> {
    let log = read_events(
        &repo(&format!("datasets/data/sorting/{run}/events.csv")),
        &plant.signals,
        TimeUnit::Ms,
    )
    .expect("shipped log");
    let mut d = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default()).expect("diagnoser");
    let mut out = Vec::new();
    d.start(log.start, &log.initial);
    for &e in &log.events {
        d.push(e, &mut |v| out.push(v));
    }
    let end = log.events.last().map_or(log.start, |e| e.t);
    d.finish(end, &mut |v| out.push(v));
    out
}

#[test]
fn shipped_runs_keep_the_true_label_and_never_lower_a_flag() {
    let (plant, model) = setup();
    assert!(replay(&plant, &model, "normal").is_empty());
    for i in 1..=12 {
        let label = format!("F{i}");
        let mut flags: Vec<String> = Vec::new();
        for v in replay(&plant, &model, &label) {
            if v.verdict != VerdictKind::Normal {
                assert!(v.labels.contains(&label), "{label}: {v:?}");
            }
            if v.part == "turntable" {
                assert!(
                    flags.iter().all(|f| v.flags.contains(f)),
                    "{label}: flag lowered: {v:?}"
                );
                flags = v.flags.clone();
            }
        }
    }
}

/// The turntable's diagnoser engine, from the shipped model.
fn turntable_engine() -> Engine {
    let (plant, model) = setup();
    let d = PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).expect("diagnoser");
    d.engines()
        .find(|e| e.part.name == "turntable")
        .expect("turntable")
        .clone()
}

#[test]
fn compiled_turntable_diagnoser_and_its_diagnosability() {
    let mut engine = turntable_engine();
    let compiled = Compiled::explore(&mut engine, 2);
    assert!(!compiled.truncated);
    let size = compiled.size();
    assert!(
        size.states > 6 && size.transitions > size.states,
        "{size:?}"
    );
    let dot = compiled.to_digraph(&engine, TimeUnit::Ms).to_dot();
    assert!(dot.contains("{F2}") && dot.contains("{N}"), "{dot}");
    let verdicts = check(&mut engine, &compiled, TimeUnit::Ms);
    let of = |l: &str| verdicts.iter().find(|v| v.label == l).expect("verdict");
    let f2 = of("F2");
    assert!(
        f2.detectable && f2.isolable && f2.counterexample.is_none(),
        "{f2:?}"
    );
    let f7 = of("F7");
    assert!(!f7.detectable, "{f7:?}");
    let c = f7.counterexample.as_ref().expect("a counterexample");
    assert!(!c.observed.is_empty());
    assert_eq!(c.faulty.len(), c.observed.len());
    assert_eq!(c.other_run.len(), c.observed.len());
    for v in &verdicts {
        // Isolable when waiting is isolable and more; a reason goes with each
        // fault that is isolable only while the plant runs.
        assert!(!v.isolable_when_waiting || v.isolable, "{v:?}");
        assert_eq!(
            v.isolable && !v.isolable_when_waiting,
            v.waiting.is_some(),
            "{v:?}"
        );
        assert_eq!(v.waiting.is_some(), !v.confused_when_waiting.is_empty());
    }
}

#[test]
fn a_control_that_waits_for_a_withheld_sensor_hides_what_a_running_plant_shows() {
    let mut engine = turntable_engine();
    let compiled = Compiled::explore(&mut engine, 2);
    let mut verdicts = check(&mut engine, &compiled, TimeUnit::Ms);
    // Under the learned control nothing tells them apart.
    assert!(
        verdicts
            .iter()
            .filter_map(|v| v.waiting.as_ref())
            .all(|w| w.until.is_none()),
        "{verdicts:?}"
    );
    separate_under_any_order(&engine, &mut verdicts, TimeUnit::Ms);
    let of = |l: &str| verdicts.iter().find(|v| v.label == l).expect("verdict");
    // Releasing the turntable with the plate at C5 (or ordering it with the
    // plate at C4) brings a moving plate back in time; a blocked one stays.
    for (f, order) in [
        ("F3", "FE(A4)"),
        ("F11", "FE(A4)"),
        ("F1", "RE(A4)"),
        ("F12", "RE(A4)"),
    ] {
        let w = of(f).waiting.as_ref().expect("waiting");
        let until = w.until.as_deref().unwrap_or_default();
        assert!(
            until.starts_with(order) && until.contains("no event until"),
            "{f}: {w:?}"
        );
        assert_eq!(w.orders_outside_control, [order], "{f}: {w:?}");
    }
    // A sensor stuck at its resting value and a plate blocked on the way to it
    // look the same once the control waits for that sensor: the plate's return
    // that would tell them apart never comes.
    for (stuck, blocked, sensor) in [("F1", "F12", "C4"), ("F3", "F11", "C5")] {
        for (f, g) in [(stuck, blocked), (blocked, stuck)] {
            let v = of(f);
            assert!(v.isolable && !v.isolable_when_waiting, "{v:?}");
            assert_eq!(v.confused_when_waiting, [g], "{v:?}");
            let w = v.waiting.as_ref().expect("where the control waits");
            assert_eq!(w.other, g);
            assert_eq!(w.control_waits_for, [format!("RE({sensor})")], "{w:?}");
        }
    }
    // A sensor stuck at the value it shows in transit, or a plate blocked at a
    // position, breaks a deadline whatever the control does.
    for f in ["F2", "F4", "F5", "F6"] {
        let v = of(f);
        assert!(v.isolable_when_waiting && v.waiting.is_none(), "{v:?}");
    }
}

fn verdict(part: &str, labels: &[&str]) -> Verdict {
    let kind = match labels {
        ["N"] => VerdictKind::Normal,
        [_] => VerdictKind::Certain,
        _ => VerdictKind::Ambiguous,
    };
    Verdict {
        t: 0,
        part: part.to_string(),
        verdict: kind,
        labels: labels.iter().map(|l| l.to_string()).collect(),
        flags: Vec::new(),
        suspects: Vec::new(),
        reason: String::new(),
    }
}

fn coordinator() -> Coordinator {
    let (plant, _) = setup();
    // Two parts reading C4: the turntable models F2 and F5; a neighbour models
    // F2 (its stuck C4) and a fault of its own, X.
    Coordinator::new(
        &plant,
        vec![
            ("turntable".into(), vec!["F2".into(), "F5".into()]),
            ("neighbour".into(), vec!["F2".into(), "X".into()]),
            ("rollers".into(), vec![]),
        ],
    )
}

#[test]
fn a_neighbour_resolves_an_ambiguity() {
    let mut c = coordinator();
    let v = c
        .update(0, &verdict("turntable", &["F2", "F5"]))
        .expect("a view");
    assert_eq!(v.labels, ["F2", "F5"]);
    let v = c
        .update(1, &verdict("neighbour", &["F2"]))
        .expect("a new view");
    assert_eq!(v.labels, ["F2"]);
    assert_eq!(v.verdict, VerdictKind::Certain);
    assert_eq!(v.flags, ["def_C4"]);
}

#[test]
fn a_part_that_models_a_fault_and_left_normal_without_it_excludes_it() {
    let mut c = coordinator();
    c.update(0, &verdict("turntable", &["F2", "F5"]));
    let v = c.update(1, &verdict("neighbour", &["X"])).expect("a view");
    // F2 is excluded by the neighbour; no label is common: two faults.
    assert_eq!(v.labels, ["F5", "X"]);
    assert_eq!(v.verdict, VerdictKind::Ambiguous);
}

#[test]
fn unexplained_deviations_are_consequences_of_a_modelled_fault() {
    let mut c = coordinator();
    let v = c
        .update(2, &verdict("rollers", &["unknown"]))
        .expect("a view");
    assert_eq!(v.labels, ["unknown"]);
    let v = c
        .update(0, &verdict("turntable", &["F2"]))
        .expect("a new view");
    assert_eq!(v.labels, ["F2"]);
    assert!(v.reason.contains("rollers"), "{}", v.reason);
    // Nothing changes: no new line.
    assert!(c.update(0, &verdict("turntable", &["F2"])).is_none());
}

/// The swivel arm of `fixtures/diagnosis/arm.toml`, its hand-made model, and the
/// final labels of a replay of `(t ms, signal, value)` events from the state
/// `B1=1`, ending at `end` ms. `edit` edits the plant file.
fn arm_labels(
    edit: impl Fn(String) -> String,
    events: &[(i64, &str, bool)],
    end: i64,
) -> Vec<String> {
    fixture_labels("arm", &edit, &["B1"], events, end)
}

/// The final labels of fixture `name`'s part of the same name (plant
/// `fixtures/diagnosis/NAME.toml`, model `NAME-model.json`) on a replay of
/// `(t ms, signal, value)` events from the state where the signals `on` are 1,
/// ending at `end` ms.
fn fixture_labels(
    name: &str,
    edit: &dyn Fn(String) -> String,
    on: &[&str],
    events: &[(i64, &str, bool)],
    end: i64,
) -> Vec<String> {
    fixture_labels_with_model(name, edit, &|m| m, on, events, end)
}

/// [`fixture_labels`], with the model's text edited by `edit_model`.
fn fixture_labels_with_model(
    name: &str,
    edit: &dyn Fn(String) -> String,
    edit_model: &dyn Fn(String) -> String,
    on: &[&str],
    events: &[(i64, &str, bool)],
    end: i64,
) -> Vec<String> {
    fixture_verdicts(name, edit, edit_model, on, events, end)
        .iter()
        .rev()
        .find(|v| v.part == name)
        .map_or_else(|| vec!["N".to_string()], |v| v.labels.clone())
}

/// Every verdict of the replay of [`fixture_labels_with_model`].
fn fixture_verdicts(
    name: &str,
    edit: &dyn Fn(String) -> String,
    edit_model: &dyn Fn(String) -> String,
    on: &[&str],
    events: &[(i64, &str, bool)],
    end: i64,
) -> Vec<Verdict> {
    let dir = "diagnoser/tests/fixtures/diagnosis";
    let text = std::fs::read_to_string(repo(&format!("{dir}/{name}.toml"))).expect("plant");
    let plant = Plant::parse(&edit(text), Path::new(name)).expect("plant parses");
    let path = repo(&format!("{dir}/{name}-model.json"));
    let text = std::fs::read_to_string(&path).expect("model");
    let model = Model::parse(&edit_model(text), &path).expect("model parses");
    let mut d =
        PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).expect("diagnoser");
    let ms = diagnoser::MS;
    let initial: Vec<bool> = plant
        .signals
        .iter()
        .map(|(_, s)| on.contains(&s.name.as_str()))
        .collect();
    let mut verdicts = Vec::new();
    d.start(0, &initial);
    for &(t, signal, value) in events {
        let signal = plant.signals.id(signal).expect("signal");
        d.push(
            diagnoser::Event {
                t: t * ms,
                signal,
                value,
            },
            &mut |v| verdicts.push(v),
        );
    }
    d.finish(end * ms, &mut |v| verdicts.push(v));
    verdicts
}

/// The table of `fixtures/diagnosis/table.toml`, from the loading position
/// (B103): turned to the work position, where it is at 3860 ms.
const TABLE_TO_WORK: [(i64, &str, bool); 4] = [
    (1000, "Y102", true),
    (1060, "B103", false),
    (3860, "Y102", false),
    (3860, "B104", true),
];

/// [`TABLE_TO_WORK`], then ordered back to the loading position at 9000 ms:
/// in transit from 9070 ms.
const TABLE_TO_LOADING: [(i64, &str, bool); 6] = [
    TABLE_TO_WORK[0],
    TABLE_TO_WORK[1],
    TABLE_TO_WORK[2],
    TABLE_TO_WORK[3],
    (9000, "Y103", true),
    (9070, "B104", false),
];

#[test]
fn a_valve_stuck_on_keeps_its_label_when_the_control_releases_it_on_arrival() {
    // The table turns to the work position; the control releases Y102 in the
    // scan B104 rises, but the valve stays on. Ordered back, the table does
    // not leave B104: both valves push.
    let mut events = TABLE_TO_WORK.to_vec();
    events.push((9000, "Y103", true));
    let labels = fixture_labels("table", &|t| t, &["B103"], &events, 12_000);
    assert!(
        labels.contains(&"Y102.actuator_stuck1".to_string()),
        "{labels:?}"
    );
    assert!(!labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
}

#[test]
fn a_stuck_switch_keeps_its_label_when_the_control_it_misleads_gives_a_pulse() {
    // B103 (loading position) sticks at 1 while the table turns there: the
    // control stops the table half-way, turns it back to B104, and next time
    // releases Y103 one scan after giving it, since it sees the table at B103
    // already. The table had started: B104 falls 70 ms after the order, inside
    // its learned window, but 60 ms after the release, where the table rests.
    // (Times from generated plant 1, `B103.stuck1` at 562 681 ms.)
    let events = [
        (540_850, "Y102", true),
        (540_910, "B103", false),
        (543_770, "Y102", false),
        (543_770, "B104", true),
        (559_940, "Y103", true),
        (560_010, "B104", false),
        (562_690, "Y103", false),
        (562_690, "B103", true),
        (563_850, "Y102", true),
        (566_810, "Y102", false),
        (566_810, "B104", true),
        (588_760, "Y103", true),
        (588_770, "Y103", false),
        (588_830, "B104", false),
        // Back to B104 from part-way, and the same pulse again.
        (589_930, "Y102", true),
        (590_900, "Y102", false),
        (590_900, "B104", true),
        (594_050, "Y103", true),
        (594_060, "Y103", false),
        (594_120, "B104", false),
    ];
    let labels = fixture_labels("table", &|t| t, &["B103"], &events, 600_000);
    assert!(labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
    // Had the table left B104 later than the order's learned window allows,
    // the stuck switch would not explain it.
    let mut late = events;
    late[13].0 = 588_960;
    let labels = fixture_labels("table", &|t| t, &["B103"], &late, 600_000);
    assert!(!labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
    // The same where the model times that edge from the last command, which
    // the release restarted: the edge still comes within its window.
    let command_clock = |m: String| m.replace("\"clock\": \"RE(Y103)\"", "\"clock\": \"command\"");
    let labels =
        fixture_labels_with_model("table", &|t| t, &command_clock, &["B103"], &events, 600_000);
    assert!(labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
}

#[test]
fn a_valve_stuck_on_turns_the_table_to_where_the_control_would_have_released_it() {
    // Y103 sticks on while the table rests at the work position: the table
    // turns to the loading position unordered, and the control has no order to
    // withdraw when B103 rises.
    let mut events = TABLE_TO_WORK.to_vec();
    events.extend([(6000, "B104", false), (9200, "B103", true)]);
    let labels = fixture_labels("table", &|t| t, &["B103"], &events, 10_000);
    assert!(
        labels.contains(&"Y103.actuator_stuck1".to_string()),
        "{labels:?}"
    );
}

/// Vacuum on, swivel to the conveyor: the arm is at B2 with the vacuum on at 720 ms.
const ARM_TO_CONVEYOR: [(i64, &str, bool); 5] = [
    (100, "Y2", true),
    (150, "B3", true),
    (200, "Y1", true),
    (220, "B1", false),
    (720, "B2", true),
];

#[test]
fn a_blocked_arm_does_not_explain_a_vacuum_switch_that_stays_on() {
    let mut events = ARM_TO_CONVEYOR.to_vec();
    // Vacuum off: B3 never falls.
    events.push((800, "Y2", false));
    let labels = arm_labels(|t| t, &events, 2000);
    assert!(labels.contains(&"B3.stuck1".to_string()), "{labels:?}");
    assert!(
        labels.contains(&"Y2.actuator_stuck1".to_string()),
        "{labels:?}"
    );
    assert!(
        !labels.contains(&"A.blocked_at.B2".to_string()),
        "{labels:?}"
    );
    // Without `drives`, the element freezes every sensor of its part, the
    // vacuum switch included, and so explains it.
    let all = arm_labels(
        |t| t.replace("drives = [\"B1\", \"B2\"]\n", ""),
        &events,
        2000,
    );
    assert!(all.contains(&"A.blocked_at.B2".to_string()), "{all:?}");
}

#[test]
fn a_blocked_arm_keeps_its_label_while_the_vacuum_switch_moves() {
    let mut events = ARM_TO_CONVEYOR.to_vec();
    // Blocked at the conveyor: the vacuum still goes off, the arm never leaves B2.
    events.extend([(800, "Y2", false), (850, "B3", false), (900, "Y1", false)]);
    let labels = arm_labels(|t| t, &events, 2000);
    assert!(
        labels.contains(&"A.blocked_at.B2".to_string()),
        "{labels:?}"
    );
    assert!(!labels.contains(&"B3.stuck1".to_string()), "{labels:?}");
}

/// The shipped normal run as a polled source may see it: every second pair
/// of consecutive PLC scans one scan apart seen at once, at the later scan's
/// time. Returns the verdicts of a diagnoser told, or not, that its events
/// come from polls.
fn merged_scans_verdicts(polled: bool) -> (usize, Vec<Verdict>) {
    let (plant, model) = setup();
    let log = read_events(
        &repo("datasets/data/sorting/normal/events.csv"),
        &plant.signals,
        TimeUnit::Ms,
    )
    .expect("shipped log");
    let mut scans: Vec<Vec<diagnoser::Event>> = Vec::new();
    for &e in &log.events {
        match scans.last_mut() {
            Some(s) if s[0].t == e.t => s.push(e),
            _ => scans.push(vec![e]),
        }
    }
    let mut events = Vec::new();
    let mut merged = 0;
    let mut i = 0;
    while i < scans.len() {
        let next = scans.get(i + 1);
        let joinable = next.is_some_and(|n| {
            n[0].t - scans[i][0].t == plant.scan_period
                && !n
                    .iter()
                    .any(|a| scans[i].iter().any(|b| a.signal == b.signal))
        });
        if joinable && merged % 2 == 0 {
            let t = next.map_or(0, |n| n[0].t);
            events.extend(scans[i].iter().map(|e| diagnoser::Event { t, ..*e }));
            events.extend(next.into_iter().flatten().copied());
            merged += 1;
            i += 2;
            continue;
        }
        merged += usize::from(joinable);
        events.extend(scans[i].iter().copied());
        i += 1;
    }
    let options = DiagnoserOptions {
        polled,
        ..DiagnoserOptions::default()
    };
    let mut d = PlantDiagnoser::new(&plant, &model, &options).expect("diagnoser");
    let mut out = Vec::new();
    d.start(log.start, &log.initial);
    for &e in &events {
        d.push(e, &mut |v| out.push(v));
    }
    let end = events.last().map_or(log.start, |e| e.t);
    d.finish(end, &mut |v| out.push(v));
    (merged / 2, out)
}

#[test]
fn a_poll_that_sees_two_plc_scans_at_once_stays_normal() {
    let (merged, as_log) = merged_scans_verdicts(false);
    assert!(merged > 50, "{merged} merges");
    // Read as a PLC's own log, some merged scans are not normal...
    assert!(!as_log.is_empty(), "no merged scan mattered");
    // ...read as polls, every one is two scans seen at once.
    let (_, as_polls) = merged_scans_verdicts(true);
    assert!(as_polls.is_empty(), "{merged} merges: {as_polls:#?}");
}

#[test]
fn a_stuck_switch_keeps_its_label_when_the_table_it_turned_back_arrives_early() {
    // B103 sticks at 1 half-way to the loading position: the control releases
    // Y103 and turns the table back to B104 at once. Coming back from
    // half-way, it reaches B104 sooner than any learned turn (2538 ms and more).
    let events = |arrival: i64| {
        let mut events = TABLE_TO_LOADING.to_vec();
        events.extend([
            (10_200, "Y103", false),
            (10_200, "B103", true),
            (10_400, "Y102", true),
            (arrival, "Y102", false),
            (arrival, "B104", true),
        ]);
        events
    };
    let labels = fixture_labels("table", &|t| t, &["B103"], &events(11_800), 20_000);
    assert!(labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
    // Sooner, never later: past the learned turn's latest time, the stuck
    // switch no longer explains the arrival.
    let labels = fixture_labels("table", &|t| t, &["B103"], &events(13_600), 20_000);
    assert!(!labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
}

#[test]
fn an_unexpected_fall_hides_the_edge_the_control_releases_the_table_on() {
    // The table reaches the loading position at 12 550 ms, but B103 shows 0
    // for 100 ms more: the control releases Y103 only when it sees B103, after
    // the learned turn's latest time (3602 ms after the order).
    let edit = |t: String| {
        t.replace(
            "[faults]\n",
            "[faults]\n\"B103.unexpected_fall\" = \"unexpected_fall(B103)\"\n",
        )
    };
    let mut events = TABLE_TO_LOADING.to_vec();
    events.extend([(12_650, "Y103", false), (12_650, "B103", true)]);
    let labels = fixture_labels("table", &edit, &["B103"], &events, 20_000);
    assert!(
        labels.contains(&"B103.unexpected_fall".to_string()),
        "{labels:?}"
    );
}

#[test]
fn an_unexpected_fall_hides_an_end_switch_among_the_edges_of_one_scan() {
    // The unloader reaches its extended switch B107 as the next machine takes
    // the workpiece (B108 falls), but B107 shows 0 for 50 ms more: the control
    // releases Y106 only then. The learned scan has all three edges at once.
    let events = [
        (1000, "Y106", true),
        (1020, "B106", false),
        (1910, "B108", false),
        (1960, "Y106", false),
        (1960, "B107", true),
        (1980, "B107", false),
        (2600, "B106", true),
    ];
    let labels = fixture_labels("unloader", &|t| t, &["B106", "B108"], &events, 4000);
    assert!(
        labels.contains(&"B107.unexpected_fall".to_string()),
        "{labels:?}"
    );
}

#[test]
fn an_end_switch_that_showed_late_keeps_its_label_when_the_workpiece_left_on_time() {
    // As above, but the workpiece leaves (B108 falls) as the unloader really
    // reaches B107, and only B107 shows 50 ms late. The learned reaction had
    // both edges in one scan; the control reacts to the late one alone, when
    // the cylinder has gone on to the end of its stroke, and the spring takes
    // 45 ms to bring it off the switch, where a release on arrival took at
    // most 21 ms.
    let events = |back: i64| {
        [
            (1000, "Y106", true),
            (1020, "B106", false),
            (1910, "B108", false),
            (1960, "Y106", false),
            (1960, "B107", true),
            (1960 + back, "B107", false),
            (1960 + back + 620, "B106", true),
        ]
    };
    let on = ["B106", "B108"];
    let labels = fixture_labels("unloader", &|t| t, &on, &events(45), 4000);
    assert!(
        labels.contains(&"B107.unexpected_fall".to_string()),
        "{labels:?}"
    );
    // Later than the longest a glitch shows, it is not explained.
    let labels = fixture_labels("unloader", &|t| t, &on, &events(200), 4000);
    assert!(
        !labels.contains(&"B107.unexpected_fall".to_string()),
        "{labels:?}"
    );
}

#[test]
fn a_stuck_switch_keeps_its_label_when_the_cylinder_it_releases_springs_back_at_once() {
    // B103 (extended) sticks at 1 while the ejector rests: when the control
    // extends it, it sees it out already and releases it one scan later. The
    // spring brings it back from where it had got to, long before a whole
    // return stroke (189 ms and more). The model saw the release only with
    // B103's rise.
    let events = |back: i64| {
        [
            (1000, "B103", true),
            (20_000, "B101", false),
            (20_000, "Y101", true),
            (20_010, "Y101", false),
            (20_010, "B102", false),
            (back, "B102", true),
        ]
    };
    let on = ["B102", "B101"];
    let labels = fixture_labels("ejector", &|t| t, &on, &events(20_020), 30_000);
    assert!(labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
    // Past a whole return stroke's latest time, it is not explained.
    let labels = fixture_labels("ejector", &|t| t, &on, &events(20_400), 30_000);
    assert!(!labels.contains(&"B103.stuck1".to_string()), "{labels:?}");
}

#[test]
fn a_switch_that_showed_late_keeps_its_label_when_the_released_cylinder_leaves_late() {
    // A 50 ms fall of B103 (extended) as the ejector reaches it holds its
    // rise back: the control releases the cylinder 50 ms late, when it has
    // gone on to the end of its stroke, and the spring takes 40 ms to bring
    // it off the switch, where a release on arrival took at most 21 ms.
    let events = |back: i64| {
        [
            (1000, "Y101", true),
            (1010, "B102", false),
            (1340, "Y101", false),
            (1340, "B103", true),
            (1340 + back, "B103", false),
            (1340 + back + 220, "B102", true),
        ]
    };
    let on = ["B102"];
    let labels = fixture_labels("ejector", &|t| t, &on, &events(40), 5000);
    assert!(
        labels.contains(&"B103.unexpected_fall".to_string()),
        "{labels:?}"
    );
    // Later than the longest a glitch shows, it is not explained.
    let labels = fixture_labels("ejector", &|t| t, &on, &events(200), 5000);
    assert!(
        !labels.contains(&"B103.unexpected_fall".to_string()),
        "{labels:?}"
    );
}

/// The ejector of `fixtures/diagnosis/ejector.toml` pushes out the last
/// workpiece of its magazine (B101, "magazine empty", rises 20 ms after the
/// order) and is released as it arrives (1300 ms); then the operator refills
/// the magazine at `refill` ms, and the ejector is back in at 1520 ms.
fn ejector_refilled_at(refill: i64) -> Vec<(i64, &'static str, bool)> {
    let mut events = vec![
        (1000, "Y101", true),
        (1010, "B102", false),
        (1020, "B101", true),
        (1300, "Y101", false),
        (1300, "B103", true),
        (1310, "B103", false),
        (1520, "B102", true),
    ];
    events.push((refill, "B101", false));
    events.sort_by_key(|e| e.0);
    events
}

#[test]
fn a_refill_during_a_stroke_is_normal() {
    // The learning logs only showed refills while the ejector rested.
    let labels = fixture_labels(
        "ejector",
        &|t| t,
        &["B102"],
        &ejector_refilled_at(1400),
        5000,
    );
    assert_eq!(labels, ["N"]);
}

#[test]
fn a_workpiece_that_arrives_while_the_separator_is_out_is_normal() {
    // The separator of `fixtures/diagnosis/separator.toml` lets a workpiece
    // through to B201, and the next one arrives before the control releases
    // it. The learning logs only showed arrivals once it was back, and the
    // joint state was only seen before the one let through had left B201.
    let events = [
        (5000, "Y201", true),
        (5025, "B202", false),
        (5055, "B201", false),
        (5600, "B201", true),
        (6375, "Y201", false),
        (7400, "B202", true),
    ];
    let labels = fixture_labels("separator", &|t| t, &["B202", "B201"], &events, 9000);
    assert_eq!(labels, ["N"]);
}

#[test]
fn a_refill_in_the_scan_the_control_releases_the_ejector_is_normal() {
    // Two transitions of the model in one scan: the refill, and the control's
    // reaction to the extended switch.
    let labels = fixture_labels(
        "ejector",
        &|t| t,
        &["B102"],
        &ejector_refilled_at(1300),
        5000,
    );
    assert_eq!(labels, ["N"]);
}

#[test]
fn a_workpiece_ready_before_the_control_reacts_is_normal() {
    // The pusher of `fixtures/diagnosis/pusher.toml` always extended in the
    // scan its workpiece sensor B305 rose; here the control waits 7 s (for a
    // condition outside the part) before it pushes.
    let events = [
        (1000, "B305", true),
        (8000, "Y301", true),
        (8005, "B304", false),
        (8170, "B305", false),
        (8250, "Y301", false),
        (8450, "B304", true),
    ];
    assert_eq!(
        fixture_labels("pusher", &|t| t, &["B304"], &events, 20_000),
        ["N"]
    );
}

#[test]
fn a_valve_stuck_on_extends_the_loader_without_the_controls_reaction() {
    // The extending valve of `fixtures/diagnosis/loader.toml` sticks on while
    // the loader rests with a workpiece at its input: it pushes the workpiece
    // out and extends, and the control, which never ordered it, does not
    // switch the valves over at the end as it learned to.
    let events = [
        (10_000, "B302", false),
        (10_006, "B301", false),
        (10_182, "B303", true),
    ];
    let labels = fixture_labels("loader", &|t| t, &["B302", "B301"], &events, 15_000);
    assert!(
        labels.contains(&"Y301.actuator_stuck1".to_string()),
        "{labels:?}"
    );
}

#[test]
fn a_valve_stuck_on_leaves_the_workpiece_sensor_to_the_workpieces() {
    // The separator of `fixtures/diagnosis/separator.toml` extends by itself
    // at 10 s; at 23 s a workpiece reaches the input sensor, in a state the
    // model never saw it do so, and the control orders the extension.
    let events = [
        (10_000, "B202", false),
        (23_000, "Y201", true),
        (23_000, "B201", true),
        (24_320, "Y201", false),
    ];
    let labels = fixture_labels("separator", &|t| t, &["B202"], &events, 30_000);
    assert!(
        labels.contains(&"Y201.actuator_stuck1".to_string()),
        "{labels:?}"
    );
}

#[test]
fn a_stuck_switch_keeps_its_label_when_the_control_it_misleads_releases_a_cylinder_leaving() {
    // The extended switch B304 of `fixtures/diagnosis/shuttle.toml` sticks on
    // while the cylinder rests retracted. The control extends it and, reading
    // B304, releases it as soon as it leaves B303: it springs back within a
    // scan, much sooner than a whole return stroke.
    let events = [
        (1000, "B304", true),
        (10_000, "Y301", true),
        (10_005, "Y301", false),
        (10_005, "B303", false),
        (10_010, "B303", true),
    ];
    let labels = fixture_labels("shuttle", &|t| t, &["B303"], &events, 20_000);
    assert!(labels.contains(&"B304.stuck1".to_string()), "{labels:?}");
}

#[test]
fn an_entry_sensor_stuck_on_starts_the_belt_for_a_workpiece_that_never_came() {
    // The entry sensor B201 of `fixtures/diagnosis/conveyor.toml` sticks on
    // as a workpiece passes it. Once that workpiece is taken from the end
    // stop, the control starts the belt again for the one it reads at the
    // entry, and the empty belt runs with nothing to carry.
    let events = [
        (1000, "B201", true),
        (3000, "M201", true),
        (3310, "B202", true),
        (3400, "B202", false),
        (3700, "M201", false),
        (3700, "B203", true),
        (30_000, "B203", false),
        (30_700, "M201", true),
    ];
    let labels = fixture_labels("conveyor", &|t| t, &[], &events, 60_000);
    assert!(labels.contains(&"B201.stuck1".to_string()), "{labels:?}");
}

#[test]
fn a_belt_stuck_on_may_carry_several_workpieces_at_once() {
    // The belt motor M201 of `fixtures/diagnosis/conveyor.toml` sticks on.
    // The control stops the belt at the end stop B203, but the belt runs on
    // and carries two more workpieces up behind the one held there. When that
    // one is taken, the next reaches B203 with a third still on B202: a joint
    // state the control, which carries one workpiece at a time, never made.
    let events = [
        (3000, "M201", true),
        (3080, "B201", false),
        (3330, "B202", true),
        (3420, "B202", false),
        (3700, "M201", false),
        (3700, "B203", true),
        (5000, "B201", true),
        (5080, "B201", false),
        (5330, "B202", true),
        (5420, "B202", false),
        (6000, "B201", true),
        (6080, "B201", false),
        (6330, "B202", true),
        (30_000, "B203", false),
        (30_085, "B203", true),
    ];
    let labels = fixture_labels("conveyor", &|t| t, &["B201"], &events, 31_000);
    assert_eq!(labels, ["M201.actuator_stuck1"]);
}

#[test]
fn a_valve_stuck_on_does_not_explain_an_end_switch_that_reads_both_ends() {
    // The retracted switch B106 of `fixtures/diagnosis/unloader.toml` sticks
    // at 1: the unloader extends without it falling, reaches B107, and is
    // released. A valve stuck on would hold the cylinder out, but B107 falls,
    // and the element's own sensors never read both ends at once.
    let events = [
        (1000, "Y106", true),
        (1960, "Y106", false),
        (1960, "B107", true),
        (1960, "B108", false),
        (1975, "B107", false),
    ];
    let labels = fixture_labels("unloader", &|t| t, &["B106", "B108"], &events, 4000);
    assert_eq!(labels, ["B106.stuck1"]);
}

#[test]
fn a_stuck_switch_keeps_its_label_when_the_control_sends_a_slide_out_from_half_way() {
    // The home switch B402 of `fixtures/diagnosis/slide.toml` sticks on. The
    // control, reading it, releases the return valve as soon as the slide
    // leaves its far end, and the slide stays half-way. Sent out again from
    // there, it no longer pushes the workpiece off the input sensor B401.
    let events = [
        (10_000, "Y401", true),
        (10_064, "B401", false),
        (11_152, "Y401", false),
        (11_152, "Y402", true),
        (11_152, "B403", true),
        (11_168, "Y402", false),
        (11_168, "B403", false),
        (11_632, "B401", true),
        (12_448, "Y401", true),
        (13_408, "Y401", false),
        (13_408, "Y402", true),
        (13_408, "B403", true),
        (13_424, "Y402", false),
        (13_440, "B403", false),
    ];
    let labels = fixture_labels("slide", &|t| t, &["B402", "B401"], &events, 20_000);
    assert!(labels.contains(&"B402.stuck1".to_string()), "{labels:?}");
}

#[test]
fn a_slide_blocked_in_transit_leaves_the_workpiece_sensor_to_the_workpieces() {
    // The slide of `fixtures/diagnosis/gate.toml` leaves its retracted switch
    // B102, pushes the workpiece off B101 and stops before B103. The next
    // workpiece reaches B101 9 s later, in a state the model only knew with a
    // slide that pushes it off within 16 ms.
    let events = [
        (10_000, "Y101", true),
        (10_005, "B102", false),
        (10_010, "B101", false),
        (18_670, "B101", true),
    ];
    let labels = fixture_labels("gate", &|t| t, &["B102", "B101"], &events, 30_000);
    assert!(
        labels.contains(&"A11.blocked_between.B102.B103".to_string()),
        "{labels:?}"
    );
}

#[test]
fn an_edge_out_of_its_window_is_timed_on_the_window_s_own_clock() {
    // On the belt of `fixtures/diagnosis/conveyor.toml`, a workpiece passes
    // the middle sensor B202 in 74–105 ms; here in 30 ms, 360 ms after the
    // belt started.
    let events = [
        (1000, "B201", true),
        (3000, "M201", true),
        (3080, "B201", false),
        (3330, "B202", true),
        (3360, "B202", false),
    ];
    let verdicts = fixture_verdicts("conveyor", &|t| t, &|m| m, &[], &events, 4000);
    let first = verdicts
        .iter()
        .find(|v| v.part == "conveyor")
        .expect("the belt leaves normal");
    assert!(
        first
            .reason
            .starts_with("FE(B202) at 30 ms after RE(B202), outside its window ["),
        "{}",
        first.reason
    );
}

/// One case of `fixtures/engine/`: a fixture part, the faults that replace
/// its plant file's, its initial values, events and end, what its final labels must
/// hold, and the exact verdict lines.
struct Case {
    plant: String,
    /// `label=template` pairs that replace the plant file's `[faults]`.
    faults: Vec<String>,
    on: Vec<String>,
    end: i64,
    contains: Vec<String>,
    excludes: Vec<String>,
    events: Vec<(i64, String, bool)>,
    verdicts: Vec<String>,
    /// The text before `verdicts:`, kept when the lines are rewritten.
    head: String,
}

/// Reads a case file. Lines: `key: value` (plant, faults, on, end, contains,
/// excludes), then `events:` and one `t signal value` per line (t in ms), then
/// `verdicts:` and the expected JSON lines. `#` starts a comment line.
fn parse_case(path: &Path) -> Case {
    let text = std::fs::read_to_string(path).expect("case file");
    let (head, verdicts) = text.split_once("verdicts:\n").unwrap_or((&text, ""));
    let mut case = Case {
        plant: String::new(),
        faults: Vec::new(),
        on: Vec::new(),
        end: 0,
        contains: Vec::new(),
        excludes: Vec::new(),
        events: Vec::new(),
        verdicts: verdicts.lines().map(str::to_string).collect(),
        head: head.to_string(),
    };
    let mut in_events = false;
    for (n, line) in head.lines().enumerate() {
        let where_ = || format!("{}:{}", path.display(), n + 1);
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if line == "events:" {
            in_events = true;
            continue;
        }
        let words: Vec<String> = line.split_whitespace().map(str::to_string).collect();
        if in_events {
            let [t, signal, value] = &words[..] else {
                panic!("{}: expected `t signal value`", where_());
            };
            let t = t.parse().unwrap_or_else(|_| panic!("{}: time", where_()));
            case.events.push((t, signal.clone(), value == "1"));
            continue;
        }
        let (key, rest) = line
            .split_once(':')
            .unwrap_or_else(|| panic!("{}", where_()));
        let list: Vec<String> = rest.split_whitespace().map(str::to_string).collect();
        match key {
            "plant" => case.plant = rest.trim().to_string(),
            "faults" => case.faults = list,
            "on" => case.on = list,
            "end" => case.end = rest.trim().parse().expect("end"),
            "contains" => case.contains = list,
            "excludes" => case.excludes = list,
            _ => panic!("{}: unknown key '{key}'", where_()),
        }
    }
    case
}

/// A plant file's text with its `[faults]` (its last table) replaced by the
/// faults `label=template`, when there are some.
fn with_faults(text: String, faults: &[String]) -> String {
    if faults.is_empty() {
        return text;
    }
    let (head, table) = text.split_once("[faults]\n").expect("[faults]");
    assert!(!table.contains("\n["), "[faults] is not the last table");
    let lines: String = faults
        .iter()
        .map(|f| {
            let (label, template) = f.split_once('=').expect("faults: label=template");
            format!("\"{label}\" = \"{template}\"\n")
        })
        .collect();
    format!("{head}[faults]\n{lines}")
}

/// Every case of `diagnoser/tests/fixtures/engine/` gives its verdict lines
/// exactly, and its final labels hold what the case says. With
/// `UPDATE_EXPECT=1`, the verdict lines are rewritten instead (the label
/// checks still hold).
#[test]
fn engine_cases_give_their_verdict_lines() {
    let dir = repo("diagnoser/tests/fixtures/engine");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("cases")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "case"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 8, "{} cases", paths.len());
    let update = std::env::var_os("UPDATE_EXPECT").is_some();
    let mut failures = Vec::new();
    for path in &paths {
        let case = parse_case(path);
        let on: Vec<&str> = case.on.iter().map(String::as_str).collect();
        let events: Vec<(i64, &str, bool)> = case
            .events
            .iter()
            .map(|(t, s, v)| (*t, s.as_str(), *v))
            .collect();
        let verdicts = fixture_verdicts(
            &case.plant,
            &|t| with_faults(t, &case.faults),
            &|m| m,
            &on,
            &events,
            case.end,
        );
        let labels = verdicts
            .iter()
            .rev()
            .find(|v| v.part == case.plant)
            .map_or_else(|| vec!["N".to_string()], |v| v.labels.clone());
        for l in &case.contains {
            assert!(
                labels.contains(l),
                "{}: {labels:?} lacks {l}",
                path.display()
            );
        }
        for l in &case.excludes {
            assert!(
                !labels.contains(l),
                "{}: {labels:?} has {l}",
                path.display()
            );
        }
        let lines: Vec<String> = verdicts
            .iter()
            .map(|v| v.json_line(diagnoser::TimeFormat::Numeric(TimeUnit::Ms), None))
            .collect();
        if update {
            let text = format!("{}verdicts:\n{}\n", case.head, lines.join("\n"));
            std::fs::write(path, text.trim_end().to_string() + "\n").expect("rewrite");
        } else if lines != case.verdicts {
            failures.push(format!(
                "{}:\nexpected\n{}\ngot\n{}",
                path.display(),
                case.verdicts.join("\n"),
                lines.join("\n")
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{}\n(rerun with UPDATE_EXPECT=1 to accept)",
        failures.join("\n\n")
    );
}
