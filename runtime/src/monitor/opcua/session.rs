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
//! are one scan. The source's clock is anchored at the latest SourceTimestamp
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
//! **Losses.** Notification messages carry sequence numbers, one more for
//! each message with data; a keep-alive carries the next one. A number that
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
        self.expect = None;
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
