//! Rewriting safety constraints with fault flags and temporal estimates (seed 002
//! eq. 29–31), and with suspicion.
//!
//! A constraint must stay 0; when it is 1 it forbids the outputs it reads. When
//! a sensor `s` is declared failed (`def_s`), each of its literals is replaced by
//! its temporal estimate: `s` becomes `(!def_s & s) | (def_s & ŝ)`.
//!
//! The estimate has *uncertain* intervals, in which the sensor may already have
//! switched. The substitution is **conservative**: in an uncertain interval the
//! estimate takes, occurrence by occurrence, whichever value keeps the
//! constraint forbidding. An occurrence under an even number of negations
//! (positive) reads `ŝ⁺` = every interval where `s` may be 1; one under an odd
//! number (negative) reads `ŝ⁻` = the intervals where `s` is certainly 1. A
//! constraint is monotone in its positive occurrences and antitone in its
//! negative ones, so the rewritten constraint is 1 whenever the constraint on
//! the healthy sensor could be: it never allows what the healthy sensor could
//! have forbidden. A sensor with no temporal estimate (its edges follow the
//! workpieces, not a command) may read anything: `ŝ⁺ = 1`, `ŝ⁻ = 0`.
//!
//! **Suspicion** (`suspect_s`, with [`RewriteOptions::use_suspects`]): the
//! verdict is ambiguous, and `s` is failed under some candidates only. Under
//! the others (another sensor failed, the element blocked, an actuator stuck)
//! its reading is true. Its possible values are then the union of the reading
//! and the estimate, and each occurrence reads the bound of that union that
//! keeps the constraint forbidding: positive `s | ŝ⁺`, negative `s & ŝ⁻`. So the
//! rewritten constraint forbids whatever any remaining candidate makes unsafe.
//!
//! Edges and previous values of a failed sensor are bounded the same way:
//! `RE(s)` and `FE(s)` positive become `ŝ⁺` and `!ŝ⁻` (an edge needs the new
//! value), negative become 0; `prev(s)` reads the estimate's intervals one scan
//! earlier. Under suspicion the reading joins in as above.

use diagnoser::Flag;
use diagnoser::expr::Expr;

/// The temporal estimate of one sensor, as intervals of its part's command clock
/// (variables `I1`, `I2`, … that the filter computes).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Estimate {
    /// The sensor.
    pub sensor: String,
    /// The fault partition whose flags switch it (`def_<partition>`); for the
    /// partitions of SPEC's plant files, the sensor's own name.
    pub partition: String,
    /// Intervals where the sensor is certainly 1.
    pub certain: Vec<String>,
    /// Intervals where it may or may not have switched yet.
    pub uncertain: Vec<String>,
    /// No temporal estimate: the sensor may read anything (`ŝ⁻ = 0`,
    /// `ŝ⁺ = 1`); the interval lists are empty.
    pub any_value: bool,
}

impl Estimate {
    /// From a learned estimate: `intervals` are every interval where the
    /// sensor is or may be 1 (`SensorEstimate::intervals`), `uncertain` the
    /// uncertain ones among them.
    pub fn from_model(
        sensor: &str,
        partition: &str,
        intervals: &[impl AsRef<str>],
        uncertain: &[String],
    ) -> Result<Estimate, String> {
        let all: Vec<String> = intervals.iter().map(|s| s.as_ref().to_string()).collect();
        if let Some(bad) = all
            .iter()
            .find(|s| !s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        {
            return Err(format!(
                "estimate of {sensor}: '{bad}' is not an interval name"
            ));
        }
        Ok(Estimate {
            sensor: sensor.to_string(),
            partition: partition.to_string(),
            certain: all
                .iter()
                .filter(|i| !uncertain.contains(i))
                .cloned()
                .collect(),
            uncertain: uncertain.to_vec(),
            any_value: false,
        })
    }

    /// For a sensor with no temporal estimate: it may read anything.
    pub fn any_value(sensor: &str, partition: &str) -> Estimate {
        Estimate {
            sensor: sensor.to_string(),
            partition: partition.to_string(),
            certain: Vec::new(),
            uncertain: Vec::new(),
            any_value: true,
        }
    }

    /// `ŝ⁺` (`upper`) or `ŝ⁻`, read in this scan or (`previous`) the last one.
    fn bound(&self, upper: bool, previous: bool) -> Expr {
        if self.any_value {
            return Expr::Const(upper);
        }
        let names = self
            .certain
            .iter()
            .chain(upper.then_some(&self.uncertain).into_iter().flatten());
        let terms: Vec<Expr> = names
            .map(|n| {
                if previous {
                    Expr::Prev(n.clone())
                } else {
                    Expr::Var(n.clone())
                }
            })
            .collect();
        match terms.len() {
            0 => Expr::Const(false),
            1 => terms.into_iter().next().unwrap_or(Expr::Const(false)),
            _ => Expr::Or(terms),
        }
    }
}

/// How the flags switch sensors to their estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RewriteOptions {
    /// Also read the sensor conservatively on `suspect_<s>` (the sensor is
    /// among the candidates of an ambiguous verdict): the union of its reading
    /// and its estimate.
    pub use_suspects: bool,
}

/// Rewrites `expr` so that each sensor with an estimate reads it while its flag
/// is raised, and the union of reading and estimate while it is suspected (see
/// the module documentation).
pub fn rewrite(expr: &Expr, estimates: &[Estimate], options: RewriteOptions) -> Expr {
    go(expr, estimates, options, true)
}

/// A literal of `e`'s sensor: `healthy` as read, `estimated` its bound for an
/// occurrence of this polarity. Declared failed, the bound; suspected, the
/// bound of the union (`healthy | estimated` positive, `healthy & estimated`
/// negative); otherwise the reading.
fn switch(
    e: &Estimate,
    options: RewriteOptions,
    positive: bool,
    healthy: Expr,
    estimated: Expr,
) -> Expr {
    let def = Expr::Var(Flag::def(&e.partition).to_string());
    let not = |x: Expr| Expr::Not(Box::new(x));
    if !options.use_suspects {
        return Expr::Or(vec![
            Expr::And(vec![not(def.clone()), healthy]),
            Expr::And(vec![def, estimated]),
        ]);
    }
    let suspect = Expr::Var(Flag::suspect(&e.partition).to_string());
    if positive {
        // !def & s | (def | suspect) & ŝ⁺
        Expr::Or(vec![
            Expr::And(vec![not(def.clone()), healthy]),
            Expr::And(vec![Expr::Or(vec![def, suspect]), estimated]),
        ])
    } else {
        // !def & s & (!suspect | ŝ⁻) | def & ŝ⁻
        let unless = match estimated.clone() {
            Expr::Or(mut terms) => {
                terms.insert(0, not(suspect));
                Expr::Or(terms)
            }
            other => Expr::Or(vec![not(suspect), other]),
        };
        Expr::Or(vec![
            Expr::And(vec![not(def.clone()), healthy, unless]),
            Expr::And(vec![def, estimated]),
        ])
    }
}

fn go(expr: &Expr, estimates: &[Estimate], options: RewriteOptions, positive: bool) -> Expr {
    let find = |n: &str| estimates.iter().find(|e| e.sensor == n);
    let literal =
        |e: &Estimate, estimated: Expr| switch(e, options, positive, expr.clone(), estimated);
    match expr {
        Expr::Var(n) => match find(n) {
            Some(e) => literal(e, e.bound(positive, false)),
            None => expr.clone(),
        },
        Expr::Rise(n) => match find(n) {
            Some(e) if positive => literal(e, e.bound(true, false)),
            Some(e) => literal(e, Expr::Const(false)),
            None => expr.clone(),
        },
        Expr::Fall(n) => match find(n) {
            Some(e) if positive => literal(e, Expr::Not(Box::new(e.bound(false, false)))),
            Some(e) => literal(e, Expr::Const(false)),
            None => expr.clone(),
        },
        Expr::Prev(n) => match find(n) {
            Some(e) => literal(e, e.bound(positive, true)),
            None => expr.clone(),
        },
        Expr::Const(_) => expr.clone(),
        Expr::Not(inner) => Expr::Not(Box::new(go(inner, estimates, options, !positive))),
        Expr::And(es) => Expr::And(
            es.iter()
                .map(|e| go(e, estimates, options, positive))
                .collect(),
        ),
        Expr::Or(es) => Expr::Or(
            es.iter()
                .map(|e| go(e, estimates, options, positive))
                .collect(),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn turntable() -> Vec<Estimate> {
        vec![
            Estimate::from_model(
                "C4",
                "C4",
                &["I1", "I2", "I9", "I10"],
                &["I2".into(), "I9".into()],
            )
            .expect("estimate"),
            Estimate::from_model(
                "C5",
                "C5",
                &["I4", "I5", "I6", "I7"],
                &["I4".into(), "I7".into()],
            )
            .expect("estimate"),
        ]
    }

    #[test]
    fn seed_002_equations_29_and_30() {
        let e = turntable();
        let cs5 = Expr::parse("!C5 & A3").expect("parses");
        assert_eq!(
            rewrite(&cs5, &e, RewriteOptions::default()).to_string(),
            "!(!def_C5 & C5 | def_C5 & (I5 | I6)) & A3"
        );
        let cs6 = Expr::parse("C4 & C6 & A2").expect("parses");
        assert_eq!(
            rewrite(&cs6, &e, RewriteOptions::default()).to_string(),
            "(!def_C4 & C4 | def_C4 & (I1 | I10 | I2 | I9)) & C6 & A2"
        );
        let with_suspects = rewrite(&cs6, &e, RewriteOptions { use_suspects: true });
        assert_eq!(
            with_suspects.to_string(),
            "(!def_C4 & C4 | (def_C4 | suspect_C4) & (I1 | I10 | I2 | I9)) & C6 & A2"
        );
        let cs5 = rewrite(&cs5, &e, RewriteOptions { use_suspects: true });
        assert_eq!(
            cs5.to_string(),
            "!(!def_C5 & C5 & (!suspect_C5 | I5 | I6) | def_C5 & (I5 | I6)) & A3"
        );
    }
}
