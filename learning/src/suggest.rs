//! Part suggestion: which sensors follow which actuator, from logs alone.
//!
//! A plant file groups signals into parts (an actuator and the sensors that see
//! what it moves). Writing that grouping needs knowledge of the plant; this
//! module proposes one from recorded behaviour, for an engineer to review.
//!
//! # Method
//!
//! For an actuator `a` and a sensor `s`, every edge of `a` opens a window that
//! closes at `a`'s next edge; the first edge of `s` in that window is its
//! *follower*. A sensor edge in the same timestamp as the actuator edge does not
//! follow it: within one PLC scan the inputs are read before the outputs are
//! written, so such a sensor edge was caused by something else (often it is the
//! cause of the actuator edge). A follower later than
//! [`SuggestOptions::max_delay`] does not count either.
//!
//! `s` is a candidate for `a` when:
//! 1. in each direction (rising, falling) in which `s` has edges, at least
//!    [`SuggestOptions::follower_share`] of them are the follower of an edge of
//!    `a` (what `a` does explains nearly everything `s` does); and
//! 2. for each pair of directions (edge of `a`, edge of `s`) that occurs — that
//!    accounts for at least [`SuggestOptions::min_pair_share`] of `s`'s edges in
//!    its direction, rarer pairs being within the tolerance of 1. — the delays
//!    are concentrated: `q95 − q05 ≤ max(spread_ratio × q50, min_spread)`. The
//!    relative term is the one of the textbook criterion; the absolute floor is
//!    there because short delays carry an absolute jitter (scan quantisation,
//!    valve and contact play) that no ratio captures: on the sorting line the
//!    turntable leaves C4 30 to 130 ms after its order, a spread of 100 ms around
//!    80 ms, yet C4 belongs to the turntable beyond doubt. Independent signals
//!    give followers spread over the whole window between two actuator edges,
//!    seconds to minutes, and fail both terms.
//!
//! A sensor goes to the candidate whose own edges are most often followed by an
//! edge of the sensor (the converse of 1.). Orders come in chains, and an order
//! given in the same scan as another explains the sensor just as well by 1. and
//! 2.: on the sorting line the rollers (A2) stop in the very scan the turntable
//! (A4) starts, so C4's edges follow A2's as closely as A4's. But every edge of
//! A4 moves the turntable off or onto C4, while a third of A2's edges (the
//! starts and stops of loading and evacuation that do not coincide with A4) are
//! followed by nothing on C4. Among candidates within
//! [`SuggestOptions::share_tie`] of the best such share, the shortest typical
//! delay (median delay averaged over the pairs, weighted by count) wins: the
//! last order before an edge is its most direct cause. Each actuator becomes
//! one part, with the sensors it won, possibly none.
//!
//! # Inputs
//!
//! A sensor that follows no actuator sees what the part does not move: a
//! workpiece arriving, an operator's refill, the next machine. The control
//! reacts to such a sensor instead, so it is read the other way round: every
//! edge of the sensor opens a window that closes at its next edge, and the
//! first edge of each actuator in that window (in the same scan included: the
//! PLC writes its outputs after reading its inputs) is a *reaction* to it, if
//! no later than [`SuggestOptions::max_delay`]. The sensor becomes an input
//! (the plant file's `inputs`) of the part whose actuator reacts to the largest
//! share of its edges in one direction, if that share is at least
//! [`SuggestOptions::follower_share`]; the earlier actuator on a tie. A sensor
//! that neither follows nor leads any actuator stays out of every part, and the
//! suggestion says, per sensor, how close it came.
//!
//! # Memory
//!
//! Logs are streamed batch by batch. What is kept is, per actuator, its last
//! edge; per (actuator, sensor), whether the window has had its follower, follower
//! counts and, allocated when the pair first occurs, four log-scale histograms of
//! delays (2 % wide bins from `max_delay / 10⁵` to `max_delay`, about 2 KiB
//! each). That is independent of the logs' length.

use std::fmt::Write as _;

use vocabulary::{Event, Located, Location, MS, SECOND, SignalId, SignalKind, SignalTable, Time};

use logs::LogStream;

/// Thresholds of the suggestion (see the [module documentation](self)).
#[derive(Debug, Clone, PartialEq)]
pub struct SuggestOptions {
    /// Share of a sensor's edges, in each direction, that must follow an edge of
    /// the actuator (default 0.9).
    pub follower_share: f64,
    /// Longest delay from an actuator edge to its follower (default 10 s).
    pub max_delay: Time,
    /// Largest `(q95 − q05) / q50` of a pair's delays (default 0.2)...
    pub spread_ratio: f64,
    /// ...unless `q95 − q05` is at most this (default 250 ms).
    pub min_spread: Time,
    /// Fewest edges a sensor needs before anything is concluded about it
    /// (default 10).
    pub min_edges: u64,
    /// Share of a sensor's edges in one direction below which a pair of
    /// directions is too rare to judge its delays (default 0.05).
    pub min_pair_share: f64,
    /// Candidates whose share of actuator edges followed by the sensor is within
    /// this of the best are ranked by delay instead (default 0.05).
    pub share_tie: f64,
}

impl Default for SuggestOptions {
    fn default() -> Self {
        SuggestOptions {
            follower_share: 0.9,
            max_delay: 10 * SECOND,
            spread_ratio: 0.2,
            min_spread: 250 * MS,
            min_edges: 10,
            min_pair_share: 0.05,
            share_tie: 0.05,
        }
    }
}

/// One suggested part.
#[derive(Debug, Clone, PartialEq)]
pub struct SuggestedPart {
    /// Its name, `part_<actuator>`.
    pub name: String,
    /// Its actuators (one).
    pub actuators: Vec<SignalId>,
    /// The sensors that follow them, in signal order.
    pub sensors: Vec<SignalId>,
    /// Why each sensor is here, in the order of `sensors`.
    pub evidence: Vec<SensorEvidence>,
    /// Sensors the actuators react to (the part's inputs), in signal order,
    /// with why.
    pub inputs: Vec<InputEvidence>,
    /// Sensors whose edges follow the actuator in one direction only (the
    /// other direction is free: an operator, a workpiece), in signal order.
    pub half: Vec<HalfFollower>,
}

/// How an actuator reacts to a sensor's edges.
#[derive(Debug, Clone, PartialEq)]
pub struct InputEvidence {
    /// The sensor.
    pub sensor: SignalId,
    /// The actuator that reacts to it most.
    pub actuator: SignalId,
    /// The sensor's falling and rising edges, in all logs.
    pub edges: [u64; 2],
    /// How many of them an edge of the actuator follows, indexed like `edges`.
    pub reactions: [u64; 2],
    /// The reactions' delays in the direction with the larger share: median,
    /// 5th and 95th percentiles.
    pub delays: Option<DelayStats>,
}

impl InputEvidence {
    /// Share of the sensor's rising (`true`) or falling edges an edge of the
    /// actuator follows (0 when it has none in that direction).
    pub fn share(&self, rising: bool) -> f64 {
        let i = usize::from(rising);
        self.reactions[i] as f64 / self.edges[i].max(1) as f64
    }

    /// The larger of the two shares.
    pub fn best_share(&self) -> f64 {
        self.share(true).max(self.share(false))
    }
}

/// Why a sensor was put with an actuator.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorEvidence {
    /// The sensor.
    pub sensor: SignalId,
    /// The actuator it follows.
    pub actuator: SignalId,
    /// Its rising and falling edges, in all logs.
    pub edges: [u64; 2],
    /// How many of them follow an edge of the actuator, indexed like `edges`.
    pub followers: [u64; 2],
    /// The actuator's edges, in all logs (each followed by at most one edge of
    /// the sensor, so `followers[0] + followers[1]` of them are followed).
    pub actuator_edges: u64,
    /// The delays of each pair of directions that occurs.
    pub delays: Vec<DelayStats>,
    /// The typical delay that ranked this actuator first (median delay
    /// averaged over the pairs, weighted by count).
    pub typical_delay: Time,
}

impl SensorEvidence {
    /// Share of the sensor's rising (`true`) or falling edges that follow an edge
    /// of the actuator (1 when it has none in that direction).
    pub fn share(&self, rising: bool) -> f64 {
        let i = usize::from(rising);
        if self.edges[i] == 0 {
            1.0
        } else {
            self.followers[i] as f64 / self.edges[i] as f64
        }
    }

    /// Share of the actuator's edges followed by an edge of the sensor.
    pub fn actuator_share(&self) -> f64 {
        let followed = self.followers[0] + self.followers[1];
        followed as f64 / self.actuator_edges.max(1) as f64
    }
}

/// Delays from edges of an actuator to the edges of a sensor that follow them,
/// for one pair of directions. Quantiles are exact to 2 %.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DelayStats {
    /// Direction of the actuator's edges (`true`: rising).
    pub actuator_rising: bool,
    /// Direction of the sensor's edges.
    pub sensor_rising: bool,
    /// Number of delays.
    pub count: u64,
    /// 5th percentile.
    pub q05: Time,
    /// Median.
    pub q50: Time,
    /// 95th percentile.
    pub q95: Time,
}

/// The suggested parts, and the sensors left out of all of them.
#[derive(Debug, Clone, PartialEq)]
pub struct Suggestion {
    /// One part per actuator.
    pub parts: Vec<SuggestedPart>,
    /// Per sensor in no part that follows no actuator in either direction,
    /// the actuator that reacts to it most, and how often (`reactions` 0 when
    /// none ever does).
    pub unplaced: Vec<InputEvidence>,
}

/// A sensor whose edges follow an actuator's in one direction at a time.
#[derive(Debug, Clone, PartialEq)]
pub struct HalfFollower {
    /// The sensor.
    pub sensor: SignalId,
    /// The actuator its falling edges follow, if any.
    pub falling: Option<SignalId>,
    /// The actuator its rising edges follow, if any.
    pub rising: Option<SignalId>,
}

/// Suggests parts from `logs`, read one after the other (edges never pair
/// across logs). Every actuator of `signals` gets one part, with the sensors
/// that follow it best and the sensors it reacts to (its inputs); sensors that
/// do neither closely are in no part.
///
/// Fails on the first error of a log, or if a log does not fit `signals` (wrong
/// number of initial values, unknown signal ids, events out of time order).
pub fn suggest_parts(
    signals: &SignalTable,
    logs: Vec<LogStream>,
    options: &SuggestOptions,
) -> Result<Suggestion, Located> {
    let mut stats = Stats::new(signals, options);
    for log in logs {
        stats.read(log)?;
    }
    Ok(stats.suggestion(signals, options))
}

/// Prints the parts as `[[parts]]` blocks of a plant file, with the evidence as
/// comments, and the sensors left out, with how close each came, as a final
/// comment.
pub fn to_toml(suggestion: &Suggestion, signals: &SignalTable) -> String {
    let (parts, unplaced) = (&suggestion.parts, &suggestion.unplaced);
    let mut out = String::from(
        "# Parts suggested by gardefou from logs alone: review them before use.\n\
         # A sensor is put with the actuator whose edges it follows most consistently.\n",
    );
    let names = |ids: &[SignalId]| {
        ids.iter()
            .map(|&id| toml_string(signals.name(id)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let ms = approx_ms;
    let edge = |rising: bool, name: &str| vocabulary::model::edge_name(name, rising);
    for part in parts {
        // `writeln!` into a String cannot fail.
        let _ = writeln!(out, "\n[[parts]]");
        let _ = writeln!(out, "name = {}", toml_string(&part.name));
        let _ = writeln!(out, "actuators = [{}]", names(&part.actuators));
        let inputs: Vec<SignalId> = part.inputs.iter().map(|e| e.sensor).collect();
        let mut sensors = part.sensors.clone();
        sensors.extend(&inputs);
        sensors.extend(part.half.iter().map(|h| h.sensor));
        sensors.sort_unstable();
        let _ = writeln!(out, "sensors = [{}]", names(&sensors));
        if !inputs.is_empty() {
            let _ = writeln!(out, "inputs = [{}]", names(&inputs));
        }
        for h in &part.half {
            let name = signals.name(h.sensor);
            let _ = match (h.rising, h.falling) {
                (Some(r), Some(f)) => writeln!(
                    out,
                    "# {name}: its rising edges follow {} and its falling edges {}: one part holds both orders",
                    signals.name(r),
                    signals.name(f)
                ),
                (Some(a), None) | (None, Some(a)) => {
                    let (moved, free) = if h.rising.is_some() {
                        ("rising", "falling")
                    } else {
                        ("falling", "rising")
                    };
                    writeln!(
                        out,
                        "# {name}: its {moved} edges follow {}, its {free} edges no order (an input that way): learning tells which edges the part causes",
                        signals.name(a)
                    )
                }
                (None, None) => Ok(()),
            };
        }
        for e in &part.inputs {
            let _ = writeln!(
                out,
                "# {} (input): follows no actuator; {}: the control reacts to it",
                signals.name(e.sensor),
                reactions(e, signals)
            );
        }
        for e in &part.evidence {
            let (s, a) = (signals.name(e.sensor), signals.name(e.actuator));
            let _ = writeln!(
                out,
                "# {s}: {}/{} rising and {}/{} falling edges follow an edge of {a}; {}/{} edges of {a} are followed by one of {s}",
                e.followers[1],
                e.edges[1],
                e.followers[0],
                e.edges[0],
                e.followers[0] + e.followers[1],
                e.actuator_edges
            );
            for d in &e.delays {
                let _ = writeln!(
                    out,
                    "#   {} -> {}: {} times, median {}, 90 % within [{}, {}]",
                    edge(d.actuator_rising, a),
                    edge(d.sensor_rising, s),
                    d.count,
                    ms(d.q50),
                    ms(d.q05),
                    ms(d.q95)
                );
            }
        }
    }
    let placed: Vec<SignalId> = parts
        .iter()
        .flat_map(|p| {
            p.sensors
                .iter()
                .copied()
                .chain(p.inputs.iter().map(|e| e.sensor))
                .chain(p.half.iter().map(|h| h.sensor))
        })
        .collect();
    let left: Vec<&str> = signals
        .iter()
        .filter(|(id, s)| s.kind == SignalKind::Sensor && !placed.contains(id))
        .map(|(_, s)| s.name.as_str())
        .collect();
    if !left.is_empty() {
        let _ = writeln!(
            out,
            "\n# Sensors in no part (they neither follow an actuator nor lead one closely enough): {}",
            left.join(", ")
        );
        for e in unplaced {
            let _ = writeln!(
                out,
                "#   {}: at best {}",
                signals.name(e.sensor),
                reactions(e, signals)
            );
        }
    }
    out
}

/// `a/b rising and c/d falling edges of S are followed by an edge of A`.
fn reactions(e: &InputEvidence, signals: &SignalTable) -> String {
    let mut text = format!(
        "{}/{} rising and {}/{} falling edges of it are followed by an edge of {}",
        e.reactions[1],
        e.edges[1],
        e.reactions[0],
        e.edges[0],
        signals.name(e.actuator)
    );
    if let Some(d) = e.delays.filter(|d| d.q95 == 0) {
        let side = if d.sensor_rising { "rising" } else { "falling" };
        let _ = write!(text, " (the {side} ones in the same scan)");
    } else if let Some(d) = &e.delays {
        let _ = write!(
            text,
            " ({} edges: median {}, 90 % within [{}, {}])",
            if d.sensor_rising { "rising" } else { "falling" },
            approx_ms(d.q50),
            approx_ms(d.q05),
            approx_ms(d.q95)
        );
    }
    text
}

/// Merges the parts of each pair of actuators in `merges` (and transitively),
/// in the order of their first actuator, named after all their actuators.
fn merged(parts: Vec<SuggestedPart>, merges: &[(usize, usize)]) -> Vec<SuggestedPart> {
    let mut root: Vec<usize> = (0..parts.len()).collect();
    fn find(root: &mut [usize], mut x: usize) -> usize {
        while root[x] != x {
            root[x] = root[root[x]];
            x = root[x];
        }
        x
    }
    for &(a, b) in merges {
        let (ra, rb) = (find(&mut root, a), find(&mut root, b));
        root[ra.max(rb)] = ra.min(rb);
    }
    let mut out: Vec<SuggestedPart> = Vec::new();
    let mut at: Vec<Option<usize>> = vec![None; parts.len()];
    for (i, part) in parts.into_iter().enumerate() {
        let r = find(&mut root, i);
        match at[r] {
            None => {
                at[r] = Some(out.len());
                out.push(part);
            }
            Some(k) => {
                let into = &mut out[k];
                into.name.push_str(part.name.trim_start_matches("part"));
                into.actuators.extend(part.actuators);
                into.sensors.extend(part.sensors);
                into.evidence.extend(part.evidence);
                into.inputs.extend(part.inputs);
                into.half.extend(part.half);
            }
        }
    }
    for part in &mut out {
        let mut placed: Vec<(SignalId, SensorEvidence)> = part
            .sensors
            .drain(..)
            .zip(part.evidence.drain(..))
            .collect();
        placed.sort_by_key(|(s, _)| *s);
        (part.sensors, part.evidence) = placed.into_iter().unzip();
        part.inputs.sort_by_key(|e| e.sensor);
        part.half.sort_by_key(|h| h.sensor);
    }
    out
}

/// A delay in milliseconds to three significant digits or so: the quantiles
/// are exact to 2 %, and more digits would pretend otherwise.
fn approx_ms(t: Time) -> String {
    let ms = t as f64 / MS as f64;
    let decimals = if ms >= 100.0 {
        0
    } else if ms >= 10.0 {
        1
    } else {
        2
    };
    format!("{ms:.decimals$} ms")
}

/// A TOML basic string.
fn toml_string(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Log-scale bins of delays.
#[derive(Debug, Clone, Copy)]
struct Bins {
    /// Lower end: delays up to it share bin 0.
    low: f64,
    /// ln of the ratio of consecutive bin edges.
    ln_ratio: f64,
    count: usize,
}

impl Bins {
    /// 2 % wide bins from `max / 10⁵` to `max`.
    fn new(max: Time) -> Self {
        let max = max.max(1) as f64;
        let low = (max / 1e5).max(1.0);
        let ln_ratio = 1.02f64.ln();
        let count = ((max / low).ln() / ln_ratio).ceil() as usize + 2;
        Bins {
            low,
            ln_ratio,
            count,
        }
    }

    fn bin(&self, delay: Time) -> usize {
        let d = delay as f64;
        if d <= self.low {
            0
        } else {
            (((d / self.low).ln() / self.ln_ratio).ceil() as usize).min(self.count - 1)
        }
    }

    /// The middle of bin `b` (geometric, as the bins are); 0 for bin 0, which
    /// holds the delays too short to tell apart, chiefly the same scan's.
    fn value(&self, b: usize) -> Time {
        if b == 0 {
            0
        } else {
            (self.low * ((b as f64 - 0.5) * self.ln_ratio).exp()).round() as Time
        }
    }

    /// The `q` quantile of the counts `h`, whose sum is `total`.
    fn quantile(&self, h: &[u32], total: u64, q: f64) -> Time {
        // The rank of the quantile among the sorted delays, from 1.
        let rank = ((q * total as f64).ceil() as u64).clamp(1, total.max(1));
        let mut seen = 0u64;
        for (b, &c) in h.iter().enumerate() {
            seen += u64::from(c);
            if seen >= rank {
                return self.value(b);
            }
        }
        self.value(h.len().saturating_sub(1))
    }
}

/// What a sensor edge is attributed to: per actuator, its last edge.
struct Stats {
    actuators: Vec<SignalId>,
    sensors: Vec<SignalId>,
    /// Position of each signal in `actuators` or `sensors`.
    role: Vec<Role>,
    max_delay: Time,
    bins: Bins,
    /// Per sensor, its falling and rising edges.
    edges: Vec<[u64; 2]>,
    /// Per actuator, its edges.
    actuator_edges: Vec<u64>,
    /// Per (actuator, sensor): its followers, by sensor direction.
    followers: Vec<[u64; 2]>,
    /// Per (actuator, sensor, actuator direction, sensor direction): delays.
    histograms: Vec<Option<Box<[u32]>>>,
    counts: Vec<u64>,
    /// Per (actuator, sensor): the sensor's edges an edge of the actuator
    /// reacts to, by sensor direction.
    reactions: Vec<[u64; 2]>,
    /// Per (actuator, sensor, sensor direction): delays of the reactions.
    reaction_delays: Vec<Option<Box<[u32]>>>,
}

#[derive(Debug, Clone, Copy)]
enum Role {
    Actuator(usize),
    Sensor(usize),
}

/// The state of the log being read.
struct LogState {
    values: Vec<bool>,
    /// Per actuator: time and direction of its last edge.
    last: Vec<Option<(Time, bool)>>,
    /// Per (actuator, sensor): whether the actuator's window has had its follower.
    matched: Vec<bool>,
    /// Per sensor: time and direction of its last edge.
    last_sensor: Vec<Option<(Time, bool)>>,
    /// Per (actuator, sensor): whether the sensor's window has had its reaction.
    reacted: Vec<bool>,
    /// The events of the scan being gathered.
    scan: Vec<Event>,
}

impl Stats {
    fn new(signals: &SignalTable, options: &SuggestOptions) -> Self {
        let actuators: Vec<SignalId> = signals.of_kind(SignalKind::Actuator).collect();
        let sensors: Vec<SignalId> = signals.of_kind(SignalKind::Sensor).collect();
        let mut role = vec![Role::Sensor(0); signals.len()];
        for (i, &a) in actuators.iter().enumerate() {
            role[a.index()] = Role::Actuator(i);
        }
        for (i, &s) in sensors.iter().enumerate() {
            role[s.index()] = Role::Sensor(i);
        }
        let pairs = actuators.len() * sensors.len();
        Stats {
            max_delay: options.max_delay,
            bins: Bins::new(options.max_delay),
            edges: vec![[0; 2]; sensors.len()],
            actuator_edges: vec![0; actuators.len()],
            followers: vec![[0; 2]; pairs],
            histograms: vec![None; pairs * 4],
            counts: vec![0; pairs * 4],
            reactions: vec![[0; 2]; pairs],
            reaction_delays: vec![None; pairs * 2],
            actuators,
            sensors,
            role,
        }
    }

    fn pair(&self, a: usize, s: usize) -> usize {
        a * self.sensors.len() + s
    }

    fn read(&mut self, log: LogStream) -> Result<(), Located> {
        let n = self.role.len();
        let whole = |message: String| Located::new(Location::new(&log.path, 0, 0), message);
        if log.initial.len() != n {
            return Err(whole(format!(
                "the log has {} initial values for {n} signals",
                log.initial.len()
            )));
        }
        let mut state = LogState {
            values: log.initial.clone(),
            last: vec![None; self.actuators.len()],
            matched: vec![false; self.actuators.len() * self.sensors.len()],
            last_sensor: vec![None; self.sensors.len()],
            reacted: vec![false; self.actuators.len() * self.sensors.len()],
            scan: Vec::new(),
        };
        let mut previous = log.start;
        for batch in log.batches {
            for event in batch? {
                if event.signal.index() >= n {
                    return Err(whole(format!(
                        "event for signal id {}, but there are only {n} signals",
                        event.signal.0
                    )));
                }
                if event.t < previous {
                    return Err(whole(format!(
                        "events out of time order: {} ns after {} ns",
                        event.t, previous
                    )));
                }
                if event.t != previous && !state.scan.is_empty() {
                    self.scan(&mut state);
                }
                previous = event.t;
                state.scan.push(event);
            }
        }
        self.scan(&mut state);
        Ok(())
    }

    /// Takes in one scan's events: sensor edges first, since they cannot have
    /// been caused by the actuator edges of the same scan.
    fn scan(&mut self, state: &mut LogState) {
        let mut scan = std::mem::take(&mut state.scan);
        for event in &scan {
            let i = event.signal.index();
            if state.values[i] == event.value {
                continue;
            }
            if let Role::Sensor(s) = self.role[i] {
                self.sensor_edge(state, s, event.t, event.value);
            }
        }
        for event in &scan {
            let i = event.signal.index();
            if state.values[i] == event.value {
                continue;
            }
            state.values[i] = event.value;
            if let Role::Actuator(a) = self.role[i] {
                state.last[a] = Some((event.t, event.value));
                self.actuator_edges[a] += 1;
                let row = self.pair(a, 0);
                state.matched[row..row + self.sensors.len()].fill(false);
                self.reaction(state, a, event.t);
            }
        }
        scan.clear();
        state.scan = scan;
    }

    /// An edge of actuator `a` at `t`: the reaction to every sensor whose
    /// window is open and has had none from `a`.
    fn reaction(&mut self, state: &mut LogState, a: usize, t: Time) {
        for s in 0..self.sensors.len() {
            let p = self.pair(a, s);
            let Some((t_s, rising)) = state.last_sensor[s] else {
                continue;
            };
            if state.reacted[p] || t - t_s > self.max_delay {
                continue;
            }
            state.reacted[p] = true;
            self.reactions[p][usize::from(rising)] += 1;
            let bins = self.bins;
            let h = self.reaction_delays[p * 2 + usize::from(rising)]
                .get_or_insert_with(|| vec![0; bins.count].into_boxed_slice());
            let b = bins.bin(t - t_s);
            h[b] = h[b].saturating_add(1);
        }
    }

    fn sensor_edge(&mut self, state: &mut LogState, s: usize, t: Time, rising: bool) {
        let d = usize::from(rising);
        self.edges[s][d] += 1;
        state.last_sensor[s] = Some((t, rising));
        for a in 0..self.actuators.len() {
            let p = self.pair(a, s);
            state.reacted[p] = false;
        }
        for a in 0..self.actuators.len() {
            let p = self.pair(a, s);
            let Some((t_a, a_rising)) = state.last[a] else {
                continue;
            };
            if state.matched[p] {
                continue;
            }
            state.matched[p] = true;
            let delay = t - t_a;
            if delay > self.max_delay {
                continue;
            }
            self.followers[p][d] += 1;
            let k = p * 4 + usize::from(a_rising) * 2 + d;
            let bins = self.bins;
            let h =
                self.histograms[k].get_or_insert_with(|| vec![0; bins.count].into_boxed_slice());
            let b = bins.bin(delay);
            h[b] = h[b].saturating_add(1);
            self.counts[k] += 1;
        }
    }

    /// The evidence for `s` following `a`, if it is a candidate.
    fn candidate(&self, a: usize, s: usize, options: &SuggestOptions) -> Option<SensorEvidence> {
        let p = self.pair(a, s);
        let edges = self.edges[s];
        if edges[0] + edges[1] < options.min_edges {
            return None;
        }
        let followers = self.followers[p];
        for d in 0..2 {
            if edges[d] > 0 && (followers[d] as f64) < options.follower_share * edges[d] as f64 {
                return None;
            }
        }
        let (delays, typical_delay) = self.pair_delays(p, 0..4, edges, options)?;
        if delays.is_empty() {
            return None;
        }
        Some(SensorEvidence {
            sensor: self.sensors[s],
            actuator: self.actuators[a],
            edges,
            followers,
            actuator_edges: self.actuator_edges[a],
            delays,
            typical_delay,
        })
    }

    /// The delays of pair `p` for the (actuator direction × 2 + sensor
    /// direction) indices `ks`, leaving out those too rare to judge (criterion
    /// 2.), with their typical delay (median averaged over them, weighted by
    /// count); `None` when one is spread.
    fn pair_delays(
        &self,
        p: usize,
        ks: impl IntoIterator<Item = usize>,
        edges: [u64; 2],
        options: &SuggestOptions,
    ) -> Option<(Vec<DelayStats>, Time)> {
        let mut delays = Vec::new();
        let (mut weighted, mut weight) = (0f64, 0u64);
        for k in ks {
            let (a_rising, d) = (k / 2 == 1, k % 2);
            let count = self.counts[p * 4 + k];
            let Some(h) = &self.histograms[p * 4 + k] else {
                continue;
            };
            if count == 0 || (count as f64) < options.min_pair_share * edges[d] as f64 {
                continue;
            }
            let q = |x| self.bins.quantile(h, count, x);
            let (q05, q50, q95) = (q(0.05), q(0.5), q(0.95));
            let allowed = (options.spread_ratio * q50 as f64).max(options.min_spread as f64);
            if (q95 - q05) as f64 > allowed {
                return None;
            }
            weighted += q50 as f64 * count as f64;
            weight += count;
            delays.push(DelayStats {
                actuator_rising: a_rising,
                sensor_rising: d == 1,
                count,
                q05,
                q50,
                q95,
            });
        }
        let typical = if weight == 0 {
            0
        } else {
            (weighted / weight as f64).round() as Time
        };
        Some((delays, typical))
    }

    /// If `s`'s edges in direction `d` follow `a`'s (criteria 1. and 2. of
    /// the [module documentation](self) in that direction alone), their
    /// typical delay.
    fn follows_in(&self, a: usize, s: usize, d: usize, options: &SuggestOptions) -> Option<Time> {
        let p = self.pair(a, s);
        let edges = self.edges[s][d];
        if edges == 0 || (self.followers[p][d] as f64) < options.follower_share * edges as f64 {
            return None;
        }
        let (delays, typical) = self.pair_delays(p, [d, 2 + d], self.edges[s], options)?;
        (!delays.is_empty()).then_some(typical)
    }

    /// Per direction (falling, rising), the actuator whose edges `s`'s edges
    /// follow in that direction alone with the shortest typical delay (the
    /// most direct cause, as for whole sensors).
    fn followed_by_direction(&self, s: usize, options: &SuggestOptions) -> [Option<usize>; 2] {
        [0, 1].map(|d| {
            (0..self.actuators.len())
                .filter_map(|a| self.follows_in(a, s, d, options).map(|t| (t, a)))
                .min()
                .map(|(_, a)| a)
        })
    }

    /// How `a` reacts to `s`: the shares, and the delays in the direction
    /// with the larger share.
    fn reaction_evidence(&self, a: usize, s: usize) -> InputEvidence {
        let p = self.pair(a, s);
        let mut e = InputEvidence {
            sensor: self.sensors[s],
            actuator: self.actuators[a],
            edges: self.edges[s],
            reactions: self.reactions[p],
            delays: None,
        };
        let rising = e.share(true) >= e.share(false);
        let d = usize::from(rising);
        if let Some(h) = &self.reaction_delays[p * 2 + d] {
            let count = e.reactions[d];
            let q = |x| self.bins.quantile(h, count, x);
            e.delays = Some(DelayStats {
                actuator_rising: rising,
                sensor_rising: rising,
                count,
                q05: q(0.05),
                q50: q(0.5),
                q95: q(0.95),
            });
        }
        e
    }

    /// The actuator that reacts, with concentrated delays, to the largest share
    /// of `s`'s edges in one direction; the earlier on a tie. Without any
    /// concentrated reaction, the largest share, for the record.
    fn best_reaction(
        &self,
        s: usize,
        options: &SuggestOptions,
    ) -> Option<(usize, InputEvidence, bool)> {
        let concentrated = |e: &InputEvidence| {
            e.delays.is_some_and(|d| {
                let allowed = (options.spread_ratio * d.q50 as f64).max(options.min_spread as f64);
                ((d.q95 - d.q05) as f64) <= allowed
            })
        };
        (0..self.actuators.len())
            .map(|a| {
                let e = self.reaction_evidence(a, s);
                let ok = concentrated(&e);
                (a, e, ok)
            })
            .rev()
            .max_by(|(_, x, ok_x), (_, y, ok_y)| {
                ok_x.cmp(ok_y)
                    .then(x.best_share().total_cmp(&y.best_share()))
            })
    }

    fn suggestion(&self, signals: &SignalTable, options: &SuggestOptions) -> Suggestion {
        let mut parts = self.parts(signals, options);
        let placed: Vec<SignalId> = parts
            .iter()
            .flat_map(|p| p.sensors.iter().copied())
            .collect();
        let mut unplaced = Vec::new();
        let mut merges = Vec::new();
        for s in 0..self.sensors.len() {
            if placed.contains(&self.sensors[s]) {
                continue;
            }
            let followed = self.followed_by_direction(s, options);
            match followed {
                [Some(a), None] | [None, Some(a)] => {
                    // Moved by the part one way, free the other: a sensor of
                    // the part, which learning classifies edge by edge.
                    parts[a].half.push(HalfFollower {
                        sensor: self.sensors[s],
                        falling: followed[0].map(|a| self.actuators[a]),
                        rising: followed[1].map(|a| self.actuators[a]),
                    });
                    continue;
                }
                [Some(a), Some(b)] => {
                    // Moved one way by one order and back by another (a
                    // double-acting valve): one part with both orders.
                    parts[a].half.push(HalfFollower {
                        sensor: self.sensors[s],
                        falling: Some(self.actuators[a]),
                        rising: Some(self.actuators[b]),
                    });
                    merges.push((a, b));
                    continue;
                }
                [None, None] => {}
            }
            let Some((a, e, concentrated)) = self.best_reaction(s, options) else {
                continue;
            };
            let enough = e.edges[0] + e.edges[1] >= options.min_edges;
            if enough && concentrated && e.best_share() >= options.follower_share {
                parts[a].inputs.push(e);
            } else {
                unplaced.push(e);
            }
        }
        Suggestion {
            parts: merged(parts, &merges),
            unplaced,
        }
    }

    fn parts(&self, signals: &SignalTable, options: &SuggestOptions) -> Vec<SuggestedPart> {
        let mut parts: Vec<SuggestedPart> = self
            .actuators
            .iter()
            .map(|&a| SuggestedPart {
                name: format!("part_{}", signals.name(a)),
                actuators: vec![a],
                sensors: Vec::new(),
                evidence: Vec::new(),
                inputs: Vec::new(),
                half: Vec::new(),
            })
            .collect();
        for s in 0..self.sensors.len() {
            let candidates: Vec<(usize, SensorEvidence)> = (0..self.actuators.len())
                .filter_map(|a| self.candidate(a, s, options).map(|e| (a, e)))
                .collect();
            let top = candidates
                .iter()
                .map(|(_, e)| e.actuator_share())
                .fold(0.0, f64::max);
            let best = candidates
                .into_iter()
                .filter(|(_, e)| e.actuator_share() >= top - options.share_tie)
                // Shortest typical delay; the earlier actuator on a tie.
                .min_by_key(|(a, e)| (e.typical_delay, *a));
            if let Some((a, evidence)) = best {
                parts[a].sensors.push(self.sensors[s]);
                parts[a].evidence.push(evidence);
            }
        }
        parts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_are_two_percent_wide() {
        let bins = Bins::new(10 * SECOND);
        for d in [MS, 80 * MS, 2_925 * MS, 10 * SECOND] {
            let v = bins.value(bins.bin(d));
            assert!((v - d).abs() as f64 <= 0.011 * d as f64, "{d} ns → {v} ns");
        }
        assert_eq!(bins.bin(1), 0);
        assert!(bins.count < 700, "{} bins", bins.count);
    }

    #[test]
    fn quantiles_of_a_histogram() {
        let bins = Bins::new(10 * SECOND);
        let mut h = vec![0u32; bins.count];
        for ms in 1..=100 {
            h[bins.bin(ms * MS)] += 1;
        }
        let near = |t: Time, ms: Time| (t - ms * MS).abs() as f64 <= 0.02 * (ms * MS) as f64;
        assert!(near(bins.quantile(&h, 100, 0.05), 5));
        assert!(near(bins.quantile(&h, 100, 0.5), 50));
        assert!(near(bins.quantile(&h, 100, 0.95), 95));
    }

    #[test]
    fn delays_are_shown_to_their_precision() {
        assert_eq!(approx_ms(2_936_224_312), "2936 ms");
        assert_eq!(approx_ms(79_902_059), "79.9 ms");
        assert_eq!(approx_ms(1_234_567), "1.23 ms");
    }

    #[test]
    fn toml_strings_are_escaped() {
        assert_eq!(toml_string("part_A4"), "\"part_A4\"");
        assert_eq!(toml_string("a\"b\\c\n"), "\"a\\\"b\\\\c\\u000A\"");
    }
}
