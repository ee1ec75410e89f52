//! A small interpreter of the Structured Text subset `gardefou filter st`
//! writes: one FUNCTION_BLOCK; VAR_INPUT, VAR_OUTPUT and VAR sections of BOOL,
//! TIME and TON; assignments, IF / ELSIF / ELSE, calls of TON instances;
//! AND, OR, XOR, NOT, comparisons, TRUE / FALSE, TIME literals, `inst.Q` and
//! `inst.ET`. Names are case-insensitive, as in IEC 61131-3. Anything else,
//! an undeclared name, a type error or an assignment to an input, is an error:
//! the parser doubles as a check of what the generator may write.
//!
//! TON follows IEC 61131-3: on a call with `IN` FALSE, `Q` is FALSE and `ET` 0;
//! on the first call with `IN` TRUE the timer starts; then `ET` is the time
//! since that call, stopped at `PT`, and `Q` is `ET >= PT`. Time is what the
//! caller passes to [`Fb::call`], in nanoseconds.

use std::collections::HashMap;

const MS: i64 = 1_000_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ty {
    Bool,
    Time,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Section {
    Input,
    Output,
    Local,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Value {
    Bool(bool),
    Time(i64),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Member {
    Q,
    Et,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    And,
    Or,
    Xor,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
}

#[derive(Debug, Clone)]
enum Ex {
    Const(Value),
    Var(usize),
    Member(usize, Member),
    Not(Box<Ex>),
    Bin(Op, Box<Ex>, Box<Ex>),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Param {
    In,
    Pt,
}

#[derive(Debug, Clone)]
enum Stmt {
    Assign(usize, Ex),
    If(Vec<(Ex, Vec<Stmt>)>, Vec<Stmt>),
    Call(usize, Vec<(Param, Ex)>),
}

#[derive(Debug, Clone, Default)]
struct Ton {
    input: bool,
    pt: i64,
    q: bool,
    et: i64,
    start: Option<i64>,
}

impl Ton {
    fn run(&mut self, now: i64) {
        if !self.input {
            self.q = false;
            self.et = 0;
            self.start = None;
        } else {
            let start = *self.start.get_or_insert(now);
            self.et = (now - start).min(self.pt);
            self.q = self.et >= self.pt;
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Slot {
    Scalar(usize),
    Ton(usize),
}

/// A parsed function block and the state of one instance of it.
#[derive(Debug, Clone)]
pub struct Fb {
    /// Its name.
    pub name: String,
    names: Vec<String>,
    sections: Vec<Section>,
    types: Vec<Ty>,
    values: Vec<Value>,
    index: HashMap<String, Slot>,
    tons: Vec<Ton>,
    body: Vec<Stmt>,
    now: i64,
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    Time(i64),
    Assign,
    Colon,
    Semi,
    LParen,
    RParen,
    Comma,
    Dot,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
}

fn lex(text: &str) -> Result<Vec<(Tok, usize)>, String> {
    let bytes = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    let starts: Vec<usize> = std::iter::once(0)
        .chain(text.match_indices('\n').map(|(i, _)| i + 1))
        .collect();
    let line = |i: usize| starts.partition_point(|&s| s <= i);
    while i < bytes.len() {
        let c = bytes[i];
        if c.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        if text[i..].starts_with("(*") {
            let end = text[i + 2..]
                .find("*)")
                .ok_or_else(|| format!("line {}: unterminated comment", line(i)))?;
            if text[i + 2..i + 2 + end].contains("(*") {
                return Err(format!("line {}: nested comment", line(i)));
            }
            i += end + 4;
            continue;
        }
        let at = line(i);
        let two = &text[i..(i + 2).min(text.len())];
        let tok = match two {
            ":=" => Some(Tok::Assign),
            "<>" => Some(Tok::Ne),
            "<=" => Some(Tok::Le),
            ">=" => Some(Tok::Ge),
            _ => None,
        };
        if let Some(t) = tok {
            out.push((t, at));
            i += 2;
            continue;
        }
        let tok = match c {
            b':' => Some(Tok::Colon),
            b';' => Some(Tok::Semi),
            b'(' => Some(Tok::LParen),
            b')' => Some(Tok::RParen),
            b',' => Some(Tok::Comma),
            b'.' => Some(Tok::Dot),
            b'=' => Some(Tok::Eq),
            b'<' => Some(Tok::Lt),
            b'>' => Some(Tok::Gt),
            _ => None,
        };
        if let Some(t) = tok {
            out.push((t, at));
            i += 1;
            continue;
        }
        if c.is_ascii_alphabetic() || c == b'_' {
            let start = i;
            while i < bytes.len() && (bytes[i].is_ascii_alphanumeric() || bytes[i] == b'_') {
                i += 1;
            }
            let word = &text[start..i];
            if word.contains("__") || word.ends_with('_') {
                return Err(format!("line {at}: '{word}' is not an IEC identifier"));
            }
            if i < bytes.len() && bytes[i] == b'#' {
                let upper = word.to_ascii_uppercase();
                if upper != "T" && upper != "TIME" {
                    return Err(format!("line {at}: unsupported literal {word}#"));
                }
                i += 1;
                let s = i;
                while i < bytes.len()
                    && (bytes[i].is_ascii_alphanumeric() || bytes[i] == b'.' || bytes[i] == b'_')
                {
                    i += 1;
                }
                out.push((
                    Tok::Time(parse_time(&text[s..i]).map_err(|e| format!("line {at}: {e}"))?),
                    at,
                ));
                continue;
            }
            out.push((Tok::Ident(word.to_string()), at));
            continue;
        }
        return Err(format!("line {at}: unexpected character '{}'", c as char));
    }
    Ok(out)
}

/// `2s970ms`, `10ms`, `1.5ms` in nanoseconds.
fn parse_time(text: &str) -> Result<i64, String> {
    let text = text.replace('_', "");
    let mut total = 0f64;
    let mut rest = text.as_str();
    if rest.is_empty() {
        return Err("empty TIME literal".into());
    }
    while !rest.is_empty() {
        let n = rest
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .ok_or_else(|| format!("TIME literal '{text}' lacks a unit"))?;
        let number: f64 = rest[..n]
            .parse()
            .map_err(|_| format!("bad number in TIME literal '{text}'"))?;
        rest = &rest[n..];
        let units = [
            ("ms", 1e6),
            ("us", 1e3),
            ("ns", 1.0),
            ("d", 864e11),
            ("h", 36e11),
            ("m", 6e10),
            ("s", 1e9),
        ];
        let (unit, scale) = units
            .iter()
            .find(|(u, _)| rest.to_ascii_lowercase().starts_with(u))
            .ok_or_else(|| format!("bad unit in TIME literal '{text}'"))?;
        total += number * scale;
        rest = &rest[unit.len()..];
    }
    Ok(total.round() as i64)
}

struct Parser {
    toks: Vec<(Tok, usize)>,
    pos: usize,
}

fn kw(t: &Tok, word: &str) -> bool {
    matches!(t, Tok::Ident(w) if w.eq_ignore_ascii_case(word))
}

const KEYWORDS: &[&str] = &[
    "FUNCTION_BLOCK",
    "END_FUNCTION_BLOCK",
    "VAR_INPUT",
    "VAR_OUTPUT",
    "VAR",
    "END_VAR",
    "IF",
    "THEN",
    "ELSIF",
    "ELSE",
    "END_IF",
    "AND",
    "OR",
    "XOR",
    "NOT",
    "TRUE",
    "FALSE",
    "BOOL",
    "TIME",
    "TON",
];

impl Parser {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos).map(|(t, _)| t)
    }
    fn line(&self) -> usize {
        self.toks
            .get(self.pos)
            .or(self.toks.last())
            .map_or(0, |(_, l)| *l)
    }
    fn err<T>(&self, message: impl std::fmt::Display) -> Result<T, String> {
        Err(format!("line {}: {message}", self.line()))
    }
    fn next(&mut self) -> Result<Tok, String> {
        match self.toks.get(self.pos) {
            Some((t, _)) => {
                self.pos += 1;
                Ok(t.clone())
            }
            None => self.err("unexpected end of text"),
        }
    }
    fn expect(&mut self, t: Tok) -> Result<(), String> {
        let got = self.next()?;
        if got == t {
            Ok(())
        } else {
            self.pos -= 1;
            self.err(format!("expected {t:?}, found {got:?}"))
        }
    }
    fn expect_kw(&mut self, word: &str) -> Result<(), String> {
        match self.next()? {
            t if kw(&t, word) => Ok(()),
            t => {
                self.pos -= 1;
                self.err(format!("expected {word}, found {t:?}"))
            }
        }
    }
    fn at_kw(&self, word: &str) -> bool {
        self.peek().is_some_and(|t| kw(t, word))
    }
    fn ident(&mut self) -> Result<String, String> {
        match self.next()? {
            Tok::Ident(w) if !KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(&w)) => Ok(w),
            t => {
                self.pos -= 1;
                self.err(format!("expected a name, found {t:?}"))
            }
        }
    }
}

impl Fb {
    /// Parses a function block.
    pub fn parse(text: &str) -> Result<Fb, String> {
        let mut p = Parser {
            toks: lex(text)?,
            pos: 0,
        };
        p.expect_kw("FUNCTION_BLOCK")?;
        let name = p.ident()?;
        let mut fb = Fb {
            name,
            names: Vec::new(),
            sections: Vec::new(),
            types: Vec::new(),
            values: Vec::new(),
            index: HashMap::new(),
            tons: Vec::new(),
            body: Vec::new(),
            now: 0,
        };
        loop {
            let section = if p.at_kw("VAR_INPUT") {
                Section::Input
            } else if p.at_kw("VAR_OUTPUT") {
                Section::Output
            } else if p.at_kw("VAR") {
                Section::Local
            } else {
                break;
            };
            p.next()?;
            while !p.at_kw("END_VAR") {
                fb.declaration(&mut p, section)?;
            }
            p.expect_kw("END_VAR")?;
        }
        fb.body = fb.statements(&mut p, &["END_FUNCTION_BLOCK"])?;
        p.expect_kw("END_FUNCTION_BLOCK")?;
        if p.pos != p.toks.len() {
            return p.err("text after END_FUNCTION_BLOCK");
        }
        Ok(fb)
    }

    fn declaration(&mut self, p: &mut Parser, section: Section) -> Result<(), String> {
        let name = p.ident()?;
        let key = name.to_ascii_uppercase();
        if self.index.contains_key(&key) || key == self.name.to_ascii_uppercase() {
            return p.err(format!("'{name}' declared twice"));
        }
        p.expect(Tok::Colon)?;
        let ty = p.next()?;
        if kw(&ty, "TON") {
            if section != Section::Local {
                return p.err("a TON instance belongs in VAR");
            }
            self.index.insert(key, Slot::Ton(self.tons.len()));
            self.tons.push(Ton::default());
            return p.expect(Tok::Semi);
        }
        let ty = if kw(&ty, "BOOL") {
            Ty::Bool
        } else if kw(&ty, "TIME") {
            Ty::Time
        } else {
            return p.err(format!("unsupported type {ty:?}"));
        };
        let mut init = match ty {
            Ty::Bool => Value::Bool(false),
            Ty::Time => Value::Time(0),
        };
        if p.peek() == Some(&Tok::Assign) {
            p.next()?;
            let e = self.expr(p)?;
            init = match (e, ty) {
                (Ex::Const(v @ Value::Bool(_)), Ty::Bool)
                | (Ex::Const(v @ Value::Time(_)), Ty::Time) => v,
                _ => return p.err("an initial value must be a literal of the variable's type"),
            };
        }
        p.expect(Tok::Semi)?;
        self.index.insert(key, Slot::Scalar(self.values.len()));
        self.names.push(name);
        self.sections.push(section);
        self.types.push(ty);
        self.values.push(init);
        Ok(())
    }

    fn lookup(&self, p: &Parser, name: &str) -> Result<Slot, String> {
        match self.index.get(&name.to_ascii_uppercase()) {
            Some(s) => Ok(*s),
            None => p.err(format!("'{name}' is not declared")),
        }
    }

    fn statements(&self, p: &mut Parser, ends: &[&str]) -> Result<Vec<Stmt>, String> {
        let mut out = Vec::new();
        while !ends.iter().any(|e| p.at_kw(e)) {
            if p.peek().is_none() {
                return p.err(format!("expected {}", ends.join(" or ")));
            }
            out.push(self.statement(p)?);
        }
        Ok(out)
    }

    fn statement(&self, p: &mut Parser) -> Result<Stmt, String> {
        if p.at_kw("IF") {
            p.next()?;
            let mut branches = Vec::new();
            let mut otherwise = Vec::new();
            loop {
                let cond = self.expr(p)?;
                self.want(p, &cond, Ty::Bool)?;
                p.expect_kw("THEN")?;
                let body = self.statements(p, &["ELSIF", "ELSE", "END_IF"])?;
                branches.push((cond, body));
                if p.at_kw("ELSIF") {
                    p.next()?;
                    continue;
                }
                if p.at_kw("ELSE") {
                    p.next()?;
                    otherwise = self.statements(p, &["END_IF"])?;
                }
                break;
            }
            p.expect_kw("END_IF")?;
            p.expect(Tok::Semi)?;
            return Ok(Stmt::If(branches, otherwise));
        }
        let name = p.ident()?;
        match (self.lookup(p, &name)?, p.next()?) {
            (Slot::Scalar(i), Tok::Assign) => {
                if self.sections[i] == Section::Input {
                    return p.err(format!("assignment to the input '{name}'"));
                }
                let e = self.expr(p)?;
                self.want(p, &e, self.types[i])?;
                p.expect(Tok::Semi)?;
                Ok(Stmt::Assign(i, e))
            }
            (Slot::Ton(t), Tok::LParen) => {
                let mut params = Vec::new();
                loop {
                    let param = p.ident()?;
                    p.expect(Tok::Assign)?;
                    let e = self.expr(p)?;
                    let param = match param.to_ascii_uppercase().as_str() {
                        "IN" => {
                            self.want(p, &e, Ty::Bool)?;
                            Param::In
                        }
                        "PT" => {
                            self.want(p, &e, Ty::Time)?;
                            Param::Pt
                        }
                        other => return p.err(format!("TON has no input {other}")),
                    };
                    params.push((param, e));
                    if p.peek() == Some(&Tok::Comma) {
                        p.next()?;
                    } else {
                        break;
                    }
                }
                p.expect(Tok::RParen)?;
                p.expect(Tok::Semi)?;
                Ok(Stmt::Call(t, params))
            }
            (_, t) => p.err(format!("unexpected {t:?} after '{name}'")),
        }
    }

    fn ty(&self, e: &Ex) -> Ty {
        match e {
            Ex::Const(Value::Bool(_)) | Ex::Not(_) => Ty::Bool,
            Ex::Const(Value::Time(_)) => Ty::Time,
            Ex::Var(i) => self.types[*i],
            Ex::Member(_, Member::Q) => Ty::Bool,
            Ex::Member(_, Member::Et) => Ty::Time,
            Ex::Bin(..) => Ty::Bool,
        }
    }

    fn want(&self, p: &Parser, e: &Ex, ty: Ty) -> Result<(), String> {
        if self.ty(e) == ty {
            Ok(())
        } else {
            p.err(format!("expected a {ty:?} expression"))
        }
    }

    // expr := xor ('OR' xor)*; xor := and ('XOR' and)*; and := cmp ('AND' cmp)*;
    // cmp := unary (('='|'<>'|'<'|'<='|'>'|'>=') unary)?; unary := 'NOT' unary | primary
    fn expr(&self, p: &mut Parser) -> Result<Ex, String> {
        self.binary(p, 0)
    }

    fn binary(&self, p: &mut Parser, level: usize) -> Result<Ex, String> {
        const LEVELS: [(&str, Op); 3] = [("OR", Op::Or), ("XOR", Op::Xor), ("AND", Op::And)];
        if level == LEVELS.len() {
            return self.comparison(p);
        }
        let (word, op) = LEVELS[level];
        let mut left = self.binary(p, level + 1)?;
        while p.at_kw(word) {
            p.next()?;
            let right = self.binary(p, level + 1)?;
            self.want(p, &left, Ty::Bool)?;
            self.want(p, &right, Ty::Bool)?;
            left = Ex::Bin(op, Box::new(left), Box::new(right));
        }
        Ok(left)
    }

    fn comparison(&self, p: &mut Parser) -> Result<Ex, String> {
        let left = self.unary(p)?;
        let op = match p.peek() {
            Some(Tok::Eq) => Op::Eq,
            Some(Tok::Ne) => Op::Ne,
            Some(Tok::Lt) => Op::Lt,
            Some(Tok::Le) => Op::Le,
            Some(Tok::Gt) => Op::Gt,
            Some(Tok::Ge) => Op::Ge,
            _ => return Ok(left),
        };
        p.next()?;
        let right = self.unary(p)?;
        if self.ty(&left) != self.ty(&right) {
            return p.err("comparison of different types");
        }
        if self.ty(&left) == Ty::Bool && !matches!(op, Op::Eq | Op::Ne) {
            return p.err("ordering of BOOL values");
        }
        Ok(Ex::Bin(op, Box::new(left), Box::new(right)))
    }

    fn unary(&self, p: &mut Parser) -> Result<Ex, String> {
        if p.at_kw("NOT") {
            p.next()?;
            let e = self.unary(p)?;
            self.want(p, &e, Ty::Bool)?;
            return Ok(Ex::Not(Box::new(e)));
        }
        match p.next()? {
            Tok::LParen => {
                let e = self.expr(p)?;
                p.expect(Tok::RParen)?;
                Ok(e)
            }
            Tok::Time(ns) => Ok(Ex::Const(Value::Time(ns))),
            t if kw(&t, "TRUE") => Ok(Ex::Const(Value::Bool(true))),
            t if kw(&t, "FALSE") => Ok(Ex::Const(Value::Bool(false))),
            Tok::Ident(name) if !KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(&name)) => {
                match self.lookup(p, &name)? {
                    Slot::Scalar(i) => Ok(Ex::Var(i)),
                    Slot::Ton(t) => {
                        p.expect(Tok::Dot)?;
                        let member = p.ident()?;
                        match member.to_ascii_uppercase().as_str() {
                            "Q" => Ok(Ex::Member(t, Member::Q)),
                            "ET" => Ok(Ex::Member(t, Member::Et)),
                            other => p.err(format!("TON has no output {other}")),
                        }
                    }
                }
            }
            t => {
                p.pos -= 1;
                p.err(format!("unexpected {t:?} in an expression"))
            }
        }
    }

    fn slot(&self, name: &str) -> Option<usize> {
        match self.index.get(&name.to_ascii_uppercase()) {
            Some(Slot::Scalar(i)) if self.types[*i] == Ty::Bool => Some(*i),
            _ => None,
        }
    }

    /// Whether it has the BOOL input `name`.
    pub fn has_input(&self, name: &str) -> bool {
        self.slot(name)
            .is_some_and(|i| self.sections[i] == Section::Input)
    }

    /// Whether it has the BOOL output `name`.
    pub fn has_output(&self, name: &str) -> bool {
        self.slot(name)
            .is_some_and(|i| self.sections[i] == Section::Output)
    }

    /// Writes BOOL input `name`.
    pub fn set(&mut self, name: &str, value: bool) {
        match self.slot(name) {
            Some(i) if self.sections[i] == Section::Input => self.values[i] = Value::Bool(value),
            _ => panic!("{} has no BOOL input {name}", self.name),
        }
    }

    /// Reads any BOOL variable.
    pub fn get(&self, name: &str) -> Option<bool> {
        self.slot(name).map(|i| self.values[i] == Value::Bool(true))
    }

    /// Runs the body once at time `now` (ns).
    pub fn call(&mut self, now: i64) {
        self.now = now;
        let body = std::mem::take(&mut self.body);
        self.run(&body);
        self.body = body;
    }

    fn run(&mut self, stmts: &[Stmt]) {
        for s in stmts {
            match s {
                Stmt::Assign(i, e) => self.values[*i] = self.eval(e),
                Stmt::If(branches, otherwise) => {
                    let mut taken = false;
                    for (cond, body) in branches {
                        if self.eval(cond) == Value::Bool(true) {
                            self.run(body);
                            taken = true;
                            break;
                        }
                    }
                    if !taken {
                        self.run(otherwise);
                    }
                }
                Stmt::Call(t, params) => {
                    for (param, e) in params {
                        match (param, self.eval(e)) {
                            (Param::In, Value::Bool(b)) => self.tons[*t].input = b,
                            (Param::Pt, Value::Time(ns)) => self.tons[*t].pt = ns,
                            _ => unreachable!("checked when parsed"),
                        }
                    }
                    let now = self.now;
                    self.tons[*t].run(now);
                }
            }
        }
    }

    fn eval(&self, e: &Ex) -> Value {
        match e {
            Ex::Const(v) => *v,
            Ex::Var(i) => self.values[*i],
            Ex::Member(t, Member::Q) => Value::Bool(self.tons[*t].q),
            Ex::Member(t, Member::Et) => Value::Time(self.tons[*t].et),
            Ex::Not(inner) => Value::Bool(self.eval(inner) != Value::Bool(true)),
            Ex::Bin(op, a, b) => {
                let truth = |v: Value| v == Value::Bool(true);
                Value::Bool(match op {
                    // Short-circuit: the result is the same, and it is faster.
                    Op::And => truth(self.eval(a)) && truth(self.eval(b)),
                    Op::Or => truth(self.eval(a)) || truth(self.eval(b)),
                    Op::Xor => truth(self.eval(a)) != truth(self.eval(b)),
                    Op::Eq => self.eval(a) == self.eval(b),
                    Op::Ne => self.eval(a) != self.eval(b),
                    Op::Lt | Op::Le | Op::Gt | Op::Ge => {
                        let (Value::Time(x), Value::Time(y)) = (self.eval(a), self.eval(b)) else {
                            unreachable!("checked when parsed")
                        };
                        match op {
                            Op::Lt => x < y,
                            Op::Le => x <= y,
                            Op::Gt => x > y,
                            _ => x >= y,
                        }
                    }
                })
            }
        }
    }
}

#[test]
fn interpreter_runs_a_ton_and_rejects_what_it_does_not_know() {
    let text = "FUNCTION_BLOCK FB (* comment *)
VAR_INPUT go : BOOL; END_VAR
VAR_OUTPUT done : BOOL; late : BOOL := TRUE; END_VAR
VAR clk : TON; END_VAR
clk(IN := go, PT := T#1s500ms);
done := clk.Q;
IF clk.ET >= T#20ms AND NOT done THEN late := FALSE; ELSIF done THEN late := TRUE; ELSE late := late XOR FALSE; END_IF;
END_FUNCTION_BLOCK";
    let mut fb = Fb::parse(text).expect("parses");
    fb.set("GO", true);
    fb.call(0);
    assert_eq!(fb.get("done"), Some(false));
    assert_eq!(fb.get("late"), Some(true));
    fb.call(30 * MS);
    assert_eq!(fb.get("late"), Some(false));
    fb.call(1_500 * MS);
    assert_eq!(fb.get("done"), Some(true));
    fb.call(10_000_000 * MS);
    assert_eq!(fb.get("done"), Some(true));
    fb.set("go", false);
    fb.call(10_000_001 * MS);
    assert_eq!(fb.get("done"), Some(false));
    for bad in [
        "FUNCTION_BLOCK F VAR_INPUT a : BOOL; END_VAR a := TRUE; END_FUNCTION_BLOCK",
        "FUNCTION_BLOCK F VAR a : BOOL; END_VAR a := b; END_FUNCTION_BLOCK",
        "FUNCTION_BLOCK F VAR a : BOOL; t : TON; END_VAR a := t.ET; END_FUNCTION_BLOCK",
        "FUNCTION_BLOCK F VAR a : BOOL; END_VAR a := a AND; END_FUNCTION_BLOCK",
        "FUNCTION_BLOCK F VAR a__b : BOOL; END_VAR END_FUNCTION_BLOCK",
        "FUNCTION_BLOCK F VAR a : INT; END_VAR END_FUNCTION_BLOCK",
    ] {
        assert!(Fb::parse(bad).is_err(), "{bad}");
    }
}
