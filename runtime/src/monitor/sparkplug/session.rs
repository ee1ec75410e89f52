//! One edge node (or one of its devices) as the monitor follows it: births,
//! data, deaths and sequence numbers in; [`Item`]s and commands out. Pure:
//! no network and no clock but the instants it is given, so that the tests
//! can feed it any interleaving.
//!
//! **Births.** The birth of the level that carries the plant's signals
//! (NBIRTH for the node, DBIRTH with a device) names every metric, with its
//! alias and value: every plant signal must be there, by name, as a boolean
//! (or an integer 0 or 1). It gives [`Item::Start`] at the birth's
//! timestamp, and the `def_` flags it shows up count as raised
//! ([`Item::FoundRaised`]).
//!
//! **Data.** A metric's value is seen at its own timestamp, or the
//! payload's. The edge node sends its messages in time order, so a payload
//! stamped `T` completes everything before `T`; a quiet node's time is
//! extrapolated from its last message on the source's clock (`speed` times
//! the wall clock), less `lateness`, the jitter allowed between its messages
//! on the way. A value behind that watermark is late: a warning, ignored.
//! Values that repeat the one known are not changes and are dropped. A
//! message stamped far ahead of that clock (a thousand scans, or ten seconds
//! of it, as on standard input) would fire every deadline in between: it is
//! a warning and a lost plant, read again from a new birth.
//!
//! **Losses.** Every message of an edge node carries a sequence number that
//! follows the one before, modulo 256 (NBIRTH starts it). A gap, a message
//! that does not decode, an NDEATH of the node's session (its `bdSeq`), a
//! DDEATH of the device, a new NBIRTH, or the broker's connection lost means
//! the plant was not seen whole: [`Item::Lost`]. The session then asks the
//! node for its births again (`Node Control/Rebirth`) and starts again from
//! them.
//!
//! **Flags.** The flags go back as a command (DCMD to the device, NCMD to
//! the node) naming each flag metric that the birth declared. They count as
//! written once the node's data shows them at those values; until then the
//! command is sent again every [`RESEND`].

use std::collections::{BTreeMap, HashMap};
use std::time::{Duration, Instant};

use diagnoser::flag::FlagKind;
use diagnoser::{Event, Failure, Plant, SignalId, Time, TimeFormat, TimeUnit};
use prost::Message as _;

use super::payload::{BD_SEQ, Kind, Metric, Payload, Topic};
use crate::monitor::source::{FlagImage, Item};

/// How long a command waits for the node to show its flags before it is
/// sent again.
pub const RESEND: Duration = Duration::from_secs(1);
/// How long the session waits for a birth before asking for one again.
pub const REBIRTH_EVERY: Duration = Duration::from_secs(2);

/// Which edge node, and which of its devices, carries the plant.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Target {
    /// The Sparkplug group.
    pub group: String,
    /// The edge node.
    pub edge: String,
    /// The device, if the signals are a device's metrics.
    pub device: Option<String>,
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.group, self.edge)?;
        if let Some(d) = &self.device {
            write!(f, "/{d}")?;
        }
        Ok(())
    }
}

/// A command for the edge node, sent by the caller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// Ask for the births again (an NCMD with `Node Control/Rebirth`).
    Rebirth,
    /// Write these flag metrics (a DCMD, or an NCMD without a device).
    Flags(Vec<(String, bool)>),
}

/// What a metric of the level stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    Signal(SignalId),
    Flag(usize),
    Other,
}

/// The edge node's current session: since its NBIRTH.
#[derive(Debug, Clone, Copy)]
struct Node {
    bd_seq: Option<u64>,
    seq: u64,
}

/// The follower of one target.
#[derive(Debug)]
pub struct Session {
    target: Target,
    signals: HashMap<String, SignalId>,
    names: Vec<String>,
    flags: Vec<(String, FlagKind)>,
    flag_index: HashMap<String, usize>,
    speed: f64,
    lateness: Time,
    /// How far ahead of the node's clock a message may be stamped.
    lead: Time,
    node: Option<Node>,
    /// The level's aliases, once it is born in this node session.
    aliases: Option<HashMap<u64, Slot>>,
    /// Whether the plant is seen: a start sent, and no loss since.
    seen: bool,
    values: Vec<bool>,
    /// Complete up to this time (inclusive), as sent.
    watermark: Option<Time>,
    /// The latest payload time, and when it arrived.
    newest: Option<(Time, Instant)>,
    waiting: BTreeMap<Time, Vec<Event>>,
    /// Each flag's value as the node shows it; `None`: not in its birth.
    shown: Vec<Option<bool>>,
    /// The flags the monitor wants up.
    wanted: FlagImage,
    /// `def_` flags found up in a birth: kept up whatever `wanted` says.
    adopted: Vec<bool>,
    asked: Option<Instant>,
    /// The flags last reported written.
    written: Option<Vec<bool>>,
    rebirth_asked: Option<Instant>,
    undeclared_warned: bool,
}

impl Session {
    /// A session following `target` for `plant`, with nothing seen yet.
    pub fn new(plant: &Plant, target: Target, speed: f64, lateness: Time) -> Session {
        let names: Vec<String> = plant.signals.iter().map(|(_, s)| s.name.clone()).collect();
        let signals = plant
            .signals
            .iter()
            .map(|(id, s)| (s.name.clone(), id))
            .collect();
        let flags: Vec<(String, FlagKind)> = plant
            .flags()
            .iter()
            .map(|f| (f.to_string(), f.kind))
            .collect();
        let flag_index = flags
            .iter()
            .enumerate()
            .map(|(k, (n, _))| (n.clone(), k))
            .collect();
        Session {
            target,
            signals,
            values: vec![false; names.len()],
            names,
            shown: vec![None; flags.len()],
            wanted: vec![false; flags.len()],
            adopted: vec![false; flags.len()],
            flags,
            flag_index,
            speed,
            lateness: lateness.max(0),
            lead: crate::monitor::stdin::lead(plant, speed),
            node: None,
            aliases: None,
            seen: false,
            watermark: None,
            newest: None,
            waiting: BTreeMap::new(),
            asked: None,
            written: None,
            rebirth_asked: None,
            undeclared_warned: false,
        }
    }

    /// How the session's times are printed: Sparkplug's milliseconds.
    pub fn time_format() -> TimeFormat {
        TimeFormat::Numeric(TimeUnit::Ms)
    }

    /// The broker's connection is up (again): every earlier message may have
    /// been missed, so the births are asked for.
    pub fn connected(&mut self, at: Instant, send: &mut Vec<Command>) {
        self.node = None;
        self.aliases = None;
        self.ask_rebirth(at, send);
    }

    /// The broker's connection is lost.
    pub fn disconnected(&mut self, why: &str, out: &mut Vec<Item>) {
        self.node = None;
        self.lose(&format!("sparkplug {}: {why}", self.target), out);
    }

    /// Takes one MQTT message.
    pub fn message(
        &mut self,
        topic: &str,
        bytes: &[u8],
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) {
        let Some(topic) = Topic::parse(topic) else {
            return;
        };
        if topic.group != self.target.group || topic.edge != self.target.edge {
            return;
        }
        if topic.kind == Kind::Other {
            return;
        }
        let payload = match Payload::decode(bytes) {
            Ok(p) => p,
            Err(e) => {
                return self.broken(
                    &format!("a message that does not decode ({e})"),
                    at,
                    out,
                    send,
                );
            }
        };
        let ours = topic.device == self.target.device.as_deref();
        match topic.kind {
            Kind::NBirth => self.node_birth(&payload, at, out, send),
            Kind::NDeath => self.node_death(&payload, out),
            _ if self.node.is_none() => self.remind_rebirth(at, send),
            _ => {
                if !self.in_sequence(&payload, at, out, send) {
                    return;
                }
                match topic.kind {
                    Kind::DBirth if ours => self.birth(&payload, at, out, send),
                    Kind::DDeath if ours => {
                        let why =
                            format!("sparkplug {}: DDEATH: the device went offline", self.target);
                        self.aliases = None;
                        self.lose(&why, out);
                    }
                    Kind::NData | Kind::DData if ours => self.data(&payload, at, out, send),
                    _ => {}
                }
            }
        }
    }

    /// Time passes with nothing received: the watermark moves on the
    /// source's clock, a command not yet shown is sent again, a birth not
    /// yet come is asked for again.
    pub fn tick(&mut self, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        if self.seen {
            if let Some(w) = self.extrapolated(at) {
                self.release(w, out);
            }
            self.write(at, out, send);
        } else {
            self.remind_rebirth(at, send);
        }
    }

    /// The flags the monitor wants on the plant now.
    pub fn flags(
        &mut self,
        image: &FlagImage,
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) {
        if image.len() == self.wanted.len() && *image != self.wanted {
            self.wanted.clone_from(image);
            self.asked = None;
            self.write(at, out, send);
        }
    }

    fn where_(&self) -> String {
        format!("sparkplug {}", self.target)
    }

    /// Asks for the births again if the last request is [`REBIRTH_EVERY`]
    /// old: a node that keeps sending data while none came is not flooded.
    fn remind_rebirth(&mut self, at: Instant, send: &mut Vec<Command>) {
        if self
            .rebirth_asked
            .is_none_or(|a| at.duration_since(a) >= REBIRTH_EVERY)
        {
            self.ask_rebirth(at, send);
        }
    }

    fn ask_rebirth(&mut self, at: Instant, send: &mut Vec<Command>) {
        self.rebirth_asked = Some(at);
        send.push(Command::Rebirth);
    }

    /// A message of the node's sequence that cannot be read: as a gap.
    fn broken(&mut self, why: &str, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        self.node = None;
        self.aliases = None;
        self.lose(&format!("{}: {why}", self.where_()), out);
        self.ask_rebirth(at, send);
    }

    /// Whether the payload's sequence number follows the node's last one;
    /// a gap loses the plant.
    fn in_sequence(
        &mut self,
        p: &Payload,
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) -> bool {
        let Some(node) = self.node.as_mut() else {
            return false;
        };
        let expected = (node.seq + 1) % 256;
        if p.seq == Some(expected) {
            node.seq = expected;
            return true;
        }
        let got = p.seq.map_or("none".to_string(), |s| s.to_string());
        self.broken(
            &format!("sequence gap: expected {expected}, got {got}"),
            at,
            out,
            send,
        );
        false
    }

    fn node_birth(
        &mut self,
        p: &Payload,
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) {
        if self.seen {
            let why = format!(
                "{}: NBIRTH: the edge node started a new session",
                self.where_()
            );
            self.lose(&why, out);
        }
        let bd_seq = metric_number(p, BD_SEQ);
        self.node = Some(Node {
            bd_seq,
            seq: p.seq.unwrap_or(0) % 256,
        });
        self.aliases = None;
        if self.target.device.is_none() {
            self.birth(p, at, out, send);
        }
    }

    fn node_death(&mut self, p: &Payload, out: &mut Vec<Item>) {
        let Some(node) = self.node else {
            return;
        };
        let bd_seq = metric_number(p, BD_SEQ);
        // The will of an earlier session, delivered late, says nothing of
        // this one.
        if bd_seq.is_some() && node.bd_seq.is_some() && bd_seq != node.bd_seq {
            return;
        }
        self.node = None;
        self.aliases = None;
        let why = format!("{}: NDEATH: the edge node went offline", self.where_());
        self.lose(&why, out);
    }

    /// The level's birth: every signal's value, the aliases, the flags shown.
    fn birth(&mut self, p: &Payload, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        let Some(t) = p.timestamp.and_then(ms_to_time) else {
            out.push(Item::Warning(format!(
                "{}: a birth without a timestamp, ignored",
                self.where_()
            )));
            return;
        };
        let mut values: Vec<Option<bool>> = vec![None; self.names.len()];
        let mut aliases = HashMap::new();
        let mut shown = vec![None; self.flags.len()];
        for m in &p.metrics {
            let Some(name) = m.name.as_deref() else {
                continue;
            };
            let slot = self.slot_of(name);
            if let Some(a) = m.alias {
                aliases.insert(a, slot);
            }
            match slot {
                Slot::Signal(id) => match m.boolean() {
                    Some(v) => values[id.index()] = Some(v),
                    None => {
                        return self.misfit(
                            out,
                            &format!(
                                "metric '{name}' is not a boolean (datatype {})",
                                m.datatype.unwrap_or(0)
                            ),
                        );
                    }
                },
                Slot::Flag(k) => shown[k] = m.boolean(),
                Slot::Other => {}
            }
        }
        let missing: Vec<&str> = values
            .iter()
            .zip(&self.names)
            .filter(|(v, _)| v.is_none())
            .map(|(_, n)| n.as_str())
            .collect();
        if !missing.is_empty() {
            let m = format!(
                "no metric for signal {}: the plant's signals are read by metric name",
                missing.join(", ")
            );
            return self.misfit(out, &m);
        }
        self.values = values.into_iter().map(|v| v.unwrap_or(false)).collect();
        self.aliases = Some(aliases);
        self.shown = shown;
        self.waiting.clear();
        self.seen = true;
        self.watermark = Some(t);
        self.newest = Some((t, at));
        self.asked = None;
        self.written = None;
        out.push(Item::Start(t, self.values.clone()));
        let found: Vec<String> = (0..self.flags.len())
            .filter(|&k| self.flags[k].1 == FlagKind::Def && self.shown[k] == Some(true))
            .map(|k| self.flags[k].0.clone())
            .collect();
        for (k, (_, kind)) in self.flags.iter().enumerate() {
            self.adopted[k] |= *kind == FlagKind::Def && self.shown[k] == Some(true);
        }
        if !found.is_empty() {
            out.push(Item::FoundRaised(found));
        }
        self.write(at, out, send);
    }

    /// A birth the plant file does not fit: the monitor cannot go on.
    fn misfit(&mut self, out: &mut Vec<Item>, why: &str) {
        let kind = if self.target.device.is_some() {
            "DBIRTH"
        } else {
            "NBIRTH"
        };
        let m = format!("{}: {kind}: {why}", self.where_());
        out.push(Item::Fatal(Failure::BadInput(m)));
    }

    fn slot_of(&self, name: &str) -> Slot {
        if let Some(&id) = self.signals.get(name) {
            Slot::Signal(id)
        } else if let Some(&k) = self.flag_index.get(name) {
            Slot::Flag(k)
        } else {
            Slot::Other
        }
    }

    /// Changes reported by the level: values queued by time, flags shown.
    fn data(&mut self, p: &Payload, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        if self.aliases.is_none() {
            return;
        }
        if let Some(ahead) = self.far_ahead(p, at) {
            // A clock that jumped: believing it would fire every deadline
            // in between. The plant is lost, and read again from a birth.
            out.push(Item::FarAhead(format!(
                "{}: a message stamped {} ms ahead of the node's clock",
                self.where_(),
                ahead / 1_000_000
            )));
            return self.broken("its clock jumped ahead", at, out, send);
        }
        let Some(aliases) = self.aliases.as_ref() else {
            return;
        };
        let slots: Vec<Slot> = p
            .metrics
            .iter()
            .map(
                |m| match (m.alias.and_then(|a| aliases.get(&a)), m.name.as_deref()) {
                    (Some(slot), _) => *slot,
                    (None, Some(name)) => self.slot_of(name),
                    (None, None) => Slot::Other,
                },
            )
            .collect();
        for (m, slot) in p.metrics.iter().zip(slots) {
            match slot {
                Slot::Signal(id) => self.value(m, id, p.timestamp, out),
                Slot::Flag(k) => self.shown[k] = m.boolean().or(self.shown[k]),
                Slot::Other => {}
            }
        }
        if let Some(t) = p.timestamp.and_then(ms_to_time) {
            if self.newest.is_none_or(|(n, _)| t >= n) {
                self.newest = Some((t, at));
            }
            let complete = if self.lateness == 0 { t } else { t - 1 };
            self.release(complete, out);
        }
        self.confirm(out);
        self.write(at, out, send);
    }

    /// One signal's value from a data message.
    fn value(&mut self, m: &Metric, id: SignalId, payload_t: Option<u64>, out: &mut Vec<Item>) {
        let name = &self.names[id.index()];
        let format = Self::time_format();
        if m.historical() {
            out.push(Item::Late(format!(
                "{}: historical value of {name}, ignored",
                self.where_()
            )));
            return;
        }
        let Some(value) = m.boolean() else {
            out.push(Item::Warning(format!(
                "{}: {name}: not a boolean value, ignored",
                self.where_()
            )));
            return;
        };
        let Some(t) = m.timestamp.or(payload_t).and_then(ms_to_time) else {
            out.push(Item::Warning(format!(
                "{}: {name}: no timestamp, ignored",
                self.where_()
            )));
            return;
        };
        if let Some(w) = self.watermark.filter(|&w| t <= w) {
            out.push(Item::Late(format!(
                "{}: {name} at {} is behind the watermark {}, ignored",
                self.where_(),
                format.format(t),
                format.format(w)
            )));
            return;
        }
        self.waiting.entry(t).or_default().push(Event {
            t,
            signal: id,
            value,
        });
    }

    /// How far (ns) a payload, or one of its metrics, is ahead of the node's
    /// clock as extrapolated, if by more than [`Session::lead`].
    fn far_ahead(&self, p: &Payload, at: Instant) -> Option<Time> {
        let (t, then) = self.newest?;
        let ran = at.saturating_duration_since(then).as_nanos() as f64 * self.speed;
        let clock = t.saturating_add(ran as Time);
        let stamps = p
            .timestamp
            .into_iter()
            .chain(p.metrics.iter().filter_map(|m| m.timestamp));
        let latest = stamps.filter_map(ms_to_time).max()?;
        let ahead = latest.saturating_sub(clock);
        (ahead > self.lead).then_some(ahead)
    }

    /// The source's time now, extrapolated from the latest message, less the
    /// lateness allowed.
    fn extrapolated(&self, at: Instant) -> Option<Time> {
        let (t, then) = self.newest?;
        let ran = at.saturating_duration_since(then).as_nanos() as f64 * self.speed;
        Some(t.saturating_add(ran as Time).saturating_sub(self.lateness))
    }

    /// Sends every scan up to `w` (inclusive), each with only the values
    /// that changed, then the watermark `w`.
    fn release(&mut self, w: Time, out: &mut Vec<Item>) {
        if !self.seen || self.watermark.is_some_and(|old| w <= old) {
            return;
        }
        while let Some(entry) = self.waiting.first_entry() {
            if *entry.key() > w {
                break;
            }
            let events = entry.remove();
            let scan = self.changes(events);
            if !scan.is_empty() {
                out.push(Item::Scan(scan));
            }
        }
        self.watermark = Some(w);
        out.push(Item::Watermark(w));
    }

    /// The changes of one time: each signal at its last value there, if that
    /// differs from its value before, in the order the signals first came.
    fn changes(&mut self, events: Vec<Event>) -> Vec<Event> {
        let mut scan: Vec<Event> = Vec::with_capacity(events.len());
        for e in events {
            match scan.iter_mut().find(|s| s.signal == e.signal) {
                Some(s) => s.value = e.value,
                None => scan.push(e),
            }
        }
        scan.retain(|e| self.values[e.signal.index()] != e.value);
        for e in &scan {
            self.values[e.signal.index()] = e.value;
        }
        scan
    }

    /// The plant is no longer seen whole.
    fn lose(&mut self, why: &str, out: &mut Vec<Item>) {
        self.waiting.clear();
        if !std::mem::take(&mut self.seen) {
            return;
        }
        let t = self.watermark.or(self.newest.map(|(t, _)| t)).unwrap_or(0);
        out.push(Item::Lost(t, why.to_string()));
    }

    /// The flags as they should stand on the node.
    fn target_image(&self) -> Vec<bool> {
        self.wanted
            .iter()
            .zip(&self.adopted)
            .map(|(w, a)| *w || *a)
            .collect()
    }

    /// Says the flags are written once the node shows every declared one at
    /// its wanted value.
    fn confirm(&mut self, out: &mut Vec<Item>) {
        let image = self.target_image();
        let shown_all = self
            .shown
            .iter()
            .zip(&image)
            .all(|(s, w)| s.is_none_or(|s| s == *w));
        if !shown_all || self.written.as_ref() == Some(&image) {
            return;
        }
        let declared = |k: &usize| self.shown[*k].is_some();
        if self.written.is_none() && !image.iter().enumerate().any(|(k, up)| *up && declared(&k)) {
            // Nothing asked for yet: nothing to report.
            self.written = Some(image);
            return;
        }
        let up: Vec<String> = (0..image.len())
            .filter(|k| image[*k] && declared(k))
            .map(|k| self.flags[k].0.clone())
            .collect();
        self.written = Some(image);
        out.push(Item::FlagsWritten(up));
    }

    /// Sends a command for the declared flags that the node does not show
    /// at their wanted value, at most every [`RESEND`].
    fn write(&mut self, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        if !self.seen {
            return;
        }
        let image = self.target_image();
        let undeclared = image
            .iter()
            .zip(&self.shown)
            .any(|(up, s)| *up && s.is_none());
        if undeclared && !self.undeclared_warned {
            self.undeclared_warned = true;
            let names: Vec<&str> = (0..image.len())
                .filter(|&k| image[k] && self.shown[k].is_none())
                .map(|k| self.flags[k].0.as_str())
                .collect();
            out.push(Item::Warning(format!(
                "{}: the birth has no metric for flag {}: it cannot be written back",
                self.where_(),
                names.join(", ")
            )));
        }
        let differs = self
            .shown
            .iter()
            .zip(&image)
            .any(|(s, w)| s.is_some_and(|s| s != *w));
        if !differs || self.asked.is_some_and(|a| at.duration_since(a) < RESEND) {
            return;
        }
        let metrics = (0..image.len())
            .filter(|&k| self.shown[k].is_some())
            .map(|k| (self.flags[k].0.clone(), image[k]))
            .collect();
        self.asked = Some(at);
        send.push(Command::Flags(metrics));
    }
}

/// A payload's integer metric by name (`bdSeq`).
fn metric_number(p: &Payload, name: &str) -> Option<u64> {
    let m = p.metrics.iter().find(|m| m.name.as_deref() == Some(name))?;
    m.long_value.or(m.int_value.map(u64::from))
}

/// Sparkplug's milliseconds since the epoch as a time; `None` out of range.
fn ms_to_time(ms: u64) -> Option<Time> {
    i64::try_from(ms).ok()?.checked_mul(1_000_000)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use proptest::prelude::*;

    use super::*;

    const NODE: &str = "spBv1.0/line/NBIRTH/plc1";
    const DBIRTH: &str = "spBv1.0/line/DBIRTH/plc1/io";
    const DDATA: &str = "spBv1.0/line/DDATA/plc1/io";

    fn plant() -> Plant {
        let p =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/data/sorting/F2/plant.toml");
        Plant::from_path(&p).expect("plant")
    }

    fn session(plant: &Plant, lateness: Time) -> Session {
        let target = Target {
            group: "line".into(),
            edge: "plc1".into(),
            device: Some("io".into()),
        };
        Session::new(plant, target, 1.0, lateness)
    }

    fn bytes(timestamp: u64, seq: u64, metrics: Vec<Metric>) -> Vec<u8> {
        let p = Payload {
            timestamp: Some(timestamp),
            seq: Some(seq),
            metrics,
        };
        p.encode_to_vec()
    }

    /// The births of a node whose device has every signal down (alias =
    /// index + 1) and every flag down; the next seq is 2.
    fn born(s: &mut Session, plant: &Plant, t: u64, at: Instant) -> Vec<Item> {
        let (mut out, mut send) = (Vec::new(), Vec::new());
        let bd = Metric {
            name: Some(BD_SEQ.into()),
            long_value: Some(0),
            ..Metric::default()
        };
        s.message(NODE, &bytes(t, 0, vec![bd]), at, &mut out, &mut send);
        let mut metrics: Vec<Metric> = plant
            .signals
            .iter()
            .map(|(id, sig)| Metric {
                alias: Some(id.index() as u64 + 1),
                ..Metric::new_boolean(&sig.name, false)
            })
            .collect();
        metrics.extend(
            plant
                .flags()
                .iter()
                .map(|f| Metric::new_boolean(&f.to_string(), false)),
        );
        s.message(DBIRTH, &bytes(t, 1, metrics), at, &mut out, &mut send);
        out
    }

    fn by_alias(id: usize, value: bool, t: u64) -> Metric {
        Metric {
            alias: Some(id as u64 + 1),
            timestamp: Some(t),
            boolean_value: Some(value),
            ..Metric::default()
        }
    }

    #[test]
    fn a_birth_starts_the_plant_and_data_comes_by_alias() {
        let plant = plant();
        let mut s = session(&plant, 0);
        let at = Instant::now();
        let out = born(&mut s, &plant, 1_000, at);
        assert!(
            matches!(out.as_slice(), [Item::Start(t, v)] if *t == 1_000 * MS_NS && v.iter().all(|x| !x)),
            "{out:?}"
        );
        let (mut out, mut send) = (Vec::new(), Vec::new());
        s.message(
            DDATA,
            &bytes(1_010, 2, vec![by_alias(3, true, 1_010)]),
            at,
            &mut out,
            &mut send,
        );
        match out.as_slice() {
            [Item::Scan(scan), Item::Watermark(w)] => {
                assert_eq!(scan.len(), 1);
                assert_eq!(
                    (scan[0].t, scan[0].signal.index(), scan[0].value),
                    (1_010 * MS_NS, 3, true)
                );
                assert_eq!(*w, 1_010 * MS_NS);
            }
            other => panic!("{other:?}"),
        }
        assert!(send.is_empty(), "{send:?}");
    }

    #[test]
    fn a_birth_without_a_signal_is_a_misfit() {
        let plant = plant();
        let mut s = session(&plant, 0);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        s.message(
            NODE,
            &bytes(1, 0, vec![]),
            Instant::now(),
            &mut out,
            &mut send,
        );
        s.message(
            DBIRTH,
            &bytes(1, 1, vec![Metric::new_boolean("C0", true)]),
            Instant::now(),
            &mut out,
            &mut send,
        );
        let Some(Item::Fatal(Failure::BadInput(m))) = out.last() else {
            panic!("{out:?}");
        };
        assert!(
            m.starts_with("sparkplug line/plc1/io: DBIRTH: no metric for signal C1, "),
            "{m}"
        );
    }

    #[test]
    fn a_stale_death_is_ignored_and_a_current_one_loses_the_plant() {
        let plant = plant();
        let mut s = session(&plant, 0);
        let at = Instant::now();
        born(&mut s, &plant, 5, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        let death = |bd| {
            bytes(
                9,
                0,
                vec![Metric {
                    name: Some(BD_SEQ.into()),
                    long_value: Some(bd),
                    ..Metric::default()
                }],
            )
        };
        s.message(
            "spBv1.0/line/NDEATH/plc1",
            &death(7),
            at,
            &mut out,
            &mut send,
        );
        assert!(out.is_empty(), "{out:?}");
        s.message(
            "spBv1.0/line/NDEATH/plc1",
            &death(0),
            at,
            &mut out,
            &mut send,
        );
        assert!(
            matches!(out.as_slice(), [Item::Lost(t, m)] if *t == 5 * MS_NS && m.contains("NDEATH")),
            "{out:?}"
        );
        // Data without a node session asks for the births.
        out.clear();
        s.message(
            DDATA,
            &bytes(10, 2, vec![by_alias(0, true, 10)]),
            at,
            &mut out,
            &mut send,
        );
        assert!(out.is_empty(), "{out:?}");
        assert_eq!(send, vec![Command::Rebirth]);
    }

    #[test]
    fn flags_go_out_until_the_node_shows_them() {
        let plant = plant();
        let mut s = session(&plant, 0);
        let at = Instant::now();
        born(&mut s, &plant, 5, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        let mut image = vec![false; plant.flags().len()];
        image[0] = true;
        s.flags(&image, at, &mut out, &mut send);
        let name = plant.flags()[0].to_string();
        let [Command::Flags(sent)] = send.as_slice() else {
            panic!("{send:?}");
        };
        assert_eq!(sent.len(), image.len());
        assert_eq!(sent[0], (name.clone(), true));
        // Not shown yet: sent again after RESEND, not before.
        send.clear();
        s.tick(at + RESEND / 2, &mut out, &mut send);
        assert!(send.is_empty());
        s.tick(at + RESEND, &mut out, &mut send);
        assert_eq!(send.len(), 1);
        // Shown: written, and no more commands.
        send.clear();
        out.clear();
        let shown = Metric::new_boolean(&name, true);
        s.message(
            DDATA,
            &bytes(6, 2, vec![shown]),
            at + RESEND,
            &mut out,
            &mut send,
        );
        assert!(
            out.iter()
                .any(|i| matches!(i, Item::FlagsWritten(up) if *up == vec![name.clone()])),
            "{out:?}"
        );
        s.tick(at + RESEND * 3, &mut out, &mut send);
        assert!(send.is_empty(), "{send:?}");
    }

    #[test]
    fn a_clock_that_jumps_ahead_loses_the_plant() {
        let plant = plant();
        let mut s = session(&plant, 0);
        let at = Instant::now();
        born(&mut s, &plant, 1_000, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        let hour = 3_600_000;
        s.message(
            DDATA,
            &bytes(1_000 + hour, 2, vec![by_alias(3, true, 1_000 + hour)]),
            at,
            &mut out,
            &mut send,
        );
        assert!(
            matches!(out.as_slice(), [Item::FarAhead(_), Item::Lost(t, _)] if *t == 1_000 * MS_NS),
            "{out:?}"
        );
        assert!(
            !out.iter()
                .any(|i| matches!(i, Item::Watermark(_) | Item::Scan(_)))
        );
        assert_eq!(send, vec![Command::Rebirth]);
    }

    const MS_NS: Time = 1_000_000;

    proptest! {
        /// Any run of changes sent as data, one payload per time, with any
        /// metrics by alias or by name: the scans are the changes, each at
        /// its time, repeats dropped; a skipped sequence number is a loss
        /// and a rebirth request, after which nothing goes out until the
        /// next birth.
        #[test]
        fn data_in_sequence_are_the_scans(
            steps in proptest::collection::vec(
                (1u64..50, proptest::collection::vec((0usize..22, any::<bool>(), any::<bool>()), 0..4)),
                1..40,
            ),
            gap in proptest::option::of(0usize..40),
        ) {
            let plant = plant();
            let n = plant.signals.len();
            let mut s = session(&plant, 0);
            let at = Instant::now();
            born(&mut s, &plant, 100, at);
            let (mut out, mut send) = (Vec::new(), Vec::new());
            let mut values = vec![false; n];
            let mut expected: Vec<Vec<(Time, usize, bool)>> = Vec::new();
            let (mut t, mut seq) = (100u64, 2u64);
            let mut lost_at = None;
            for (k, (dt, changes)) in steps.iter().enumerate() {
                t += dt;
                if gap == Some(k) {
                    seq += 1;
                    lost_at = Some(k);
                }
                let metrics = changes.iter().map(|&(i, v, named)| {
                    let i = i % n;
                    if named {
                        let name = &plant.signals.iter().nth(i).expect("signal").1.name;
                        Metric { timestamp: Some(t), ..Metric::new_boolean(name, v) }
                    } else {
                        by_alias(i, v, t)
                    }
                }).collect();
                s.message(DDATA, &bytes(t, seq % 256, metrics), at, &mut out, &mut send);
                seq += 1;
                if lost_at.is_none() {
                    // Each signal's last value in the payload, where it
                    // differs from the one before.
                    let mut scan: Vec<(Time, usize, bool)> = Vec::new();
                    for &(i, v, _) in changes {
                        let i = i % n;
                        match scan.iter_mut().find(|e| e.1 == i) {
                            Some(e) => e.2 = v,
                            None => scan.push((t as Time * MS_NS, i, v)),
                        }
                    }
                    scan.retain(|e| values[e.1] != e.2);
                    for e in &scan {
                        values[e.1] = e.2;
                    }
                    if !scan.is_empty() {
                        expected.push(scan);
                    }
                }
            }
            let scans: Vec<Vec<(Time, usize, bool)>> = out
                .iter()
                .filter_map(|i| match i {
                    Item::Scan(e) => Some(e.iter().map(|e| (e.t, e.signal.index(), e.value)).collect()),
                    _ => None,
                })
                .collect();
            let losses = out.iter().filter(|i| matches!(i, Item::Lost(..))).count();
            prop_assert_eq!(losses, usize::from(lost_at.is_some()));
            prop_assert_eq!(send.contains(&Command::Rebirth), lost_at.is_some());
            if lost_at.is_none() {
                prop_assert_eq!(scans, expected);
            }
            let mut last = None;
            for i in &out {
                if let Item::Watermark(w) = i {
                    prop_assert!(last.is_none_or(|l| *w > l));
                    last = Some(*w);
                }
            }
        }
    }
}
