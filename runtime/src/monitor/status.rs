//! What the monitor knows now, shared with the HTTP endpoint: every part's
//! latest verdict, the flags, counters and the label latency.

use std::fmt::Write as _;
use std::time::Duration;

use diagnoser::diagnosis::Verdict;
use diagnoser::{Plant, Time, TimeFormat};
use serde::Serialize;

/// Latencies are counted per microsecond up to this many; longer ones share
/// the last bucket (and [`Latency::max`] keeps the exact worst).
const FINE_US: usize = 100_000;

/// Label latency: from the evidence (an event's arrival, a deadline's expiry)
/// to the verdict line written. Kept per microsecond, so that percentiles are
/// exact to the microsecond below 100 ms.
#[derive(Debug, Clone)]
pub struct Latency {
    counts: Vec<u32>,
    n: u64,
    sum: Duration,
    max: Duration,
}

impl Default for Latency {
    fn default() -> Self {
        Latency {
            counts: vec![0; FINE_US + 1],
            n: 0,
            sum: Duration::ZERO,
            max: Duration::ZERO,
        }
    }
}

impl Latency {
    /// Counts one latency.
    pub fn record(&mut self, d: Duration) {
        let us = (d.as_micros() as usize).min(FINE_US);
        self.counts[us] = self.counts[us].saturating_add(1);
        self.n += 1;
        self.sum += d;
        self.max = self.max.max(d);
    }

    /// `n, p50, p99, max` in microseconds, for people.
    pub fn summary(&self) -> String {
        let us = |d: Option<Duration>| d.map_or("-".into(), |d| d.as_micros().to_string());
        format!(
            "n {}, p50 {} µs, p99 {} µs, max {} µs",
            self.n,
            us(self.quantile(0.5)),
            us(self.quantile(0.99)),
            self.max.as_micros()
        )
    }

    /// The `q` quantile (0 < q ≤ 1), rounded up to the microsecond; `None`
    /// before the first count.
    pub fn quantile(&self, q: f64) -> Option<Duration> {
        if self.n == 0 {
            return None;
        }
        let rank = ((q * self.n as f64).ceil() as u64).clamp(1, self.n);
        let mut seen = 0u64;
        for (us, &c) in self.counts.iter().enumerate() {
            seen += u64::from(c);
            if seen >= rank {
                if us == FINE_US {
                    return Some(self.max);
                }
                return Some(Duration::from_micros(us as u64 + 1));
            }
        }
        Some(self.max)
    }

    /// How many took less than `us` microseconds (so at most `us`).
    fn at_most(&self, us: usize) -> u64 {
        self.counts[..us.min(FINE_US)]
            .iter()
            .map(|&c| u64::from(c))
            .sum()
    }
}

/// One part's latest verdict.
#[derive(Debug, Clone, Serialize)]
pub struct PartStatus {
    /// The part (or `plant`, the fused view).
    pub part: String,
    /// `normal`, `certain` or `ambiguous` (as in the JSON lines).
    pub verdict: serde_json::Value,
    /// The candidate labels (`["N"]` when normal).
    pub labels: Vec<String>,
    /// `def_` flags raised by this part.
    pub flags: Vec<String>,
    /// Suspected partitions.
    pub suspects: Vec<String>,
    /// When the verdict last changed.
    pub since: serde_json::Value,
    /// What was observed, in words.
    pub reason: String,
}

/// The monitor's state, as `/status` and `/metrics` show it.
#[derive(Debug, Clone, Serialize)]
pub struct Status {
    /// The plant's name.
    pub plant: String,
    /// The source, e.g. `modbus 127.0.0.1:502`.
    pub source: String,
    /// Whether the source sees the plant now.
    pub connected: bool,
    /// Whether the source's watermark keeps up with the live clock: when not,
    /// no deadline fires (what is missing may still come).
    pub observed: bool,
    /// Time of the last scan read, if any (printed when `/status` is asked:
    /// not on every scan).
    #[serde(serialize_with = "no_time")]
    pub t: Option<Time>,
    /// Every part's latest verdict, in plant order.
    pub parts: Vec<PartStatus>,
    /// `def_` flags raised (never lowered).
    pub flags: Vec<String>,
    /// `suspect_` flags up now.
    pub suspects: Vec<String>,
    /// Events read.
    pub events: u64,
    /// Verdict lines written.
    pub verdict_changes: u64,
    /// Warnings given.
    pub warnings: u64,
    /// Times the source lost the plant.
    pub gaps: u64,
    /// Data that came behind the watermark, ignored.
    pub late: u64,
    /// Data far ahead of the live clock, ignored.
    pub far_ahead: u64,
    /// Flag images written to the PLC.
    pub flag_writes: u64,
    /// The probing move under way (`--probe`), as its verdict's reason will
    /// begin: `released A4 to tell F3, F11 apart`.
    pub probe: Option<String>,
    /// Probing moves made.
    pub probes: u64,
    /// From evidence to a changed verdict written: the label latency.
    #[serde(skip)]
    pub latency: Latency,
    /// From evidence to the diagnosers done with it, for every scan and
    /// deadline, whether or not a verdict changed: what a label would wait.
    #[serde(skip)]
    pub evidence: Latency,
    /// How the source writes its times (`t` is written in it).
    #[serde(skip)]
    pub time: TimeFormat,
    #[serde(skip)]
    all_flags: Vec<String>,
}

/// `t` is written by [`Status::json`], in the source's time form.
fn no_time<S: serde::Serializer>(_: &Option<Time>, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_none()
}

/// A time as the JSON lines write it: a number, or RFC 3339 text.
pub fn time_value(t: Time, time: TimeFormat) -> serde_json::Value {
    let text = time.format(t);
    match time {
        TimeFormat::Numeric(_) => {
            serde_json::from_str(&text).unwrap_or(serde_json::Value::String(text))
        }
        TimeFormat::Rfc3339 => serde_json::Value::String(text),
    }
}

impl Status {
    /// The state before the first event: every part normal.
    pub fn new(plant: &Plant, source: String, time: TimeFormat) -> Status {
        Status {
            plant: plant.name.clone(),
            source,
            connected: false,
            observed: true,
            t: None,
            parts: plant
                .parts
                .iter()
                .map(|p| PartStatus {
                    part: p.name.clone(),
                    verdict: serde_json::Value::String("normal".into()),
                    labels: vec!["N".into()],
                    flags: Vec::new(),
                    suspects: Vec::new(),
                    since: serde_json::Value::Null,
                    reason: String::new(),
                })
                .collect(),
            flags: Vec::new(),
            suspects: Vec::new(),
            events: 0,
            verdict_changes: 0,
            warnings: 0,
            gaps: 0,
            late: 0,
            far_ahead: 0,
            flag_writes: 0,
            probe: None,
            probes: 0,
            latency: Latency::default(),
            evidence: Latency::default(),
            time,
            all_flags: plant.flags().iter().map(ToString::to_string).collect(),
        }
    }

    /// Takes in one verdict line.
    pub fn verdict(&mut self, v: &Verdict) {
        self.verdict_changes += 1;
        let status = PartStatus {
            part: v.part.clone(),
            verdict: serde_json::to_value(v.verdict).unwrap_or_default(),
            labels: v.labels.clone(),
            flags: v.flags.clone(),
            suspects: v.suspects.clone(),
            since: time_value(v.t, self.time),
            reason: v.reason.clone(),
        };
        match self.parts.iter_mut().find(|p| p.part == v.part) {
            Some(p) => *p = status,
            None => self.parts.push(status),
        }
    }

    /// The `/status` body: the fields above, with the last scan's time in the
    /// source's form and the label latency's 99th percentile. The latency
    /// counts are not copied.
    pub fn json(&self) -> String {
        let Ok(serde_json::Value::Object(mut body)) = serde_json::to_value(self) else {
            return "{}".into();
        };
        let t = self.t.map(|t| time_value(t, self.time));
        body.insert("t".into(), t.unwrap_or_default());
        let p99 = self.latency.quantile(0.99).map(|d| d.as_micros() as u64);
        body.insert("latency_p99_us".into(), p99.into());
        serde_json::to_string_pretty(&body).unwrap_or_else(|_| "{}".into())
    }

    /// The `/metrics` body, in the Prometheus text format.
    pub fn metrics(&self) -> String {
        let mut m = String::new();
        let mut counter = |name: &str, help: &str, v: u64| {
            let _ = writeln!(m, "# HELP gardefou_{name} {help}");
            let _ = writeln!(m, "# TYPE gardefou_{name} counter");
            let _ = writeln!(m, "gardefou_{name} {v}");
        };
        counter("events_total", "Events read from the source.", self.events);
        counter(
            "verdict_changes_total",
            "Verdict lines written.",
            self.verdict_changes,
        );
        counter("warnings_total", "Warnings given.", self.warnings);
        counter("gaps_total", "Times the source lost the plant.", self.gaps);
        counter(
            "late_total",
            "Data behind the watermark, ignored.",
            self.late,
        );
        counter(
            "far_ahead_total",
            "Data far ahead of the live clock, ignored.",
            self.far_ahead,
        );
        counter(
            "flag_writes_total",
            "Flag images written to the PLC.",
            self.flag_writes,
        );
        counter("probes_total", "Probing moves made.", self.probes);
        let _ = writeln!(
            m,
            "# HELP gardefou_connected Whether the source sees the plant."
        );
        let _ = writeln!(m, "# TYPE gardefou_connected gauge");
        let _ = writeln!(m, "gardefou_connected {}", u8::from(self.connected));
        let _ = writeln!(
            m,
            "# HELP gardefou_observed Whether the source's watermark keeps up with the live clock."
        );
        let _ = writeln!(m, "# TYPE gardefou_observed gauge");
        let _ = writeln!(m, "gardefou_observed {}", u8::from(self.observed));
        let _ = writeln!(
            m,
            "# HELP gardefou_probing Whether a probing move is under way."
        );
        let _ = writeln!(m, "# TYPE gardefou_probing gauge");
        let _ = writeln!(m, "gardefou_probing {}", u8::from(self.probe.is_some()));
        let _ = writeln!(
            m,
            "# HELP gardefou_flag Flags the PLC's filter reads (1: up)."
        );
        let _ = writeln!(m, "# TYPE gardefou_flag gauge");
        for f in &self.all_flags {
            let up = self.flags.contains(f) || self.suspects.contains(f);
            let _ = writeln!(m, "gardefou_flag{{flag=\"{f}\"}} {}", u8::from(up));
        }
        let _ = writeln!(
            m,
            "# HELP gardefou_part_certain Whether a part's verdict is a certain fault."
        );
        let _ = writeln!(m, "# TYPE gardefou_part_certain gauge");
        for p in &self.parts {
            let certain = p.verdict.as_str() == Some("certain");
            let _ = writeln!(
                m,
                "gardefou_part_certain{{part=\"{}\"}} {}",
                p.part,
                u8::from(certain)
            );
        }
        histogram(
            &mut m,
            "label_latency_seconds",
            "From evidence (event or deadline) to verdict line written.",
            &self.latency,
        );
        histogram(
            &mut m,
            "evidence_latency_seconds",
            "From evidence (event or deadline) to the diagnosers done with it.",
            &self.evidence,
        );
        m
    }

    /// Takes in the flags now up.
    pub fn set_flags(&mut self, raised: &[String], suspects: &[String]) {
        raised.clone_into(&mut self.flags);
        suspects.clone_into(&mut self.suspects);
    }
}

/// One latency histogram in the Prometheus text format.
fn histogram(m: &mut String, name: &str, help: &str, l: &Latency) {
    let _ = writeln!(m, "# HELP gardefou_{name} {help}");
    let _ = writeln!(m, "# TYPE gardefou_{name} histogram");
    for us in [50, 100, 250, 500, 1000, 2500, 5000, 10_000, 50_000] {
        let _ = writeln!(
            m,
            "gardefou_{name}_bucket{{le=\"{}\"}} {}",
            us as f64 / 1e6,
            l.at_most(us)
        );
    }
    let _ = writeln!(m, "gardefou_{name}_bucket{{le=\"+Inf\"}} {}", l.n);
    let _ = writeln!(m, "gardefou_{name}_sum {}", l.sum.as_secs_f64());
    let _ = writeln!(m, "gardefou_{name}_count {}", l.n);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_exact_to_the_microsecond() {
        let mut l = Latency::default();
        for us in 1..=1000u64 {
            l.record(Duration::from_nanos(us * 1000 - 500));
        }
        // 990 of 1000 took at most 990 µs (rounded up).
        assert_eq!(l.quantile(0.99), Some(Duration::from_micros(990)));
        assert_eq!(l.quantile(1.0), Some(Duration::from_micros(1000)));
        l.record(Duration::from_secs(3));
        assert_eq!(l.quantile(1.0), Some(Duration::from_secs(3)));
        assert_eq!(l.max, Duration::from_secs(3));
        assert_eq!(l.at_most(100), 100);
    }

    #[test]
    fn a_probe_under_way_shows_in_status_and_metrics() {
        let plant = datasets::sorting::plant();
        let mut s = Status::new(
            &plant,
            "test".into(),
            TimeFormat::Numeric(diagnoser::TimeUnit::Ms),
        );
        let idle = s.metrics();
        assert!(idle.contains("gardefou_probing 0\n"), "{idle}");
        s.probe = Some("released A4 to tell F3, F11 apart".into());
        s.probes = 1;
        let body: serde_json::Value = serde_json::from_str(&s.json()).expect("JSON");
        assert_eq!(body["probe"], "released A4 to tell F3, F11 apart");
        assert_eq!(body["probes"], 1);
        let m = s.metrics();
        assert!(m.contains("gardefou_probing 1\n"), "{m}");
        assert!(m.contains("gardefou_probes_total 1\n"), "{m}");
    }
}
