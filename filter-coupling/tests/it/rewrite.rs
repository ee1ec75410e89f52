//! The rewriting is conservative: with the flag raised, a rewritten constraint
//! forbids whenever the constraint on the healthy sensor could forbid, for every
//! value the sensor may take in the estimate's intervals; with the flag down it
//! is the original constraint.

use std::collections::HashMap;

use diagnoser::expr::Expr;
use filter_coupling::eval::{Scan, eval};
use filter_coupling::rewrite::{Estimate, RewriteOptions, rewrite};
use proptest::prelude::*;

/// Values now and in the previous scan.
struct Values(HashMap<String, (bool, bool)>);

impl Scan for Values {
    fn value(&self, name: &str) -> bool {
        self.0.get(name).is_some_and(|v| v.0)
    }
    fn previous(&self, name: &str) -> bool {
        self.0.get(name).is_some_and(|v| v.1)
    }
}

const NAMES: [&str; 3] = ["S", "X", "Y"];

fn expr() -> impl Strategy<Value = Expr> {
    let leaf = prop_oneof![
        (0usize..3).prop_map(|i| Expr::Var(NAMES[i].to_string())),
        (0usize..3).prop_map(|i| Expr::Rise(NAMES[i].to_string())),
        (0usize..3).prop_map(|i| Expr::Fall(NAMES[i].to_string())),
        (0usize..3).prop_map(|i| Expr::Prev(NAMES[i].to_string())),
        any::<bool>().prop_map(Expr::Const),
    ];
    leaf.prop_recursive(4, 24, 3, |inner| {
        prop_oneof![
            inner.clone().prop_map(|e| Expr::Not(Box::new(e))),
            prop::collection::vec(inner.clone(), 2..4).prop_map(Expr::And),
            prop::collection::vec(inner, 2..4).prop_map(Expr::Or),
        ]
    })
}

/// Per interval I1..I4: 0 = sensor certainly 0, 1 = certainly 1, 2 = uncertain.
fn kinds() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(0u8..3, 4)
}

fn estimate(kinds: &[u8]) -> Estimate {
    let name = |i: usize| format!("I{}", i + 1);
    Estimate {
        sensor: "S".into(),
        partition: "S".into(),
        certain: (0..kinds.len())
            .filter(|&i| kinds[i] == 1)
            .map(name)
            .collect(),
        uncertain: (0..kinds.len())
            .filter(|&i| kinds[i] == 2)
            .map(name)
            .collect(),
    }
}

/// A scan: the interval active now and before, the sensor's true values (free
/// only where the interval is uncertain), the other signals, the flag.
fn scan(
    kinds: &[u8],
    now: usize,
    before: usize,
    free: (bool, bool),
    others: [(bool, bool); 2],
    flag: bool,
) -> Values {
    let truth = |k: u8, f: bool| match k {
        0 => false,
        1 => true,
        _ => f,
    };
    let mut v = HashMap::new();
    v.insert(
        "S".to_string(),
        (truth(kinds[now], free.0), truth(kinds[before], free.1)),
    );
    v.insert("X".to_string(), others[0]);
    v.insert("Y".to_string(), others[1]);
    for i in 0..kinds.len() {
        v.insert(format!("I{}", i + 1), (i == now, i == before));
    }
    v.insert("def_S".to_string(), (flag, flag));
    Values(v)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, .. ProptestConfig::default() })]

    #[test]
    fn never_allows_what_the_healthy_sensor_could_forbid(
        e in expr(),
        kinds in kinds(),
        now in 0usize..4,
        before in 0usize..4,
        free in any::<(bool, bool)>(),
        others in any::<[(bool, bool); 2]>(),
    ) {
        let est = estimate(&kinds);
        let rewritten = rewrite(&e, std::slice::from_ref(&est), RewriteOptions::default());
        let healthy = scan(&kinds, now, before, free, others, true);
        if eval(&e, &healthy) {
            prop_assert!(eval(&rewritten, &healthy), "{} allowed where {} forbids", rewritten, e);
        }
    }

    #[test]
    fn with_the_flag_down_it_is_the_original(
        e in expr(),
        kinds in kinds(),
        now in 0usize..4,
        before in 0usize..4,
        free in any::<(bool, bool)>(),
        others in any::<[(bool, bool); 2]>(),
    ) {
        let rewritten = rewrite(&e, &[estimate(&kinds)], RewriteOptions::default());
        let values = scan(&kinds, now, before, free, others, false);
        prop_assert_eq!(eval(&rewritten, &values), eval(&e, &values));
    }
}

/// The conservative choice matters: the seed's plain substitution (uncertain
/// intervals read as 1 everywhere) would allow `!C5 & A3` while the turntable
/// may still be at C5's position.
#[test]
fn a_plain_substitution_would_allow_what_the_healthy_sensor_forbids() {
    let est = Estimate::from_model(
        "C5",
        "C5",
        &["I4", "I5", "I6", "I7"],
        &["I4".into(), "I7".into()],
    )
    .expect("estimate");
    let cs5 = Expr::parse("!C5 & A3").expect("parses");
    let plain = Expr::parse("!(!def_C5 & C5 | def_C5 & (I4 | I5 | I6 | I7)) & A3").expect("parses");
    let ours = rewrite(&cs5, &[est], RewriteOptions::default());
    // In I4 the turntable may not have reached C5 yet (C5 = 0): A3 must be forbidden.
    let mut v = HashMap::new();
    for (n, x) in [("C5", false), ("A3", true), ("def_C5", true), ("I4", true)] {
        v.insert(n.to_string(), (x, x));
    }
    let values = Values(v);
    assert!(eval(&cs5, &values), "the healthy sensor forbids");
    assert!(!eval(&plain, &values), "the plain substitution allows");
    assert!(eval(&ours, &values), "the conservative one forbids");
}
