//! The rewriting is conservative: with the flag raised, a rewritten constraint
//! forbids whenever the constraint on the healthy sensor could forbid, for every
//! value the sensor may take in the estimate's intervals; with the flag down it
//! is the original constraint. Under suspicion it forbids whatever any
//! remaining candidate could make the constraint forbid: the sensor failed
//! (its estimate, or anything if it has none) or healthy (its reading).

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
    expr_over(NAMES)
}

/// Random constraints over three signals: literals, edges, previous values,
/// constants, under negations, conjunctions and disjunctions.
fn expr_over(names: [&'static str; 3]) -> impl Strategy<Value = Expr> {
    let name = move |i: usize| names[i].to_string();
    let leaf = prop_oneof![
        (0usize..3).prop_map(move |i| Expr::Var(name(i))),
        (0usize..3).prop_map(move |i| Expr::Rise(name(i))),
        (0usize..3).prop_map(move |i| Expr::Fall(name(i))),
        (0usize..3).prop_map(move |i| Expr::Prev(name(i))),
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
        any_value: false,
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

/// Values now and in the previous scan of the sensors and flags of
/// [`under_suspicion_never_allows_what_any_candidate_forbids`]: `S` has an
/// estimate over I1..I4, `T` has none, `X` is another signal.
struct Candidates {
    kinds: Vec<u8>,
    now: usize,
    before: usize,
    /// What S and T read, and X.
    s: (bool, bool),
    t: (bool, bool),
    x: (bool, bool),
    /// def_S, suspect_S, def_T, suspect_T.
    flags: [bool; 4],
}

impl Candidates {
    /// The scan the filter sees: readings, intervals, flags.
    fn read(&self) -> Values {
        let mut v = HashMap::new();
        v.insert("S".to_string(), self.s);
        v.insert("T".to_string(), self.t);
        v.insert("X".to_string(), self.x);
        for i in 0..self.kinds.len() {
            v.insert(format!("I{}", i + 1), (i == self.now, i == self.before));
        }
        for (name, on) in ["def_S", "suspect_S", "def_T", "suspect_T"]
            .iter()
            .zip(self.flags)
        {
            v.insert(name.to_string(), (on, on));
        }
        Values(v)
    }

    /// One candidate world: S failed (`s_failed`, where its flags allow it)
    /// with true values within its estimate (`s_free` where uncertain), else
    /// as read; T failed with any true values `t_free`, else as read.
    fn world(
        &self,
        s_failed: bool,
        s_free: (bool, bool),
        t_failed: bool,
        t_free: (bool, bool),
    ) -> Values {
        let [def_s, sus_s, def_t, sus_t] = self.flags;
        let truth = |k: u8, f: bool| match k {
            0 => false,
            1 => true,
            _ => f,
        };
        let mut v = self.read().0;
        if def_s || sus_s && s_failed {
            let s = (
                truth(self.kinds[self.now], s_free.0),
                truth(self.kinds[self.before], s_free.1),
            );
            v.insert("S".to_string(), s);
        }
        if def_t || sus_t && t_failed {
            v.insert("T".to_string(), t_free);
        }
        Values(v)
    }
}

/// The names of [`Candidates`]' constraints.
const NAMES_T: [&str; 3] = ["S", "T", "X"];

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, .. ProptestConfig::default() })]

    /// Random constraints, estimates, flags and candidate worlds: wherever one
    /// candidate world makes the constraint forbid, the rewritten constraint
    /// forbids on what the filter reads.
    #[test]
    fn under_suspicion_never_allows_what_any_candidate_forbids(
        e in expr_over(NAMES_T),
        kinds in kinds(),
        now in 0usize..4,
        before in 0usize..4,
        read in any::<[(bool, bool); 3]>(),
        flags in any::<[bool; 4]>(),
        world in any::<(bool, (bool, bool), bool, (bool, bool))>(),
    ) {
        let estimates = [estimate(&kinds), Estimate::any_value("T", "T")];
        let rewritten = rewrite(&e, &estimates, RewriteOptions { use_suspects: true });
        let c = Candidates { kinds, now, before, s: read[0], t: read[1], x: read[2], flags };
        let (s_failed, s_free, t_failed, t_free) = world;
        if eval(&e, &c.world(s_failed, s_free, t_failed, t_free)) {
            prop_assert!(eval(&rewritten, &c.read()), "{} allowed where {} forbids", rewritten, e);
        }
    }

    /// With no flag raised, suspicion included, it is the original.
    #[test]
    fn with_no_flag_raised_it_is_the_original(
        e in expr_over(NAMES_T),
        kinds in kinds(),
        now in 0usize..4,
        before in 0usize..4,
        read in any::<[(bool, bool); 3]>(),
    ) {
        let estimates = [estimate(&kinds), Estimate::any_value("T", "T")];
        let rewritten = rewrite(&e, &estimates, RewriteOptions { use_suspects: true });
        let c = Candidates { kinds, now, before, s: read[0], t: read[1], x: read[2], flags: [false; 4] };
        prop_assert_eq!(eval(&rewritten, &c.read()), eval(&e, &c.read()));
    }
}

/// The union matters: reading the suspected sensor's estimate alone (as the
/// coupling did before) allows `!C4 & RE(A4)` with the turntable blocked away
/// from loading, where C4 reads 0 truly and the estimate says "at loading".
#[test]
fn a_suspected_sensor_reads_the_union_of_reading_and_estimate() {
    let est = Estimate::from_model("C4", "C4", &["I1", "I2"], &["I2".into()]).expect("estimate");
    let cs14 = Expr::parse("!C4 & RE(A4)").expect("parses");
    let ours = rewrite(
        &cs14,
        std::slice::from_ref(&est),
        RewriteOptions { use_suspects: true },
    );
    let mut v = HashMap::new();
    for (n, now, before) in [
        ("C4", false, false),
        ("A4", true, false),
        ("suspect_C4", true, true),
        ("I1", true, true),
    ] {
        v.insert(n.to_string(), (now, before));
    }
    let values = Values(v);
    assert!(eval(&cs14, &values), "the reading forbids");
    assert!(eval(&ours, &values), "{ours} allows it");
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
