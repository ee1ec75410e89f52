//! Time: `i64` nanoseconds in memory, a unit or RFC 3339 text in files.

use std::fmt;
use std::str::FromStr;

/// A point in time or a duration, in nanoseconds.
///
/// Logs carry timestamps relative to an arbitrary origin (usually the start of the
/// recording); RFC 3339 timestamps are converted to nanoseconds since the Unix epoch.
pub type Time = i64;

/// One millisecond in [`Time`] units.
pub const MS: Time = 1_000_000;
/// One second in [`Time`] units.
pub const SECOND: Time = 1_000 * MS;

/// The unit of numeric timestamps in a log (`--time-unit`, `time_unit` in `plant.toml`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TimeUnit {
    /// Seconds.
    S,
    /// Milliseconds, the default.
    #[default]
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds.
    Ns,
}

impl TimeUnit {
    /// Nanoseconds in one unit.
    pub fn nanos(self) -> Time {
        match self {
            TimeUnit::S => SECOND,
            TimeUnit::Ms => MS,
            TimeUnit::Us => 1_000,
            TimeUnit::Ns => 1,
        }
    }

    /// The unit's name as written in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TimeUnit::S => "s",
            TimeUnit::Ms => "ms",
            TimeUnit::Us => "us",
            TimeUnit::Ns => "ns",
        }
    }

    /// Formats `t` in this unit: an integer when exact, else a decimal with no
    /// trailing zeros, so that formatting then parsing gives `t` back.
    pub fn format(self, t: Time) -> String {
        let n = self.nanos();
        let (q, r) = (t / n, t % n);
        if r == 0 {
            return q.to_string();
        }
        let digits = n.ilog10() as usize;
        let sign = if t < 0 && q == 0 { "-" } else { "" };
        let frac = format!("{:0width$}", r.unsigned_abs(), width = digits);
        format!("{sign}{q}.{}", frac.trim_end_matches('0'))
    }

    /// Parses a numeric timestamp in this unit (integer or decimal, exact to the
    /// nanosecond). Returns `None` for anything else.
    pub fn parse(self, text: &str) -> Option<Time> {
        // Logs mostly hold plain integers: nothing to trim, sign or split,
        // and up to 18 digits cannot overflow.
        if (1..=18).contains(&text.len()) {
            let (mut value, mut digits) = (0i64, true);
            for b in text.bytes() {
                let digit = b.wrapping_sub(b'0');
                digits &= digit < 10;
                value = value.wrapping_mul(10).wrapping_add(i64::from(digit));
            }
            if digits {
                return value.checked_mul(self.nanos());
            }
        }
        let text = text.trim();
        let (neg, body) = match text.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, text),
        };
        let (int, frac) = body.split_once('.').unwrap_or((body, ""));
        if int.is_empty() && frac.is_empty() {
            return None;
        }
        if !int.bytes().all(|b| b.is_ascii_digit()) || !frac.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let n = self.nanos();
        let whole = decimal(int.as_bytes())?;
        // Digits beyond the nanosecond are dropped: logs never carry them.
        let digits = n.ilog10() as usize;
        let kept = &frac.as_bytes()[..frac.len().min(digits)];
        let frac_ns = decimal(kept)? * 10i64.pow((digits - kept.len()) as u32);
        let value = whole.checked_mul(n)?.checked_add(frac_ns)?;
        Some(if neg { -value } else { value })
    }
}

/// The value of ASCII decimal digits (0 for none); `None` past `i64::MAX`.
fn decimal(digits: &[u8]) -> Option<i64> {
    digits.iter().try_fold(0i64, |value, &b| {
        value.checked_mul(10)?.checked_add(i64::from(b - b'0'))
    })
}

impl FromStr for TimeUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "s" => Ok(TimeUnit::S),
            "ms" => Ok(TimeUnit::Ms),
            "us" => Ok(TimeUnit::Us),
            "ns" => Ok(TimeUnit::Ns),
            other => Err(format!(
                "unknown time unit '{other}' (expected s, ms, us or ns)"
            )),
        }
    }
}

impl fmt::Display for TimeUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How timestamps are written in a log: numbers in a unit, or RFC 3339 text.
///
/// Outputs reuse the representation of their input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeFormat {
    /// A number in the given unit.
    Numeric(TimeUnit),
    /// RFC 3339 text, e.g. `2026-11-21T05:00:00.010Z`.
    Rfc3339,
}

impl TimeFormat {
    /// Parses a timestamp written in this representation.
    pub fn parse(self, text: &str) -> Option<Time> {
        match self {
            TimeFormat::Numeric(unit) => unit.parse(text),
            TimeFormat::Rfc3339 => parse_rfc3339(text),
        }
    }

    /// Formats a timestamp in this representation.
    pub fn format(self, t: Time) -> String {
        match self {
            TimeFormat::Numeric(unit) => unit.format(t),
            TimeFormat::Rfc3339 => format_rfc3339(t),
        }
    }

    /// Picks the representation of a first timestamp: RFC 3339 if it parses as
    /// such, numeric in `unit` otherwise.
    pub fn detect(text: &str, unit: TimeUnit) -> TimeFormat {
        if unit.parse(text).is_none() && parse_rfc3339(text).is_some() {
            TimeFormat::Rfc3339
        } else {
            TimeFormat::Numeric(unit)
        }
    }
}

/// Parses RFC 3339 text into nanoseconds since the Unix epoch.
pub fn parse_rfc3339(text: &str) -> Option<Time> {
    chrono::DateTime::parse_from_rfc3339(text.trim())
        .ok()?
        .timestamp_nanos_opt()
}

/// Formats nanoseconds since the Unix epoch as RFC 3339 UTC text.
pub fn format_rfc3339(t: Time) -> String {
    chrono::DateTime::from_timestamp_nanos(t).to_rfc3339_opts(chrono::SecondsFormat::AutoSi, true)
}

/// Parses a human duration such as `2h`, `90min`, `600s`, `250ms`, `1.5h` or `3d`.
///
/// A bare number is taken in seconds.
pub fn parse_duration(text: &str) -> Result<Time, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(text.len());
    let (number, unit) = text.split_at(split);
    let scale: Time = match unit.trim() {
        "" | "s" => SECOND,
        "ns" => 1,
        "us" => 1_000,
        "ms" => MS,
        "m" | "min" => 60 * SECOND,
        "h" => 3_600 * SECOND,
        "d" => 86_400 * SECOND,
        other => {
            return Err(format!(
                "bad duration '{text}': unknown unit '{other}' (use ns, us, ms, s, min, h or d)"
            ));
        }
    };
    let value: f64 = number.parse().map_err(|_| {
        format!("bad duration '{text}': expected a number followed by a unit, e.g. 2h")
    })?;
    let nanos = value * scale as f64;
    if !nanos.is_finite() || nanos < 0.0 || nanos > i64::MAX as f64 {
        return Err(format!("bad duration '{text}': out of range"));
    }
    Ok(nanos.round() as Time)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn formats_exact_and_fractional_times() {
        assert_eq!(TimeUnit::Ms.format(600 * SECOND), "600000");
        assert_eq!(TimeUnit::Ms.format(1_500_000), "1.5");
        assert_eq!(TimeUnit::S.format(10 * MS), "0.01");
        assert_eq!(TimeUnit::Ms.format(-500_000), "-0.5");
    }

    #[test]
    fn parses_numbers_and_rejects_text() {
        assert_eq!(TimeUnit::Ms.parse("12.5"), Some(12_500_000));
        assert_eq!(TimeUnit::S.parse("3"), Some(3 * SECOND));
        assert_eq!(TimeUnit::Ms.parse("abc"), None);
        assert_eq!(TimeUnit::Ms.parse(""), None);
        assert_eq!(TimeUnit::Ms.parse("1e3"), None);
    }

    #[test]
    fn rfc3339_round_trips() {
        let t = parse_rfc3339("2026-11-21T05:00:00.010Z").expect("valid");
        assert_eq!(format_rfc3339(t), "2026-11-21T05:00:00.010Z");
        assert_eq!(
            TimeFormat::detect("2026-11-21T05:00:00Z", TimeUnit::Ms),
            TimeFormat::Rfc3339
        );
        assert_eq!(
            TimeFormat::detect("10", TimeUnit::Ms),
            TimeFormat::Numeric(TimeUnit::Ms)
        );
    }

    #[test]
    fn parses_durations() {
        assert_eq!(parse_duration("2h"), Ok(7_200 * SECOND));
        assert_eq!(parse_duration("600s"), Ok(600 * SECOND));
        assert_eq!(parse_duration("1.5min"), Ok(90 * SECOND));
        assert_eq!(parse_duration("250ms"), Ok(250 * MS));
        assert!(parse_duration("2 fortnights").is_err());
        assert!(parse_duration("h").is_err());
    }

    /// The reading of numeric times as it was first written: the reference
    /// for the one that skips the work for plain integers.
    fn parse_by_parts(unit: TimeUnit, text: &str) -> Option<Time> {
        let text = text.trim();
        let (neg, body) = match text.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, text),
        };
        let (int, frac) = body.split_once('.').unwrap_or((body, ""));
        if int.is_empty() && frac.is_empty() {
            return None;
        }
        if !int.bytes().all(|b| b.is_ascii_digit()) || !frac.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let n = unit.nanos();
        let whole: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
        let digits = n.ilog10() as usize;
        let kept: String = frac.chars().take(digits).collect();
        let scale = 10i64.pow((digits - kept.len()) as u32);
        let frac_ns: i64 = if kept.is_empty() {
            0
        } else {
            kept.parse::<i64>().ok()? * scale
        };
        let value = whole.checked_mul(n)?.checked_add(frac_ns)?;
        Some(if neg { -value } else { value })
    }

    proptest! {
        #[test]
        fn parses_as_by_parts(
            text in prop_oneof![
                "[0-9]{1,20}",
                "[-+. 0-9]{0,24}",
                "\\s?-?[0-9]{0,19}(\\.[0-9]{0,12})?\\s?",
                any::<String>(),
            ],
        ) {
            for unit in [TimeUnit::S, TimeUnit::Ms, TimeUnit::Us, TimeUnit::Ns] {
                prop_assert_eq!(unit.parse(&text), parse_by_parts(unit, &text), "{:?}", text);
            }
        }

        #[test]
        fn format_then_parse_is_identity(t in -1_000_000_000_000i64..1_000_000_000_000i64) {
            for unit in [TimeUnit::S, TimeUnit::Ms, TimeUnit::Us, TimeUnit::Ns] {
                prop_assert_eq!(unit.parse(&unit.format(t)), Some(t));
            }
        }
    }
}
