//! Tests of `diagnoser::faudes::product`: a plant given as several generators
//! gets the verdicts its product would (`parallel`, then the check of one
//! generator), with counterexamples that are runs of the product, however its
//! components share events.

use std::collections::{BTreeSet, HashSet};
use std::path::Path;

use diagnoser::faudes::product::{self, ProductError, clusters, parallel};
use diagnoser::faudes::{
    AssumptionViolation, EventDiagnosability, FailureTypes, Generator, event_diagnosability,
    parse_failure_types, parse_generator, render,
};
use proptest::prelude::*;

use super::faudes::check_counterexample;

/// Events `e0`..`e5`: each observable or not, and (unobservable) maybe a
/// failure of type F1 or F2. Two or three components, each over a random
/// subset of them (so they share events or not), 1 to 4 states, random
/// transitions and initial states.
fn random_plant() -> impl Strategy<Value = (Vec<Generator>, FailureTypes)> {
    const EVENTS: usize = 6;
    let component = (
        1usize..=4,
        1u8..(1 << EVENTS),
        proptest::collection::vec((0usize..4, 0usize..EVENTS, 0usize..4), 0..=8),
        proptest::collection::btree_set(0usize..4, 1..=2),
    );
    (
        proptest::collection::vec(any::<bool>(), EVENTS),
        proptest::collection::vec(0u8..3, EVENTS),
        proptest::collection::vec(component, 2..=3),
    )
        .prop_map(|(observable, role, components)| {
            let name = |e: usize| format!("e{e}");
            let mut types: Vec<(String, Vec<String>)> =
                vec![("F1".into(), Vec::new()), ("F2".into(), Vec::new())];
            for e in 0..EVENTS {
                if !observable[e] && role[e] > 0 {
                    types[usize::from(role[e] - 1)].1.push(name(e));
                }
            }
            let generators = (components.into_iter().enumerate())
                .map(|(i, (n, mask, transitions, initial))| {
                    let mine: Vec<usize> = (0..EVENTS).filter(|e| mask >> e & 1 == 1).collect();
                    let local = |e: usize| mine.iter().position(|&m| m == e);
                    let mut seen = HashSet::new();
                    Generator {
                        name: format!("c{i}"),
                        events: mine.iter().map(|&e| name(e)).collect(),
                        observable: mine.iter().map(|&e| observable[e]).collect(),
                        states: (0..n).map(|x| format!("s{x}")).collect(),
                        initial: initial.into_iter().filter(|&x| x < n).collect(),
                        marked: Vec::new(),
                        transitions: (transitions.into_iter())
                            .filter(|&(x, _, y)| x < n && y < n)
                            .filter_map(|(x, e, y)| Some((x, local(e)?, y)))
                            .filter(|t| seen.insert(*t))
                            .collect(),
                    }
                })
                .collect();
            (generators, FailureTypes { types })
        })
}

fn whole(components: &[Generator]) -> Generator {
    let refs: Vec<&Generator> = components.iter().collect();
    parallel(&refs, usize::MAX).expect("no budget").generator
}

/// The assumptions as compared: kinds, failure events, and the dead states
/// (counted, and listed ones among the product's).
fn same_assumptions(
    ours: &EventDiagnosability,
    theirs: &EventDiagnosability,
) -> Result<(), TestCaseError> {
    let kinds = |r: &EventDiagnosability| -> Vec<String> {
        (r.assumptions.iter())
            .map(|v| match v {
                AssumptionViolation::Deadlock { states, more } => {
                    format!("deadlock {}", states.len() + more)
                }
                AssumptionViolation::UnobservableCycle { .. } => "cycle".to_string(),
                other => format!("{other:?}"),
            })
            .collect()
    };
    prop_assert_eq!(kinds(ours), kinds(theirs));
    for (a, b) in ours.assumptions.iter().zip(&theirs.assumptions) {
        if let (
            AssumptionViolation::Deadlock { states: listed, .. },
            AssumptionViolation::Deadlock { states: all, .. },
        ) = (a, b)
        {
            let all: BTreeSet<&String> = all.iter().collect();
            prop_assert!(
                listed.iter().all(|x| all.contains(x)),
                "{:?} {:?}",
                listed,
                all
            );
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    /// The verdicts of the product, checked as a whole, and counterexamples
    /// that are two runs of it.
    #[test]
    fn components_get_the_verdicts_of_their_product((components, f) in random_plant()) {
        let g = whole(&components);
        let theirs = event_diagnosability(&g, &f);
        let ours = product::event_diagnosability(&components, &f, usize::MAX)
            .expect("consistent observability, no budget");
        prop_assert_eq!(ours.diagnosable, theirs.diagnosable, "{}\n{}", render(&ours), render(&theirs));
        same_assumptions(&ours, &theirs)?;
        for ((name, failures), (mine, whole)) in f.types.iter().zip(ours.types.iter().zip(&theirs.types)) {
            prop_assert_eq!(mine.diagnosable, whole.diagnosable, "type {}: {}", name, render(&ours));
            if let Some(ce) = &mine.counterexample {
                let checked = check_counterexample(&g, failures, ce);
                prop_assert!(checked.is_ok(), "{:?}: {:?}", checked, ce);
            }
        }
    }

    /// Every transition of the product is one of each component that has its
    /// event, the others standing still; every state is reachable.
    #[test]
    fn the_product_moves_as_its_components((components, _) in random_plant()) {
        let refs: Vec<&Generator> = components.iter().collect();
        let p = parallel(&refs, usize::MAX).expect("no budget");
        for &(x, e, y) in &p.generator.transitions {
            let name = &p.generator.events[e];
            for (i, g) in components.iter().enumerate() {
                let (a, b) = (p.members(x)[i] as usize, p.members(y)[i] as usize);
                match g.events.iter().position(|n| n == name) {
                    Some(local) => prop_assert!(g.transitions.contains(&(a, local, b))),
                    None => prop_assert_eq!(a, b),
                }
            }
        }
        let mut reached: BTreeSet<usize> = p.generator.initial.iter().copied().collect();
        loop {
            let more: Vec<usize> = (p.generator.transitions.iter())
                .filter(|t| reached.contains(&t.0) && !reached.contains(&t.2))
                .map(|t| t.2)
                .collect();
            if more.is_empty() {
                break;
            }
            reached.extend(more);
        }
        prop_assert_eq!(reached.len(), p.generator.states.len());
    }
}

/// One turntable `i` that may lose its C5 sensor (`f_i`), as in
/// `scripts/turntable-product.py`; with `link`, its release also needs the
/// shared event `go`.
fn turntable(i: usize, link: bool) -> Generator {
    let text = format!(
        "<Generator> \"t{i}\" <Alphabet> a_{i} c5_{i} r_{i} c4_{i} f_{i} +o+ m_{i} +o+ {} </Alphabet>
         <States> 1 2 3 4 5 6 7 8 </States>
         <TransRel> 1 a_{i} 2  2 c5_{i} 3  3 {} 4  4 c4_{i} 1  1 f_{i} 5
                    5 a_{i} 6  6 m_{i} 7  7 {} 8  8 c4_{i} 5 </TransRel>
         <InitStates> 1 </InitStates> </Generator>",
        if link { "go" } else { "" },
        if link { "go".to_string() } else { format!("r_{i}") },
        if link { "go".to_string() } else { format!("r_{i}") },
    );
    parse_generator(&text, Path::new("t.gen")).expect("turntable")
}

fn failures_of(n: usize) -> FailureTypes {
    let events: String = (0..n).map(|i| format!("f_{i} ")).collect();
    let text =
        format!("<FailureTypes> F <FailureEvents> {events} </FailureEvents> </FailureTypes>");
    parse_failure_types(&text, Path::new("f.txt")).expect("failure types")
}

#[test]
fn independent_turntables_are_checked_apart_however_many() {
    // Twelve turntables: 8^12 product states, far past any verifier; each
    // cluster is one turntable.
    let plant: Vec<Generator> = (0..12).map(|i| turntable(i, false)).collect();
    assert_eq!(clusters(&plant).len(), 12);
    let result = product::event_diagnosability(&plant, &failures_of(12), 10_000).expect("answered");
    assert!(!result.diagnosable);
    let ce = result.types[0]
        .counterexample
        .as_ref()
        .expect("counterexample");
    // Turntable 0 fails and waits; turntable 1 goes on alone in both runs.
    assert_eq!(ce.faulty[0], "f_0");
    assert_eq!(&ce.faulty[1..], &ce.normal[..]);
    assert!(ce.normal.iter().all(|e| e.ends_with("_1")), "{ce:?}");
    // Three of them, against their product checked as one generator.
    let three = &plant[..3];
    check_counterexample(
        &whole(three),
        &failures_of(3).types[0].1,
        product::event_diagnosability(three, &failures_of(3), 10_000)
            .expect("answered")
            .types[0]
            .counterexample
            .as_ref()
            .expect("counterexample"),
    )
    .expect("a counterexample of the product");
    // One turntable alone is diagnosable.
    assert!(
        product::event_diagnosability(&plant[..1], &failures_of(1), 10_000)
            .expect("answered")
            .diagnosable
    );
}

#[test]
fn linked_components_are_composed_within_the_budget() {
    // Releases synchronised on `go`: one cluster, checked as its product.
    let plant: Vec<Generator> = (0..3).map(|i| turntable(i, true)).collect();
    assert_eq!(clusters(&plant), vec![vec![0, 1, 2]]);
    let result = product::event_diagnosability(&plant, &failures_of(3), 1 << 20).expect("answered");
    let alone = event_diagnosability(&whole(&plant), &failures_of(3));
    assert_eq!(render(&result), render(&alone));
    let too_large =
        product::event_diagnosability(&plant, &failures_of(3), 100).expect_err("over budget");
    assert!(
        matches!(&too_large, ProductError::ProductTooLarge { components, reached } if components == &[0, 1, 2] && *reached > 100),
        "{too_large:?}"
    );
}

#[test]
fn an_event_observable_in_one_component_only_is_refused() {
    let observed = |i: usize, hidden: bool| {
        let text = format!(
            "<Generator> \"c{i}\" <Alphabet> x {} y{i} </Alphabet> <States> 1 </States>
             <TransRel> 1 x 1 1 y{i} 1 </TransRel> <InitStates> 1 </InitStates> </Generator>",
            if hidden { "+o+" } else { "" }
        );
        parse_generator(&text, Path::new("c.gen")).expect("component")
    };
    let error = product::event_diagnosability(
        &[observed(0, false), observed(1, true)],
        &failures_of(0),
        1000,
    )
    .expect_err("refused");
    assert_eq!(
        error,
        ProductError::Observability {
            event: "x".into(),
            observable_in: 0,
            unobservable_in: 1
        }
    );
}

#[test]
fn a_product_too_large_is_refused_before_it_is_made() {
    // Four components of 400 initial states each: 2.56 × 10^10 initial
    // states in the product, refused before one is made.
    let wide = |i: usize| Generator {
        name: format!("w{i}"),
        events: vec![format!("e{i}")],
        observable: vec![true],
        states: (0..400).map(|x| format!("s{x}")).collect(),
        initial: (0..400).collect(),
        marked: Vec::new(),
        transitions: (0..400).map(|x| (x, 0, x)).collect(),
    };
    let plant: Vec<Generator> = (0..4).map(wide).collect();
    let refs: Vec<&Generator> = plant.iter().collect();
    assert_eq!(parallel(&refs, 1_000_000).err(), Some(400usize.pow(4)));
    // Nondeterminism alike: one shared event with 400 successors in each.
    let fan = |i: usize| Generator {
        name: format!("n{i}"),
        events: vec!["go".into()],
        observable: vec![true],
        states: (0..400).map(|x| format!("s{x}")).collect(),
        initial: vec![0],
        marked: Vec::new(),
        transitions: (0..400).map(|y| (0, 0, y)).collect(),
    };
    let plant: Vec<Generator> = (0..4).map(fan).collect();
    let error =
        product::event_diagnosability(&plant, &failures_of(0), 1_000_000).expect_err("too large");
    assert!(
        matches!(error, ProductError::ProductTooLarge { reached, .. } if reached > 1_000_000),
        "{error:?}"
    );
}
