//! The safety filter as IEC 61131-3 Structured Text.
//!
//! [`generate`] writes one `FUNCTION_BLOCK` that does, once per PLC scan, what
//! [`Filter::scan`] does: the same observers, estimate intervals, orders, checks
//! and fallback, scan for scan. The PLC calls it after the control program and
//! before writing the outputs.
//!
//! - `VAR_INPUT`: every sensor, the control program's proposed orders (`A4_REQ`),
//!   the flags the diagnosers' monitor writes (`def_C4`, `suspect_C4`: only
//!   those the filter reads), and, when coupled, a probing move per output
//!   (`A4_PROBE`, `A4_PROBE_VALUE`), taken unless a safety constraint would
//!   then hold (`A4_PROBE_REFUSED` out), as [`Filter::request`] does.
//! - `VAR_OUTPUT`: the orders to write (`A4`), one `<constraint>_VIOLATED` per
//!   safety constraint, `FALLBACK` (a constraint was violated: every order took
//!   the value the constraints force, priority to 0), and `FALLBACK_<part>` (a
//!   fault of the part's actuators, element, or of a sensor of it that has no
//!   estimate, is flagged: its orders took that value).
//! - `VAR`: observers, previous values (`C3_PREV`, for edges and `prev`), the
//!   forced values `A4_F0` / `A4_F1`, and per clocked part a TON and the
//!   intervals `I1…In`.
//!
//! **Timing.** The Rust filter's clock of a part reads `t - since`, where `since`
//! is the time of the scan that wrote the part's present orders: one scan period
//! `P` in the scan after a change. A TON's `ET` counts from the first call that
//! saw `IN` TRUE. The generated code calls the part's TON with `IN := FALSE` at
//! the end of the scan that changed its orders, and with `IN := TRUE` at the
//! start of every scan, so `ET` starts at 0 in the next scan and the elapsed time
//! is exactly `ET + P`. An interval `[from, to[` is therefore
//! `ET >= from - P AND ET < to - P`, bounds rounded up to the millisecond (exact
//! for a TIME of millisecond resolution, and at any scan period that divides
//! them). `PT` is the largest bound, and `Q` says "past it", so a TON that has
//! run for hours still reads right: `ET` stops at `PT`. Until a part's orders
//! first change its clock reads "past every bound", as in the Rust filter.
//!
//! **Names.** Plant names become identifiers as they are when they can (`C4`,
//! `def_C4`, `P36`); a name that starts with a digit or is a reserved word gets
//! a leading underscore (`2P` becomes `_2P`), other characters become `_`.
//! Identifiers are case-insensitive in Structured Text: two names that would
//! clash are an error.

use std::cell::RefCell;
use std::collections::{BTreeSet, HashMap};
use std::fmt::Write as _;

use diagnoser::expr::Expr;
use diagnoser::plant::ObserverRule;
use diagnoser::{Flag, FlagKind, MS, Plant, SignalKind, Time};

use crate::filter::{Filter, Mode, PartIntervals};
use crate::synthesis::{CombinedLaw, OutputLaw, reduce};

/// What to generate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StOptions {
    /// [`Mode::Filter`]: check the control program's orders; [`Mode::Control`]:
    /// compute them by safe control by constraints, then check them.
    pub mode: Mode,
    /// Name of the function block.
    pub name: String,
}

impl Default for StOptions {
    fn default() -> Self {
        StOptions {
            mode: Mode::Filter,
            name: "GARDEFOU_FILTER".to_string(),
        }
    }
}

/// What a plant name stands for, as the filter reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Sensor,
    Actuator,
    Observer,
    Interval,
    /// Flags and internal variables: written by the caller between scans.
    Input,
}

/// Where an expression is evaluated, which decides what an output reads.
#[derive(Debug, Clone, Copy)]
enum Ctx<'a> {
    /// Before the orders are computed (intervals, observers, forced values):
    /// an output reads the order written in the previous scan.
    Before,
    /// In the safe law of this output: it reads the control program's order
    /// (the law keeps it where no functional constraint speaks), the other
    /// outputs their previous orders.
    Law(&'a str),
    /// On the orders being computed (combined constraints, the check).
    Orders,
}

/// IEC 61131-3 keywords, standard types and standard function block names an
/// identifier must not be.
const RESERVED: &[&str] = &[
    "ABS",
    "ACOS",
    "ACTION",
    "ADD",
    "AND",
    "ANY",
    "ARRAY",
    "ASIN",
    "AT",
    "ATAN",
    "BOOL",
    "BY",
    "BYTE",
    "CASE",
    "CD",
    "CLK",
    "CONFIGURATION",
    "CONSTANT",
    "COS",
    "CTD",
    "CTU",
    "CTUD",
    "CU",
    "CV",
    "DATE",
    "DATE_AND_TIME",
    "DINT",
    "DIV",
    "DO",
    "DT",
    "DWORD",
    "ELSE",
    "ELSIF",
    "EN",
    "END_ACTION",
    "END_CASE",
    "END_CONFIGURATION",
    "END_FOR",
    "END_FUNCTION",
    "END_FUNCTION_BLOCK",
    "END_IF",
    "END_PROGRAM",
    "END_REPEAT",
    "END_RESOURCE",
    "END_STEP",
    "END_STRUCT",
    "END_TRANSITION",
    "END_TYPE",
    "END_VAR",
    "END_WHILE",
    "ENO",
    "EQ",
    "ET",
    "EXIT",
    "EXP",
    "EXPT",
    "F_EDGE",
    "F_TRIG",
    "FALSE",
    "FOR",
    "FROM",
    "FUNCTION",
    "FUNCTION_BLOCK",
    "GE",
    "GT",
    "IF",
    "IN",
    "INITIAL_STEP",
    "INT",
    "INTERVAL",
    "LD",
    "LDATE",
    "LE",
    "LINT",
    "LN",
    "LOG",
    "LREAL",
    "LT",
    "LTIME",
    "LWORD",
    "MAX",
    "MID",
    "MIN",
    "MOD",
    "MOVE",
    "MUL",
    "MUX",
    "NE",
    "NOT",
    "OF",
    "ON",
    "OR",
    "PRIORITY",
    "PROGRAM",
    "PT",
    "PV",
    "Q",
    "QD",
    "QU",
    "R",
    "R_EDGE",
    "R_TRIG",
    "READ_ONLY",
    "READ_WRITE",
    "REAL",
    "REPEAT",
    "RESOURCE",
    "RETAIN",
    "RETURN",
    "ROL",
    "ROR",
    "RS",
    "S",
    "SEL",
    "SHL",
    "SHR",
    "SIN",
    "SINT",
    "SQRT",
    "SR",
    "STEP",
    "STRING",
    "STRUCT",
    "SUB",
    "TAN",
    "TASK",
    "THEN",
    "TIME",
    "TIME_OF_DAY",
    "TO",
    "TOD",
    "TOF",
    "TON",
    "TP",
    "TRANSITION",
    "TRUE",
    "TYPE",
    "UDINT",
    "UINT",
    "ULINT",
    "UNTIL",
    "USINT",
    "VAR",
    "VAR_ACCESS",
    "VAR_CONFIG",
    "VAR_EXTERNAL",
    "VAR_GLOBAL",
    "VAR_IN_OUT",
    "VAR_INPUT",
    "VAR_OUTPUT",
    "VAR_TEMP",
    "WHILE",
    "WITH",
    "WORD",
    "WSTRING",
    "XOR",
];

/// The start of the identifiers made from a name (`C4` in `C4_PREV`): letters,
/// digits and single inner underscores, a leading underscore before a digit.
fn stem(name: &str) -> String {
    let mut s = String::new();
    for c in name.chars() {
        let c = if c.is_ascii_alphanumeric() { c } else { '_' };
        if !(c == '_' && s.ends_with('_')) {
            s.push(c);
        }
    }
    let s = s.trim_end_matches('_');
    if s.is_empty() {
        "_V".to_string()
    } else if s.starts_with(|c: char| c.is_ascii_digit()) {
        format!("_{s}")
    } else {
        s.to_string()
    }
}

/// A name as a Structured Text identifier: its [`stem`], with a leading
/// underscore if that is a reserved word.
fn mangle(name: &str) -> String {
    let s = stem(name);
    if RESERVED.iter().any(|r| r.eq_ignore_ascii_case(&s)) {
        format!("_{s}")
    } else {
        s
    }
}

/// Text safe inside a `(* … *)` comment, on one line.
fn comment_text(text: &str) -> String {
    text.replace("(*", "( *")
        .replace("*)", "* )")
        .replace(['\n', '\r'], " ")
}

/// A whole number of milliseconds as a TIME literal.
fn time_literal(ms: i64) -> String {
    format!("T#{ms}ms")
}

/// `ns` rounded up to whole milliseconds.
fn ceil_ms(ns: Time) -> i64 {
    ns.div_euclid(MS) + i64::from(ns.rem_euclid(MS) != 0)
}

/// A time in ms for comments: `140` or `140.000001`.
fn ms_text(ns: Time) -> String {
    if ns % MS == 0 {
        format!("{}", ns / MS)
    } else {
        let text = format!("{}.{:06}", ns / MS, (ns % MS).abs());
        text.trim_end_matches('0').to_string()
    }
}

fn var(name: &str) -> Expr {
    Expr::Var(name.to_string())
}

fn not(e: Expr) -> Expr {
    Expr::Not(Box::new(e))
}

/// An expression over Structured Text identifiers (every leaf a `Var` or a
/// constant, after [`Gen::translate`]) as Structured Text.
fn st_expr(e: &Expr) -> String {
    fn prec(e: &Expr) -> u8 {
        match e {
            Expr::Or(_) => 1,
            Expr::And(_) => 2,
            _ => 3,
        }
    }
    fn child(e: &Expr, min: u8) -> String {
        if prec(e) < min {
            format!("({})", st_expr(e))
        } else {
            st_expr(e)
        }
    }
    match e {
        Expr::Const(true) => "TRUE".to_string(),
        Expr::Const(false) => "FALSE".to_string(),
        Expr::Var(n) => n.clone(),
        Expr::Not(inner) => format!("NOT {}", child(inner, 3)),
        Expr::And(es) => es
            .iter()
            .map(|e| child(e, 2))
            .collect::<Vec<_>>()
            .join(" AND "),
        Expr::Or(es) => es
            .iter()
            .map(|e| child(e, 1))
            .collect::<Vec<_>>()
            .join(" OR "),
        // Resolved by `translate`: if one slipped through, it shows, and no
        // PLC compiler takes it for something else.
        Expr::Rise(_) | Expr::Fall(_) | Expr::Prev(_) => e.to_string(),
    }
}

/// Longest line before an expression is broken at its top-level operators.
const WIDTH: usize = 100;

/// `prefix expr suffix`, broken after the top-level `OR` / `AND` terms when
/// longer than [`WIDTH`], continuation lines indented under `indent`.
fn wrapped(indent: &str, prefix: &str, e: &Expr, suffix: &str) -> String {
    let one = format!("{indent}{prefix}{}{suffix}", st_expr(e));
    if one.len() <= WIDTH {
        return one;
    }
    let (terms, op, min) = match e {
        Expr::Or(es) => (es, "OR", 1),
        Expr::And(es) => (es, "AND", 2),
        _ => return one,
    };
    let mut out = String::new();
    let cont = format!("{indent}        ");
    for (i, t) in terms.iter().enumerate() {
        let text = if min == 2 && matches!(t, Expr::Or(_)) {
            format!("({})", st_expr(t))
        } else {
            st_expr(t)
        };
        if i == 0 {
            let _ = write!(out, "{indent}{prefix}{text}");
        } else {
            let _ = write!(out, "\n{cont}{op} {text}");
        }
    }
    out.push_str(suffix);
    out
}

/// One clocked part, as generated.
struct Clock {
    part: String,
    actuators: Vec<String>,
    intervals: PartIntervals,
}

/// The generator's state: names, and what the body turned out to read.
struct Gen<'a> {
    plant: &'a Plant,
    filter: &'a Filter,
    options: &'a StOptions,
    kind: HashMap<String, Kind>,
    ident: HashMap<String, String>,
    /// Plant names whose previous value the body reads.
    prev_used: RefCell<BTreeSet<String>>,
    /// Flags and internal variables the body reads.
    read: RefCell<BTreeSet<String>>,
    /// Outputs whose proposed order (`_REQ`) the body reads.
    req_used: RefCell<BTreeSet<String>>,
    /// Identifiers taken, upper-cased, with what took them.
    taken: HashMap<String, String>,
}

impl<'a> Gen<'a> {
    fn new(plant: &'a Plant, filter: &'a Filter, options: &'a StOptions) -> Result<Self, String> {
        let names = filter.names();
        let signals: Vec<&str> = plant.signals.iter().map(|(_, s)| s.name.as_str()).collect();
        if names.len() < signals.len() || names[..signals.len()] != signals[..] {
            return Err("the filter was not built for this plant".to_string());
        }
        let mut kind = HashMap::new();
        for (_, s) in plant.signals.iter() {
            let k = match s.kind {
                SignalKind::Sensor => Kind::Sensor,
                SignalKind::Actuator => Kind::Actuator,
            };
            kind.insert(s.name.clone(), k);
        }
        for o in &plant.observers {
            kind.insert(o.name.clone(), Kind::Observer);
        }
        for part in filter.intervals() {
            for (_, iv) in &part.states {
                for i in iv {
                    kind.insert(i.name.clone(), Kind::Interval);
                }
            }
        }
        // Flags, variables: whatever else the filter holds.
        for n in names {
            kind.entry(n.clone()).or_insert(Kind::Input);
        }
        let mut g = Gen {
            plant,
            filter,
            options,
            ident: HashMap::new(),
            kind,
            prev_used: RefCell::new(BTreeSet::new()),
            read: RefCell::new(BTreeSet::new()),
            req_used: RefCell::new(BTreeSet::new()),
            taken: HashMap::new(),
        };
        g.take(&options.name, "the function block")?;
        if mangle(&options.name) != options.name {
            return Err(format!(
                "the function block's name '{}' is a reserved word or not an identifier",
                options.name
            ));
        }
        for n in names {
            let id = mangle(n);
            g.take(&id, n)?;
            g.ident.insert(n.clone(), id);
        }
        for n in names {
            let id = stem(n);
            match g.kind[n] {
                Kind::Sensor | Kind::Observer | Kind::Interval => {
                    g.take(&format!("{id}_PREV"), &format!("prev({n})"))?
                }
                Kind::Actuator => {
                    for suffix in ["_PREV", "_REQ", "_F0", "_F1"] {
                        g.take(&format!("{id}{suffix}"), &format!("{n}{suffix}"))?;
                    }
                }
                Kind::Input => {}
            }
        }
        for c in &plant.constraints {
            g.take(&format!("{}_VIOLATED", stem(&c.name)), &c.name)?;
        }
        g.take("FALLBACK", "the fallback")?;
        g.take("FIRST_SCAN", "the first scan")?;
        for p in &plant.parts {
            let id = stem(&p.name);
            for name in [
                format!("FALLBACK_{id}"),
                format!("{id}_CLK"),
                format!("{id}_CLK_SET"),
            ] {
                g.take(&name, &format!("part {}", p.name))?;
            }
        }
        Ok(g)
    }

    /// Reserves an identifier; two names that are the same identifier are an error.
    fn take(&mut self, ident: &str, owner: &str) -> Result<(), String> {
        let key = ident.to_ascii_uppercase();
        if let Some(other) = self.taken.get(&key)
            && other != owner
        {
            return Err(format!(
                "'{other}' and '{owner}' are the same Structured Text identifier '{ident}' (identifiers ignore case): rename one"
            ));
        }
        self.taken.insert(key, owner.to_string());
        Ok(())
    }

    fn id(&self, name: &str) -> Result<String, String> {
        self.ident
            .get(name)
            .cloned()
            .ok_or_else(|| format!("the filter has no variable '{name}'"))
    }

    fn kind_of(&self, name: &str) -> Result<Kind, String> {
        self.kind
            .get(name)
            .copied()
            .ok_or_else(|| format!("the filter has no variable '{name}'"))
    }

    /// The identifier of `name`'s previous value, marked as read.
    fn prev_id(&self, name: &str) -> Result<String, String> {
        self.prev_used.borrow_mut().insert(name.to_string());
        self.id(name)?;
        Ok(format!("{}_PREV", stem(name)))
    }

    /// The value `name` has in `ctx`, as an expression over identifiers.
    fn cur(&self, name: &str, ctx: Ctx) -> Result<Expr, String> {
        Ok(match (self.kind_of(name)?, ctx) {
            (Kind::Actuator, Ctx::Law(own)) if own == name => {
                self.req_used.borrow_mut().insert(name.to_string());
                self.id(name)?;
                var(&format!("{}_REQ", stem(name)))
            }
            (Kind::Actuator, Ctx::Before | Ctx::Law(_)) => var(&self.prev_id(name)?),
            (Kind::Input, _) => {
                self.read.borrow_mut().insert(name.to_string());
                var(&self.id(name)?)
            }
            _ => var(&self.id(name)?),
        })
    }

    /// The value `name` had in the previous scan.
    fn prev(&self, name: &str) -> Result<Expr, String> {
        if self.kind_of(name)? == Kind::Input {
            // A flag or variable read through `prev` or an edge is an input too.
            self.read.borrow_mut().insert(name.to_string());
        }
        Ok(var(&self.prev_id(name)?))
    }

    /// `e` over Structured Text identifiers, edges and `prev` resolved, simplified.
    fn translate(&self, e: &Expr, ctx: Ctx) -> Result<Expr, String> {
        fn go(g: &Gen, e: &Expr, ctx: Ctx) -> Result<Expr, String> {
            Ok(match e {
                Expr::Const(b) => Expr::Const(*b),
                Expr::Var(n) => g.cur(n, ctx)?,
                Expr::Prev(n) => g.prev(n)?,
                Expr::Rise(n) => Expr::And(vec![g.cur(n, ctx)?, not(g.prev(n)?)]),
                Expr::Fall(n) => Expr::And(vec![not(g.cur(n, ctx)?), g.prev(n)?]),
                Expr::Not(inner) => not(go(g, inner, ctx)?),
                Expr::And(es) => {
                    Expr::And(es.iter().map(|e| go(g, e, ctx)).collect::<Result<_, _>>()?)
                }
                Expr::Or(es) => {
                    Expr::Or(es.iter().map(|e| go(g, e, ctx)).collect::<Result<_, _>>()?)
                }
            })
        }
        Ok(reduce(&go(self, e, ctx)?))
    }

    /// The plant's actuators, in signal order.
    fn actuators(&self) -> Vec<String> {
        self.plant
            .signals
            .of_kind(SignalKind::Actuator)
            .map(|a| self.plant.signals.name(a).to_string())
            .collect()
    }

    /// The part whose actuators are exactly `actuators`.
    fn part_named_by(&self, actuators: &[String]) -> Result<String, String> {
        self.plant
            .parts
            .iter()
            .find(|p| {
                p.actuators.len() == actuators.len()
                    && p.actuators
                        .iter()
                        .zip(actuators)
                        .all(|(a, n)| self.plant.signals.name(*a) == n)
            })
            .map(|p| p.name.clone())
            .ok_or_else(|| format!("no part has the actuators {}", actuators.join(", ")))
    }

    fn clocks(&self) -> Result<Vec<Clock>, String> {
        self.filter
            .intervals()
            .into_iter()
            .map(|iv| {
                Ok(Clock {
                    part: self.part_named_by(&iv.actuators)?,
                    actuators: iv.actuators.clone(),
                    intervals: iv,
                })
            })
            .collect()
    }

    /// The names of the constraints feeding output `a`'s law: simple safety
    /// constraints, and functional ones.
    fn law_sources(&self, a: &str) -> (Vec<String>, Vec<String>) {
        let reads = |e: &Expr| -> Vec<String> {
            let mut outs: Vec<String> = e
                .names()
                .into_iter()
                .filter(|n| self.kind.get(*n) == Some(&Kind::Actuator))
                .map(str::to_string)
                .collect();
            outs.sort();
            outs.dedup();
            outs
        };
        let safety = self
            .plant
            .constraints
            .iter()
            .filter(|c| c.priority.is_none() && reads(&c.expr) == [a])
            .map(|c| c.name.clone())
            .collect();
        let functional = self
            .plant
            .functional
            .iter()
            .filter(|c| reads(&c.expr).iter().any(|o| o == a))
            .map(|c| c.name.clone())
            .collect();
        (safety, functional)
    }

    /// `CSs6 = C4 & C6 & A2, rewritten with the estimate of C4 (while def_C4)`:
    /// a safety constraint as written in the plant file, and the estimates the
    /// filter rewrote it with.
    fn constraint_note(&self, name: &str, rewritten: &Expr) -> String {
        let Some(original) = self.plant.constraints.iter().find(|c| c.name == name) else {
            return format!("{name} = {rewritten}");
        };
        let mut note = format!("{name} = {}", original.expr);
        if original.expr != *rewritten {
            let names = original.expr.names();
            let used: Vec<String> = self
                .filter
                .estimates()
                .iter()
                .filter(|e| names.contains(&e.sensor.as_str()))
                .map(|e| format!("{} (while {})", e.sensor, self.switch_text(&e.partition)))
                .collect();
            if !used.is_empty() {
                let s = if used.len() > 1 { "s" } else { "" };
                let _ = write!(
                    note,
                    ", rewritten with the estimate{s} of {}",
                    used.join(" and ")
                );
            }
        }
        comment_text(&note)
    }

    /// The switch of an estimate, e.g. `def_C4 OR suspect_C4`, for comments.
    fn switch_text(&self, partition: &str) -> String {
        match self.filter.coupling() {
            crate::filter::Coupling::FlagsAndSuspects => {
                format!("{} OR {}", Flag::def(partition), Flag::suspect(partition))
            }
            _ => Flag::def(partition).to_string(),
        }
    }

    /// The statements of one scan, in the order the Rust filter runs them:
    /// estimate intervals, observers, forced values, orders, the check of the
    /// orders, the fallbacks, and the restart of the clocks.
    fn body(&self, out: &mut String) -> Result<BodyFacts, String> {
        let mut facts = BodyFacts::default();
        let period = self.plant.scan_period;
        let actuators = self.actuators();
        let clocks = self.clocks()?;
        for c in &clocks {
            self.write_intervals(out, c, period, &mut facts)?;
        }
        self.write_observers(out)?;
        let (laws, combined) = self.filter.laws();
        let forced = self.write_forced_values(out, &laws, &mut facts)?;
        if self.options.mode == Mode::Control {
            self.write_safe_control(out, &laws, &forced)?;
            self.write_combined_constraints(out, &combined)?;
        } else {
            self.write_proposed_orders(out, &actuators)?;
        }
        if self.filter.coupling() != crate::filter::Coupling::None {
            self.write_probes(out, &actuators, &mut facts)?;
        }
        self.write_check(out, &mut facts)?;
        self.write_fallback(out, &actuators, &forced)?;
        self.write_part_fallbacks(out, &forced, &mut facts)?;
        self.write_clock_restarts(out, &clocks, &facts)?;
        Ok(facts)
    }

    /// The observers, from the plant file, updated before this scan's orders
    /// (as in the Rust filter: an observer reading an output sees its previous
    /// order).
    fn write_observers(&self, out: &mut String) -> Result<(), String> {
        if !self.plant.observers.is_empty() {
            out.push_str(
                "\n(* Observers, from the plant file: on a set/reset observer reset wins. *)\n",
            );
        }
        for o in &self.plant.observers {
            let id = self.id(&o.name)?;
            let read = match &o.rule {
                ObserverRule::SetReset { set, reset } => [set.names(), reset.names()].concat(),
                ObserverRule::Toggle(e) => e.names(),
            };
            let mut orders: Vec<&str> = read
                .into_iter()
                .filter(|n| self.kind.get(*n) == Some(&Kind::Actuator))
                .collect();
            orders.sort_unstable();
            orders.dedup();
            if !orders.is_empty() {
                let _ = writeln!(
                    out,
                    "(* {}: reads {} as ordered in the previous scan, as the Rust filter does: observers\n   are updated before this scan's orders, so an edge of an order is never seen here. *)",
                    comment_text(&o.name),
                    orders.join(", ")
                );
            }
            match &o.rule {
                ObserverRule::SetReset { set, reset } => {
                    self.write_set_reset(out, &o.name, &id, set, reset)?;
                }
                ObserverRule::Toggle(e) => self.write_toggle(out, &o.name, &id, e)?,
            }
        }
        Ok(())
    }

    /// A set/reset observer: reset wins, a condition that never holds is left out.
    fn write_set_reset(
        &self,
        out: &mut String,
        name: &str,
        id: &str,
        set: &Expr,
        reset: &Expr,
    ) -> Result<(), String> {
        let _ = writeln!(
            out,
            "(* {}: set on {}, reset on {} *)",
            comment_text(name),
            comment_text(&set.to_string()),
            comment_text(&reset.to_string())
        );
        let set = self.translate(set, Ctx::Before)?;
        let reset = self.translate(reset, Ctx::Before)?;
        let mut branches = Vec::new();
        if reset != Expr::Const(false) {
            branches.push((reset, "FALSE"));
        }
        if set != Expr::Const(false) {
            branches.push((set, "TRUE"));
        }
        if_chain(out, "", &branches, id);
        Ok(())
    }

    /// A toggle observer: flips while its condition holds.
    fn write_toggle(&self, out: &mut String, name: &str, id: &str, e: &Expr) -> Result<(), String> {
        let _ = writeln!(
            out,
            "(* {}: toggles on {} *)",
            comment_text(name),
            comment_text(&e.to_string())
        );
        let e = self.translate(e, Ctx::Before)?;
        if e != Expr::Const(false) {
            out.push_str(&wrapped("", "IF ", &e, " THEN\n"));
            let _ = writeln!(out, "    {id} := NOT {id};\nEND_IF;");
        }
        Ok(())
    }

    /// What the simple safety constraints force on each output (`f0k` in safe
    /// control only, `f1k` always, for the fallback). A forced value that is
    /// not a constant is kept in a variable (`A4_F0`, `A4_F1`), declared from
    /// `facts`; the map gives each output's pair as read afterwards.
    fn write_forced_values(
        &self,
        out: &mut String,
        laws: &[OutputLaw],
        facts: &mut BodyFacts,
    ) -> Result<Forced, String> {
        let control = self.options.mode == Mode::Control;
        let mut forced = Forced::new();
        let mut section = String::new();
        let mut unforced = Vec::new();
        for law in laws {
            let id = stem(&law.output);
            let ctx = Ctx::Law(&law.output);
            let (sources, _) = self.law_sources(&law.output);
            let f0 = if control {
                self.translate(&law.f0, ctx)?
            } else {
                Expr::Const(false)
            };
            let f1 = self.translate(&law.f1, ctx)?;
            let keep = |e: &Expr, suffix: &str, facts: &mut BodyFacts, out: &mut String| {
                if matches!(e, Expr::Const(_)) {
                    e.clone()
                } else {
                    let name = format!("{id}{suffix}");
                    out.push_str(&wrapped("", &format!("{name} := "), e, ";\n"));
                    facts
                        .forced_vars
                        .push((name.clone(), law.output.clone(), suffix == "_F1"));
                    var(&name)
                }
            };
            if matches!(f0, Expr::Const(false)) && matches!(f1, Expr::Const(false)) {
                unforced.push(law.output.clone());
            } else {
                let _ = writeln!(section, "(* {}: from {} *)", law.output, sources.join(", "));
            }
            let f0 = keep(&f0, "_F0", facts, &mut section);
            let f1 = keep(&f1, "_F1", facts, &mut section);
            forced.insert(law.output.clone(), (f0, f1));
        }
        let what = if control {
            "What the simple safety constraints force on each output: f0k (it must be 0) and\n   f1k (it must be 1)"
        } else {
            "What the simple safety constraints force to 1 on each output (f1k), for the fallback"
        };
        let _ = write!(
            out,
            "\n(* {what}, by cofactors of the constraints that read it (seed 001 section 4).{} *)\n{section}",
            if unforced.is_empty() {
                String::new()
            } else {
                format!("\n   Nothing forced on {}.", unforced.join(", "))
            }
        );
        Ok(forced)
    }

    /// The orders by safe control by constraints: `S'k := NOT f0k AND g1k OR
    /// f1k`, one output after the other.
    fn write_safe_control(
        &self,
        out: &mut String,
        laws: &[OutputLaw],
        forced: &Forced,
    ) -> Result<(), String> {
        out.push_str(
            "\n(* Safe control by constraints (seed 001 section 4): S'k := NOT f0k AND g1k OR f1k, g1k from the\n   functional constraints (an output with none keeps the control program's order). *)\n",
        );
        for law in laws {
            let id = self.id(&law.output)?;
            let (_, functional) = self.law_sources(&law.output);
            let g1 = self.translate(&law.g1, Ctx::Law(&law.output))?;
            let (f0, f1) = forced
                .get(&law.output)
                .cloned()
                .unwrap_or((Expr::Const(false), Expr::Const(false)));
            let _ = writeln!(
                out,
                "(* {}: g1 {} *)",
                law.output,
                if functional.is_empty() {
                    format!("= {}_REQ (no functional constraint)", stem(&law.output))
                } else {
                    format!("from {}", functional.join(", "))
                }
            );
            let safe = reduce(&Expr::Or(vec![Expr::And(vec![not(f0), g1]), f1]));
            out.push_str(&wrapped("", &format!("{id} := "), &safe, ";\n"));
        }
        Ok(())
    }

    /// The combined constraints after safe control: while one holds, its
    /// non-priority output goes to 0. The Rust filter loops until nothing
    /// changes, at most one pass more than there are combined constraints; the
    /// loop is unrolled to that many passes.
    fn write_combined_constraints(
        &self,
        out: &mut String,
        combined: &[CombinedLaw],
    ) -> Result<(), String> {
        if combined.is_empty() {
            return Ok(());
        }
        let passes = combined.len() + 1;
        let _ = writeln!(
            out,
            "\n(* Combined constraints (seed 001 fig. 3): while one holds, its non-priority output\n   goes to 0. The loop is unrolled: {passes} passes, as many as the Rust filter runs at most. *)"
        );
        for pass in 1..=passes {
            if pass == 1 {
                let _ = writeln!(out, "(* Pass 1 of {passes}. *)");
            } else {
                let _ = writeln!(out, "(* Pass {pass} of {passes}: the same. *)");
            }
            for c in combined {
                let other = self.id(&c.other)?;
                if pass == 1 {
                    let _ = writeln!(
                        out,
                        "(* {}; priority {}: {} goes to 0 *)",
                        self.constraint_note(&c.constraint, &c.expr),
                        c.priority,
                        c.other
                    );
                }
                let holds = self.translate(&c.expr, Ctx::Orders)?;
                let cond = reduce(&Expr::And(vec![holds, var(&other)]));
                if cond != Expr::Const(false) {
                    out.push_str(&wrapped("", "IF ", &cond, " THEN\n"));
                    let _ = writeln!(out, "    {other} := FALSE;\nEND_IF;");
                }
            }
        }
        Ok(())
    }

    /// The orders as the control program proposes them (filter mode).
    fn write_proposed_orders(&self, out: &mut String, actuators: &[String]) -> Result<(), String> {
        out.push_str("\n(* The orders the control program proposes. *)\n");
        for a in actuators {
            let id = self.id(a)?;
            self.req_used.borrow_mut().insert(a.clone());
            let _ = writeln!(out, "{id} := {}_REQ;", stem(a));
        }
        Ok(())
    }

    /// Probing moves asked for from outside the control, as
    /// [`Filter::request`] applies them: output by output, the requested value
    /// replaces the order unless a safety constraint would then hold.
    fn write_probes(
        &self,
        out: &mut String,
        actuators: &[String],
        facts: &mut BodyFacts,
    ) -> Result<(), String> {
        out.push_str(
            "\n(* Probing moves requested from outside the control (A_PROBE, A_PROBE_VALUE): each output,\n   in turn, takes its requested value unless a safety constraint would then hold. *)\n",
        );
        let mut constraints = Vec::new();
        for (_, expr) in self.filter.safety_constraints() {
            constraints.push(self.translate(expr, Ctx::Orders)?);
        }
        let any = reduce(&Expr::Or(constraints));
        for a in actuators {
            let (id, st) = (self.id(a)?, stem(a));
            let refused = format!("{st}_PROBE_REFUSED");
            let _ = writeln!(
                out,
                "{refused} := FALSE;\nIF {st}_PROBE AND ({id} XOR {st}_PROBE_VALUE) THEN\n    {id} := {st}_PROBE_VALUE;"
            );
            out.push_str(&wrapped("    ", &format!("{refused} := "), &any, ";\n"));
            let _ = writeln!(
                out,
                "    IF {refused} THEN\n        {id} := NOT {st}_PROBE_VALUE;\n    END_IF;\nEND_IF;"
            );
            facts.probes.push(a.clone());
        }
        Ok(())
    }

    /// The check of the orders: one `<constraint>_VIOLATED` per safety
    /// constraint, as the filter evaluates it (rewritten when coupled), and
    /// `FALLBACK` if any is set.
    fn write_check(&self, out: &mut String, facts: &mut BodyFacts) -> Result<(), String> {
        out.push_str("\n(* Safety constraints on the orders: each must stay 0. *)\n");
        let mut bits = Vec::new();
        for ((name, expr), original) in self
            .filter
            .safety_constraints()
            .zip(&self.plant.constraints)
        {
            if name != original.name {
                return Err("the filter was not built for this plant".to_string());
            }
            let bit = format!("{}_VIOLATED", stem(name));
            let _ = writeln!(out, "(* {} *)", self.constraint_note(name, expr));
            let e = self.translate(expr, Ctx::Orders)?;
            out.push_str(&wrapped("", &format!("{bit} := "), &e, ";\n"));
            bits.push(var(&bit));
            facts
                .violated
                .push((bit, name.to_string(), original.expr.to_string()));
        }
        let any = reduce(&Expr::Or(bits));
        out.push_str(&wrapped("", "FALLBACK := ", &any, ";\n"));
        Ok(())
    }

    /// The plant's fallback: on a violated constraint every order takes `f1k`.
    fn write_fallback(
        &self,
        out: &mut String,
        actuators: &[String],
        forced: &Forced,
    ) -> Result<(), String> {
        out.push_str(
            "\n(* Fallback: a constraint was violated, so every order takes the value the constraints\n   force, priority to 0 (Sk := f1k). *)\nIF FALLBACK THEN\n",
        );
        self.write_orders_to_f1(out, actuators, forced)?;
        out.push_str("END_IF;\n");
        Ok(())
    }

    /// `A := f1;` for each of `actuators`, inside an `IF`: the value the
    /// constraints force (0 where they force nothing).
    fn write_orders_to_f1(
        &self,
        out: &mut String,
        actuators: &[String],
        forced: &Forced,
    ) -> Result<(), String> {
        for a in actuators {
            let f1 = forced.get(a).map_or(Expr::Const(false), |f| f.1.clone());
            out.push_str(&wrapped(
                "    ",
                &format!("{} := ", self.id(a)?),
                &f1,
                ";\n",
            ));
        }
        Ok(())
    }

    /// The parts' fallbacks: while one of a part's actuator or element faults is
    /// flagged (and the plant is not in its fallback already), its orders take
    /// `f1k`. One `FALLBACK_<part>` per part with such a fault.
    fn write_part_fallbacks(
        &self,
        out: &mut String,
        forced: &Forced,
        facts: &mut BodyFacts,
    ) -> Result<(), String> {
        // `fallback_parts` keeps the plant's order of parts: match them in turn.
        let mut next_part = 0;
        for (flags, acts) in self.filter.fallback_parts() {
            let same = |p: &diagnoser::plant::Part| {
                p.actuators.len() == acts.len()
                    && p.actuators
                        .iter()
                        .zip(&acts)
                        .all(|(a, n)| self.plant.signals.name(*a) == n)
            };
            let offset = self.plant.parts[next_part..]
                .iter()
                .position(same)
                .ok_or_else(|| format!("no part has the actuators {}", acts.join(", ")))?;
            let part = self.plant.parts[next_part + offset].name.clone();
            next_part += offset + 1;
            let pid = stem(&part);
            let bit = format!("FALLBACK_{pid}");
            let _ = writeln!(
                out,
                "(* Part {part}: a flagged actuator or element fault ({}) sends its orders to f1k. *)",
                flags.join(", ")
            );
            let flag_exprs = flags
                .iter()
                .map(|f| self.cur(f, Ctx::Before))
                .collect::<Result<Vec<_>, _>>()?;
            let cond = reduce(&Expr::And(vec![not(var("FALLBACK")), Expr::Or(flag_exprs)]));
            out.push_str(&wrapped("", &format!("{bit} := "), &cond, ";\n"));
            let _ = writeln!(out, "IF {bit} THEN");
            self.write_orders_to_f1(out, &acts, forced)?;
            out.push_str("END_IF;\n");
            facts.part_bits.push((bit, part));
        }
        Ok(())
    }

    /// The end of the scan for the clocks: a part whose orders changed in this
    /// scan restarts its timer (`IN := FALSE`, so that `ET` counts from the next
    /// call) and notes that its clock has started. Only what the intervals read.
    fn write_clock_restarts(
        &self,
        out: &mut String,
        clocks: &[Clock],
        facts: &BodyFacts,
    ) -> Result<(), String> {
        if !clocks.is_empty() {
            out.push_str(
                "\n(* Restart the clock of a part whose orders changed in this scan. *)\n",
            );
        }
        for c in clocks {
            let pid = stem(&c.part);
            let changed = c
                .actuators
                .iter()
                .map(|a| Ok(format!("{} XOR {}", self.id(a)?, self.prev_id(a)?)))
                .collect::<Result<Vec<_>, String>>()?;
            let cond = if changed.len() == 1 {
                changed[0].clone()
            } else {
                changed
                    .iter()
                    .map(|c| format!("({c})"))
                    .collect::<Vec<_>>()
                    .join(" OR ")
            };
            if !facts.timed.contains(&c.part) && !facts.set_used.contains(&c.part) {
                continue;
            }
            let _ = writeln!(out, "IF {cond} THEN");
            if facts.timed.contains(&c.part) {
                let _ = writeln!(out, "    {pid}_CLK(IN := FALSE);");
            }
            if facts.set_used.contains(&c.part) {
                let _ = writeln!(out, "    {pid}_CLK_SET := TRUE;");
            }
            out.push_str("END_IF;\n");
        }
        Ok(())
    }

    /// The intervals of one clocked part.
    fn write_intervals(
        &self,
        out: &mut String,
        c: &Clock,
        period: Time,
        facts: &mut BodyFacts,
    ) -> Result<(), String> {
        let pid = stem(&c.part);
        let clk = format!("{pid}_CLK");
        let set = format!("{pid}_CLK_SET");
        // Thresholds on ET, in whole ms: `from - P` and `to - P`.
        let lo = |from: Time| ceil_ms(from - period);
        let mut pt = 0;
        for (_, iv) in &c.intervals.states {
            for i in iv {
                pt = pt.max(lo(i.from));
                if let Some(to) = i.to {
                    pt = pt.max(lo(to));
                }
            }
        }
        let timed = pt > 0;
        let _ = writeln!(
            out,
            "\n(* Estimate intervals of part {part}, learned: the time since the scan that wrote the\n   present order of {acts} is {clk}.ET + {p} ms (the scan period): {clk} restarts\n   (IN := FALSE) at the end of the scan that changes the order and counts from the next\n   call. Bounds on ET are the learned ones minus {p} ms, rounded up to the ms; ET stops at\n   PT, the largest, and Q says past it. Until {acts} first changes, the clock is past every\n   bound. *)",
            part = c.part,
            acts = c.actuators.join(", "),
            p = ms_text(period),
        );
        if timed {
            let _ = writeln!(out, "{clk}(IN := TRUE, PT := {});", time_literal(pt));
        }
        let at_least = |ms: i64| -> Option<String> {
            if ms <= 0 {
                None
            } else if ms == pt {
                Some(format!("{clk}.Q"))
            } else {
                Some(format!("({clk}.ET >= {})", time_literal(ms)))
            }
        };
        let below = |ms: i64| -> Option<String> {
            if ms <= 0 {
                Some("FALSE".to_string())
            } else if ms == pt {
                Some(format!("NOT {clk}.Q"))
            } else {
                Some(format!("({clk}.ET < {})", time_literal(ms)))
            }
        };
        for (values, iv) in &c.intervals.states {
            let mut here = Vec::new();
            let mut state = Vec::new();
            for (a, v) in c.actuators.iter().zip(values) {
                let p = self.prev_id(a)?;
                here.push(if *v { p } else { format!("NOT {p}") });
                state.push(format!("{a} = {}", u8::from(*v)));
            }
            let _ = writeln!(out, "(* {} *)", state.join(", "));
            for i in iv {
                let id = self.id(&i.name)?;
                let mut terms = here.clone();
                match i.to {
                    Some(to) => {
                        facts.set_used.insert(c.part.clone());
                        terms.push(set.clone());
                        terms.extend(at_least(lo(i.from)));
                        terms.extend(below(lo(to)));
                    }
                    None => {
                        if let Some(t) = at_least(lo(i.from)) {
                            facts.set_used.insert(c.part.clone());
                            terms.push(format!("(NOT {set} OR {t})"));
                        }
                    }
                }
                if terms.iter().any(|t| t == "FALSE") {
                    terms = vec!["FALSE".to_string()];
                }
                if terms.is_empty() {
                    terms.push("TRUE".to_string());
                }
                let bounds = format!(
                    "[{} ms, {}[",
                    ms_text(i.from),
                    i.to.map_or("inf".to_string(), |t| format!("{} ms", ms_text(t)))
                );
                let _ = writeln!(
                    out,
                    "{id} := {}; (* {} = {bounds} *)",
                    terms.join(" AND "),
                    i.name
                );
                facts
                    .intervals
                    .push((id, i.name.clone(), values.clone(), bounds));
            }
        }
        if timed {
            facts.timed.insert(c.part.clone());
        }
        Ok(())
    }
}

/// `IF c1 THEN x := v1; ELSIF c2 THEN x := v2; END_IF;` (constant conditions folded).
fn if_chain(out: &mut String, indent: &str, branches: &[(Expr, &str)], target: &str) {
    let mut first = true;
    for (cond, value) in branches {
        if *cond == Expr::Const(true) {
            if first {
                let _ = writeln!(out, "{indent}{target} := {value};");
                return;
            }
            let _ = writeln!(out, "{indent}ELSE\n{indent}    {target} := {value};");
            let _ = writeln!(out, "{indent}END_IF;");
            return;
        }
        let keyword = if first { "IF " } else { "ELSIF " };
        out.push_str(&wrapped(indent, keyword, cond, " THEN\n"));
        let _ = writeln!(out, "{indent}    {target} := {value};");
        first = false;
    }
    if !first {
        let _ = writeln!(out, "{indent}END_IF;");
    }
}

/// What the body declared as it went.
#[derive(Debug, Default)]
struct BodyFacts {
    /// `(identifier, output, is f1)` of the forced values kept in variables.
    forced_vars: Vec<(String, String, bool)>,
    /// `(bit, constraint, expression)`.
    violated: Vec<(String, String, String)>,
    /// `(bit, part)` of the parts' fallbacks.
    part_bits: Vec<(String, String)>,
    /// `(identifier, name, actuator values, bounds)` of the intervals.
    intervals: Vec<(String, String, Vec<bool>, String)>,
    /// Parts whose clock needs a TON.
    timed: BTreeSet<String>,
    /// Parts whose clock needs its "started" flag.
    set_used: BTreeSet<String>,
    /// Outputs that take probing moves (`<A>_PROBE`, `<A>_PROBE_VALUE` in,
    /// `<A>_PROBE_REFUSED` out).
    probes: Vec<String>,
}

/// Per output, what the constraints force on it, `(f0, f1)`, as the orders
/// read it: a constant, or the variable that holds it (`A4_F1`).
type Forced = HashMap<String, (Expr, Expr)>;

/// The filter as a Structured Text function block (see the module documentation).
///
/// # Errors
/// A filter built for another plant, or plant names that clash as identifiers.
pub fn generate(plant: &Plant, filter: &Filter, options: &StOptions) -> Result<String, String> {
    let g = Gen::new(plant, filter, options)?;
    let mut body = String::new();
    let facts = g.body(&mut body)?;
    let ordered = g.write_prev_updates(&mut body)?;
    // What the body reads of the proposed orders, before the first scan reads more.
    let req_in_body = g.req_used.borrow().clone();
    let head = g.first_scan_block(&ordered)?;

    let mut out = String::new();
    g.write_header(&mut out);
    g.write_inputs(&mut out, &req_in_body, &facts)?;
    g.write_outputs(&mut out, &facts)?;
    // The first scan's block is empty when it has nothing to set.
    g.write_locals(&mut out, &facts, !head.is_empty(), &ordered)?;
    out.push_str(&head);
    out.push_str(&body);
    out.push_str("END_FUNCTION_BLOCK\n");
    Ok(out)
}

/// The function block around the body: the previous values, the first scan,
/// the header and the declarations, which depend on what the body read.
impl<'a> Gen<'a> {
    /// The end of the scan: the previous values the body read, for the next
    /// scan's edges and `prev()`. Returns those names, in the filter's order.
    fn write_prev_updates(&self, body: &mut String) -> Result<Vec<&'a String>, String> {
        let prev_used = self.prev_used.borrow().clone();
        let ordered: Vec<&String> = self
            .filter
            .names()
            .iter()
            .filter(|n| prev_used.contains(*n))
            .collect();
        if !ordered.is_empty() {
            body.push_str("\n(* Values for the next scan's edges and prev(). *)\n");
        }
        for n in &ordered {
            let id = self.id(n)?;
            let _ = writeln!(body, "{}_PREV := {id};", stem(n));
        }
        Ok(ordered)
    }

    /// The first scan, which sees no edge: the previous values of the signals
    /// and inputs are their present ones, and, as in `Filter::scan`, the
    /// proposed orders stand for those of the scan before. Empty when no such
    /// previous value is read.
    fn first_scan_block(&self, ordered: &[&String]) -> Result<String, String> {
        let first: Vec<&&String> = ordered
            .iter()
            .filter(|n| {
                matches!(
                    self.kind.get(n.as_str()),
                    Some(Kind::Sensor | Kind::Actuator | Kind::Input)
                )
            })
            .collect();
        let mut head = String::new();
        if !first.is_empty() {
            head.push_str(
                "\n(* First scan: no edge. The proposed orders stand for those of the scan before,\n   as in the Rust filter. *)\nIF FIRST_SCAN THEN\n",
            );
            for n in &first {
                let id = self.id(n)?;
                if self.kind.get(n.as_str()) == Some(&Kind::Actuator) {
                    self.req_used.borrow_mut().insert(n.to_string());
                    let _ = writeln!(head, "    {0}_PREV := {0}_REQ;", stem(n));
                } else {
                    let _ = writeln!(head, "    {}_PREV := {id};", stem(n));
                }
            }
            head.push_str("    FIRST_SCAN := FALSE;\nEND_IF;\n");
        }
        Ok(head)
    }

    /// The comment at the top (plant, mode, coupling, how to call the block)
    /// and the `FUNCTION_BLOCK` line.
    fn write_header(&self, out: &mut String) {
        let mode = match self.options.mode {
            Mode::Filter => "filter: the control program's orders are checked",
            Mode::Control => "safe control by constraints: the orders are computed, then checked",
        };
        let _ = writeln!(
            out,
            "(* {name}: the safety filter of plant '{plant}', generated by gardefou (filter-coupling st.rs).\n   Mode: {mode}.\n   Coupling: {coupling}.\n   Call it once per PLC scan, every {p} ms (the plant's scan period, which the estimate\n   intervals assume), after the control program and before the outputs are written:\n   sensors as read in this scan, the proposed orders *_REQ, the diagnosers' flags in;\n   the orders to write out. *)",
            name = self.options.name,
            plant = comment_text(&self.plant.name),
            p = ms_text(self.plant.scan_period),
            coupling = comment_text(&self.coupling_text()),
        );
        let _ = writeln!(out, "FUNCTION_BLOCK {}", self.options.name);
    }

    /// The coupling, for the header: which sensors' estimates the constraints
    /// switch to, and on which flags.
    fn coupling_text(&self) -> String {
        match self.filter.coupling() {
            crate::filter::Coupling::None => {
                "none: the constraints read the sensors as they are".to_string()
            }
            c => {
                let estimates: Vec<String> = self
                    .filter
                    .estimates()
                    .iter()
                    .map(|e| format!("{} (while {})", e.sensor, self.switch_text(&e.partition)))
                    .collect();
                if estimates.is_empty() {
                    format!("{}: no learned estimate", c.name())
                } else {
                    format!(
                        "{}: learned estimates of {}",
                        c.name(),
                        estimates.join(", ")
                    )
                }
            }
        }
    }

    /// `VAR_INPUT`: every sensor, the proposed orders read (`req_in_body`: those
    /// the body reads; the others only at the first scan), and the flags and
    /// internal variables read.
    fn write_inputs(
        &self,
        out: &mut String,
        req_in_body: &BTreeSet<String>,
        facts: &BodyFacts,
    ) -> Result<(), String> {
        let plant = self.plant;
        out.push_str("VAR_INPUT\n");
        for s in plant.signals.of_kind(SignalKind::Sensor) {
            let s = plant.signals.get(s);
            let _ = writeln!(
                out,
                "    {} : BOOL; (* {} *)",
                self.id(&s.name)?,
                comment_text(&s.description)
            );
        }
        let req = self.req_used.borrow().clone();
        for s in plant.signals.of_kind(SignalKind::Actuator) {
            let s = plant.signals.get(s);
            if req.contains(&s.name) {
                let only_first = if req_in_body.contains(&s.name) {
                    ""
                } else {
                    " (read at the first scan only)"
                };
                let _ = writeln!(
                    out,
                    "    {}_REQ : BOOL; (* proposed by the control program{only_first}: {} *)",
                    stem(&s.name),
                    comment_text(&s.description)
                );
            }
        }
        for a in &facts.probes {
            let st = stem(a);
            let _ = writeln!(
                out,
                "    {st}_PROBE : BOOL; (* a probing move of {} is requested *)\n    {st}_PROBE_VALUE : BOOL; (* the value it asks for *)",
                comment_text(a)
            );
        }
        let read = self.read.borrow().clone();
        for n in self.filter.names() {
            if read.contains(n) {
                let what = describe_input(plant, n);
                let _ = writeln!(
                    out,
                    "    {} : BOOL; (* {} *)",
                    self.id(n)?,
                    comment_text(&what)
                );
            }
        }
        out.push_str("END_VAR\n");
        Ok(())
    }

    /// `VAR_OUTPUT`: the orders, one `<constraint>_VIOLATED` per safety
    /// constraint, `FALLBACK`, and the parts' `FALLBACK_<part>`.
    fn write_outputs(&self, out: &mut String, facts: &BodyFacts) -> Result<(), String> {
        let plant = self.plant;
        out.push_str("VAR_OUTPUT\n");
        for s in plant.signals.of_kind(SignalKind::Actuator) {
            let s = plant.signals.get(s);
            let _ = writeln!(
                out,
                "    {} : BOOL; (* {} *)",
                self.id(&s.name)?,
                comment_text(&s.description)
            );
        }
        for (bit, name, expr) in &facts.violated {
            let _ = writeln!(
                out,
                "    {bit} : BOOL; (* {} was 1 on the orders *)",
                comment_text(&format!("{name} = {expr}"))
            );
        }
        out.push_str(
            "    FALLBACK : BOOL; (* a safety constraint was violated: every order took f1k *)\n",
        );
        for a in &facts.probes {
            let _ = writeln!(
                out,
                "    {}_PROBE_REFUSED : BOOL; (* the probing move of {} was refused: a constraint forbids it *)",
                stem(a),
                comment_text(a)
            );
        }
        for (bit, part) in &facts.part_bits {
            let _ = writeln!(
                out,
                "    {bit} : BOOL; (* part {} is in its fallback: a fault that stops it is flagged *)",
                comment_text(part)
            );
        }
        out.push_str("END_VAR\n");
        Ok(())
    }

    /// `VAR`: the first scan's flag, the observers, the forced values kept in
    /// variables, the clocks and intervals, and the previous values (`ordered`).
    fn write_locals(
        &self,
        out: &mut String,
        facts: &BodyFacts,
        first_scan: bool,
        ordered: &[&String],
    ) -> Result<(), String> {
        let plant = self.plant;
        out.push_str("VAR\n");
        if first_scan {
            out.push_str("    FIRST_SCAN : BOOL := TRUE;\n");
        }
        for o in &plant.observers {
            let init = if o.init { " := TRUE" } else { "" };
            let _ = writeln!(
                out,
                "    {} : BOOL{init}; (* observer {} *)",
                self.id(&o.name)?,
                comment_text(&o.name)
            );
        }
        for (id, output, f1) in &facts.forced_vars {
            let what = if *f1 { "must be 1" } else { "must be 0" };
            let _ = writeln!(
                out,
                "    {id} : BOOL; (* the safety constraints say {output} {what} *)"
            );
        }
        self.write_clock_vars(out, facts)?;
        for n in ordered {
            let init = plant
                .observers
                .iter()
                .find(|o| o.name == **n)
                .is_some_and(|o| o.init);
            let init = if init { " := TRUE" } else { "" };
            let _ = writeln!(
                out,
                "    {}_PREV : BOOL{init}; (* {n} in the previous scan *)",
                stem(n)
            );
        }
        out.push_str("END_VAR\n");
        Ok(())
    }

    /// Per clocked part: its timer (`TON`) if an interval reads the time, its
    /// "started" flag if one reads it, and its intervals.
    fn write_clock_vars(&self, out: &mut String, facts: &BodyFacts) -> Result<(), String> {
        for c in self.clocks()? {
            let pid = stem(&c.part);
            if facts.timed.contains(&c.part) {
                let _ = writeln!(
                    out,
                    "    {pid}_CLK : TON; (* time since the scan that wrote {}'s order, minus one scan *)",
                    c.actuators.join(", ")
                );
            }
            if facts.set_used.contains(&c.part) {
                let _ = writeln!(
                    out,
                    "    {pid}_CLK_SET : BOOL; (* {} changed at least once *)",
                    c.actuators.join(", ")
                );
            }
            for (id, name, values, bounds) in &facts.intervals {
                let belongs = c
                    .intervals
                    .states
                    .iter()
                    .any(|(_, iv)| iv.iter().any(|i| i.name == *name));
                if belongs {
                    let state: Vec<String> = c
                        .actuators
                        .iter()
                        .zip(values)
                        .map(|(a, v)| format!("{a} = {}", u8::from(*v)))
                        .collect();
                    let _ = writeln!(
                        out,
                        "    {id} : BOOL; (* {} {bounds} since {} *)",
                        name,
                        state.join(", ")
                    );
                }
            }
        }
        Ok(())
    }
}

/// What a flag or variable input is, for its comment.
fn describe_input(plant: &Plant, name: &str) -> String {
    for p in &plant.partitions {
        if Flag::names(FlagKind::Def, &p.name, name) {
            return format!("a fault of partition {} is certain (diagnosers)", p.name);
        }
        if Flag::names(FlagKind::Suspect, &p.name, name) {
            return format!(
                "partition {} is among the candidates of an ambiguous verdict",
                p.name
            );
        }
    }
    format!("internal variable {name}")
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use diagnoser::model::{
        ClockInterval, CommandEstimate, LearnSettings, Model, PartModel, Provenance, SensorEstimate,
    };

    use super::*;
    use crate::filter::Coupling;

    const PLANT: &str = r#"
name = "table"
scan_period_ms = 10
time_unit = "ms"

[signals]
C4 = { kind = "sensor", description = "turntable at loading position" }
C5 = { kind = "sensor", description = "turntable at unloading position" }
C6 = { kind = "sensor", description = "box on the turntable" }
A3 = { kind = "actuator", description = "rollers, to the right" }
A4 = { kind = "actuator", description = "rotate the turntable" }

[[parts]]
name = "turntable"
actuators = ["A4"]
sensors = ["C4", "C5"]
element = "P"

[[parts]]
name = "rollers"
actuators = ["A3"]
sensors = ["C6"]

[faults]
F1 = "stuck0(C4)"
F5 = "blocked_at(P, C4)"

[partitions]
C4 = ["F1"]
P = ["F5"]

[observers]
2P = { set = "FE(C6)", reset = "RE(C4)" }

[[constraints]]
name = "CSs5"
expr = "!C5 & A3"
[[constraints]]
name = "CSs13"
expr = "C4 & !C6 & A4"
[[constraints]]
name = "CSs14"
expr = "!C4 & RE(A4)"

[[functional]]
name = "CFs4"
expr = "C6 & !A4"
"#;

    fn model() -> Model {
        let iv = |name: &str, from: f64, to: Option<f64>| ClockInterval {
            name: name.into(),
            from,
            to,
        };
        Model {
            version: 1,
            plant: "table".into(),
            plant_digest: None,
            time_unit: diagnoser::TimeUnit::Ms,
            scan_period: 10.0,
            learned_from: Provenance {
                logs: Vec::new(),
                events: 0,
                duration: 0.0,
            },
            settings: LearnSettings {
                margin: 10.0,
                margin_relative: 0.0,
                trim: 0.0,
                drift: 0.0,
                drift_sigma: 0.0,
            },
            parts: vec![PartModel {
                name: "turntable".into(),
                signals: vec!["A4".into(), "C4".into(), "C5".into()],
                actuators: 1,
                states: Vec::new(),
                transitions: Vec::new(),
                estimates: vec![
                    CommandEstimate {
                        actuators: "A4=1".into(),
                        intervals: vec![
                            iv("I1", 0.0, Some(20.0)),
                            iv("I2", 20.0, Some(140.000001)),
                            iv("I3", 140.000001, None),
                        ],
                        sensors: Vec::new(),
                    },
                    CommandEstimate {
                        actuators: "A4=0".into(),
                        intervals: vec![iv("I4", 0.0, Some(2980.0)), iv("I5", 2980.0, None)],
                        sensors: Vec::new(),
                    },
                ],
                sensor_estimates: vec![SensorEstimate {
                    sensor: "C4".into(),
                    expr: "I1 | I2 | I5".into(),
                    uncertain: vec!["I2".into()],
                }],
                untimed: Vec::new(),
                inputs: vec![],
                sensor_classes: vec![],
            }],
        }
    }

    fn text(coupling: Coupling, mode: Mode) -> String {
        let plant = Plant::parse(PLANT, Path::new("table.toml")).expect("plant");
        let filter = Filter::new(&plant, Some(&model()), coupling).expect("filter");
        let options = StOptions {
            mode,
            ..StOptions::default()
        };
        let text = generate(&plant, &filter, &options).expect("generates");
        assert_eq!(
            text,
            generate(&plant, &filter, &options).expect("again"),
            "stable"
        );
        text
    }

    fn has(text: &str, line: &str) {
        assert!(
            text.lines().any(|l| l == line),
            "no line\n{line}\nin\n{text}"
        );
    }

    #[test]
    fn coupled_filter_of_a_small_plant() {
        let t = text(Coupling::Flags, Mode::Filter);
        for line in [
            "FUNCTION_BLOCK GARDEFOU_FILTER",
            "    C4 : BOOL; (* turntable at loading position *)",
            "    A4_REQ : BOOL; (* proposed by the control program: rotate the turntable *)",
            "    def_C4 : BOOL; (* a fault of partition C4 is certain (diagnosers) *)",
            "    def_P : BOOL; (* a fault of partition P is certain (diagnosers) *)",
            "    A4 : BOOL; (* rotate the turntable *)",
            "    CSs14_VIOLATED : BOOL; (* CSs14 = !C4 & RE(A4) was 1 on the orders *)",
            "    FALLBACK_turntable : BOOL; (* part turntable is in its fallback: a fault that stops it is flagged *)",
            "    _2P : BOOL; (* observer 2P *)",
            "    turntable_CLK : TON; (* time since the scan that wrote A4's order, minus one scan *)",
            "    I2 : BOOL; (* I2 [20 ms, 140.000001 ms[ since A4 = 1 *)",
            // Reset wins.
            "IF C4 AND NOT C4_PREV THEN",
            "    _2P := FALSE;",
            "ELSIF NOT C6 AND C6_PREV THEN",
            // 10 ms earlier than learned, rounded up to the ms; the largest is PT.
            "turntable_CLK(IN := TRUE, PT := T#2970ms);",
            "I1 := A4_PREV AND turntable_CLK_SET AND (turntable_CLK.ET < T#10ms); (* I1 = [0 ms, 20 ms[ *)",
            "I2 := A4_PREV AND turntable_CLK_SET AND (turntable_CLK.ET >= T#10ms) AND (turntable_CLK.ET < T#131ms); (* I2 = [20 ms, 140.000001 ms[ *)",
            "I3 := A4_PREV AND (NOT turntable_CLK_SET OR (turntable_CLK.ET >= T#131ms)); (* I3 = [140.000001 ms, inf[ *)",
            "I5 := NOT A4_PREV AND (NOT turntable_CLK_SET OR turntable_CLK.Q); (* I5 = [2980 ms, inf[ *)",
            "(* CSs14 = !C4 & RE(A4), rewritten with the estimate of C4 (while def_C4) *)",
            "CSs14_VIOLATED := NOT (NOT def_C4 AND C4 OR def_C4 AND (I1 OR I5)) AND A4 AND NOT A4_PREV;",
            "(* CSs5 = !C5 & A3 *)",
            "CSs5_VIOLATED := NOT C5 AND A3;",
            "FALLBACK := CSs5_VIOLATED OR CSs13_VIOLATED OR CSs14_VIOLATED;",
            "IF FALLBACK THEN",
            "    A3 := FALSE;",
            "    A4 := FALSE;",
            "FALLBACK_turntable := NOT FALLBACK AND def_P;",
            "IF A4 XOR A4_PREV THEN",
            "    turntable_CLK(IN := FALSE);",
            "    turntable_CLK_SET := TRUE;",
            "A4_PREV := A4;",
            "END_FUNCTION_BLOCK",
        ] {
            has(&t, line);
        }
        // Only the flags it reads; no suspects without `def+suspect`.
        assert!(!t.contains("suspect_"), "{t}");
        // The sections in scan order.
        let at = |s: &str| t.find(s).unwrap_or_else(|| panic!("no {s}"));
        assert!(at("IF FIRST_SCAN") < at("turntable_CLK(IN := TRUE"));
        assert!(at("turntable_CLK(IN := TRUE") < at("_2P := FALSE"));
        assert!(at("_2P := FALSE") < at("A4 := A4_REQ;"));
        assert!(at("A4 := A4_REQ;") < at("CSs5_VIOLATED :="));
        assert!(at("IF FALLBACK THEN") < at("turntable_CLK(IN := FALSE)"));
        assert!(at("turntable_CLK(IN := FALSE)") < at("A4_PREV := A4;"));
    }

    #[test]
    fn safe_control_and_no_coupling() {
        let t = text(Coupling::None, Mode::Control);
        for line in [
            "A3_F0 := NOT C5;",
            "A4_F0 := C4 AND NOT C6 OR NOT C4 AND NOT A4_PREV;",
            "(* A4: g1 from CFs4 *)",
            "A4 := NOT A4_F0 AND C6;",
            "(* A3: g1 = A3_REQ (no functional constraint) *)",
            "A3 := NOT A3_F0 AND A3_REQ;",
        ] {
            has(&t, line);
        }
        // No estimates, no clock, no flags, no part fallback without coupling.
        for absent in ["TON", "def_", "FALLBACK_turntable"] {
            assert!(!t.contains(absent), "{absent} in\n{t}");
        }
        // A4's law does not read the proposal; the first scan does.
        for line in [
            "    A4_REQ : BOOL; (* proposed by the control program (read at the first scan only): rotate the turntable *)",
            "    A4_PREV := A4_REQ;",
        ] {
            has(&t, line);
        }
    }

    #[test]
    fn names_become_identifiers() {
        assert_eq!(mangle("2P"), "_2P");
        assert_eq!(mangle("Q"), "_Q");
        assert_eq!(stem("Q"), "Q");
        assert_eq!(mangle("a__b_"), "a_b");
        assert_eq!(mangle("_"), "_V");
        assert_eq!(mangle("def_C4"), "def_C4");
        assert_eq!(ceil_ms(130_000_001), 131);
        assert_eq!(ceil_ms(130_000_000), 130);
        assert_eq!(ceil_ms(-5_000_000), -5);
        assert_eq!(ms_text(140_000_001), "140.000001");
        assert_eq!(comment_text("a (* b *)\nc"), "a ( * b * ) c");
        // Identifiers ignore case: two names that differ only by it clash.
        let clash = PLANT.replace(
            "C6 = { kind = \"sensor\"",
            "c4 = { kind = \"sensor\", description = \"x\" }\nC6 = { kind = \"sensor\"",
        );
        let plant = Plant::parse(&clash, Path::new("clash.toml")).expect("plant");
        let filter = Filter::new(&plant, None, Coupling::None).expect("filter");
        let e = generate(&plant, &filter, &StOptions::default()).expect_err("clash");
        assert!(e.contains("same Structured Text identifier"), "{e}");
    }
}
