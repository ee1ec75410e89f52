//! The plant as the monitor follows it over one OPC UA server: the values
//! read on connecting, the subscription's notification messages and the
//! results of flag writes in; [`Item`]s and commands out. Pure: no network
//! and no clock but the instants it is given, so that the tests can feed it
//! any interleaving.
//!
//! **Start.** On each connection the caller subscribes to every signal's
//! variable first, then reads them all: nothing that changes in between is
//! missed, and notifications that come before the read's answer are held.
//! The values read give [`Item::Start`] at the latest of their
//! SourceTimestamps (or the watermark, if later): each value has held since
//! its own timestamp, so the plant stood so then. Every signal must read as a
//! Boolean with a SourceTimestamp; `def_` flags read up count as raised
//! ([`Item::FoundRaised`]).
//!
//! **Event time.** A change counts at its SourceTimestamp; changes at one time
//! are one scan, in plant-file order. The source's clock is anchored at the latest SourceTimestamp
//! and the instant its notification arrived, and runs `speed` times the wall
//! clock from there. The read's values say when they last changed, not what
//! the time is now, so a Start anchors the clock from below: the first change
//! after it may be far ahead and moves the clock. Each notification message
//! (data or keep-alive: the subscription sends one every publishing interval)
//! shows that the server has sent every change made before it was published;
//! on its arrival the watermark moves to the clock less `lateness`, the jitter
//! allowed between a change and its notification (sampling, queueing,
//! transport). Deadlines therefore fire only on the server's messages: a
//! server that falls silent stops the watermark. A change behind the
//! watermark is late: a warning, ignored (a repeat of the known value, as each
//! monitored item's first notification is, is dropped silently). A change
//! stamped far ahead of the clock (a thousand scans, or ten seconds of it)
//! would fire every deadline in between: a warning and a lost plant.
//!
//! **Losses.** Notification messages carry sequence numbers, from 1, one more
//! for each message with data; a keep-alive carries the next one. A number that
//! does not follow means a message was lost: the plant was not seen whole. So
//! does a value whose status is not good (or whose queue overflowed), a change
//! without a SourceTimestamp, a subscription whose status changed, or the
//! session lost. Each is an [`Item::Lost`] and a [`Command::Reopen`]: the
//! caller opens the connection again and the session starts from a new read.
//!
//! **Flags.** The flags are written with one Write of every flag variable the
//! server has, at its wanted value, and count as written
//! ([`Item::FlagsWritten`]) once the server answers good for all of them. A
//! write that fails is a warning and goes again after [`RESEND`]. After every
//! Start the current image is written again, whatever the server showed.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use diagnoser::flag::FlagKind;
use diagnoser::{Event, Failure, Plant, SignalId, Time, TimeFormat, TimeUnit};

use crate::monitor::source::{FlagImage, Item};

/// How long after a failed flag write it is tried again.
pub const RESEND: Duration = Duration::from_secs(1);

/// A variable's value as the server gave it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Value {
    /// A good Boolean.
    Bool(bool),
    /// A status that is not good (or a queue that overflowed): the value is
    /// unknown. Says which.
    Bad(String),
    /// A good value of another type: names it.
    Other(String),
}

/// A variable's value and its SourceTimestamp.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reading {
    /// The value.
    pub value: Value,
    /// The SourceTimestamp, in nanoseconds since the Unix epoch.
    pub t: Option<Time>,
}

/// One notification message of the subscription.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Notice {
    /// Its sequence number.
    pub seq: u32,
    /// Whether it carries no notification (a keep-alive: `seq` is then the
    /// number of the next message with data).
    pub keep_alive: bool,
    /// The data changes, by signal (index in plant order), in the order sent.
    pub changes: Vec<(usize, Reading)>,
    /// A status change of the subscription, if any (e.g. `BadTimeout`).
    pub status: Option<String>,
}

/// What the session asks of the caller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// Write these flags (index in [`Plant::flags`] order, value).
    Write(Vec<(usize, bool)>),
    /// Close the connection and open it again (after a wait): the plant was
    /// lost, and is read again from a new start.
    Reopen,
}

/// The source's clock: a time and the instant it was seen.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    t: Time,
    at: Instant,
    /// Set by a read: the time is only a lower bound of the plant's.
    from_below: bool,
}

/// The follower of one server.
#[derive(Debug)]
pub struct Session {
    url: String,
    ids: Vec<SignalId>,
    names: Vec<String>,
    flags: Vec<(String, FlagKind)>,
    speed: f64,
    lateness: Time,
    /// How far ahead of the source's clock a change may be stamped.
    lead: Time,
    /// Whether a subscription is open (after [`Session::opened`]).
    open: bool,
    /// Whether the plant is seen: a start sent, and no loss since.
    seen: bool,
    values: Vec<bool>,
    /// Complete up to this time (inclusive), as sent.
    watermark: Option<Time>,
    anchor: Option<Anchor>,
    waiting: BTreeMap<Time, Vec<Event>>,
    /// The sequence number the next notification message must carry.
    expect: Option<u32>,
    /// Notifications that came before the read's answer, with their arrival.
    held: Vec<(Notice, Instant)>,
    /// Whether a read that could not start was said (until a start).
    told_unreadable: bool,
    /// Which flags have a variable on the server.
    present: Vec<bool>,
    /// The flags the monitor wants up.
    wanted: FlagImage,
    /// `def_` flags found up on the server: kept up whatever `wanted` says.
    adopted: Vec<bool>,
    /// The image last written (answered good), on this connection.
    written: Option<Vec<bool>>,
    /// The image of the write under way.
    in_flight: Option<Vec<bool>>,
    retry_at: Option<Instant>,
    /// Whether a flag was ever reported written up.
    reported: bool,
    absent_warned: bool,
}

impl Session {
    /// A session following the server at `url` for `plant`, with nothing
    /// seen yet; the source's clock runs `speed` times the wall clock.
    pub fn new(plant: &Plant, url: &str, speed: f64, lateness: Time) -> Session {
        let (ids, names): (Vec<SignalId>, Vec<String>) = plant
            .signals
            .iter()
            .map(|(id, s)| (id, s.name.clone()))
            .unzip();
        let flags: Vec<(String, FlagKind)> = plant
            .flags()
            .iter()
            .map(|f| (f.to_string(), f.kind))
            .collect();
        let n = flags.len();
        Session {
            url: url.to_string(),
            values: vec![false; names.len()],
            ids,
            names,
            flags,
            speed,
            lateness: lateness.max(0),
            lead: crate::monitor::stdin::lead(plant, speed),
            open: false,
            seen: false,
            watermark: None,
            anchor: None,
            waiting: BTreeMap::new(),
            expect: None,
            held: Vec::new(),
            told_unreadable: false,
            present: vec![false; n],
            wanted: vec![false; n],
            adopted: vec![false; n],
            written: None,
            in_flight: None,
            retry_at: None,
            reported: false,
            absent_warned: false,
        }
    }

    /// How the session's times are printed: milliseconds since the epoch.
    pub fn time_format() -> TimeFormat {
        TimeFormat::Numeric(TimeUnit::Ms)
    }

    /// A connection is open, its variables found (`present`: which flags have
    /// one) and a new subscription made: its notifications may come.
    pub fn opened(&mut self, present: Vec<bool>, out: &mut Vec<Item>) {
        if present.len() == self.present.len() {
            self.present = present;
        }
        self.open = true;
        // A subscription's first message carries number 1 (Part 4, 5.13.1.1):
        // a first message lost is a gap too.
        self.expect = Some(1);
        self.held.clear();
        self.written = None;
        self.in_flight = None;
        self.retry_at = None;
        let absent: Vec<&str> = (0..self.flags.len())
            .filter(|&k| !self.present[k])
            .map(|k| self.flags[k].0.as_str())
            .collect();
        if !absent.is_empty() && !self.absent_warned {
            self.absent_warned = true;
            out.push(Item::Warning(format!(
                "{}: no variable for flag {}: it cannot be written back",
                self.where_(),
                absent.join(", ")
            )));
        }
    }

    /// The connection is gone (or closed by the caller).
    pub fn disconnected(&mut self, why: &str, out: &mut Vec<Item>) {
        self.open = false;
        self.expect = None;
        self.held.clear();
        self.in_flight = None;
        self.lose(&format!("{}: {why}", self.where_()), out);
    }

    /// The values read on connecting: every signal's in plant order, and each
    /// flag's (`None`: no variable, or not read).
    pub fn read(
        &mut self,
        signals: &[Reading],
        flags: &[Option<Reading>],
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) {
        if !self.open || self.seen || signals.len() != self.names.len() {
            return;
        }
        let mut values = Vec::with_capacity(signals.len());
        let mut t0 = self.watermark;
        for (name, r) in self.names.iter().zip(signals) {
            match &r.value {
                Value::Bool(v) => values.push(*v),
                Value::Other(kind) => {
                    let m = format!(
                        "{}: {name} is not a Boolean but {kind}; the plant's signals are Boolean variables",
                        self.where_()
                    );
                    out.push(Item::Fatal(Failure::BadInput(m)));
                    return;
                }
                Value::Bad(why) => {
                    if !std::mem::replace(&mut self.told_unreadable, true) {
                        out.push(Item::Warning(format!(
                            "{}: {name} reads {why}: the plant cannot be seen; reading again",
                            self.where_()
                        )));
                    }
                    send.push(Command::Reopen);
                    return;
                }
            }
            let Some(t) = r.t else {
                let m = format!(
                    "{}: {name} has no SourceTimestamp; the monitor takes event times from them",
                    self.where_()
                );
                out.push(Item::Fatal(Failure::BadInput(m)));
                return;
            };
            t0 = Some(t0.map_or(t, |w| w.max(t)));
        }
        let Some(t0) = t0 else {
            return;
        };
        self.told_unreadable = false;
        self.values = values;
        self.seen = true;
        self.waiting.clear();
        self.watermark = Some(t0);
        self.anchor = Some(Anchor {
            t: t0,
            at,
            from_below: true,
        });
        out.push(Item::Start(t0, self.values.clone()));
        self.found(flags, out);
        for (notice, arrived) in std::mem::take(&mut self.held) {
            if !self.take(&notice, arrived, out, send) {
                return;
            }
        }
        self.write(at, send);
    }

    /// One notification message of the subscription, arrived at `at`.
    pub fn notice(&mut self, n: Notice, at: Instant, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        if !self.open {
            return;
        }
        if let Some(e) = self.expect
            && n.seq != e
        {
            let why = format!(
                "notification message {} where {e} was due: a message was lost",
                n.seq
            );
            return self.broken(&why, out, send);
        }
        self.expect = Some(if n.keep_alive { n.seq } else { next_seq(n.seq) });
        if let Some(status) = &n.status {
            let why = format!("the subscription's status changed to {status}");
            return self.broken(&why, out, send);
        }
        if !self.seen {
            self.held.push((n, at));
            return;
        }
        self.take(&n, at, out, send);
    }

    /// Time passes: a failed flag write is tried again.
    pub fn tick(&mut self, at: Instant, send: &mut Vec<Command>) {
        self.write(at, send);
    }

    /// The flags the monitor wants on the plant now.
    pub fn flags(&mut self, image: &FlagImage, at: Instant, send: &mut Vec<Command>) {
        if image.len() == self.wanted.len() && *image != self.wanted {
            self.wanted.clone_from(image);
            self.write(at, send);
        }
    }

    /// The server's answer to the last [`Command::Write`]: `Err` says which
    /// flag was refused, and why.
    pub fn written(
        &mut self,
        result: Result<(), String>,
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) {
        let Some(image) = self.in_flight.take() else {
            return;
        };
        match result {
            Ok(()) => {
                let up: Vec<String> = (0..image.len())
                    .filter(|&k| image[k] && self.present[k])
                    .map(|k| self.flags[k].0.clone())
                    .collect();
                self.written = Some(image);
                if self.reported || !up.is_empty() {
                    self.reported = true;
                    out.push(Item::FlagsWritten(up));
                }
            }
            Err(why) => {
                self.retry_at = Some(at + RESEND);
                out.push(Item::Warning(format!(
                    "{}: flags not written ({why}); trying again in {} s",
                    self.where_(),
                    RESEND.as_secs()
                )));
            }
        }
        self.write(at, send);
    }

    fn where_(&self) -> String {
        format!("opcua {}", self.url)
    }

    /// The flag values read on connecting: `def_` flags up are kept up.
    fn found(&mut self, flags: &[Option<Reading>], out: &mut Vec<Item>) {
        let mut found = Vec::new();
        for (k, r) in flags.iter().enumerate().take(self.flags.len()) {
            let Some(r) = r else {
                continue;
            };
            match &r.value {
                Value::Bool(true) if self.flags[k].1 == FlagKind::Def => {
                    if !self.adopted[k] {
                        found.push(self.flags[k].0.clone());
                    }
                    self.adopted[k] = true;
                }
                Value::Other(kind) => {
                    self.present[k] = false;
                    out.push(Item::Warning(format!(
                        "{}: flag {} is not a Boolean but {kind}: it cannot be written back",
                        self.where_(),
                        self.flags[k].0
                    )));
                }
                _ => {}
            }
        }
        if !found.is_empty() {
            out.push(Item::FoundRaised(found));
        }
    }

    /// A notification's changes, once the plant is seen; false if it lost
    /// the plant.
    fn take(
        &mut self,
        n: &Notice,
        at: Instant,
        out: &mut Vec<Item>,
        send: &mut Vec<Command>,
    ) -> bool {
        let mut latest: Option<Time> = None;
        let mut fresh = Vec::with_capacity(n.changes.len());
        for (k, r) in &n.changes {
            let Some(name) = self.names.get(*k) else {
                continue;
            };
            let value = match &r.value {
                Value::Bool(v) => *v,
                Value::Bad(why) => {
                    self.broken(&format!("{name} is {why}"), out, send);
                    return false;
                }
                Value::Other(kind) => {
                    self.broken(&format!("{name} changed to {kind}"), out, send);
                    return false;
                }
            };
            let Some(t) = r.t else {
                self.broken(
                    &format!("{name} changed without a SourceTimestamp"),
                    out,
                    send,
                );
                return false;
            };
            latest = Some(latest.map_or(t, |l| l.max(t)));
            fresh.push((*k, value, t));
        }
        if let Some(ahead) = latest.and_then(|t| self.far_ahead(t, at)) {
            // A clock that jumped: believing it would fire every deadline in
            // between. The plant is lost, and read again.
            out.push(Item::FarAhead(format!(
                "{}: a change stamped {} ms ahead of the source's clock",
                self.where_(),
                ahead / 1_000_000
            )));
            self.broken("its clock jumped ahead", out, send);
            return false;
        }
        for (k, value, t) in fresh {
            self.change(k, value, t, out);
        }
        // Only a change newer than the clock's time sets it: repeats and late
        // changes say nothing of the time now.
        if let Some(t) = latest
            && self.anchor.is_none_or(|a| t > a.t)
        {
            self.anchor = Some(Anchor {
                t,
                at,
                from_below: false,
            });
        }
        if let Some(w) = self.clock(at).map(|c| c.saturating_sub(self.lateness)) {
            self.release(w, out);
        }
        true
    }

    /// One signal's change: queued at its time, unless behind the watermark.
    fn change(&mut self, k: usize, value: bool, t: Time, out: &mut Vec<Item>) {
        if let Some(w) = self.watermark.filter(|&w| t <= w) {
            if self.values[k] == value {
                // A repeat of the value known (a monitored item's first
                // notification): nothing happened.
                return;
            }
            let format = Self::time_format();
            out.push(Item::Late(format!(
                "{}: {} at {} is behind the watermark {}, ignored",
                self.where_(),
                self.names[k],
                format.format(t),
                format.format(w)
            )));
            return;
        }
        self.waiting.entry(t).or_default().push(Event {
            t,
            signal: self.ids[k],
            value,
        });
    }

    /// The source's time at `at`, from the anchor.
    fn clock(&self, at: Instant) -> Option<Time> {
        let a = self.anchor?;
        let ran = at.saturating_duration_since(a.at).as_nanos() as f64 * self.speed;
        Some(a.t.saturating_add(ran as Time))
    }

    /// How far (ns) `t` is ahead of the source's clock, if by more than the
    /// lead allowed. A clock anchored from below bounds nothing.
    fn far_ahead(&self, t: Time, at: Instant) -> Option<Time> {
        if self.anchor.is_none_or(|a| a.from_below) {
            return None;
        }
        let ahead = t.saturating_sub(self.clock(at)?);
        (ahead > self.lead).then_some(ahead)
    }

    /// Sends every scan up to `w` (inclusive), each with only the values that
    /// changed, then the watermark `w`.
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
    /// differs from its value before, in plant-file order. A server sends a
    /// message's changes grouped by monitored item, not in the order they
    /// were made; plant-file order is the order of a log's scans.
    fn changes(&mut self, events: Vec<Event>) -> Vec<Event> {
        let mut scan: Vec<Event> = Vec::with_capacity(events.len());
        for e in events {
            match scan.iter_mut().find(|s| s.signal == e.signal) {
                Some(s) => s.value = e.value,
                None => scan.push(e),
            }
        }
        scan.sort_by_key(|e| e.signal.index());
        scan.retain(|e| self.values[e.signal.index()] != e.value);
        for e in &scan {
            self.values[e.signal.index()] = e.value;
        }
        scan
    }

    /// The plant is not seen whole on this connection: lost, and read again
    /// on a new one.
    fn broken(&mut self, why: &str, out: &mut Vec<Item>, send: &mut Vec<Command>) {
        self.open = false;
        self.expect = None;
        self.held.clear();
        self.in_flight = None;
        self.lose(&format!("{}: {why}", self.where_()), out);
        send.push(Command::Reopen);
    }

    /// The plant is no longer seen.
    fn lose(&mut self, why: &str, out: &mut Vec<Item>) {
        self.waiting.clear();
        if !std::mem::take(&mut self.seen) {
            return;
        }
        let t = self.watermark.unwrap_or(0);
        out.push(Item::Lost(t, why.to_string()));
    }

    /// The flags as they should stand on the server.
    fn target_image(&self) -> Vec<bool> {
        self.wanted
            .iter()
            .zip(&self.adopted)
            .map(|(w, a)| *w || *a)
            .collect()
    }

    /// Writes every flag variable at its wanted value if the server may not
    /// show them so: one write at a time, a failed one again after
    /// [`RESEND`].
    fn write(&mut self, at: Instant, send: &mut Vec<Command>) {
        if !self.seen || self.in_flight.is_some() || self.retry_at.is_some_and(|r| at < r) {
            return;
        }
        let image = self.target_image();
        if self.written.as_ref() == Some(&image) || !self.present.iter().any(|p| *p) {
            return;
        }
        self.retry_at = None;
        let values = (0..image.len())
            .filter(|&k| self.present[k])
            .map(|k| (k, image[k]))
            .collect();
        self.in_flight = Some(image);
        send.push(Command::Write(values));
    }
}

/// The sequence number after `seq`: 0 is never used, so 1 follows the
/// largest.
fn next_seq(seq: u32) -> u32 {
    if seq == u32::MAX { 1 } else { seq + 1 }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use proptest::prelude::*;

    use super::*;

    const MS: Time = 1_000_000;
    const LATENESS: Time = 50 * MS;

    fn plant() -> Plant {
        let p =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/data/sorting/F2/plant.toml");
        Plant::from_path(&p).expect("plant")
    }

    fn session(plant: &Plant) -> Session {
        Session::new(plant, "opc.tcp://plc:4840/", 1.0, LATENESS)
    }

    fn at_ms(value: bool, t: Time) -> Reading {
        Reading {
            value: Value::Bool(value),
            t: Some(t * MS),
        }
    }

    /// An open session started from every signal down at `t0` ms (the last
    /// one stamped then, the others earlier), every flag down; the first
    /// notification is due with sequence number 1.
    fn started(s: &mut Session, plant: &Plant, t0: Time, at: Instant) -> (Vec<Item>, Vec<Command>) {
        let (mut out, mut send) = (Vec::new(), Vec::new());
        s.opened(vec![true; plant.flags().len()], &mut out);
        let n = plant.signals.len();
        let signals: Vec<Reading> = (0..n)
            .map(|k| at_ms(false, if k + 1 == n { t0 } else { t0 - 100 }))
            .collect();
        let flags = vec![Some(at_ms(false, 0)); plant.flags().len()];
        s.read(&signals, &flags, at, &mut out, &mut send);
        (out, send)
    }

    fn data(seq: u32, changes: Vec<(usize, Reading)>) -> Notice {
        Notice {
            seq,
            keep_alive: false,
            changes,
            status: None,
        }
    }

    fn keep_alive(seq: u32) -> Notice {
        Notice {
            seq,
            keep_alive: true,
            changes: Vec::new(),
            status: None,
        }
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn a_read_starts_the_plant_at_its_latest_timestamp_and_rewrites_the_flags() {
        let plant = plant();
        let mut s = session(&plant);
        let (out, send) = started(&mut s, &plant, 1_000, Instant::now());
        assert!(
            matches!(out.as_slice(), [Item::Start(t, v)] if *t == 1_000 * MS && v.iter().all(|x| !x)),
            "{out:?}"
        );
        let [Command::Write(flags)] = send.as_slice() else {
            panic!("{send:?}");
        };
        assert_eq!(flags.len(), plant.flags().len());
        assert!(flags.iter().all(|(_, up)| !up));
    }

    #[test]
    fn changes_are_scans_once_the_watermark_has_passed_them() {
        let plant = plant();
        let mut s = session(&plant);
        let at = Instant::now();
        started(&mut s, &plant, 1_000, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        // A change 10 ms after the start, arriving at once: the clock is at
        // its time, and the watermark lateness behind it.
        s.notice(
            data(1, vec![(3, at_ms(true, 1_010))]),
            at,
            &mut out,
            &mut send,
        );
        assert!(out.is_empty(), "{out:?}");
        // A keep-alive 60 ms later: the clock at 1 070 ms, the watermark at
        // 1 020 ms, past the change.
        s.notice(keep_alive(2), at + ms(60), &mut out, &mut send);
        match out.as_slice() {
            [Item::Scan(scan), Item::Watermark(w)] => {
                let got: Vec<(Time, usize, bool)> = scan
                    .iter()
                    .map(|e| (e.t, e.signal.index(), e.value))
                    .collect();
                assert_eq!(got, [(1_010 * MS, 3, true)]);
                assert_eq!(*w, 1_020 * MS);
            }
            other => panic!("{other:?}"),
        }
        assert!(send.is_empty(), "{send:?}");
    }

    #[test]
    fn a_repeat_behind_the_watermark_is_dropped_and_a_change_there_is_late() {
        let plant = plant();
        let mut s = session(&plant);
        let at = Instant::now();
        started(&mut s, &plant, 1_000, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        // Each monitored item's first notification repeats the value read.
        let first = (0..plant.signals.len())
            .map(|k| (k, at_ms(false, 900)))
            .collect();
        s.notice(data(1, first), at, &mut out, &mut send);
        assert!(out.is_empty(), "{out:?}");
        s.notice(
            data(2, vec![(0, at_ms(true, 990))]),
            at,
            &mut out,
            &mut send,
        );
        assert!(
            matches!(out.as_slice(), [Item::Late(m)] if m.contains("C0 at 990 is behind the watermark 1000")),
            "{out:?}"
        );
        assert!(send.is_empty());
    }

    #[test]
    fn a_lost_message_loses_the_plant_and_reopens_the_connection() {
        let plant = plant();
        let at = Instant::now();
        for skipped in [data(3, vec![(0, at_ms(true, 1_010))]), keep_alive(3)] {
            let mut s = session(&plant);
            started(&mut s, &plant, 1_000, at);
            let (mut out, mut send) = (Vec::new(), Vec::new());
            s.notice(
                data(1, vec![(0, at_ms(true, 1_005))]),
                at,
                &mut out,
                &mut send,
            );
            s.notice(skipped, at, &mut out, &mut send);
            assert!(
                matches!(out.as_slice(), [Item::Lost(t, m)] if *t == 1_000 * MS && m.contains("message 3 where 2 was due")),
                "{out:?}"
            );
            assert_eq!(send, [Command::Reopen]);
            // Nothing more from this subscription counts.
            out.clear();
            s.notice(keep_alive(4), at + ms(500), &mut out, &mut send);
            assert!(out.is_empty(), "{out:?}");
        }
    }

    #[test]
    fn a_bad_value_or_a_status_change_loses_the_plant() {
        let plant = plant();
        let at = Instant::now();
        let bad = Reading {
            value: Value::Bad("BadCommunicationError".into()),
            t: Some(1_010 * MS),
        };
        let mut status = keep_alive(1);
        status.status = Some("BadTimeout".into());
        for (notice, why) in [
            (data(1, vec![(4, bad)]), "C4 is BadCommunicationError"),
            (status, "status changed to BadTimeout"),
            (
                data(
                    1,
                    vec![(
                        4,
                        Reading {
                            value: Value::Bool(true),
                            t: None,
                        },
                    )],
                ),
                "C4 changed without a SourceTimestamp",
            ),
        ] {
            let mut s = session(&plant);
            started(&mut s, &plant, 1_000, at);
            let (mut out, mut send) = (Vec::new(), Vec::new());
            s.notice(notice, at, &mut out, &mut send);
            assert!(
                matches!(out.as_slice(), [Item::Lost(_, m)] if m.contains(why)),
                "{why}: {out:?}"
            );
            assert_eq!(send, [Command::Reopen]);
        }
    }

    #[test]
    fn a_signal_of_another_type_or_without_timestamp_is_a_misfit() {
        let plant = plant();
        let n = plant.signals.len();
        for (reading, why) in [
            (
                Reading {
                    value: Value::Other("Int16".into()),
                    t: Some(5 * MS),
                },
                "C2 is not a Boolean but Int16",
            ),
            (
                Reading {
                    value: Value::Bool(false),
                    t: None,
                },
                "C2 has no SourceTimestamp",
            ),
        ] {
            let mut s = session(&plant);
            let (mut out, mut send) = (Vec::new(), Vec::new());
            s.opened(vec![true; plant.flags().len()], &mut out);
            let mut signals = vec![at_ms(false, 5); n];
            signals[2] = reading;
            s.read(&signals, &[], Instant::now(), &mut out, &mut send);
            let Some(Item::Fatal(Failure::BadInput(m))) = out.last() else {
                panic!("{out:?}");
            };
            assert!(
                m.starts_with("opcua opc.tcp://plc:4840/: ") && m.contains(why),
                "{m}"
            );
        }
    }

    #[test]
    fn notifications_before_the_read_are_held_until_the_start() {
        let plant = plant();
        let mut s = session(&plant);
        let at = Instant::now();
        let (mut out, mut send) = (Vec::new(), Vec::new());
        s.opened(vec![true; plant.flags().len()], &mut out);
        // C0 changes after the read's values were taken: its notification
        // comes before the read's answer.
        s.notice(
            data(1, vec![(0, at_ms(true, 1_020))]),
            at,
            &mut out,
            &mut send,
        );
        assert!(out.is_empty());
        let signals = vec![at_ms(false, 1_000); plant.signals.len()];
        s.read(&signals, &[], at + ms(100), &mut out, &mut send);
        assert!(
            matches!(out.as_slice(), [Item::Start(t, _)] if *t == 1_000 * MS),
            "{out:?}"
        );
        // Released once a message shows the watermark past it.
        s.notice(keep_alive(2), at + ms(200), &mut out, &mut send);
        assert!(
            out.iter()
                .any(|i| matches!(i, Item::Scan(e) if e[0].t == 1_020 * MS && e[0].value)),
            "{out:?}"
        );
    }

    #[test]
    fn a_change_far_ahead_loses_the_plant_but_not_the_first_after_a_start() {
        let plant = plant();
        let mut s = session(&plant);
        let at = Instant::now();
        started(&mut s, &plant, 1_000, at);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        // The plant was quiet for an hour before the read: its first change
        // sets the clock.
        let hour = 3_600_000;
        s.notice(
            data(1, vec![(0, at_ms(true, 1_000 + hour))]),
            at,
            &mut out,
            &mut send,
        );
        assert!(
            !out.iter()
                .any(|i| matches!(i, Item::Lost(..) | Item::FarAhead(_))),
            "{out:?}"
        );
        s.notice(
            data(2, vec![(1, at_ms(true, 1_000 + 2 * hour))]),
            at,
            &mut out,
            &mut send,
        );
        assert!(
            matches!(out.as_slice(), [.., Item::FarAhead(_), Item::Lost(..)]),
            "{out:?}"
        );
        assert_eq!(send, [Command::Reopen]);
    }

    #[test]
    fn flags_are_written_whole_and_again_after_a_refusal() {
        let plant = plant();
        let mut s = session(&plant);
        let at = Instant::now();
        let (_, mut send) = started(&mut s, &plant, 1_000, at);
        let (mut out, mut more) = (Vec::new(), Vec::new());
        // The start's write is answered: nothing was up, nothing to say.
        s.written(Ok(()), at, &mut out, &mut more);
        assert!(out.is_empty() && more.is_empty(), "{out:?} {more:?}");
        send.clear();
        let mut image = vec![false; plant.flags().len()];
        image[0] = true;
        s.flags(&image, at, &mut send);
        let [Command::Write(w)] = send.as_slice() else {
            panic!("{send:?}");
        };
        assert_eq!(w.len(), image.len());
        assert_eq!(w[0], (0, true));
        // Refused: a warning, and again after RESEND, not before.
        send.clear();
        s.written(
            Err("def_C4: BadUserAccessDenied".into()),
            at,
            &mut out,
            &mut send,
        );
        assert!(matches!(out.as_slice(), [Item::Warning(m)] if m.contains("BadUserAccessDenied")));
        assert!(send.is_empty());
        s.tick(at + RESEND / 2, &mut send);
        assert!(send.is_empty());
        s.tick(at + RESEND, &mut send);
        assert_eq!(send.len(), 1);
        out.clear();
        s.written(Ok(()), at + RESEND, &mut out, &mut send);
        let name = plant.flags()[0].to_string();
        assert!(
            matches!(out.as_slice(), [Item::FlagsWritten(up)] if *up == vec![name.clone()]),
            "{out:?}"
        );
        // Written: nothing more to write.
        send.clear();
        s.tick(at + RESEND * 3, &mut send);
        assert!(send.is_empty(), "{send:?}");
    }

    #[test]
    fn a_def_flag_read_up_is_kept_up() {
        let plant = plant();
        let mut s = session(&plant);
        let (mut out, mut send) = (Vec::new(), Vec::new());
        s.opened(vec![true; plant.flags().len()], &mut out);
        let signals = vec![at_ms(false, 5); plant.signals.len()];
        let mut flags = vec![Some(at_ms(false, 0)); plant.flags().len()];
        flags[2] = Some(at_ms(true, 0));
        s.read(&signals, &flags, Instant::now(), &mut out, &mut send);
        let name = plant.flags()[2].to_string();
        assert!(
            out.iter()
                .any(|i| matches!(i, Item::FoundRaised(f) if *f == vec![name.clone()])),
            "{out:?}"
        );
        let [Command::Write(w)] = send.as_slice() else {
            panic!("{send:?}");
        };
        assert!(w.contains(&(2, true)), "{w:?}");
    }

    proptest! {
        /// Any run of changes, in notification messages and keep-alives that
        /// arrive on the source's time (speed 1), some changes spread over
        /// two messages: the scans are the changes, each at its time, in
        /// plant-file order, repeats dropped; watermarks only grow, and no
        /// scan comes at or behind one already sent. A skipped sequence
        /// number is one loss, after which nothing goes out.
        #[test]
        fn notifications_in_sequence_are_the_scans(
            steps in proptest::collection::vec(
                (1i64..80, proptest::collection::vec((0usize..18, any::<bool>()), 0..4), any::<bool>()),
                1..40,
            ),
            gap in proptest::option::of(0usize..40),
        ) {
            let plant = plant();
            let n = plant.signals.len();
            let mut s = session(&plant);
            let base = Instant::now();
            let t0: Time = 1_000;
            started(&mut s, &plant, t0, base);
            let (mut out, mut send) = (Vec::new(), Vec::new());
            let mut values = vec![false; n];
            let mut expected: Vec<Vec<(Time, usize, bool)>> = Vec::new();
            let (mut t, mut seq) = (t0, 1u32);
            let mut lost = false;
            let arrive = |t: Time| base + Duration::from_millis((t - t0) as u64);
            for (k, (dt, changes, split)) in steps.iter().enumerate() {
                t += dt;
                if gap == Some(k) {
                    seq += 1;
                    lost = true;
                }
                let changes: Vec<(usize, Reading)> =
                    changes.iter().map(|&(i, v)| (i % n, at_ms(v, t))).collect();
                // A server may publish the changes of one time in two messages.
                let cut = if *split { changes.len() / 2 } else { changes.len() };
                for part in [&changes[..cut], &changes[cut..]] {
                    if part.is_empty() {
                        s.notice(keep_alive(seq), arrive(t), &mut out, &mut send);
                    } else {
                        s.notice(data(seq, part.to_vec()), arrive(t), &mut out, &mut send);
                        seq += 1;
                    }
                }
                if !lost {
                    let mut scan: Vec<(Time, usize, bool)> = Vec::new();
                    for (i, r) in &changes {
                        let Value::Bool(v) = r.value else { unreachable!() };
                        match scan.iter_mut().find(|e| e.1 == *i) {
                            Some(e) => e.2 = v,
                            None => scan.push((t * MS, *i, v)),
                        }
                    }
                    scan.sort_by_key(|e| e.1);
                    scan.retain(|e| values[e.1] != e.2);
                    for e in &scan {
                        values[e.1] = e.2;
                    }
                    if !scan.is_empty() {
                        expected.push(scan);
                    }
                }
            }
            // A keep-alive well after the end releases every scan left.
            s.notice(keep_alive(seq), arrive(t + 1_000), &mut out, &mut send);
            let scans: Vec<Vec<(Time, usize, bool)>> = out
                .iter()
                .filter_map(|i| match i {
                    Item::Scan(e) => Some(e.iter().map(|e| (e.t, e.signal.index(), e.value)).collect()),
                    _ => None,
                })
                .collect();
            let losses = out.iter().filter(|i| matches!(i, Item::Lost(..))).count();
            prop_assert_eq!(losses, usize::from(lost));
            prop_assert_eq!(send.contains(&Command::Reopen), lost);
            if !lost {
                prop_assert_eq!(scans, expected);
            }
            let mut last: Option<Time> = None;
            for i in &out {
                match i {
                    Item::Watermark(w) => {
                        prop_assert!(last.is_none_or(|l| *w > l));
                        last = Some(*w);
                    }
                    Item::Scan(e) => prop_assert!(last.is_none_or(|l| e[0].t > l)),
                    _ => {}
                }
            }
        }
    }
}
