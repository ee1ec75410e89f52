//! The filter-based simplification of the diagnosers (seed 002 §4) on the
//! sorting line, with the model learned from the shipped normal run
//! (`diagnoser/tests/fixtures/diagnosis/sorting-model.json`), and the universal
//! quantification over what a constraint reads outside the part.

use std::path::{Path, PathBuf};

use diagnoser::Plant;
use diagnoser::diagnosis::compile::{Commands, Compiled, Trigger};
use diagnoser::diagnosis::{DiagnoserOptions, Engine, PlantDiagnoser};
use diagnoser::expr::Expr;
use diagnoser::model::Model;
use diagnoser::plant::Constraint;
use filter_coupling::simplify::PartFilter;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn plant() -> Plant {
    Plant::from_path(&repo("datasets/plants/sorting.toml")).expect("plant")
}

/// The parts' engines as `check --filter` explores them: orders come
/// anywhere, each starting a whole stroke.
fn engines(plant: &Plant) -> Vec<Engine> {
    let model = Model::from_path(&repo(
        "diagnoser/tests/fixtures/diagnosis/sorting-model.json",
    ))
    .expect("model");
    PlantDiagnoser::new(plant, &model, &DiagnoserOptions::default())
        .expect("diagnoser")
        .engines()
        .map(|e| Engine::new(e.part.without_reversals()))
        .collect()
}

fn engine(plant: &Plant, part: &str) -> Engine {
    engines(plant)
        .into_iter()
        .find(|e| e.part.name == part)
        .expect("part")
}

/// The observed scans (state vectors before and after) of a compiled diagnoser.
fn scans(engine: &Engine, compiled: &Compiled) -> Vec<(u32, u32)> {
    let g = &compiled.graph;
    g.edge_indices()
        .filter_map(|e| {
            let (a, _) = g.edge_endpoints(e)?;
            match g[e] {
                Trigger::Scan(ch) => {
                    let obs = engine.state(g[a].state).obs;
                    Some((obs, obs ^ ch))
                }
                Trigger::Time { .. } => None,
            }
        })
        .collect()
}

fn bit(engine: &Engine, name: &str) -> u32 {
    engine
        .part
        .names
        .iter()
        .position(|n| n == name)
        .expect("signal of the part") as u32
}

#[test]
fn the_turntable_filter_uses_cs14_and_cs15() {
    let plant = plant();
    let e = engine(&plant, "turntable");
    let f = PartFilter::new(&plant, &e.part.names).expect("filter");
    // CSs13 = C4 & !C6 & A4 and the others read signals of other parts, which
    // may take the value that keeps them at 0.
    assert_eq!(f.constraints().collect::<Vec<_>>(), ["CSs14", "CSs15"]);
    assert!(f.skipped().is_empty());
}

#[test]
fn the_filtered_turntable_is_smaller_and_never_breaks_cs14_or_cs15() {
    let plant = plant();
    let mut e = engine(&plant, "turntable");
    let f = PartFilter::new(&plant, &e.part.names).expect("filter");
    let allows = |a: u32, b: u32| f.allows(a, b);
    let any = Compiled::explore_with(&mut e, 2, Commands::Any);
    let filtered = Compiled::explore_with(&mut e, 2, Commands::Filter(&allows));
    assert!(!any.truncated && !filtered.truncated);
    let (sa, sf) = (any.size(), filtered.size());
    assert!(
        sf.states < sa.states && sf.transitions < sa.transitions,
        "any {sa:?}, filtered {sf:?}"
    );

    let (a4, c4, c5) = (bit(&e, "A4"), bit(&e, "C4"), bit(&e, "C5"));
    let on = |v: u32, b: u32| v >> b & 1 == 1;
    // CSs14 = !C4 & RE(A4), CSs15 = !C5 & FE(A4), on the observed values.
    let breaks = |(before, after): (u32, u32)| {
        let rise = on(after, a4) && !on(before, a4);
        let fall = !on(after, a4) && on(before, a4);
        (rise && !on(after, c4)) || (fall && !on(after, c5))
    };
    let bad_any = scans(&e, &any).into_iter().filter(|&s| breaks(s)).count();
    assert!(bad_any > 0, "with any command, such scans are explored");
    let bad: Vec<(u32, u32)> = scans(&e, &filtered)
        .into_iter()
        .filter(|&s| breaks(s))
        .collect();
    assert!(bad.is_empty(), "filtered scans breaking CSs14/15: {bad:?}");
}

#[test]
fn the_learned_control_exploration_is_unchanged() {
    let plant = plant();
    let mut e = engine(&plant, "turntable");
    let default = Compiled::explore(&mut e, 2).size();
    let learned = Compiled::explore_with(&mut e, 2, Commands::Learned).size();
    assert_eq!(default, learned);
    let any = Compiled::explore_with(&mut e, 2, Commands::Any).size();
    assert!(learned.states < any.states, "{learned:?} {any:?}");
}

#[test]
fn parts_without_a_constraint_of_their_own_keep_their_size() {
    let plant = plant();
    for mut e in engines(&plant) {
        if e.part.name == "turntable" {
            continue;
        }
        let f = PartFilter::new(&plant, &e.part.names).expect("filter");
        assert_eq!(f.constraints().count(), 0, "{}", e.part.name);
        let allows = |a: u32, b: u32| f.allows(a, b);
        let any = Compiled::explore_with(&mut e, 2, Commands::Any).size();
        let filtered = Compiled::explore_with(&mut e, 2, Commands::Filter(&allows)).size();
        assert_eq!(any, filtered, "{}", e.part.name);
    }
}

fn filter(exprs: &[&str]) -> PartFilter {
    let constraints: Vec<Constraint> = exprs
        .iter()
        .enumerate()
        .map(|(i, e)| Constraint {
            name: format!("K{i}"),
            expr: Expr::parse(e).expect("parses"),
            priority: None,
        })
        .collect();
    let names = ["A4", "C4", "C5"].map(String::from);
    PartFilter::from_constraints(&constraints, &names, &|n| n.starts_with('A')).expect("filter")
}

// Bits: A4 = 1, C4 = 2, C5 = 4.
const REST_AT_C4: u32 = 0b010;
const START_AT_C4: u32 = 0b011;
const START_AWAY: u32 = 0b001;

#[test]
fn an_unknown_observer_prunes_only_when_both_values_do() {
    // P36 = 1 alone would forbid; P36 = 0 allows: nothing is removed.
    let f = filter(&["!C4 & RE(A4) & P36"]);
    assert_eq!(f.constraints().count(), 0);
    assert!(f.allows(0, START_AWAY));
    // True for P36 = 1 and for P36 = 0: removed.
    let f = filter(&["!C4 & RE(A4) & P36 | !C4 & RE(A4) & !P36"]);
    assert!(!f.allows(0, START_AWAY));
    assert!(f.allows(REST_AT_C4, START_AT_C4));
    // Another part's sensor, negated or not, is the same.
    let f = filter(&["C4 & !C6 & A4"]);
    assert!(f.allows(REST_AT_C4, START_AT_C4));
}

#[test]
fn an_unknowns_previous_value_is_free_too() {
    // Were prev(X) tied to X, `X | !prev(X)` would always hold; X = 0 after
    // X = 1 makes it 0.
    let f = filter(&["A4 & (X | !prev(X))"]);
    assert!(f.allows(REST_AT_C4, START_AT_C4));
    let f = filter(&["A4 & (X | !X)"]);
    assert!(!f.allows(REST_AT_C4, START_AT_C4));
    assert!(f.allows(START_AT_C4, REST_AT_C4));
    // An edge of an unknown: RE(X) | FE(X) | X | prev(X) misses X = prev(X) = 0.
    let f = filter(&["A4 & (RE(X) | FE(X) | X | prev(X))"]);
    assert!(f.allows(REST_AT_C4, START_AT_C4));
}
