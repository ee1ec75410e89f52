//! Fault templates (seed 002, table 1): what can go wrong with a sensor, an actuator
//! or a moving element, written `template(arguments)` in plant files.

use std::fmt;
use std::str::FromStr;

/// One fault, as a template applied to named signals or elements.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FaultTemplate {
    /// `stuck0(s)`: sensor `s` reads 0 whatever the plant does (not observable as such).
    Stuck0(String),
    /// `stuck1(s)`: sensor `s` reads 1 whatever the plant does.
    Stuck1(String),
    /// `unexpected_rise(s)`: sensor `s` rises when nothing in the plant explains it.
    UnexpectedRise(String),
    /// `unexpected_fall(s)`: sensor `s` falls when nothing in the plant explains it.
    UnexpectedFall(String),
    /// `actuator_stuck0(a)`: actuator `a` stays off whatever the order.
    ActuatorStuck0(String),
    /// `actuator_stuck1(a)`: actuator `a` stays on whatever the order.
    ActuatorStuck1(String),
    /// `blocked_at(e, s)`: moving element `e` cannot leave the position sensed by `s`.
    BlockedAt {
        /// The element (e.g. `P`, the turntable).
        element: String,
        /// The sensor of the position where it is stuck.
        at: String,
    },
    /// `blocked_between(e, from, to)`: element `e` stops in transit from the position
    /// of sensor `from` to that of sensor `to`.
    BlockedBetween {
        /// The element.
        element: String,
        /// Sensor of the position it leaves.
        from: String,
        /// Sensor of the position it never reaches.
        to: String,
    },
    /// `slow(x)`: element or actuator `x` still moves, but each of its motions
    /// (a stroke, a flow, a heating) takes longer by a factor from the onset on:
    /// a degraded element that slows down before it fails. The factor is the
    /// injection's ([`Factor`]), not the template's: a diagnoser looks for any
    /// slowdown.
    Slow(String),
}

/// What a template is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultTarget {
    /// A sensor fault.
    Sensor,
    /// An actuator fault.
    Actuator,
    /// A fault of a moving element.
    Element,
    /// A fault of a motion: an element's, or what an actuator drives (`slow`).
    Motion,
}

impl FaultTemplate {
    /// The template's name, e.g. `stuck1`.
    pub fn name(&self) -> &'static str {
        match self {
            FaultTemplate::Stuck0(_) => "stuck0",
            FaultTemplate::Stuck1(_) => "stuck1",
            FaultTemplate::UnexpectedRise(_) => "unexpected_rise",
            FaultTemplate::UnexpectedFall(_) => "unexpected_fall",
            FaultTemplate::ActuatorStuck0(_) => "actuator_stuck0",
            FaultTemplate::ActuatorStuck1(_) => "actuator_stuck1",
            FaultTemplate::BlockedAt { .. } => "blocked_at",
            FaultTemplate::BlockedBetween { .. } => "blocked_between",
            FaultTemplate::Slow(_) => "slow",
        }
    }

    /// Whether the template concerns a sensor, an actuator or an element.
    pub fn target(&self) -> FaultTarget {
        match self {
            FaultTemplate::Stuck0(_)
            | FaultTemplate::Stuck1(_)
            | FaultTemplate::UnexpectedRise(_)
            | FaultTemplate::UnexpectedFall(_) => FaultTarget::Sensor,
            FaultTemplate::ActuatorStuck0(_) | FaultTemplate::ActuatorStuck1(_) => {
                FaultTarget::Actuator
            }
            FaultTemplate::BlockedAt { .. } | FaultTemplate::BlockedBetween { .. } => {
                FaultTarget::Element
            }
            FaultTemplate::Slow(_) => FaultTarget::Motion,
        }
    }

    /// The signal (sensor or actuator) a signal fault is on; `None` for element faults.
    pub fn signal(&self) -> Option<&str> {
        match self {
            FaultTemplate::Stuck0(s)
            | FaultTemplate::Stuck1(s)
            | FaultTemplate::UnexpectedRise(s)
            | FaultTemplate::UnexpectedFall(s)
            | FaultTemplate::ActuatorStuck0(s)
            | FaultTemplate::ActuatorStuck1(s) => Some(s),
            _ => None,
        }
    }

    /// The sensor a sensor fault is on; `None` for actuator and element faults.
    pub fn sensor(&self) -> Option<&str> {
        match self.target() {
            FaultTarget::Sensor => self.signal(),
            _ => None,
        }
    }

    /// The arguments in order, as written.
    pub fn arguments(&self) -> Vec<&str> {
        match self {
            FaultTemplate::BlockedAt { element, at } => vec![element, at],
            FaultTemplate::BlockedBetween { element, from, to } => vec![element, from, to],
            FaultTemplate::Slow(x) => vec![x],
            other => other.signal().into_iter().collect(),
        }
    }
}

impl fmt::Display for FaultTemplate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({})", self.name(), self.arguments().join(", "))
    }
}

impl FromStr for FaultTemplate {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let text = text.trim();
        let (name, rest) = text.split_once('(').ok_or_else(|| {
            format!("'{text}' is not a fault template (expected e.g. stuck1(C4))")
        })?;
        let inner = rest
            .trim_end()
            .strip_suffix(')')
            .ok_or_else(|| format!("'{text}': missing ')'"))?;
        let args: Vec<String> = inner.split(',').map(|a| a.trim().to_string()).collect();
        if args
            .iter()
            .any(|a| a.is_empty() || !a.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        {
            return Err(format!(
                "'{text}': arguments must be signal or element names"
            ));
        }
        let want = |n: usize| -> Result<(), String> {
            if args.len() == n {
                Ok(())
            } else {
                Err(format!(
                    "'{text}': {} takes {n} argument{}, found {}",
                    name.trim(),
                    if n == 1 { "" } else { "s" },
                    args.len()
                ))
            }
        };
        let one = |f: fn(String) -> FaultTemplate| -> Result<FaultTemplate, String> {
            want(1)?;
            Ok(f(args[0].clone()))
        };
        match name.trim() {
            "stuck0" => one(FaultTemplate::Stuck0),
            "stuck1" => one(FaultTemplate::Stuck1),
            "unexpected_rise" => one(FaultTemplate::UnexpectedRise),
            "unexpected_fall" => one(FaultTemplate::UnexpectedFall),
            "actuator_stuck0" => one(FaultTemplate::ActuatorStuck0),
            "actuator_stuck1" => one(FaultTemplate::ActuatorStuck1),
            "slow" => one(FaultTemplate::Slow),
            "blocked_at" => {
                want(2)?;
                Ok(FaultTemplate::BlockedAt {
                    element: args[0].clone(),
                    at: args[1].clone(),
                })
            }
            "blocked_between" => {
                want(3)?;
                Ok(FaultTemplate::BlockedBetween {
                    element: args[0].clone(),
                    from: args[1].clone(),
                    to: args[2].clone(),
                })
            }
            other => Err(format!(
                "unknown fault template '{other}' (expected stuck0, stuck1, unexpected_rise, \
                 unexpected_fall, actuator_stuck0, actuator_stuck1, blocked_at, blocked_between or slow)"
            )),
        }
    }
}

/// How much slower a `slow` fault makes its motions: a factor above 1, kept in
/// thousandths so that an injection compares and prints exactly. Written `x3`
/// or `x1.5` after an injection's onset (`F40@600s:x3`).
///
/// ```
/// use vocabulary::fault::Factor;
///
/// let f: Factor = "x1.5".parse().unwrap();
/// assert_eq!(f.get(), 1.5);
/// assert_eq!(f.to_string(), "x1.5");
/// assert!("x1".parse::<Factor>().is_err());
/// assert!("x1000".parse::<Factor>().is_err());
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Factor(u32);

impl Factor {
    /// The factor a `slow` fault gets when its injection names none.
    pub const DEFAULT: Factor = Factor(2000);
    /// The largest factor: beyond it, the motion has stopped (`blocked_between`).
    pub const MAX: Factor = Factor(100_000);

    /// The factor.
    pub fn get(self) -> f64 {
        f64::from(self.0) / 1000.0
    }

    /// `d` made longer by the factor.
    pub fn stretch(self, d: i64) -> i64 {
        (i128::from(d) * i128::from(self.0) / 1000) as i64
    }
}

impl fmt::Display for Factor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (whole, frac) = (self.0 / 1000, self.0 % 1000);
        if frac == 0 {
            write!(f, "x{whole}")
        } else {
            let digits = format!("{frac:03}");
            write!(f, "x{whole}.{}", digits.trim_end_matches('0'))
        }
    }
}

impl FromStr for Factor {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "bad factor '{text}': expected x and a number above 1 and at most 100, with at most 3 decimals, e.g. x1.5"
            )
        };
        let number = text.trim().strip_prefix('x').ok_or_else(bad)?;
        let (whole, frac) = number.split_once('.').unwrap_or((number, ""));
        let digits = |s: &str| s.chars().all(|c| c.is_ascii_digit());
        if whole.is_empty() || whole.len() > 3 || frac.len() > 3 || !digits(whole) || !digits(frac)
        {
            return Err(bad());
        }
        let whole: u32 = whole.parse().map_err(|_| bad())?;
        let frac: u32 = format!("{frac:0<3}").parse().map_err(|_| bad())?;
        let f = Factor(whole * 1000 + frac);
        if f.0 <= 1000 || f > Factor::MAX {
            return Err(bad());
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_every_template() {
        for text in [
            "stuck0(C4)",
            "stuck1(C4)",
            "unexpected_rise(C5)",
            "unexpected_fall(C5)",
            "actuator_stuck0(A4)",
            "actuator_stuck1(A4)",
            "blocked_at(P, C4)",
            "blocked_between(P, C4, C5)",
            "slow(P)",
        ] {
            let t: FaultTemplate = text.parse().expect("valid template");
            assert_eq!(t.to_string(), text);
        }
    }

    #[test]
    fn rejects_malformed_templates() {
        assert!("stuck2(C4)".parse::<FaultTemplate>().is_err());
        assert!("stuck1(C4, C5)".parse::<FaultTemplate>().is_err());
        assert!("blocked_at(P)".parse::<FaultTemplate>().is_err());
        assert!("stuck1 C4".parse::<FaultTemplate>().is_err());
        assert!("stuck1()".parse::<FaultTemplate>().is_err());
    }
}
