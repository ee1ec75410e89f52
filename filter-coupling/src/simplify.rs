//! Removing the diagnoser branches the safety filter makes impossible (seed 002 §4).
//!
//! The filter runs at the end of every PLC scan and keeps every safety
//! constraint of the plant file at 0 on what it sees: sensors as read, outputs
//! as written, `RE`/`FE`/`prev` against the previous scan. A log recorded under
//! the filter therefore never shows a scan after which a constraint is 1, and a
//! part's diagnoser needs no branch for such a scan. [`PartFilter`] is that
//! knowledge for one part, as a predicate on the part's observed scans (state
//! vectors before and after), for
//! [`Compiled::explore_with`](diagnoser::diagnosis::compile::Compiled::explore_with)
//! with [`Commands::Filter`](diagnoser::diagnosis::compile::Commands::Filter).
//! For the sorting turntable it removes, e.g., every branch in which the table
//! starts rotating away from the loading position (`CSs14 = !C4 & RE(A4)`).
//!
//! A constraint usually reads more than the part: signals of other parts,
//! observers, flags (`def_…`, `suspect_…`), estimate intervals. Those are
//! *unknowns* (each with its value now and in the previous scan, taken
//! independently), and a scan is removed only when the constraint is 1 for
//! **every** value of the unknowns. A constraint with more than
//! [`MAX_UNKNOWNS`] unknown names is not used; neither is one that reads none
//! of the part's signals (it says nothing of the part) or no actuator at all
//! (the filter only writes outputs, so it cannot keep such a constraint at 0).
//!
//! **Assumption.** The pruning holds while the filter reads the part's *real*
//! sensors: until a `def_` (or `suspect_`) flag of one of the part's partitions
//! makes the filter read a sensor's temporal estimate instead
//! ([`crate::rewrite`]). From then on the filter keeps the rewritten
//! constraint at 0, not the original one on the observed sensor, and a pruned
//! branch may well happen. Flags of other parts do not matter: their sensors
//! are unknowns here. It also assumes that an observed scan is a PLC scan
//! (events with equal timestamps), so that `RE`, `FE` and `prev` mean what the
//! filter computed.

use diagnoser::expr::Expr;
use diagnoser::plant::Constraint;
use diagnoser::{Plant, SignalKind};

use crate::eval::{Scan, eval};

/// Most unknown names a constraint may read and still be used.
pub const MAX_UNKNOWNS: usize = 10;

/// Most boolean variables (the part's values now and before, then the
/// unknowns') a constraint's table is enumerated over.
const MAX_VARIABLES: usize = 24;

/// The filter's restriction of one part's observed scans.
#[derive(Debug, Clone)]
pub struct PartFilter {
    names: Vec<String>,
    rules: Vec<Rule>,
    skipped: Vec<Skipped>,
}

/// A constraint that removes scans, in table form.
#[derive(Debug, Clone)]
struct Rule {
    name: String,
    /// The part's values it reads: (bit in the state vector, previous scan).
    reads: Vec<(u8, bool)>,
    /// Indexed by the values of `reads` packed as bits (first read: bit 0):
    /// the constraint is 1 whatever the unknowns.
    forced: Vec<bool>,
}

/// A constraint that reads the part but is not used: too many unknowns.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Skipped {
    /// The constraint's name.
    pub constraint: String,
    /// The names it reads outside the part.
    pub unknowns: Vec<String>,
}

impl PartFilter {
    /// The restriction, by the safety constraints of `plant`, of the part whose
    /// signals are `names`, in the bit order of its state vectors
    /// ([`PartDiagnoser::names`](diagnoser::diagnosis::PartDiagnoser::names):
    /// actuators first, then sensors).
    pub fn new(plant: &Plant, names: &[String]) -> Result<PartFilter, String> {
        let actuators: Vec<&str> = plant
            .signals
            .of_kind(SignalKind::Actuator)
            .map(|id| plant.signals.name(id))
            .collect();
        PartFilter::from_constraints(&plant.constraints, names, &|n| actuators.contains(&n))
    }

    /// The same from a list of constraints; `is_actuator` tells the outputs
    /// among the names they read.
    pub fn from_constraints(
        constraints: &[Constraint],
        names: &[String],
        is_actuator: &dyn Fn(&str) -> bool,
    ) -> Result<PartFilter, String> {
        if names.len() > 32 {
            return Err(format!(
                "a part of {} signals: state vectors hold at most 32",
                names.len()
            ));
        }
        let bit = |n: &str| names.iter().position(|m| m == n).map(|b| b as u8);
        let mut rules = Vec::new();
        let mut skipped = Vec::new();
        for c in constraints {
            let read = c.expr.names();
            if !read.iter().any(|n| bit(n).is_some()) || !read.iter().any(|n| is_actuator(n)) {
                continue;
            }
            // Every boolean the constraint reads: the part's first, then the
            // unknowns'.
            let mut reads: Vec<(u8, bool)> = Vec::new();
            let mut unknown: Vec<(&str, bool)> = Vec::new();
            let mut unknown_names: Vec<String> = Vec::new();
            literals(&c.expr, &mut |name, previous| match bit(name) {
                Some(b) => {
                    if !reads.contains(&(b, previous)) {
                        reads.push((b, previous));
                    }
                }
                None => {
                    if !unknown.contains(&(name, previous)) {
                        unknown.push((name, previous));
                    }
                    if !unknown_names.iter().any(|u| u == name) {
                        unknown_names.push(name.to_string());
                    }
                }
            });
            if unknown_names.len() > MAX_UNKNOWNS || reads.len() + unknown.len() > MAX_VARIABLES {
                skipped.push(Skipped {
                    constraint: c.name.clone(),
                    unknowns: unknown_names,
                });
                continue;
            }
            let variables: Vec<(&str, bool)> = reads
                .iter()
                .map(|&(b, p)| (names[b as usize].as_str(), p))
                .chain(unknown.iter().copied())
                .collect();
            let forced: Vec<bool> = (0u64..1 << reads.len())
                .map(|known| {
                    (0u64..1 << unknown.len()).all(|u| {
                        eval(
                            &c.expr,
                            &Assignment {
                                variables: &variables,
                                values: known | u << reads.len(),
                            },
                        )
                    })
                })
                .collect();
            if forced.iter().any(|&f| f) {
                rules.push(Rule {
                    name: c.name.clone(),
                    reads,
                    forced,
                });
            }
        }
        Ok(PartFilter {
            names: names.to_vec(),
            rules,
            skipped,
        })
    }

    /// Whether the filter lets the part's observed state go from `before` to
    /// `after` in one scan.
    pub fn allows(&self, before: u32, after: u32) -> bool {
        self.forbidding(before, after).is_none()
    }

    /// The first constraint that is 1 after the scan from `before` to `after`
    /// whatever the unknowns, if any.
    pub fn forbidding(&self, before: u32, after: u32) -> Option<&str> {
        self.rules.iter().find_map(|r| {
            let index = r
                .reads
                .iter()
                .enumerate()
                .fold(0usize, |i, (k, &(b, previous))| {
                    let word = if previous { before } else { after };
                    i | ((word >> b & 1) as usize) << k
                });
            r.forced[index].then_some(r.name.as_str())
        })
    }

    /// The constraints that remove scans of this part.
    pub fn constraints(&self) -> impl Iterator<Item = &str> {
        self.rules.iter().map(|r| r.name.as_str())
    }

    /// The constraints that read the part but are not used (too many unknowns).
    pub fn skipped(&self) -> &[Skipped] {
        &self.skipped
    }

    /// The part's signals, in bit order.
    pub fn names(&self) -> &[String] {
        &self.names
    }
}

/// Calls `f(name, previous)` for every value `expr` reads: `x` reads `x` now,
/// `prev(x)` before, `RE(x)` and `FE(x)` both.
fn literals<'a>(expr: &'a Expr, f: &mut impl FnMut(&'a str, bool)) {
    match expr {
        Expr::Const(_) => {}
        Expr::Var(n) => f(n, false),
        Expr::Prev(n) => f(n, true),
        Expr::Rise(n) | Expr::Fall(n) => {
            f(n, false);
            f(n, true);
        }
        Expr::Not(e) => literals(e, f),
        Expr::And(es) | Expr::Or(es) => es.iter().for_each(|e| literals(e, f)),
    }
}

/// Values of the variables a constraint reads: bit `k` of `values` is
/// `variables[k]`.
struct Assignment<'a> {
    variables: &'a [(&'a str, bool)],
    values: u64,
}

impl Assignment<'_> {
    fn get(&self, name: &str, previous: bool) -> bool {
        self.variables
            .iter()
            .position(|&(n, p)| n == name && p == previous)
            .is_some_and(|k| self.values >> k & 1 == 1)
    }
}

impl Scan for Assignment<'_> {
    fn value(&self, name: &str) -> bool {
        self.get(name, false)
    }

    fn previous(&self, name: &str) -> bool {
        self.get(name, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn constraint(name: &str, expr: &str) -> Constraint {
        Constraint {
            name: name.to_string(),
            expr: Expr::parse(expr).expect("parses"),
            priority: None,
        }
    }

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|s| s.to_string()).collect()
    }

    fn is_a(n: &str) -> bool {
        n.starts_with('A')
    }

    #[test]
    fn edge_constraint_on_the_part_alone() {
        // Bits: A4 = 0, C4 = 1.
        let f = PartFilter::from_constraints(
            &[constraint("CSs14", "!C4 & RE(A4)")],
            &names(&["A4", "C4"]),
            &is_a,
        )
        .expect("filter");
        assert_eq!(f.forbidding(0b00, 0b01), Some("CSs14"));
        assert!(f.allows(0b10, 0b11));
        assert!(f.allows(0b01, 0b01));
        assert!(!f.allows(0b10, 0b01), "RE(A4) with FE(C4) in one scan");
    }

    #[test]
    fn sensor_only_constraints_are_not_the_filters() {
        let f = PartFilter::from_constraints(
            &[constraint("both", "C4 & C5")],
            &names(&["A4", "C4", "C5"]),
            &is_a,
        )
        .expect("filter");
        assert_eq!(f.constraints().count(), 0);
        assert!(f.allows(0b010, 0b110));
    }

    #[test]
    fn too_many_unknowns_are_skipped() {
        let expr = (0..=MAX_UNKNOWNS)
            .map(|i| format!("X{i}"))
            .chain(["A4".to_string()])
            .collect::<Vec<_>>()
            .join(" | ");
        let f = PartFilter::from_constraints(
            &[constraint("wide", &expr)],
            &names(&["A4", "C4"]),
            &is_a,
        )
        .expect("filter");
        assert_eq!(f.skipped().len(), 1);
        assert_eq!(f.skipped()[0].unknowns.len(), MAX_UNKNOWNS + 1);
        assert!(f.allows(0, 1), "a skipped constraint removes nothing");
    }
}
