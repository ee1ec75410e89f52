//! The boolean expression language of plant files: constraints, observers and
//! functional requirements.
//!
//! Grammar (`!` binds tightest, then `&`, then `|`):
//! ```text
//! expr  := and ('|' and)*
//! and   := unary ('&' unary)*
//! unary := '!' unary | atom
//! atom  := '(' expr ')' | '0' | '1' | ('RE' | 'FE' | 'prev') '(' name ')' | name
//! name  := [A-Za-z0-9_]+      e.g. C4, A4, 2P, P36, def_C4
//! ```
//! `RE(x)` is true in the scan where `x` rose, `FE(x)` where it fell, `prev(x)` is
//! `x` in the previous scan. Evaluation and rewriting live in `filter-coupling`;
//! this module only parses and prints.

use std::fmt;

/// A parsed boolean expression.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Expr {
    /// `0` or `1`.
    Const(bool),
    /// A signal, observer or flag by name.
    Var(String),
    /// `RE(x)`: `x` rose in this scan.
    Rise(String),
    /// `FE(x)`: `x` fell in this scan.
    Fall(String),
    /// `prev(x)`: `x` in the previous scan.
    Prev(String),
    /// Negation.
    Not(Box<Expr>),
    /// Conjunction of two or more terms.
    And(Vec<Expr>),
    /// Disjunction of two or more terms.
    Or(Vec<Expr>),
}

/// A syntax error, at a byte offset of the expression text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("at character {}: {message}", offset + 1)]
pub struct ExprError {
    /// Byte offset in the expression.
    pub offset: usize,
    /// What is wrong.
    pub message: String,
}

impl Expr {
    /// Parses an expression.
    pub fn parse(text: &str) -> Result<Expr, ExprError> {
        let mut p = Parser { text, pos: 0 };
        let e = p.or()?;
        p.skip_ws();
        if p.pos < text.len() {
            return Err(p.error(format!("unexpected '{}'", p.rest_token())));
        }
        Ok(e)
    }

    /// Every name the expression reads (variables, and the arguments of `RE`, `FE`
    /// and `prev`), in order of appearance, with repetitions.
    pub fn names(&self) -> Vec<&str> {
        let mut out = Vec::new();
        self.collect_names(&mut out);
        out
    }

    fn collect_names<'a>(&'a self, out: &mut Vec<&'a str>) {
        match self {
            Expr::Const(_) => {}
            Expr::Var(n) | Expr::Rise(n) | Expr::Fall(n) | Expr::Prev(n) => out.push(n),
            Expr::Not(e) => e.collect_names(out),
            Expr::And(es) | Expr::Or(es) => es.iter().for_each(|e| e.collect_names(out)),
        }
    }

    fn precedence(&self) -> u8 {
        match self {
            Expr::Or(_) => 1,
            Expr::And(_) => 2,
            _ => 3,
        }
    }
}

impl fmt::Display for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let child = |f: &mut fmt::Formatter<'_>, e: &Expr, min: u8| {
            if e.precedence() < min {
                write!(f, "({e})")
            } else {
                write!(f, "{e}")
            }
        };
        match self {
            Expr::Const(b) => write!(f, "{}", u8::from(*b)),
            Expr::Var(n) => f.write_str(n),
            Expr::Rise(n) => write!(f, "RE({n})"),
            Expr::Fall(n) => write!(f, "FE({n})"),
            Expr::Prev(n) => write!(f, "prev({n})"),
            Expr::Not(e) => {
                f.write_str("!")?;
                child(f, e, 3)
            }
            Expr::And(es) | Expr::Or(es) => {
                let (sep, min) = if matches!(self, Expr::And(_)) {
                    (" & ", 3)
                } else {
                    (" | ", 2)
                };
                for (i, e) in es.iter().enumerate() {
                    if i > 0 {
                        f.write_str(sep)?;
                    }
                    child(f, e, min)?;
                }
                Ok(())
            }
        }
    }
}

struct Parser<'a> {
    text: &'a str,
    pos: usize,
}

impl Parser<'_> {
    fn error(&self, message: impl Into<String>) -> ExprError {
        ExprError {
            offset: self.pos,
            message: message.into(),
        }
    }

    fn skip_ws(&mut self) {
        while self.text[self.pos..].starts_with(char::is_whitespace) {
            self.pos += self.text[self.pos..]
                .chars()
                .next()
                .map_or(1, char::len_utf8);
        }
    }

    fn rest_token(&self) -> String {
        self.text[self.pos..].chars().take(12).collect()
    }

    fn eat(&mut self, c: char) -> bool {
        self.skip_ws();
        if self.text[self.pos..].starts_with(c) {
            self.pos += c.len_utf8();
            true
        } else {
            false
        }
    }

    fn or(&mut self) -> Result<Expr, ExprError> {
        let mut terms = vec![self.and()?];
        while self.eat('|') {
            terms.push(self.and()?);
        }
        Ok(if terms.len() == 1 {
            terms.remove(0)
        } else {
            Expr::Or(terms)
        })
    }

    fn and(&mut self) -> Result<Expr, ExprError> {
        let mut terms = vec![self.unary()?];
        while self.eat('&') {
            terms.push(self.unary()?);
        }
        Ok(if terms.len() == 1 {
            terms.remove(0)
        } else {
            Expr::And(terms)
        })
    }

    fn unary(&mut self) -> Result<Expr, ExprError> {
        if self.eat('!') {
            return Ok(Expr::Not(Box::new(self.unary()?)));
        }
        self.atom()
    }

    fn name(&mut self) -> Option<&str> {
        self.skip_ws();
        let rest = &self.text[self.pos..];
        let len = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        if len == 0 {
            return None;
        }
        self.pos += len;
        Some(&rest[..len])
    }

    fn atom(&mut self) -> Result<Expr, ExprError> {
        if self.eat('(') {
            let e = self.or()?;
            if !self.eat(')') {
                return Err(self.error("expected ')'"));
            }
            return Ok(e);
        }
        let start = self.pos;
        let Some(name) = self.name() else {
            self.skip_ws();
            return Err(if self.pos >= self.text.len() {
                self.error("expression ends too early")
            } else {
                self.error(format!(
                    "expected a name, '!' or '(', found '{}'",
                    self.rest_token()
                ))
            });
        };
        let name = name.to_string();
        match name.as_str() {
            "0" => return Ok(Expr::Const(false)),
            "1" => return Ok(Expr::Const(true)),
            _ => {}
        }
        if name.bytes().all(|b| b.is_ascii_digit()) {
            self.pos = start;
            self.skip_ws();
            return Err(self.error(format!(
                "'{name}' is not a name (only 0 and 1 are constants)"
            )));
        }
        let wrap: Option<fn(String) -> Expr> = match name.as_str() {
            "RE" => Some(Expr::Rise),
            "FE" => Some(Expr::Fall),
            "prev" => Some(Expr::Prev),
            _ => None,
        };
        match wrap {
            Some(wrap) if self.eat('(') => {
                let Some(arg) = self.name() else {
                    return Err(self.error(format!("expected a signal name inside {name}(...)")));
                };
                let arg = arg.to_string();
                if !self.eat(')') {
                    return Err(self.error(format!("expected ')' to close {name}(")));
                }
                Ok(wrap(arg))
            }
            _ => Ok(Expr::Var(name)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parses_seed_constraints() {
        let e = Expr::parse("C3 & !C4 & A1").expect("parses");
        assert_eq!(
            e,
            Expr::And(vec![
                Expr::Var("C3".into()),
                Expr::Not(Box::new(Expr::Var("C4".into()))),
                Expr::Var("A1".into())
            ])
        );
        assert_eq!(
            Expr::parse("!C4 & RE(A4)").expect("parses").to_string(),
            "!C4 & RE(A4)"
        );
        assert_eq!(
            Expr::parse("2P & A0").expect("parses").names(),
            vec!["2P", "A0"]
        );
        let text = "(!def_C4 & C4) | (def_C4 & Ĉ4)";
        assert_eq!(
            Expr::parse(text).map_err(|e| e.offset),
            Err(text.find('Ĉ').unwrap_or(0))
        );
    }

    #[test]
    fn reports_errors_with_offsets() {
        let err = Expr::parse("C4 & ").expect_err("incomplete");
        assert_eq!(err.message, "expression ends too early");
        let err = Expr::parse("C4 && C5").expect_err("double &");
        assert_eq!(err.offset, 4);
        assert!(Expr::parse("RE(C4").is_err());
        assert!(Expr::parse("C4 C5").is_err());
        assert!(Expr::parse("12 & C4").is_err());
    }

    fn arb_expr() -> impl Strategy<Value = Expr> {
        let leaf = prop_oneof![
            any::<bool>().prop_map(Expr::Const),
            "[A-C][0-9]".prop_map(Expr::Var),
            "[A-C][0-9]".prop_map(Expr::Rise),
            "[A-C][0-9]".prop_map(Expr::Fall),
            "[A-C][0-9]".prop_map(Expr::Prev),
        ];
        leaf.prop_recursive(4, 24, 3, |inner| {
            prop_oneof![
                inner.clone().prop_map(|e| Expr::Not(Box::new(e))),
                prop::collection::vec(inner.clone(), 2..4).prop_map(Expr::And),
                prop::collection::vec(inner, 2..4).prop_map(Expr::Or),
            ]
        })
    }

    /// Flattens nested And/Or so that printing then parsing is comparable.
    fn normal(e: &Expr) -> Expr {
        match e {
            Expr::Not(x) => Expr::Not(Box::new(normal(x))),
            Expr::And(es) => Expr::And(
                es.iter()
                    .map(normal)
                    .flat_map(|x| match x {
                        Expr::And(inner) => inner,
                        other => vec![other],
                    })
                    .collect(),
            ),
            Expr::Or(es) => Expr::Or(
                es.iter()
                    .map(normal)
                    .flat_map(|x| match x {
                        Expr::Or(inner) => inner,
                        other => vec![other],
                    })
                    .collect(),
            ),
            other => other.clone(),
        }
    }

    proptest! {
        #[test]
        fn print_then_parse_round_trips(e in arb_expr()) {
            let printed = e.to_string();
            let back = Expr::parse(&printed).expect("printed expressions parse");
            prop_assert_eq!(normal(&back), normal(&e));
        }
    }
}
