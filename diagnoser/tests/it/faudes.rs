//! Tests of `diagnoser::faudes`: libFAUDES files and event-diagnosability.
//!
//! The models are those of libFAUDES's diagnosis tutorial, plus a few small ones
//! pinning down points of libFAUDES's semantics (`tests/fixtures/faudes/models.txt`
//! says which is which). Their expected verdicts, `expected.txt`, are libFAUDES's
//! own, written by `scripts/faudes-compare.py --write`; the tests check that ours
//! are the same, that every counterexample is a genuine pair of runs, and that bad
//! files fail with an error naming file, line and column.

use std::collections::{BTreeSet, HashSet, VecDeque};
use std::fs;
use std::path::{Path, PathBuf};

use diagnoser::faudes::{
    AssumptionViolation, Counterexample, EventDiagnosability, FailureTypes, Generator,
    event_diagnosability, event_diagnosability_explored, event_diagnosability_within,
    parse_failure_types, parse_generator, render,
};
use proptest::prelude::*;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/faudes")
}

fn fixture_text(name: &str) -> String {
    fs::read_to_string(fixtures().join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn generator(name: &str) -> Generator {
    parse_generator(&fixture_text(name), Path::new(name)).unwrap_or_else(|e| panic!("{e}"))
}

fn failure_types(name: &str) -> FailureTypes {
    parse_failure_types(&fixture_text(name), Path::new(name)).unwrap_or_else(|e| panic!("{e}"))
}

/// Non-comment lines of a fixture list, split into fields.
fn rows(name: &str) -> Vec<Vec<String>> {
    fixture_text(name)
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .collect()
}

fn word(diagnosable: bool) -> &'static str {
    if diagnosable {
        "diagnosable"
    } else {
        "not-diagnosable"
    }
}

/// Our verdicts in the form of `expected.txt`: for the map, then per type alone.
fn verdict_line(result: &EventDiagnosability, f: &FailureTypes) -> String {
    let mut line = word(result.diagnosable).to_string();
    for (name, _) in &f.types {
        let alone = result.type_diagnosable(name).expect("type in the result");
        line.push_str(&format!(" {name}={}", word(alone)));
    }
    line
}

#[test]
fn verdicts_match_libfaudes() {
    let expected = rows("expected.txt");
    let mut mismatches = Vec::new();
    for row in &expected {
        let (gen_file, map_file) = (&row[0], &row[1]);
        let f = failure_types(map_file);
        let ours = verdict_line(&event_diagnosability(&generator(gen_file), &f), &f);
        let theirs = row[2..].join(" ");
        if ours != theirs {
            mismatches.push(format!("{gen_file}: libFAUDES '{theirs}', ours '{ours}'"));
        }
    }
    assert!(mismatches.is_empty(), "{mismatches:#?}");
    // Both verdicts occur, overall and per type, so that a verifier answering
    // always the same would fail.
    let words: Vec<&str> = expected
        .iter()
        .flat_map(|r| r[2..].iter())
        .map(|w| w.rsplit('=').next().unwrap_or(w))
        .collect();
    assert!(expected.iter().any(|r| r[2] == "diagnosable"));
    assert!(expected.iter().any(|r| r[2] == "not-diagnosable"));
    assert!(words.iter().filter(|w| **w == "diagnosable").count() >= 3);
}

#[test]
fn expected_verdicts_cover_every_model() {
    let models: Vec<(String, String)> = rows("models.txt")
        .into_iter()
        .map(|r| (r[0].clone(), r[1].clone()))
        .collect();
    let expected: Vec<(String, String)> = rows("expected.txt")
        .into_iter()
        .map(|r| (r[0].clone(), r[1].clone()))
        .collect();
    assert_eq!(
        models, expected,
        "expected.txt is stale: run scripts/faudes-compare.py --write"
    );
    assert!(models.len() >= 9, "only {} models", models.len());
}

/// States reachable from `from` by the run `events` (the generator may be
/// nondeterministic).
fn after(g: &Generator, from: &BTreeSet<usize>, events: &[usize]) -> BTreeSet<usize> {
    let mut states = from.clone();
    for &e in events {
        states = g
            .transitions
            .iter()
            .filter(|(x, ev, _)| *ev == e && states.contains(x))
            .map(|&(_, _, y)| y)
            .collect();
    }
    states
}

/// Checks that `ce` is a genuine indeterminate cycle of `g` for the failure events
/// `failures`: two runs from an initial state whose loops can repeat, the same
/// observation, a failure in the faulty stem and none in the normal run.
pub(crate) fn check_counterexample(
    g: &Generator,
    failures: &[String],
    ce: &Counterexample,
) -> Result<(), String> {
    let index = |name: &String| {
        g.events
            .iter()
            .position(|e| e == name)
            .ok_or(format!("unknown event {name}"))
    };
    let observable_part = |run: &[usize]| -> Vec<String> {
        run.iter()
            .filter(|&&e| g.observable[e])
            .map(|&e| g.events[e].clone())
            .collect()
    };
    if ce.cycle_from >= ce.observed.len() {
        return Err("the loop shows no observable event".into());
    }
    let initial: BTreeSet<usize> = g.initial.iter().copied().collect();
    let mut stems = Vec::new();
    for (role, run) in [("faulty", &ce.faulty), ("normal", &ce.normal)] {
        let run: Vec<usize> = run.iter().map(index).collect::<Result<_, _>>()?;
        if observable_part(&run) != ce.observed {
            return Err(format!("the {role} run does not show the observation"));
        }
        // The loop starts right after the cycle_from-th observable event.
        let mut seen = 0;
        let mut split = 0;
        while seen < ce.cycle_from {
            if g.observable[run[split]] {
                seen += 1;
            }
            split += 1;
        }
        let (stem, cycle) = run.split_at(split);
        let closes = after(g, &initial, stem)
            .into_iter()
            .any(|x| after(g, &BTreeSet::from([x]), cycle).contains(&x));
        if !closes {
            return Err(format!(
                "the {role} run is not a stem and a loop of the generator"
            ));
        }
        stems.push((stem.to_vec(), run.clone()));
    }
    let is_failure = |e: &usize| failures.contains(&g.events[*e]);
    if !stems[0].0.iter().any(is_failure) {
        return Err("no failure in the faulty stem".into());
    }
    if stems[1].1.iter().any(is_failure) {
        return Err("a failure in the normal run".into());
    }
    Ok(())
}

#[test]
fn counterexamples_are_genuine() {
    let mut checked = 0;
    for row in rows("expected.txt") {
        let g = generator(&row[0]);
        let f = failure_types(&row[1]);
        let result = event_diagnosability(&g, &f);
        for ((name, failures), verdict) in f.types.iter().zip(&result.types) {
            assert_eq!(&verdict.failure_type, name);
            match &verdict.counterexample {
                Some(ce) => {
                    assert!(!verdict.diagnosable, "{}: {name}", row[0]);
                    check_counterexample(&g, failures, ce)
                        .unwrap_or_else(|e| panic!("{} {name}: {e}: {ce:?}", row[0]));
                    checked += 1;
                }
                None => assert!(verdict.diagnosable, "{}: {name}", row[0]),
            }
        }
    }
    assert!(checked >= 4, "only {checked} counterexamples");
}

#[test]
fn forged_counterexamples_are_rejected() {
    // The check above must be able to fail: each forgery breaks one condition.
    let g = generator("diag_system_4.gen");
    let f = failure_types("diag_failure_typemap_4.txt");
    let result = event_diagnosability(&g, &f);
    let ce = result.types[0]
        .counterexample
        .clone()
        .expect("F1 is not diagnosable");
    let failures = &f.types[0].1;
    check_counterexample(&g, failures, &ce).expect("genuine");
    let swapped = Counterexample {
        faulty: ce.normal.clone(),
        normal: ce.faulty.clone(),
        ..ce.clone()
    };
    let mut not_a_path = ce.clone();
    not_a_path.faulty.swap(0, 2);
    let mut other_observation = ce.clone();
    other_observation.observed[1] = "alpha".into();
    let mut no_loop = ce.clone();
    no_loop.cycle_from = ce.observed.len();
    for forged in [swapped, not_a_path, other_observation, no_loop] {
        assert!(
            check_counterexample(&g, failures, &forged).is_err(),
            "{forged:?}"
        );
    }
}

#[test]
fn tutorial_system_4_is_explained() {
    // libFAUDES's tutorial expects "not diagnosable" (diag_1_eventdiagnosis.cpp):
    // F1 cannot be told from the unobservable sigma_uo; F2 is revealed by sigma_I2.
    let result = event_diagnosability(
        &generator("diag_system_4.gen"),
        &failure_types("diag_failure_typemap_4.txt"),
    );
    assert_eq!(
        render(&result),
        "not diagnosable\n\
         failure type F1: not diagnosable\n\
         \x20 faulty:   sigma_I1 sigma_f1 beta (gamma)*\n\
         \x20 normal:   sigma_I1 sigma_uo beta (gamma)*\n\
         \x20 observed: sigma_I1 beta (gamma)*\n\
         failure type F2: diagnosable\n"
    );
}

#[test]
fn loops_with_unobservable_events_are_explained() {
    let result = event_diagnosability(
        &generator("semantics_nondeterministic.gen"),
        &failure_types("semantics_f1_f2.txt"),
    );
    assert_eq!(
        render(&result),
        "not diagnosable\n\
         failure type F1: not diagnosable\n\
         \x20 faulty:   a f1 b (a u b)*\n\
         \x20 normal:   a u b (a u b)*\n\
         \x20 observed: a b (a b)*\n\
         failure type F2: diagnosable\n"
    );
}

#[test]
fn failed_assumptions_are_reported() {
    let deadlock = event_diagnosability(
        &generator("semantics_unreachable_deadlock.gen"),
        &failure_types("semantics_f.txt"),
    );
    assert_eq!(
        deadlock.assumptions,
        vec![AssumptionViolation::Deadlock {
            states: vec!["3".into()],
            more: 0,
        }]
    );
    // The failure type itself is diagnosable; libFAUDES's verdict is not.
    assert!(deadlock.types[0].diagnosable);
    assert!(!deadlock.diagnosable);
    assert_eq!(deadlock.type_diagnosable("F"), Some(false));
    assert_eq!(deadlock.type_diagnosable("G"), None);
    assert!(
        render(&deadlock).contains("the generator is not live: no transition leaves state 3\n"),
        "{}",
        render(&deadlock)
    );

    let cycle = event_diagnosability(
        &generator("semantics_unreachable_unobservable_cycle.gen"),
        &failure_types("semantics_f.txt"),
    );
    assert_eq!(
        cycle.assumptions,
        vec![AssumptionViolation::UnobservableCycle {
            states: vec!["3".into(), "4".into()],
            events: vec!["u".into(), "u".into()],
        }]
    );
    assert!(render(&cycle).contains("cycle of unobservable events 3 -u-> 4 -u-> 3\n"));

    let g = generator("diag_system_3.gen");
    let f = FailureTypes {
        types: vec![
            ("F".into(), vec!["f".into()]),
            ("G".into(), vec!["alpha".into(), "nowhere".into()]),
        ],
    };
    let result = event_diagnosability(&g, &f);
    assert_eq!(
        result.assumptions,
        vec![
            AssumptionViolation::ObservableFailureEvent {
                failure_type: "G".into(),
                event: "alpha".into()
            },
            AssumptionViolation::UnknownFailureEvent {
                failure_type: "G".into(),
                event: "nowhere".into()
            },
        ]
    );
    assert_eq!(result.type_diagnosable("F"), Some(true));
    assert_eq!(result.type_diagnosable("G"), Some(false));
    assert!(!result.diagnosable);
}

#[test]
fn several_initial_states_are_allowed() {
    // libFAUDES refuses them; the definition does not need a single one. From 1
    // the failure is revealed by "b"; from 3 the same "a" loop hides it.
    let text = r#"<Generator> "two"
        <Alphabet> a b f +o+ </Alphabet>
        <States> 1 2 3 4 </States>
        <TransRel> 1 a 1  1 f 2  2 b 2  3 a 3  3 f 4  4 a 4 </TransRel>
        <InitStates> 1 3 </InitStates>
        </Generator>"#;
    let g = parse_generator(text, Path::new("two.gen")).expect("parses");
    let f = FailureTypes {
        types: vec![("F".into(), vec!["f".into()])],
    };
    let result = event_diagnosability(&g, &f);
    let ce = result.types[0]
        .counterexample
        .as_ref()
        .expect("not diagnosable");
    check_counterexample(&g, &f.types[0].1, ce).expect("genuine");
    assert_eq!(ce.observed, ["a", "a"]);
    assert_eq!(ce.cycle_from, 1);

    let mut from_1 = g.clone();
    from_1.initial = vec![0];
    assert!(event_diagnosability(&from_1, &f).diagnosable);
    let mut none = g;
    none.initial.clear();
    assert!(event_diagnosability(&none, &f).types[0].diagnosable);
}

#[test]
fn tutorial_files_read_as_libfaudes_reads_them() {
    let g = generator("diag_system_4.gen");
    assert_eq!(g.name, "Generator");
    assert_eq!(g.events.len(), 9);
    let unobservable: Vec<&str> = g
        .events
        .iter()
        .zip(&g.observable)
        .filter(|(_, o)| !**o)
        .map(|(e, _)| e.as_str())
        .collect();
    assert_eq!(unobservable, ["sigma_uo", "sigma_f1", "sigma_f2"]);
    assert_eq!(g.states, ["1", "2", "3", "4", "5", "6", "7"]);
    assert_eq!(g.transitions.len(), 10);
    assert_eq!(g.transitions[0], (0, 7, 1));
    assert_eq!(g.initial, [0]);
    assert!(g.marked.is_empty());

    // A <Consecutive> range of states, CRLF line ends.
    let g = generator("diag_system_2_language.gen");
    assert_eq!(g.states.len(), 7);
    assert!(fixture_text("diag_system_2_language.gen").contains("\r\n"));

    // Named states "1".."9" get indices 1..9: the initial state given as index 1
    // is the state named "1".
    let g = generator("diag_system_4_decentralized1.gen");
    assert_eq!(
        g.initial.iter().map(|&x| &g.states[x]).collect::<Vec<_>>(),
        ["1"]
    );

    // +C+ (controllable) does not touch observability.
    let g = generator("diag_system_3_modular_sf.gen");
    let flag = |name: &str| g.observable[g.events.iter().position(|e| e == name).expect(name)];
    assert!(flag("sf-c1") && flag("sfa") && !flag("pass") && !flag("f_pjm"));
    assert_eq!(g.states[0], "sf1");

    let g = generator("semantics_syntax.gen");
    assert_eq!(g.name, "syntax");
    assert_eq!(g.observable, [true, true, false, false]);
    assert_eq!(g.initial, [0]);
    assert_eq!(g.marked, [0]);

    let f = failure_types("diag_failure_typemap_4.txt");
    assert_eq!(
        f.types,
        [
            ("F1".to_string(), vec!["sigma_f1".to_string()]),
            ("F2".to_string(), vec!["sigma_f2".to_string()]),
        ]
    );
}

#[test]
fn event_flags_follow_libfaudes() {
    // As libFAUDES 2.34 reads them (checked with faudes.System(...).Observable):
    // observable unless the option holds 'o' or the flags lack bit 0x02.
    let text = "<Generator> \"flags\" <Alphabet> a b +O+ c +o+ d +Oo+ e +C+ g 0x00 h 0x02 \
                </Alphabet> <TransRel> </TransRel> </Generator>";
    let g = parse_generator(text, Path::new("flags.gen")).expect("parses");
    assert_eq!(g.observable, [true, true, false, false, true, false, true]);
}

#[test]
fn states_and_events_may_be_declared_by_transitions() {
    // libFAUDES declares them by their first use when <States> or <Alphabet> is
    // missing.
    let g = parse_generator(
        "<Generator> <TransRel> s a t  t b s </TransRel> <InitStates> s </InitStates> </Generator>",
        Path::new("implicit.gen"),
    )
    .expect("parses");
    assert_eq!(g.states, ["s", "t"]);
    assert_eq!(g.events, ["a", "b"]);
    assert_eq!(g.initial, [0]);
}

/// The error of parsing `text` as a generator at `path`.
fn generator_error(text: &str) -> String {
    parse_generator(text, Path::new("models/bad.gen"))
        .expect_err("must fail")
        .to_string()
}

#[test]
fn truncated_generator_fails_at_the_end() {
    let text = fixture_text("diag_system_3.gen");
    let cut = text
        .find("3             \"beta\"")
        .expect("line of state 3");
    let message = generator_error(&text[..cut]);
    assert_eq!(
        message,
        "models/bad.gen:16:1: field 'TransRel': the file ends early: expected the source \
         state of a transition"
    );
    let message = generator_error(&text[..text.find("</Generator>").expect("end")]);
    assert_eq!(
        message,
        "models/bad.gen:27:1: field 'Generator': the file ends early: expected </Generator>"
    );
}

#[test]
fn unknown_state_in_transitions_is_located() {
    let text = fixture_text("diag_system_3.gen").replace(
        "3             \"beta\"         2",
        "3             \"beta\"         9",
    );
    assert_eq!(
        generator_error(&text),
        "models/bad.gen:16:30: field 'TransRel': unknown state 9 (not in <States>)"
    );
    let text = fixture_text("diag_system_3_modular_sf.gen")
        .replace("\"sf9\"\t\t\"t_sf\"", "\"sf9\"\t\t\"t_sg\"");
    assert_eq!(
        generator_error(&text),
        "models/bad.gen:37:8: field 'TransRel': unknown event \"t_sg\" (not in <Alphabet>)"
    );
    let text = fixture_text("diag_system_3_modular_sf.gen").replace(
        "\"sf8\"\t\t\"sfs\"\t\t\"sf1\"",
        "\"sf8\"\t\t\"sfs\"\t\t\"sf0\"",
    );
    assert_eq!(
        generator_error(&text),
        "models/bad.gen:36:15: field 'TransRel': unknown state \"sf0\" (not in <States>)"
    );
}

#[test]
fn malformed_generators_are_located() {
    let cases = [
        (
            "",
            "models/bad.gen:1:1: field 'Generator': expected <Generator>, found the end of the file",
        ),
        (
            "<Generator> <Alphabet> \"a </Alphabet>",
            "models/bad.gen:1:24: field 'token': unterminated string: missing '\"'",
        ),
        (
            "<Generator> <Alphabet> a a </Alphabet>",
            "models/bad.gen:1:26: field 'Alphabet': event \"a\" is declared twice",
        ),
        (
            "<Generator> <Alphabet> a </Alphabet> <States> 1 1 </States>",
            "models/bad.gen:1:49: field 'States': state 1 is declared twice",
        ),
        (
            "<Generator>\n<TransRel> 1 a 1 </TransRel>\n<MarkedStates> </MarkedStates>\n\
             <InitStates> 1 </InitStates>\n</Generator>",
            "models/bad.gen:4:1: field 'Generator': section <InitStates> is out of place or \
             repeated: libFAUDES reads <Alphabet>, <States>, <TransRel>, <InitStates>, \
             <MarkedStates> in this order",
        ),
        (
            "<Generator> <States> <Consecutive> 3 1 </Consecutive> </States>",
            "models/bad.gen:1:22: field 'States': invalid range of states 3 to 1",
        ),
        (
            "<Generator> <TransRel> 1 a 1 </TransRel> <InitStates> 2 </InitStates> </Generator>",
            "models/bad.gen:1:55: field 'InitStates': unknown state 2 (not in <States>)",
        ),
        (
            "<Generator> <TransRel> 1 a 1 </TransRel> </Generator> <Generator>",
            "models/bad.gen:1:55: field 'Generator': unexpected <Generator> after </Generator>",
        ),
        (
            "% a <comment>\n<Generator> <TransRel> </TransRel> </Generator>",
            "models/bad.gen:1:5: field 'Generator': '<' or '>' in a comment before <Generator> \
             (libFAUDES refuses them there)",
        ),
        (
            "<Generator>\n<StateSet> </StateSet>",
            "models/bad.gen:2:1: field 'Generator': the XML form of generators is not \
             supported: write the generator in libFAUDES's token format (<States>, <TransRel>)",
        ),
    ];
    for (text, expected) in cases {
        assert_eq!(generator_error(text), expected, "{text:?}");
    }
}

#[test]
fn malformed_failure_types_are_located() {
    let error = |text: &str| {
        parse_failure_types(text, Path::new("models/bad.txt"))
            .expect_err("must fail")
            .to_string()
    };
    let text = fixture_text("diag_failure_typemap_4.txt");
    let cut = text.find("\"F2\"").expect("type F2");
    assert_eq!(
        error(&text[..cut]),
        "models/bad.txt:9:1: field 'FailureTypes': the file ends early: expected a failure \
         type name, <FailureEvents>, <IndicatorEvents> or </FailureTypes>"
    );
    assert_eq!(
        error("<FailureTypes> \"F\" <FailureEvents> \"f\" 12 </FailureEvents> </FailureTypes>"),
        "models/bad.txt:1:40: field 'FailureEvents': expected an event name or \
         </FailureEvents>, found 12"
    );
    assert_eq!(
        error("<FailureTypes> \"F\" \"F\" </FailureTypes>"),
        "models/bad.txt:1:20: field 'FailureTypes': failure type \"F\" is given twice"
    );
    assert_eq!(
        error("<Generator>"),
        "models/bad.txt:1:1: field 'FailureTypes': expected <FailureTypes>, found <Generator>"
    );
}

// ---------------------------------------------------------------------------------
// Random generators

/// A reference verifier built differently: the verifier of Jiang et al. (2001) on
/// the generator itself, where either run moves alone on unobservable events and
/// both move together on observable ones. A failure type is not diagnosable iff a
/// reachable verifier state where run 1 has failed (and run 2, which never takes a
/// failure, has not) lies on a cycle that shows an observable event.
fn reference_diagnosable(g: &Generator, failures: &[String]) -> bool {
    let n = g.states.len();
    let is_failure = |e: usize| !g.observable[e] && failures.contains(&g.events[e]);
    let id = |x1: usize, failed: bool, x2: usize| (x1 * 2 + usize::from(failed)) * n + x2;
    let count = 2 * n * n;
    // Successors: (node, observable move?).
    let mut succ: Vec<Vec<(usize, bool)>> = vec![Vec::new(); count];
    for x1 in 0..n {
        for failed in [false, true] {
            for x2 in 0..n {
                let v = id(x1, failed, x2);
                for &(a, e, b) in &g.transitions {
                    if g.observable[e] {
                        if a != x1 {
                            continue;
                        }
                        for &(c, e2, d) in &g.transitions {
                            if c == x2 && e2 == e {
                                succ[v].push((id(b, failed, d), true));
                            }
                        }
                    } else {
                        if a == x1 {
                            succ[v].push((id(b, failed || is_failure(e), x2), false));
                        }
                        if a == x2 && !is_failure(e) {
                            succ[v].push((id(x1, failed, b), false));
                        }
                    }
                }
            }
        }
    }
    let mut reachable = vec![false; count];
    let mut queue: VecDeque<usize> = VecDeque::new();
    for &i in &g.initial {
        for &j in &g.initial {
            let v = id(i, false, j);
            if !reachable[v] {
                reachable[v] = true;
                queue.push_back(v);
            }
        }
    }
    while let Some(v) = queue.pop_front() {
        for &(w, _) in &succ[v] {
            if !reachable[w] {
                reachable[w] = true;
                queue.push_back(w);
            }
        }
    }
    for x1 in 0..n {
        for x2 in 0..n {
            let v = id(x1, true, x2);
            if !reachable[v] {
                continue;
            }
            // Does v reach itself along a path with an observable move?
            let mut seen = HashSet::from([(v, false)]);
            let mut queue = VecDeque::from([(v, false)]);
            while let Some((u, shown)) = queue.pop_front() {
                for &(w, observable) in &succ[u] {
                    let next = (w, shown || observable);
                    if next == (v, true) {
                        return false;
                    }
                    if seen.insert(next) {
                        queue.push_back(next);
                    }
                }
            }
        }
    }
    true
}

/// Small random generators: 1 to 5 states, events e0.. with random observability,
/// the unobservable ones possibly failures (of one or two types), random
/// transitions, one or two initial states.
fn random_model() -> impl Strategy<Value = (Generator, FailureTypes)> {
    (1usize..=5, 1usize..=4).prop_flat_map(|(n, m)| {
        (
            proptest::collection::vec(any::<bool>(), m),
            proptest::collection::vec(0u8..3, m),
            proptest::collection::vec((0..n, 0..m, 0..n), 0..=12),
            proptest::collection::btree_set(0..n, 1..=2),
        )
            .prop_map(move |(observable, role, transitions, initial)| {
                let events: Vec<String> = (0..m).map(|e| format!("e{e}")).collect();
                let mut types: Vec<(String, Vec<String>)> =
                    vec![("F1".into(), Vec::new()), ("F2".into(), Vec::new())];
                for e in 0..m {
                    // Role 1 or 2: a failure of that type, when unobservable.
                    if !observable[e] && role[e] > 0 {
                        types[usize::from(role[e] - 1)].1.push(events[e].clone());
                    }
                }
                let mut seen = HashSet::new();
                let g = Generator {
                    name: "random".into(),
                    events,
                    observable,
                    states: (0..n).map(|x| format!("s{x}")).collect(),
                    initial: initial.into_iter().collect(),
                    marked: Vec::new(),
                    transitions: transitions
                        .into_iter()
                        .filter(|t| seen.insert(*t))
                        .collect(),
                };
                (g, FailureTypes { types })
            })
    })
}

/// The generator written in libFAUDES's token format.
fn write_generator(g: &Generator) -> String {
    let mut text = format!("<Generator> \"{}\"\n<Alphabet>", g.name);
    for (e, observable) in g.events.iter().zip(&g.observable) {
        text.push_str(&format!(
            " \"{e}\"{}",
            if *observable { "" } else { " +o+" }
        ));
    }
    text.push_str(" </Alphabet>\n<States>");
    for x in &g.states {
        text.push_str(&format!(" \"{x}\""));
    }
    text.push_str(" </States>\n<TransRel>\n");
    for &(x, e, y) in &g.transitions {
        text.push_str(&format!(
            "\"{}\" \"{}\" \"{}\"\n",
            g.states[x], g.events[e], g.states[y]
        ));
    }
    text.push_str("</TransRel>\n<InitStates>");
    for &x in &g.initial {
        text.push_str(&format!(" \"{}\"", g.states[x]));
    }
    text.push_str(" </InitStates>\n</Generator>\n");
    text
}

/// Every verdict of `result` is the reference's, and every counterexample a
/// pair of runs of `g`.
fn agrees_with_the_reference(
    g: &Generator,
    f: &FailureTypes,
    result: &EventDiagnosability,
) -> Result<(), TestCaseError> {
    for ((name, failures), verdict) in f.types.iter().zip(&result.types) {
        prop_assert_eq!(
            verdict.diagnosable,
            reference_diagnosable(g, failures),
            "type {}: {}",
            name,
            render(result)
        );
        if let Some(ce) = &verdict.counterexample {
            let checked = check_counterexample(g, failures, ce);
            prop_assert!(checked.is_ok(), "{:?}: {:?}", checked, ce);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn verifier_agrees_with_the_reference((g, f) in random_model()) {
        agrees_with_the_reference(&g, &f, &event_diagnosability(&g, &f))?;
    }

    /// The depth-first search large verifiers get: the same verdicts, and
    /// counterexamples that are runs of the generator.
    #[test]
    fn depth_first_search_agrees_with_the_reference((g, f) in random_model()) {
        let result = event_diagnosability_explored(&g, &f, usize::MAX, 0).expect("no budget");
        agrees_with_the_reference(&g, &f, &result)?;
    }

    #[test]
    fn written_generators_read_back((g, _) in random_model()) {
        let back = parse_generator(&write_generator(&g), Path::new("random.gen"));
        prop_assert_eq!(back, Ok(g));
    }

    #[test]
    fn no_input_makes_the_parsers_panic(cut in 0usize..800, junk in "[ <>/\"+%a-z0-9#\n]{0,8}") {
        let text = fixture_text("diag_system_4.gen");
        let mut cut = cut.min(text.len());
        while !text.is_char_boundary(cut) {
            cut -= 1;
        }
        let mangled = format!("{}{junk}{}", &text[..cut], &text[cut..]);
        let _ = parse_generator(&mangled, Path::new("mangled.gen"));
        let _ = parse_generator(&text[..cut], Path::new("cut.gen"));
        let map = fixture_text("diag_failure_typemap_4.txt");
        let cut = cut.min(map.len());
        let _ = parse_failure_types(&format!("{}{junk}{}", &map[..cut], &map[cut..]), Path::new("m.txt"));
    }
}

/// `n` turntables, each of which may lose its C5 sensor, as one generator (the
/// product of independent components, as `scripts/turntable-product.py`
/// writes it) and its failure-type map.
fn turntables(n: u32) -> (String, String) {
    // (state, event, next) of one turntable; 4-7 after the failure `f`.
    const ONE: [(u32, &str, u32); 9] = [
        (0, "a", 1),
        (1, "c5", 2),
        (2, "r", 3),
        (3, "c4", 0),
        (0, "f", 4),
        (4, "a", 5),
        (5, "m", 6),
        (6, "r", 7),
        (7, "c4", 4),
    ];
    let mut text = String::from("<Generator>\n\"product\"\n<Alphabet>\n");
    for i in 0..n {
        for e in ["a", "c5", "r", "c4"] {
            text.push_str(&format!("\"{e}_{i}\"\n"));
        }
        text.push_str(&format!("\"f_{i}\" +o+\n\"m_{i}\" +o+\n"));
    }
    let states = 8u32.pow(n);
    text.push_str("</Alphabet>\n<States>\n");
    for s in 0..states {
        text.push_str(&format!("{}\n", s + 1));
    }
    text.push_str("</States>\n<TransRel>\n");
    for s in 0..states {
        for i in 0..n {
            let digit = s / 8u32.pow(i) % 8;
            for &(x, e, y) in ONE.iter().filter(|t| t.0 == digit) {
                let t = s - x * 8u32.pow(i) + y * 8u32.pow(i);
                text.push_str(&format!("{} \"{e}_{i}\" {}\n", s + 1, t + 1));
            }
        }
    }
    text.push_str("</TransRel>\n<InitStates>\n1\n</InitStates>\n<MarkedStates>\n</MarkedStates>\n</Generator>\n");
    let failures: String = (0..n).map(|i| format!("\"f_{i}\"\n")).collect();
    let map = format!(
        "<FailureTypes>\n\"F\"\n<FailureEvents>\n{failures}</FailureEvents>\n</FailureTypes>\n"
    );
    (text, map)
}

#[test]
fn a_product_of_turntables_is_answered_and_a_budget_gives_up_in_time() {
    // One turntable: a lost C5 shows when the plate comes back unseen.
    let (one, map) = turntables(1);
    let (g, f) = (
        parse_generator(&one, Path::new("one.gen")).expect("generator"),
        parse_failure_types(&map, Path::new("f.txt")).expect("map"),
    );
    assert!(event_diagnosability(&g, &f).diagnosable);
    // Three: the others may run for ever while one waits for its C5.
    let (three, map) = turntables(3);
    let (g, f) = (
        parse_generator(&three, Path::new("three.gen")).expect("generator"),
        parse_failure_types(&map, Path::new("f.txt")).expect("map"),
    );
    let result = event_diagnosability(&g, &f);
    assert!(!result.diagnosable);
    let shown = render(&result);
    assert!(shown.contains("faulty:   f_0 a_0 ("), "{shown}");
    let within = event_diagnosability_within(&g, &f, 10_000_000).expect("within budget");
    assert_eq!(render(&within), shown);
    let too_large = event_diagnosability_within(&g, &f, 1_000).expect_err("over budget");
    assert_eq!(too_large.failure_type, "F");
    assert!(too_large.reached > 1_000);
}

#[test]
fn a_large_verifier_stops_at_its_first_counterexample() {
    let (four, map) = turntables(4);
    let (g, f) = (
        parse_generator(&four, Path::new("four.gen")).expect("generator"),
        parse_failure_types(&map, Path::new("f.txt")).expect("map"),
    );
    let whole = event_diagnosability_explored(&g, &f, usize::MAX, usize::MAX).expect("no budget");
    let (depth_first, size) = (1..)
        .map(|k| 1usize << (2 * k))
        .find_map(|budget| {
            let r = event_diagnosability_explored(&g, &f, budget, 0).ok()?;
            Some((r, budget))
        })
        .expect("an answer within some budget");
    assert!(!whole.diagnosable && !depth_first.diagnosable);
    let ce = depth_first.types[0]
        .counterexample
        .as_ref()
        .expect("a counterexample");
    check_counterexample(&g, &f.types[0].1, ce).expect("a run of the generator");
    // The whole breadth-first exploration needs far more than the search.
    let too_small = event_diagnosability_explored(&g, &f, size, usize::MAX);
    assert!(too_small.is_err(), "the whole twin plant fits in {size}");
}
