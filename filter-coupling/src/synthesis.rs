//! Safe control by constraints in closed form (seed 001 §4): each output's
//! `f0k` (it must be 0), `f1k` (it must be 1) and `g1k` (it should be 1) as
//! expressions, `S'k = !f0k & g1k | f1k`, and the outputs after the combined
//! constraints. [`crate::filter::Filter`] computes the same thing numerically
//! once per scan; this form is for people, for Structured Text, and for
//! comparing with a printed control law.

use diagnoser::expr::Expr;

/// The control law of one output.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputLaw {
    /// The output, e.g. `A2`.
    pub output: String,
    /// Where the safety constraints force it to 0.
    pub f0: Expr,
    /// Where they force it to 1.
    pub f1: Expr,
    /// Where the functional constraints want it at 1 (`Var(output)` when it has
    /// none: the control program's order is kept).
    pub g1: Expr,
    /// `S'k = !f0k & g1k | f1k`.
    pub safe: Expr,
}

/// A combined constraint as the control law applies it.
#[derive(Debug, Clone, PartialEq)]
pub struct CombinedLaw {
    /// Its name, e.g. `CSc1`.
    pub constraint: String,
    /// The constraint.
    pub expr: Expr,
    /// The output that keeps its value.
    pub priority: String,
    /// The output set to 0 while the constraint holds.
    pub other: String,
}

/// `e` with output `name` replaced by `value` (its edges read `prev(name)`).
pub fn cofactor(e: &Expr, name: &str, value: bool) -> Expr {
    let c = |b: bool| Expr::Const(b);
    let prev = || Expr::Prev(name.to_string());
    let not = |e: Expr| Expr::Not(Box::new(e));
    reduce(&match e {
        Expr::Var(n) if n == name => c(value),
        Expr::Rise(n) if n == name => {
            if value {
                not(prev())
            } else {
                c(false)
            }
        }
        Expr::Fall(n) if n == name => {
            if value {
                c(false)
            } else {
                prev()
            }
        }
        Expr::Not(inner) => not(cofactor(inner, name, value)),
        Expr::And(es) => Expr::And(es.iter().map(|e| cofactor(e, name, value)).collect()),
        Expr::Or(es) => Expr::Or(es.iter().map(|e| cofactor(e, name, value)).collect()),
        other => other.clone(),
    })
}

/// Replaces every `Var(name)` by `by` (edges and `prev` are left alone).
pub fn substitute(e: &Expr, name: &str, by: &Expr) -> Expr {
    match e {
        Expr::Var(n) if n == name => by.clone(),
        Expr::Not(inner) => Expr::Not(Box::new(substitute(inner, name, by))),
        Expr::And(es) => Expr::And(es.iter().map(|e| substitute(e, name, by)).collect()),
        Expr::Or(es) => Expr::Or(es.iter().map(|e| substitute(e, name, by)).collect()),
        other => other.clone(),
    }
}

/// Constant folding, flattening, double negations and repeated terms: enough
/// to keep the closed forms readable.
pub fn reduce(e: &Expr) -> Expr {
    match e {
        Expr::Not(inner) => match reduce(inner) {
            Expr::Const(b) => Expr::Const(!b),
            Expr::Not(x) => *x,
            x => Expr::Not(Box::new(x)),
        },
        Expr::And(es) | Expr::Or(es) => {
            let and = matches!(e, Expr::And(_));
            let mut terms: Vec<Expr> = Vec::new();
            for t in es.iter().map(reduce) {
                match t {
                    // The absorbing element decides; the neutral one vanishes.
                    Expr::Const(b) if b != and => return Expr::Const(b),
                    Expr::Const(_) => {}
                    Expr::And(inner) if and => extend_unique(&mut terms, inner),
                    Expr::Or(inner) if !and => extend_unique(&mut terms, inner),
                    t => extend_unique(&mut terms, vec![t]),
                }
            }
            // `x` and `!x` together.
            let contradiction = terms
                .iter()
                .any(|t| terms.iter().any(|u| matches!(u, Expr::Not(x) if **x == *t)));
            if contradiction {
                return Expr::Const(!and);
            }
            match terms.len() {
                0 => Expr::Const(and),
                1 => terms.pop().unwrap_or(Expr::Const(and)),
                _ if and => Expr::And(terms),
                _ => Expr::Or(terms),
            }
        }
        other => other.clone(),
    }
}

fn extend_unique(terms: &mut Vec<Expr>, more: Vec<Expr>) {
    for t in more {
        if !terms.contains(&t) {
            terms.push(t);
        }
    }
}

fn or(terms: Vec<Expr>) -> Expr {
    reduce(&Expr::Or(terms))
}

fn and(terms: Vec<Expr>) -> Expr {
    reduce(&Expr::And(terms))
}

fn not(e: Expr) -> Expr {
    reduce(&Expr::Not(Box::new(e)))
}

/// Whether `e` reads `name` under an odd number of negations.
fn reads_negated(e: &Expr, name: &str) -> bool {
    fn go(e: &Expr, name: &str, negated: bool) -> bool {
        match e {
            Expr::Var(n) | Expr::Rise(n) | Expr::Fall(n) => n == name && negated,
            Expr::Not(x) => go(x, name, !negated),
            Expr::And(es) | Expr::Or(es) => es.iter().any(|e| go(e, name, negated)),
            Expr::Const(_) | Expr::Prev(_) => false,
        }
    }
    go(e, name, false)
}

/// The law of `output` from the simple safety constraints and the functional
/// constraints that read it (already rewritten if the filter is coupled).
pub fn output_law(output: &str, safety: &[&Expr], functional: &[&Expr]) -> OutputLaw {
    let split = |cs: &[&Expr]| -> (Expr, Expr) {
        let (mut zero, mut one) = (Vec::new(), Vec::new());
        for c in cs {
            let (c1, c0) = (cofactor(c, output, true), cofactor(c, output, false));
            zero.push(and(vec![c1.clone(), not(c0.clone())]));
            one.push(and(vec![c0, not(c1)]));
        }
        (or(zero), or(one))
    };
    let (f0, f1) = split(safety);
    let (g0, g1) = split(functional);
    let g1 = if functional.iter().any(|c| reads_negated(c, output)) {
        and(vec![g1, not(g0)])
    } else if functional.is_empty() {
        Expr::Var(output.to_string())
    } else {
        not(g0)
    };
    let safe = or(vec![and(vec![not(f0.clone()), g1.clone()]), f1.clone()]);
    OutputLaw {
        output: output.to_string(),
        f0,
        f1,
        g1,
        safe,
    }
}

/// The outputs after the combined constraints, as closed forms: seed 001's
/// figure 3 run "by hand". Each pass sets `Sl = Sl & !CSc(S)` for every
/// combined constraint, with the outputs replaced by their current forms;
/// passes repeat as many times as there are combined constraints, which is
/// what the loop needs to settle when constraints chain.
pub fn closed_form(laws: &[OutputLaw], combined: &[CombinedLaw]) -> Vec<(String, Expr)> {
    let mut forms: Vec<(String, Expr)> = laws
        .iter()
        .map(|l| (l.output.clone(), l.safe.clone()))
        .collect();
    for _ in 0..combined.len() {
        for c in combined {
            let mut holds = c.expr.clone();
            for (name, form) in &forms {
                holds = substitute(&holds, name, form);
            }
            let holds = reduce(&holds);
            if let Some((_, form)) = forms.iter_mut().find(|(n, _)| *n == c.other) {
                *form = and(vec![form.clone(), not(holds)]);
            }
        }
    }
    forms
}
