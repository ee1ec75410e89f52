//! `--stdin`: events as JSON lines on standard input, put in event-time order.
//!
//! ```text
//! {"t": 1200, "signal": "C4", "value": 1}    an event
//! {"t": 1500}                                a watermark: nothing else up to 1500
//! ```
//!
//! The lines of the first timestamp give the initial values (as in an events
//! log). A scan is complete, and goes to the diagnosers, only once the source
//! has shown that no more of it can come: a line with a later time (beyond
//! `--lateness`), a watermark line, or the end of input. No timer splits a
//! scan, however the lines are paced. So a producer that pauses delays the
//! verdicts and never changes them, and a producer feeding a quiet plant sends
//! watermark lines for the deadlines to fire.
//!
//! What is not believed:
//! - a line behind the watermark (later than `--lateness` allows): a warning;
//! - a line far ahead of both the stream and the live clock: held until
//!   [`CONFIRMING`] lines agree with it (the stream really jumped), dropped
//!   with a warning when the next line falls back in line (one bad clock);
//! - a line that is not UTF-8, not JSON, or longer than [`MAX_LINE`] bytes: a
//!   warning. None of them stops the monitor.

use std::collections::BTreeMap;

use diagnoser::{Event, Plant, Time, TimeUnit, time};
use tokio::io::{AsyncBufRead, AsyncBufReadExt};
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::source::{Item, Link, Source};
use diagnoser::TimeFormat;

/// Longest line read; the rest of a longer line is skipped unread into memory.
pub const MAX_LINE: usize = 4096;
/// Lines far ahead that must agree before the stream counts as having jumped.
pub const CONFIRMING: usize = 8;

/// JSON events on standard input.
pub struct Stdin {
    /// The plant.
    pub plant: Plant,
    /// Unit of numeric timestamps.
    pub unit: TimeUnit,
    /// How late (in event time) a line may come after a later one.
    pub lateness: Time,
    /// How fast the producer's clock runs against the wall clock.
    pub speed: f64,
}

impl Source for Stdin {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Numeric(self.unit)
    }

    fn spawn(self: Box<Self>, link: Link) {
        let lead = lead(&self.plant, self.speed);
        let order = Order::new(&self.plant, self.unit, self.lateness, lead);
        let input = tokio::io::BufReader::new(tokio::io::stdin());
        tokio::spawn(read(
            input, self.plant, self.unit, self.speed, order, link.items,
        ));
    }
}

/// How far ahead of the stream (and of the live clock) a line may be before it
/// must be confirmed: a thousand scans, or ten seconds of the producer's clock.
pub fn lead(plant: &Plant, speed: f64) -> Time {
    let scans = plant.scan_period.max(1).saturating_mul(1000);
    scans.max((10e9 * speed.max(1.0)) as Time)
}

/// Reads lines until the end of input, and sends what `order` makes of them.
async fn read(
    mut input: impl AsyncBufRead + Unpin,
    plant: Plant,
    unit: TimeUnit,
    speed: f64,
    mut order: Order,
    tx: mpsc::Sender<Item>,
) {
    let mut number = 0u64;
    let mut line = Vec::with_capacity(256);
    let mut clock: Option<(Time, Instant)> = None;
    let mut out = Vec::new();
    loop {
        let read = match read_line(&mut input, &mut line).await {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(e) => {
                out.push(Item::Warning(format!("standard input: {e}; reading stops")));
                break;
            }
        };
        number += 1;
        let record = match read {
            Line::TooLong(n) => Err(format!("{n} bytes, more than {MAX_LINE}")),
            Line::Text => parse(&line, &plant, unit),
        };
        match record {
            Ok(None) => {}
            Ok(Some(r)) => {
                let live =
                    clock.map(|(t, at)| t + (at.elapsed().as_nanos() as f64 * speed) as Time);
                order.push(r, number, live, &mut out);
                let newest = order.newest();
                if let Some(n) = newest
                    && live.is_none_or(|l| n > l)
                {
                    clock = Some((n, Instant::now()));
                }
            }
            Err(m) => out.push(Item::Warning(format!("standard input: line {number}: {m}"))),
        }
        if !send(&tx, &mut out).await {
            return;
        }
    }
    order.end(&mut out);
    send(&tx, &mut out).await;
}

/// Sends the items gathered; false once the monitor has gone.
async fn send(tx: &mpsc::Sender<Item>, out: &mut Vec<Item>) -> bool {
    for item in out.drain(..) {
        if tx.send(item).await.is_err() {
            return false;
        }
    }
    true
}

/// What one read gave.
enum Line {
    /// A line, in the buffer (without its end of line).
    Text,
    /// A line of this many bytes, longer than [`MAX_LINE`], skipped.
    TooLong(usize),
}

/// Reads one line into `buf`, keeping at most [`MAX_LINE`] bytes in memory;
/// `None` at the end of input.
async fn read_line(
    input: &mut (impl AsyncBufRead + Unpin),
    buf: &mut Vec<u8>,
) -> std::io::Result<Option<Line>> {
    buf.clear();
    let mut total = 0usize;
    loop {
        let chunk = input.fill_buf().await?;
        if chunk.is_empty() {
            return Ok((total > 0).then(|| finish(buf, total)));
        }
        let (take, end) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (chunk.len(), false),
        };
        if buf.len() < MAX_LINE + 1 {
            let room = MAX_LINE + 1 - buf.len();
            buf.extend_from_slice(&chunk[..take.min(room)]);
        }
        total += take;
        input.consume(take + usize::from(end));
        if end {
            return Ok(Some(finish(buf, total)));
        }
    }
}

fn finish(buf: &mut Vec<u8>, total: usize) -> Line {
    if buf.last() == Some(&b'\r') {
        buf.pop();
    }
    if total > MAX_LINE {
        Line::TooLong(total)
    } else {
        Line::Text
    }
}

/// One line read: an event, or a watermark (a line with a time and no signal).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Record {
    /// A signal's new value.
    Event(Event),
    /// Nothing else happened up to this time.
    Watermark(Time),
}

impl Record {
    fn t(&self) -> Time {
        match self {
            Record::Event(e) => e.t,
            Record::Watermark(t) => *t,
        }
    }
}

/// One line: `None` if blank.
fn parse(line: &[u8], plant: &Plant, unit: TimeUnit) -> Result<Option<Record>, String> {
    let text = std::str::from_utf8(line).map_err(|e| format!("not UTF-8 ({e})"))?;
    if text.trim().is_empty() {
        return Ok(None);
    }
    parse_record(text, plant, unit).map(Some)
}

/// One JSON line: `{"t": …, "signal": "C4", "value": 1}`, or `{"t": …}`.
pub fn parse_record(line: &str, plant: &Plant, unit: TimeUnit) -> Result<Record, String> {
    let v: serde_json::Value = serde_json::from_str(line).map_err(|e| format!("not JSON: {e}"))?;
    let t = match &v["t"] {
        serde_json::Value::Number(n) => n
            .as_f64()
            .filter(|x| x.is_finite() && x.abs() < 9e18 / unit.nanos() as f64)
            .map(|x| (x * unit.nanos() as f64).round() as Time)
            .ok_or("field 't': not a number in range")?,
        serde_json::Value::String(s) => {
            time::parse_rfc3339(s).ok_or("field 't': not an RFC 3339 time")?
        }
        _ => return Err("field 't': missing".into()),
    };
    let Some(name) = v.get("signal") else {
        return Ok(Record::Watermark(t));
    };
    let name = name.as_str().ok_or("field 'signal': not text")?;
    let signal = plant
        .signals
        .id(name)
        .ok_or_else(|| format!("field 'signal': unknown signal '{name}'"))?;
    let value = match &v["value"] {
        serde_json::Value::Bool(b) => *b,
        serde_json::Value::Number(n) if n.as_u64() == Some(0) => false,
        serde_json::Value::Number(n) if n.as_u64() == Some(1) => true,
        _ => return Err("field 'value': expected 0, 1, true or false".into()),
    };
    Ok(Record::Event(Event { t, signal, value }))
}

/// Puts records in event-time order and says how far they are complete: the
/// initial values, then scans and watermarks, each scan after the last
/// watermark. Pure (no I/O, no clock), so that any pacing of the same lines
/// gives the same items.
#[derive(Debug)]
pub struct Order {
    signals: usize,
    /// How times are written in messages.
    time: TimeFormat,
    lateness: Time,
    lead: Time,
    /// The latest time accepted.
    newest: Option<Time>,
    /// Complete up to this time (inclusive): sent.
    watermark: Option<Time>,
    started: bool,
    /// Accepted events not yet complete, by time.
    waiting: BTreeMap<Time, Vec<Event>>,
    /// Lines far ahead, waiting to be confirmed, with their line numbers.
    held: Vec<(u64, Record)>,
}

impl Order {
    /// An empty order for `plant`'s signals.
    pub fn new(plant: &Plant, unit: TimeUnit, lateness: Time, lead: Time) -> Order {
        Order {
            signals: plant.signals.len(),
            time: TimeFormat::Numeric(unit),
            lateness: lateness.max(0),
            lead: lead.max(1),
            newest: None,
            watermark: None,
            started: false,
            waiting: BTreeMap::new(),
            held: Vec::new(),
        }
    }

    /// The latest time accepted.
    pub fn newest(&self) -> Option<Time> {
        self.newest
    }

    /// Takes one record (`line` is its line number, `live` the producer's
    /// clock now, if known) and adds what became complete to `out`.
    pub fn push(&mut self, r: Record, line: u64, live: Option<Time>, out: &mut Vec<Item>) {
        let Some(newest) = self.newest else {
            self.accept(r, line, out);
            return;
        };
        let far = r.t() > newest.max(live.unwrap_or(newest)).saturating_add(self.lead);
        if !far {
            self.drop_held("the next line fell back in line", out);
            self.accept(r, line, out);
            return;
        }
        let agrees = self.held.last().is_none_or(|(_, h)| {
            // In line with the held ones: not before them by more than
            // the lateness, nor far after them.
            r.t() >= h.t().saturating_sub(self.lateness) && r.t() <= h.t().saturating_add(self.lead)
        });
        if !agrees {
            self.drop_held("the lines after it disagree", out);
        }
        self.held.push((line, r));
        if self.held.len() >= CONFIRMING {
            for (n, h) in std::mem::take(&mut self.held) {
                self.accept(h, n, out);
            }
        }
    }

    /// The end of input: everything accepted is complete.
    pub fn end(&mut self, out: &mut Vec<Item>) {
        self.drop_held("the input ended before it was confirmed", out);
        if let Some(n) = self.newest {
            self.release(n, out);
        }
    }

    fn drop_held(&mut self, why: &str, out: &mut Vec<Item>) {
        for (n, h) in self.held.drain(..) {
            out.push(Item::FarAhead(format!(
                "standard input: line {n}: time {} far ahead of the stream, ignored: {why}",
                self.time.format(h.t())
            )));
        }
    }

    fn accept(&mut self, r: Record, line: u64, out: &mut Vec<Item>) {
        let t = r.t();
        if let Some(w) = self.watermark
            && t <= w
        {
            if let Record::Event(_) = r {
                out.push(Item::Late(format!(
                    "standard input: line {line}: time {} is behind the watermark {}, ignored",
                    self.time.format(t),
                    self.time.format(w)
                )));
            }
            return;
        }
        self.newest = Some(self.newest.map_or(t, |n| n.max(t)));
        match r {
            Record::Watermark(t) => self.release(t, out),
            Record::Event(e) => {
                self.waiting.entry(t).or_default().push(e);
                let n = self.newest.unwrap_or(t);
                self.release(n.saturating_sub(self.lateness).saturating_sub(1), out);
            }
        }
    }

    /// Sends every scan up to `w` (inclusive), then the watermark `w`.
    fn release(&mut self, w: Time, out: &mut Vec<Item>) {
        if self.watermark.is_some_and(|old| w <= old) {
            return;
        }
        while let Some(entry) = self.waiting.first_entry() {
            if *entry.key() > w {
                break;
            }
            let (t, events) = entry.remove_entry();
            if self.started {
                out.push(Item::Scan(events));
            } else {
                let mut initial = vec![false; self.signals];
                for e in events {
                    initial[e.signal.index()] = e.value;
                }
                out.push(Item::Start(t, initial));
                self.started = true;
            }
        }
        self.watermark = Some(w);
        if self.started {
            out.push(Item::Watermark(w));
        }
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
    use diagnoser::model::Model;
    use proptest::prelude::*;

    use super::*;

    fn fixture(rel: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
    }

    /// The shipped F2 run's plant, diagnoser and events.
    fn f2() -> (Plant, PlantDiagnoser, Vec<Event>) {
        let plant =
            Plant::from_path(&fixture("datasets/data/sorting/F2/plant.toml")).expect("plant");
        let model = Model::from_path(&fixture(
            "diagnoser/tests/fixtures/diagnosis/sorting-model.json",
        ))
        .expect("model");
        let diagnoser =
            PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).expect("diagnoser");
        let csv =
            std::fs::read_to_string(fixture("datasets/data/sorting/F2/events.csv")).expect("log");
        let events = csv
            .lines()
            .skip(1)
            .filter_map(|r| {
                let mut f = r.split(',');
                let t: Time = f.next()?.parse().ok()?;
                let signal = plant.signals.id(f.next()?)?;
                let value = f.next()? == "1";
                Some(Event {
                    t: t * 1_000_000,
                    signal,
                    value,
                })
            })
            .collect();
        (plant, diagnoser, events)
    }

    /// The verdicts of `diagnose`: the events in order, then the end.
    fn offline(mut d: PlantDiagnoser, plant: &Plant, events: &[Event]) -> Vec<String> {
        let mut out = Vec::new();
        let t0 = events[0].t;
        let mut initial = vec![false; plant.signals.len()];
        for e in events.iter().take_while(|e| e.t == t0) {
            initial[e.signal.index()] = e.value;
        }
        d.start(t0, &initial);
        for &e in events.iter().skip_while(|e| e.t == t0) {
            d.push(e, &mut |v| out.push(format!("{v:?}")));
        }
        let end = events.last().map_or(t0, |e| e.t);
        d.finish(end, &mut |v| out.push(format!("{v:?}")));
        out
    }

    /// The verdicts from the items `Order` gives, fed as the monitor feeds them.
    fn online(mut d: PlantDiagnoser, items: Vec<Item>) -> Vec<String> {
        let mut out = Vec::new();
        let mut mark = None;
        for item in items {
            let mut emit = |v| out.push(format!("{v:?}"));
            match item {
                Item::Start(t0, initial) => {
                    d.start(t0, &initial);
                    mark = Some(t0);
                }
                Item::Scan(scan) => {
                    let t = scan[0].t;
                    d.advance_to(t - 1, &mut emit);
                    for e in scan {
                        d.push(e, &mut emit);
                    }
                    d.advance_to(t, &mut emit);
                    mark = Some(t);
                }
                Item::Watermark(w) => {
                    d.advance_to(w, &mut emit);
                    mark = Some(w);
                }
                _ => {}
            }
        }
        d.finish(mark.unwrap_or(0), &mut |v| out.push(format!("{v:?}")));
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        /// However the lines come (shuffled within the lateness, duplicated,
        /// with watermark lines a producer may send), the verdicts are the
        /// offline ones.
        #[test]
        fn any_delivery_within_the_lateness_gives_the_offline_verdicts(
            lateness_ms in 0i64..3000,
            seed in any::<u64>(),
            duplicates in 0.0f64..0.2,
            watermarks in 0.0f64..0.3,
        ) {
            let (plant, d, events) = f2();
            let want = offline(d.clone(), &plant, &events);
            prop_assert!(want.iter().any(|v| v.contains("labels: [\"F2\"]")));
            let lateness = lateness_ms * 1_000_000;
            let mut order = Order::new(&plant, TimeUnit::Ms, lateness, lead(&plant, 1.0));
            let mut items = Vec::new();
            let mut rng = seed | 1;
            let mut next = || {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng
            };
            // Each event is delivered at its time plus a random delay within
            // the lateness; ties keep their order. The first scan comes first.
            let t0 = events[0].t;
            let mut delivery: Vec<(Time, usize)> = events
                .iter()
                .enumerate()
                .map(|(i, e)| {
                    let delay = if e.t == t0 || lateness == 0 { 0 } else { (next() % lateness as u64) as Time };
                    (e.t + delay, i)
                })
                .collect();
            delivery.sort();
            for (n, &(_, i)) in delivery.iter().enumerate() {
                let e = events[i];
                order.push(Record::Event(e), n as u64, None, &mut items);
                if (next() % 1000) as f64 / 1000.0 < duplicates {
                    order.push(Record::Event(e), n as u64, None, &mut items);
                }
                // A watermark is true when every event up to it has been sent.
                let unsent = delivery[n + 1..].iter().map(|&(_, j)| events[j].t).min();
                if (next() % 1000) as f64 / 1000.0 < watermarks
                    && let Some(u) = unsent
                    && u > e.t
                {
                    order.push(Record::Watermark(u - 1), n as u64, None, &mut items);
                }
            }
            order.end(&mut items);
            prop_assert!(!items.iter().any(|i| matches!(i, Item::Late(_) | Item::FarAhead(_))));
            prop_assert_eq!(online(d, items), want);
        }
    }
}
