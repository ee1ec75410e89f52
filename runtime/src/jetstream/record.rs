//! The subjects and payloads of a plant's streams on NATS JetStream.
//!
//! | stream | subject | one message per | payload |
//! |---|---|---|---|
//! | `GARDEFOU_EVENTS_PLANT` | `gardefou.events.PLANT` | what the source showed: the first values, a scan, a watermark, a lost plant, the end | JSON, below |
//! | `GARDEFOU_VERDICTS` | `gardefou.verdicts.PLANT` | verdict line | the JSON line of SPEC §3, as `monitor` prints it |
//! | `GARDEFOU_FLAGS` | `gardefou.flags.PLANT` | change of the flags written to the PLC | `{"t_ns":…,"up":["def_C4"]}` |
//! | `GARDEFOU_FLEET` | `gardefou.fleet.FLEET.PLANT` | verdict line of a fleet worker ([`crate::fleet`]) | the line `fleet` prints, with `plant` and `model` fields; header `Gardefou-Line`: its number |
//!
//! Events, times in integer nanoseconds (`t_ns`), signals by name:
//!
//! ```text
//! {"t_ns":590000000000,"start":{"A0":0,"A1":1,…},"time":"ms"}
//!                                                   every signal's value, and how
//!                                                   the monitor printed times
//! {"t_ns":602850000000,"scan":[["A4",1],["C5",0]]}  the changes of one scan, in order
//! {"t_ns":602950000000,"watermark":true}            nothing else up to then
//! {"t_ns":602990000000,"lost":"modbus …: no reply"} the plant unseen from then on
//! {"t_ns":612000000000,"end":true}                  the monitor stopped
//! ```
//!
//! A scan is one message, whatever groups of signals it touches, so that the
//! stream keeps the order of the scans and of the events within one.
//! Watermarks go out at most every [`WATERMARK_SCANS`] scan periods: a
//! replay of the stream fires the same deadlines, a little later.

use diagnoser::{Event, Plant, Time, TimeFormat, TimeUnit};
use serde_json::json;

use crate::monitor::source::Item;

/// The streams every plant shares, and the subjects each takes. Each
/// plant's events have a stream of their own ([`Subjects::stream`]): a
/// consumer of one plant's events is then a consumer of a whole stream,
/// which costs the server nothing per message of the other plants (a
/// consumer filtered out of a stream of a thousand plants does).
pub const STREAMS: [(&str, &str); 3] = [
    ("GARDEFOU_VERDICTS", "gardefou.verdicts.>"),
    ("GARDEFOU_FLAGS", "gardefou.flags.>"),
    ("GARDEFOU_FLEET", "gardefou.fleet.>"),
];

/// The stream of fleet workers' verdict lines.
pub const FLEET_STREAM: &str = STREAMS[2].0;

/// Scan periods of the source's time between two watermarks published.
pub const WATERMARK_SCANS: Time = 10;

/// The subjects of one plant.
#[derive(Debug, Clone)]
pub struct Subjects {
    /// `GARDEFOU_EVENTS_PLANT`: the stream of the plant's events.
    pub stream: String,
    /// `gardefou.events.PLANT`.
    pub events: String,
    /// `gardefou.verdicts.PLANT`.
    pub verdicts: String,
    /// `gardefou.flags.PLANT`.
    pub flags: String,
}

impl Subjects {
    /// The subjects of the plant named `name`: one subject token (letters,
    /// digits, `-` and `_`).
    pub fn of(name: &str) -> Result<Subjects, String> {
        let fits = |c: char| c.is_ascii_alphanumeric() || c == '-' || c == '_';
        if name.is_empty() || !name.chars().all(fits) {
            return Err(format!(
                "'{name}': a plant's name on NATS is letters, digits, '-' and '_' only"
            ));
        }
        Ok(Subjects {
            stream: format!("GARDEFOU_EVENTS_{name}"),
            events: format!("gardefou.events.{name}"),
            verdicts: format!("gardefou.verdicts.{name}"),
            flags: format!("gardefou.flags.{name}"),
        })
    }
}

/// Writes items as events payloads.
#[derive(Debug)]
pub struct EventWriter {
    names: Vec<String>,
    time: TimeFormat,
    watermark_every: Time,
    /// The time of the last message written.
    last: Option<Time>,
}

impl EventWriter {
    /// A writer for `plant`'s signals, whose verdicts print times as `time`.
    pub fn new(plant: &Plant, time: TimeFormat) -> EventWriter {
        EventWriter {
            names: plant.signals.iter().map(|(_, s)| s.name.clone()).collect(),
            time,
            watermark_every: plant.scan_period.max(1).saturating_mul(WATERMARK_SCANS),
            last: None,
        }
    }

    /// The payload of `item`, if it is one the stream keeps.
    pub fn item(&mut self, item: &Item) -> Option<Vec<u8>> {
        let (t, body) = match item {
            Item::Start(t, values) => {
                let values: serde_json::Map<String, serde_json::Value> = self
                    .names
                    .iter()
                    .zip(values)
                    .map(|(n, v)| (n.clone(), json!(u8::from(*v))))
                    .collect();
                (*t, json!({ "start": values, "time": time_name(self.time) }))
            }
            Item::Scan(events) => {
                let t = events.first()?.t;
                let changes: Vec<serde_json::Value> = events
                    .iter()
                    .map(|e| json!([self.names[e.signal.index()], u8::from(e.value)]))
                    .collect();
                (t, json!({ "scan": changes }))
            }
            Item::Watermark(t) => {
                if self
                    .last
                    .is_some_and(|l| *t < l.saturating_add(self.watermark_every))
                {
                    return None;
                }
                (*t, json!({ "watermark": true }))
            }
            Item::Lost(t, why) => (*t, json!({ "lost": why })),
            _ => return None,
        };
        self.last = Some(t);
        Some(with_time(t, body))
    }

    /// The time of the last payload written.
    pub fn last(&self) -> Option<Time> {
        self.last
    }

    /// The payload of the monitor's end at `t`.
    pub fn end(&mut self, t: Time) -> Vec<u8> {
        with_time(t, json!({ "end": true }))
    }
}

/// The payload of the flags up at `t` (the last event's time), in plant order.
pub fn flags(t: Option<Time>, up: &[String]) -> Vec<u8> {
    let mut body = json!({ "up": up });
    if let Some(t) = t {
        body["t_ns"] = json!(t);
    }
    body.to_string().into_bytes()
}

/// What an events message says.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// Every signal's value, and how the monitor printed times.
    Start(Time, Vec<bool>, Option<TimeFormat>),
    /// The changes of one scan.
    Scan(Vec<Event>),
    /// Nothing else up to then.
    Watermark(Time),
    /// The plant unseen from then on.
    Lost(Time, String),
    /// The monitor stopped.
    End(Time),
}

/// Reads an events message for `plant`.
pub fn read(payload: &[u8], plant: &Plant) -> Result<Record, String> {
    let v: serde_json::Value =
        serde_json::from_slice(payload).map_err(|e| format!("not JSON ({e})"))?;
    let t = v["t_ns"].as_i64().ok_or("no integer 't_ns'")?;
    if let Some(values) = v.get("start") {
        let values = values.as_object().ok_or("'start' is not an object")?;
        let mut initial = vec![false; plant.signals.len()];
        for (id, s) in plant.signals.iter() {
            let value = values.get(&s.name).and_then(serde_json::Value::as_u64);
            initial[id.index()] = match value {
                Some(0) => false,
                Some(1) => true,
                _ => return Err(format!("'start' has no value 0 or 1 for signal {}", s.name)),
            };
        }
        let time = v["time"].as_str().and_then(time_of);
        return Ok(Record::Start(t, initial, time));
    }
    if let Some(changes) = v.get("scan") {
        let changes = changes.as_array().ok_or("'scan' is not an array")?;
        let events = changes
            .iter()
            .map(|c| {
                let name = c[0].as_str().ok_or("a change without a signal name")?;
                let signal = plant
                    .signals
                    .id(name)
                    .ok_or_else(|| format!("unknown signal '{name}'"))?;
                let value = match c[1].as_u64() {
                    Some(0) => false,
                    Some(1) => true,
                    _ => return Err(format!("signal {name}: a value not 0 or 1")),
                };
                Ok(Event { t, signal, value })
            })
            .collect::<Result<Vec<_>, String>>()?;
        return Ok(Record::Scan(events));
    }
    if v.get("watermark").is_some() {
        return Ok(Record::Watermark(t));
    }
    if let Some(why) = v.get("lost") {
        return Ok(Record::Lost(t, why.as_str().unwrap_or("lost").to_string()));
    }
    if v.get("end").is_some() {
        return Ok(Record::End(t));
    }
    Err("neither start, scan, watermark, lost nor end".into())
}

/// A verdict's JSON line (SPEC §3) with `fields` (JSON strings) after its
/// time: how the fleet names the plant and the model version.
pub fn with_fields(line: &str, fields: &[(&str, &str)]) -> String {
    let Some(i) = line.find(',') else {
        return line.to_string();
    };
    let mut out = String::with_capacity(line.len() + 64);
    out.push_str(&line[..i]);
    for (name, value) in fields {
        out.push_str(&format!(
            ",\"{name}\":{}",
            serde_json::Value::String(value.to_string())
        ));
    }
    out.push_str(&line[i..]);
    out
}

/// A time format's name in a start message.
pub fn time_name(time: TimeFormat) -> &'static str {
    match time {
        TimeFormat::Numeric(unit) => unit.name(),
        TimeFormat::Rfc3339 => "rfc3339",
    }
}

/// The time format named `name` (as [`time_name`] names it).
pub fn time_of(name: &str) -> Option<TimeFormat> {
    match name {
        "rfc3339" => Some(TimeFormat::Rfc3339),
        _ => name.parse::<TimeUnit>().ok().map(TimeFormat::Numeric),
    }
}

/// `{"t_ns":T,…}`: the time first.
fn with_time(t: Time, body: serde_json::Value) -> Vec<u8> {
    let rest = body.to_string();
    format!("{{\"t_ns\":{t},{}", rest.strip_prefix('{').unwrap_or(&rest)).into_bytes()
}

#[cfg(test)]
mod tests {
    use diagnoser::Event;

    use super::*;

    fn plant() -> Plant {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../datasets/data/sorting/F2/plant.toml");
        Plant::from_path(&p).expect("plant")
    }

    #[test]
    fn items_are_written_as_documented() {
        let plant = plant();
        let mut w = EventWriter::new(&plant, TimeFormat::Numeric(TimeUnit::Ms));
        let c4 = plant.signals.id("C4").expect("C4");
        let a4 = plant.signals.id("A4").expect("A4");
        let scan = Item::Scan(vec![
            Event {
                t: 5,
                signal: c4,
                value: true,
            },
            Event {
                t: 5,
                signal: a4,
                value: false,
            },
        ]);
        let text = String::from_utf8(w.item(&scan).expect("kept")).expect("UTF-8");
        assert_eq!(text, r#"{"t_ns":5,"scan":[["C4",1],["A4",0]]}"#);
        let lost = Item::Lost(7, "gone".into());
        assert_eq!(w.item(&lost).expect("kept"), br#"{"t_ns":7,"lost":"gone"}"#);
        assert!(w.item(&Item::Warning("w".into())).is_none());
        let start = String::from_utf8(
            w.item(&Item::Start(0, vec![false; plant.signals.len()]))
                .expect("kept"),
        )
        .expect("UTF-8");
        let v: serde_json::Value = serde_json::from_str(&start).expect("JSON");
        assert_eq!(
            v["start"].as_object().map(|o| o.len()),
            Some(plant.signals.len())
        );
    }

    #[test]
    fn watermarks_are_thinned_to_every_few_scans() {
        let plant = plant();
        let mut w = EventWriter::new(&plant, TimeFormat::Numeric(TimeUnit::Ms));
        let every = plant.scan_period * WATERMARK_SCANS;
        assert!(w.item(&Item::Watermark(0)).is_some());
        assert!(w.item(&Item::Watermark(every - 1)).is_none());
        assert!(w.item(&Item::Watermark(every)).is_some());
    }

    #[test]
    fn plant_names_are_one_token() {
        assert_eq!(
            Subjects::of("line-7_a").expect("fits").events,
            "gardefou.events.line-7_a"
        );
        for bad in ["", "a.b", "a b", "a*", "a>"] {
            assert!(Subjects::of(bad).is_err(), "{bad}");
        }
    }
}
