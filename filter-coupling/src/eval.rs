//! Evaluating constraint expressions in one PLC scan.

use diagnoser::expr::Expr;

/// What an expression reads, in one scan.
pub trait Scan {
    /// The value of a signal, observer, flag or interval by name, in this scan.
    fn value(&self, name: &str) -> bool;
    /// Its value in the previous scan.
    fn previous(&self, name: &str) -> bool;
}

/// Evaluates `expr` in `scan`: `RE(x)` is `x & !prev(x)`, `FE(x)` is
/// `!x & prev(x)`.
pub fn eval(expr: &Expr, scan: &impl Scan) -> bool {
    match expr {
        Expr::Const(b) => *b,
        Expr::Var(n) => scan.value(n),
        Expr::Rise(n) => scan.value(n) && !scan.previous(n),
        Expr::Fall(n) => !scan.value(n) && scan.previous(n),
        Expr::Prev(n) => scan.previous(n),
        Expr::Not(e) => !eval(e, scan),
        Expr::And(es) => es.iter().all(|e| eval(e, scan)),
        Expr::Or(es) => es.iter().any(|e| eval(e, scan)),
    }
}

/// The literals of `expr` that hold in `scan` and make it true, as text: what a
/// violated constraint is reported with. For a conjunction, all its literals; for
/// a disjunction, those of its true terms.
pub fn true_literals(expr: &Expr, scan: &impl Scan) -> Vec<String> {
    let mut out = Vec::new();
    collect(expr, scan, &mut out);
    out
}

fn collect(expr: &Expr, scan: &impl Scan, out: &mut Vec<String>) {
    if !eval(expr, scan) {
        return;
    }
    match expr {
        Expr::And(es) | Expr::Or(es) => es.iter().for_each(|e| collect(e, scan, out)),
        Expr::Const(_) => {}
        other => out.push(other.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    struct Values(HashMap<&'static str, (bool, bool)>);

    impl Scan for Values {
        fn value(&self, name: &str) -> bool {
            self.0.get(name).is_some_and(|v| v.0)
        }
        fn previous(&self, name: &str) -> bool {
            self.0.get(name).is_some_and(|v| v.1)
        }
    }

    #[test]
    fn edges_and_literals() {
        let scan = Values(HashMap::from([
            ("A4", (true, false)),
            ("C4", (false, false)),
        ]));
        let e = Expr::parse("!C4 & RE(A4)").expect("parses");
        assert!(eval(&e, &scan));
        assert_eq!(true_literals(&e, &scan), ["!C4", "RE(A4)"]);
        let e = Expr::parse("C4 | FE(A4) | prev(A4)").expect("parses");
        assert!(!eval(&e, &scan));
        assert!(true_literals(&e, &scan).is_empty());
    }
}
