//! One replay of a log for the report: every part's diagnoser and the safety
//! filter run side by side, as they would beside the PLC, and the replay keeps
//! what a maintenance engineer needs afterwards: the signals' edges, the verdict
//! changes with the states around them, the constraints that started to hold and
//! the rewrites that the flags caused.

use std::collections::{HashMap, VecDeque};

use diagnoser::diagnosis::{DiagnoserOptions, PartSummary, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::expr::Expr;
use diagnoser::model::Model;
use diagnoser::{Event, Flag, FlagKind, Plant, Time, TimeFormat};
use filter_coupling::filter::{Coupling, Filter};
use filter_coupling::synthesis::{cofactor, reduce};
use logs::LogStream;

/// Scans of history kept for "the last changes" of an explanation.
const HISTORY: usize = 6;

/// Trips of one constraint explained in full; later ones are only drawn.
pub const EXPLAINED_TRIPS: usize = 3;

/// Trips drawn on the timeline of one log: beyond, they are only counted.
pub const DRAWN_TRIPS: usize = 20_000;

/// One scan's edges: `(plant signal index, new value)`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Change {
    /// When.
    pub t: Time,
    /// The edges, in signal order.
    pub edges: Vec<(usize, bool)>,
}

/// A part's verdict change, with the states around it.
#[derive(Debug, Clone)]
pub struct Detection {
    /// The verdict as `diagnose` prints it.
    pub verdict: Verdict,
    /// Index of the part in the plant.
    pub part: usize,
    /// Every plant signal when the verdict changed.
    pub now: Vec<bool>,
    /// Every plant signal before the scan that changed it; for a deadline that
    /// passed, the state the part waited in (then equal to `now` on its signals).
    pub before: Vec<bool>,
    /// Since when the part had been in `before`.
    pub since: Time,
    /// Whether a scan changed the verdict (otherwise a deadline passed).
    pub by_scan: bool,
    /// The part's last changes, oldest first, up to the verdict.
    pub changes: Vec<Change>,
}

/// A safety constraint that started to hold in the log.
#[derive(Debug, Clone)]
pub struct Trip {
    /// The scan.
    pub t: Time,
    /// Constraint name.
    pub constraint: String,
    /// The constraint as the filter evaluated it then (rewritten by the flags
    /// raised at the time, simplified).
    pub evaluated: String,
    /// The literals that made it true, under the flags raised then (a switched
    /// sensor's literal reads its estimate's intervals).
    pub literals: Vec<String>,
    /// Per literal, the sensor whose estimate it reads, if any.
    pub estimated: Vec<Option<String>>,
    /// Parts whose signals it reads.
    pub parts: Vec<String>,
    /// For explained trips: every plant signal in the scan before, and in it.
    pub detail: Option<TripDetail>,
}

/// What an explained trip keeps.
#[derive(Debug, Clone)]
pub struct TripDetail {
    /// Every plant signal in the scan before the trip.
    pub before: Vec<bool>,
    /// Every plant signal in the trip's scan.
    pub now: Vec<bool>,
    /// The plant's last changes, oldest first, the trip's scan last.
    pub changes: Vec<Change>,
    /// `def_` flags raised at the time.
    pub flags: Vec<String>,
}

/// A `def_` flag raised: the constraints that read a switched sensor now read
/// its estimate.
#[derive(Debug, Clone)]
pub struct Rewrite {
    /// When the flag was raised.
    pub t: Time,
    /// The flag, e.g. `def_C4`.
    pub flag: String,
    /// Sensors switched to their estimates.
    pub sensors: Vec<String>,
    /// `(constraint, as written, as now evaluated)`.
    pub constraints: Vec<(String, String, String)>,
    /// Parts of the switched sensors (or of the flagged partition's faults).
    pub parts: Vec<String>,
}

/// Everything the report shows of one log.
#[derive(Debug, Clone)]
pub struct LogReplay {
    /// The log, as named on the command line.
    pub name: String,
    /// How its timestamps are written.
    pub time: TimeFormat,
    /// First record.
    pub start: Time,
    /// Last record (or `--end`).
    pub end: Time,
    /// Every plant signal at `start`.
    pub initial: Vec<bool>,
    /// Per plant signal, the times of its edges.
    pub edges: Vec<Vec<Time>>,
    /// Events read.
    pub events: u64,
    /// The unit of the page's timeline data, in nanoseconds: the largest of
    /// 1 ms, 1 µs and 1 ns that divides every edge's offset from `start`,
    /// keeping the embedded numbers short.
    pub tick: Time,
    /// Every verdict change of every part (the plant view excluded), in order.
    pub verdicts: Vec<Verdict>,
    /// Per part, then the plant view last.
    pub summary: Vec<PartSummary>,
    /// Verdict changes away from normal, or between fault labels.
    pub detections: Vec<Detection>,
    /// Constraints starting to hold (at most [`DRAWN_TRIPS`]).
    pub trips: Vec<Trip>,
    /// Per constraint, how many times it started to hold.
    pub trip_counts: Vec<(String, u64)>,
    /// Flags raised and the rewrites they caused.
    pub rewrites: Vec<Rewrite>,
}

/// What every replay shares.
#[derive(Clone, Copy)]
pub struct Setup<'a> {
    /// The plant.
    pub plant: &'a Plant,
    /// Its learned model.
    pub model: &'a Model,
    /// Diagnoser settings.
    pub options: &'a DiagnoserOptions,
    /// Which flags the filter reads.
    pub coupling: Coupling,
}

/// Replays one log. `end` (`--end`) extends the log's end, its last event or
/// its end row (deadlines up to it count).
pub fn replay(
    setup: Setup<'_>,
    stream: LogStream,
    name: &str,
    end: Option<Time>,
    mut progress: impl FnMut(u64),
) -> Result<LogReplay, String> {
    let Setup {
        plant,
        model,
        options,
        coupling,
    } = setup;
    let mut diagnoser = PlantDiagnoser::new(plant, model, options)?;
    let filter = Filter::new(plant, Some(model), coupling)?;
    let n = plant.signals.len();
    let mut io = stream.initial.clone();
    io.resize(n, false);
    let mut r = Replayer {
        plant,
        filter,
        part_of_signal: part_of_signal(plant),
        constraint_parts: constraint_parts(plant),
        io: io.clone(),
        pending: Vec::new(),
        pending_t: None,
        last_checked: stream.start,
        raised: Vec::new(),
        holding: Vec::new(),
        part_since: vec![stream.start; plant.parts.len()],
        part_history: vec![VecDeque::new(); plant.parts.len()],
        plant_history: VecDeque::new(),
        out: LogReplay {
            name: name.to_string(),
            time: stream.time,
            start: stream.start,
            end: stream.start,
            initial: io,
            edges: vec![Vec::new(); n],
            events: 0,
            tick: 1,
            verdicts: Vec::new(),
            summary: Vec::new(),
            detections: Vec::new(),
            trips: Vec::new(),
            trip_counts: plant
                .constraints
                .iter()
                .map(|c| (c.name.clone(), 0))
                .collect(),
            rewrites: Vec::new(),
        },
    };
    diagnoser.start(stream.start, &r.out.initial);
    let initial = r.out.initial.clone();
    r.note_violations(stream.start, &initial, &initial);
    let mut verdicts: Vec<Verdict> = Vec::new();
    let mut last = stream.start;
    for batch in stream.batches {
        let batch = batch.map_err(|e| e.to_string())?;
        for &e in &batch {
            diagnoser.push(e, &mut |v| verdicts.push(v));
            if r.pending_t.is_some_and(|p| p != e.t) {
                r.complete(&mut verdicts);
            }
            r.pending_t = Some(e.t);
            r.pending.push(e);
        }
        if let Some(e) = batch.last() {
            last = e.t;
        }
        r.out.events += batch.len() as u64;
        progress(r.out.events);
    }
    let end = stream.end.extend(last, end);
    let mut summary = diagnoser.finish(end, &mut |v| verdicts.push(v));
    if r.pending_t.is_some() {
        r.complete(&mut verdicts);
    }
    // Deadlines after the last scan: the state is the last one.
    r.verdicts(&mut verdicts, end);
    if !r.raised.is_empty() {
        r.every_scan_until(end + 1);
    }
    summary.push(diagnoser.plant_summary(end, &summary));
    r.out.summary = summary;
    r.out.end = end;
    r.out.tick = [1_000_000, 1_000]
        .into_iter()
        .find(|tick| {
            r.out
                .edges
                .iter()
                .flatten()
                .all(|t| (t - r.out.start) % tick == 0)
        })
        .unwrap_or(1);
    Ok(r.out)
}

struct Replayer<'a> {
    plant: &'a Plant,
    filter: Filter,
    part_of_signal: Vec<Option<usize>>,
    constraint_parts: HashMap<String, Vec<String>>,
    /// Every signal after the last completed scan.
    io: Vec<bool>,
    /// The scan being read.
    pending: Vec<Event>,
    pending_t: Option<Time>,
    /// Last scan the filter checked.
    last_checked: Time,
    /// `def_` flags raised.
    raised: Vec<String>,
    /// Constraints holding in the last checked scan.
    holding: Vec<String>,
    part_since: Vec<Time>,
    part_history: Vec<VecDeque<Change>>,
    plant_history: VecDeque<Change>,
    out: LogReplay,
}

impl Replayer<'_> {
    /// The scan at `pending_t` is complete; `verdicts` came out while the
    /// diagnosers completed it.
    fn complete(&mut self, verdicts: &mut Vec<Verdict>) {
        let Some(t) = self.pending_t.take() else {
            return;
        };
        // Deadlines before the scan saw the state before it.
        verdicts.sort_by_key(|v| v.t);
        let split = verdicts.partition_point(|v| v.t < t);
        let mut later: Vec<Verdict> = verdicts.drain(split..).collect();
        self.verdicts(verdicts, t);
        if !self.raised.is_empty() {
            // Estimates follow time: every scan counts once a sensor is switched.
            self.every_scan_until(t);
        }
        let before = self.io.clone();
        for e in self.pending.drain(..) {
            if let Some(v) = self.io.get_mut(e.signal.index()) {
                *v = e.value;
            }
        }
        // The scan's edges: what differs from the scan before (a signal that
        // went and came back within the scan did not change).
        let change = Change {
            t,
            edges: (0..self.io.len())
                .filter(|&i| self.io[i] != before[i])
                .map(|i| (i, self.io[i]))
                .collect(),
        };
        for &(i, _) in &change.edges {
            self.out.edges[i].push(t);
        }
        let mut touched: Vec<usize> = change
            .edges
            .iter()
            .filter_map(|&(i, _)| self.part_of_signal[i])
            .collect();
        touched.sort_unstable();
        touched.dedup();
        for &p in &touched {
            let edges: Vec<(usize, bool)> = change
                .edges
                .iter()
                .copied()
                .filter(|&(i, _)| self.part_of_signal[i] == Some(p))
                .collect();
            push_bounded(&mut self.part_history[p], Change { t, edges });
        }
        if !change.edges.is_empty() {
            push_bounded(&mut self.plant_history, change);
        }
        // The scan's own verdicts see the state after it and before it, and
        // `part_since` still holds the entry into the state before it.
        for v in later.drain(..) {
            self.verdict(v, &before, true);
        }
        let now = std::mem::take(&mut self.io);
        self.note_violations(t, &before, &now);
        self.io = now;
        // Parts whose signals changed entered a new state.
        for p in touched {
            self.part_since[p] = t;
        }
    }

    /// Verdicts due to deadlines, up to `t` (the state is the current one).
    fn verdicts(&mut self, verdicts: &mut Vec<Verdict>, t: Time) {
        verdicts.sort_by_key(|v| v.t);
        for v in verdicts.drain(..) {
            if !self.raised.is_empty() {
                self.every_scan_until(v.t.min(t) + 1);
            }
            let state = self.io.clone();
            self.verdict(v, &state, false);
        }
    }

    fn verdict(&mut self, v: Verdict, before: &[bool], by_scan: bool) {
        // The plant view repeats a part's verdict; the summary keeps its last.
        if v.part == diagnoser::diagnosis::fusion::PLANT_VIEW {
            return;
        }
        let Some(p) = self.plant.parts.iter().position(|x| x.name == v.part) else {
            return;
        };
        let previous = self.out.verdicts.iter().rev().find(|x| x.part == v.part);
        let interesting = v.verdict != VerdictKind::Normal
            && previous.is_none_or(|x| x.labels != v.labels || x.verdict != v.verdict);
        if interesting {
            let since = self.part_since[p];
            self.out.detections.push(Detection {
                verdict: v.clone(),
                part: p,
                now: self.io.clone(),
                before: before.to_vec(),
                since,
                by_scan,
                changes: self.part_history[p].iter().cloned().collect(),
            });
        }
        for flag in &v.flags {
            if !self.raised.contains(flag) {
                self.raise(flag, v.t, &v.part);
            }
        }
        self.out.verdicts.push(v);
    }

    /// A `def_` flag raised at `t` by `part`'s diagnoser: the filter switches
    /// from the next scan.
    fn raise(&mut self, flag: &str, t: Time, part: &str) {
        self.raised.push(flag.to_string());
        let coupled = self.filter.coupling() != Coupling::None && self.filter.set(flag, true);
        let partition = Flag::parse(flag).map_or(flag.to_string(), |f| f.partition);
        let sensors: Vec<String> = self
            .filter
            .estimates()
            .iter()
            .filter(|e| e.partition == partition)
            .map(|e| e.sensor.clone())
            .collect();
        let mut constraints = Vec::new();
        if coupled {
            let written: HashMap<&str, &Expr> = self
                .plant
                .constraints
                .iter()
                .map(|c| (c.name.as_str(), &c.expr))
                .collect();
            for (name, expr) in self.filter.safety_constraints() {
                if expr.names().contains(&flag) {
                    let original = written.get(name).map_or(String::new(), |e| e.to_string());
                    constraints.push((
                        name.to_string(),
                        original,
                        self.evaluated(expr).to_string(),
                    ));
                }
            }
        }
        let mut parts: Vec<String> = sensors
            .iter()
            .filter_map(|s| self.plant.signals.id(s))
            .filter_map(|id| self.part_of_signal[id.index()])
            .map(|p| self.plant.parts[p].name.clone())
            .collect();
        if parts.is_empty() {
            // An actuator or element partition: the part whose diagnoser raised it.
            parts.push(part.to_string());
        }
        parts.sort();
        parts.dedup();
        self.out.rewrites.push(Rewrite {
            t,
            flag: flag.to_string(),
            sensors,
            constraints,
            parts,
        });
    }

    /// A rewritten constraint under the flags raised now: every `def_` flag
    /// replaced by its value, then simplified.
    fn evaluated(&self, expr: &Expr) -> Expr {
        let mut e = expr.clone();
        for name in expr.names() {
            if Flag::parse(name).is_some() {
                let up = self.raised.iter().any(|f| f == name);
                e = cofactor(&e, name, up);
            }
        }
        reduce(&e)
    }

    /// A true literal as the flags raised make it read, and the sensor whose
    /// estimate it then reads.
    fn literal(&self, text: &str) -> (String, Option<String>) {
        let Ok(e) = Expr::parse(text) else {
            return (text.to_string(), None);
        };
        let sensor = e.names().into_iter().find_map(|n| {
            let partition = Flag::parse(n)
                .filter(|f| f.kind == FlagKind::Def)?
                .partition;
            self.raised.iter().any(|f| f == n).then(|| {
                self.filter
                    .estimates()
                    .iter()
                    .find(|est| est.partition == partition)
                    .map_or_else(|| partition.to_string(), |est| est.sensor.clone())
            })
        });
        (self.evaluated(&e).to_string(), sensor)
    }

    /// Checks the scans between the last checked one and `t` (excluded), with
    /// nothing changed: the intervals of the estimates still move.
    fn every_scan_until(&mut self, t: Time) {
        let period = self.plant.scan_period.max(1);
        let io = self.io.clone();
        while self.last_checked + period < t {
            let at = self.last_checked + period;
            self.note_violations(at, &io, &io);
        }
    }

    /// Records the constraints the scan at `t` violates, as trips.
    fn note_violations(&mut self, t: Time, before: &[bool], now: &[bool]) {
        self.last_checked = self.last_checked.max(t);
        let violated = self.filter.violations(t, now);
        if violated.is_empty() && self.holding.is_empty() {
            return;
        }
        for v in &violated {
            if self.holding.contains(&v.constraint) {
                continue;
            }
            let Some(count) = self
                .out
                .trip_counts
                .iter_mut()
                .find(|(c, _)| *c == v.constraint)
            else {
                continue;
            };
            count.1 += 1;
            let explained = count.1 as usize <= EXPLAINED_TRIPS;
            if self.out.trips.len() >= DRAWN_TRIPS {
                continue;
            }
            let evaluated = self
                .filter
                .safety_constraints()
                .find(|(n, _)| *n == v.constraint)
                .map(|(_, e)| self.evaluated(e).to_string())
                .unwrap_or_default();
            let detail = explained.then(|| TripDetail {
                before: before.to_vec(),
                now: now.to_vec(),
                changes: self.plant_history.iter().cloned().collect(),
                flags: self.raised.clone(),
            });
            let (literals, estimated) = v.literals.iter().map(|l| self.literal(l)).unzip();
            self.out.trips.push(Trip {
                t,
                constraint: v.constraint.clone(),
                evaluated,
                literals,
                estimated,
                parts: self
                    .constraint_parts
                    .get(&v.constraint)
                    .cloned()
                    .unwrap_or_default(),
                detail,
            });
        }
        self.holding.clear();
        self.holding
            .extend(violated.into_iter().map(|v| v.constraint));
    }
}

fn push_bounded(history: &mut VecDeque<Change>, change: Change) {
    if history.len() == HISTORY {
        history.pop_front();
    }
    history.push_back(change);
}

/// Per plant signal, the part it belongs to.
pub fn part_of_signal(plant: &Plant) -> Vec<Option<usize>> {
    let mut out = vec![None; plant.signals.len()];
    for (p, part) in plant.parts.iter().enumerate() {
        for s in part.actuators.iter().chain(&part.sensors) {
            if let Some(slot) = out.get_mut(s.index()) {
                *slot = Some(p);
            }
        }
    }
    out
}

/// Per safety constraint, the parts whose signals it reads.
fn constraint_parts(plant: &Plant) -> HashMap<String, Vec<String>> {
    let owner = part_of_signal(plant);
    plant
        .constraints
        .iter()
        .map(|c| {
            let mut parts: Vec<String> = c
                .expr
                .names()
                .into_iter()
                .filter_map(|n| plant.signals.id(n))
                .filter_map(|id| owner[id.index()])
                .map(|p| plant.parts[p].name.clone())
                .collect();
            parts.sort();
            parts.dedup();
            (c.name.clone(), parts)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use diagnoser::fault::FaultTemplate;
    use diagnoser::model::Model;
    use serde_json::Value;

    use super::*;
    use crate::fixtures::{learned, plant, replay, sorting};

    /// The fault injected in `run`, its onset in nanoseconds, and the index of
    /// the part whose sensor it concerns, from the run's ground truth.
    fn truth(plant: &Plant, run: &str) -> (String, Time, usize) {
        let text = std::fs::read_to_string(sorting(run).join("truth.json"))
            .unwrap_or_else(|e| panic!("{e}"));
        let truth: Value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}"));
        let fault = &truth["faults"][0];
        let label = fault["label"].as_str().expect("a label").to_string();
        let onset = fault["onset"].as_i64().expect("an onset") * plant.time_unit.nanos();
        let Some(FaultTemplate::Stuck1(sensor)) = plant.fault(&label).map(|f| &f.template) else {
            panic!("{label} is a sensor stuck at 1 in the plant file");
        };
        let id = plant.signals.id(sensor).expect("a signal");
        let part = plant
            .parts
            .iter()
            .position(|p| p.sensors.contains(&id))
            .expect("the sensor belongs to a part");
        (label, onset, part)
    }

    fn learned_sorting() -> (Plant, Model) {
        let plant = plant();
        let model = learned(&plant);
        (plant, model)
    }

    #[test]
    fn a_stuck_sensor_is_found_after_its_onset_and_flagged() {
        let (plant, model) = learned_sorting();
        let (label, onset, part) = truth(&plant, "F4");
        let name = &plant.parts[part].name;
        let r = replay(&plant, &model, "F4");

        // The part's first verdict away from normal comes at or after the onset,
        // with the fault among its candidates; no other part leaves normal.
        let first = r
            .verdicts
            .iter()
            .find(|v| v.verdict != VerdictKind::Normal)
            .expect("a verdict away from normal");
        assert_eq!(&first.part, name, "{first:?}");
        assert!(first.t >= onset, "{} before the onset {onset}", first.t);
        assert!(first.labels.contains(&label), "{first:?}");
        assert!(
            r.verdicts
                .iter()
                .all(|v| &v.part == name || v.verdict == VerdictKind::Normal),
            "{:?}",
            r.verdicts
        );
        // It ends certain of that fault alone, its partition's flag raised.
        let partition = plant.partition_of(&label).expect("a partition");
        let flag = partition.flag().to_string();
        let summary = &r.summary[part];
        assert_eq!(summary.verdict, VerdictKind::Certain, "{summary:?}");
        assert_eq!(summary.labels, [label.as_str()]);
        assert_eq!(summary.flags, [flag.as_str()]);
        assert!(summary.detected.is_some_and(|t| t >= onset));
        // The plant view, last, says the same.
        assert_eq!(r.summary.len(), plant.parts.len() + 1);
        assert_eq!(r.summary[plant.parts.len()].labels, [label]);

        // Each detection is explained from the part's states around it.
        assert!(!r.detections.is_empty());
        for d in &r.detections {
            assert_eq!(d.part, part);
            assert!(d.since <= d.verdict.t);
            assert_eq!(d.now.len(), plant.signals.len());
            assert!(d.changes.len() <= HISTORY);
            assert!(d.changes.windows(2).all(|w| w[0].t < w[1].t));
        }
        // The flag, raised once, rewrote the filter from then on.
        assert_eq!(r.rewrites.len(), 1);
        assert_eq!(r.rewrites[0].flag, flag);
        assert!(r.rewrites[0].t >= onset);
        assert!(!r.rewrites[0].sensors.is_empty());
        assert_eq!(r.rewrites[0].parts, [name.as_str()]);
    }

    #[test]
    fn the_fault_free_run_stays_normal() {
        let (plant, model) = learned_sorting();
        let r = replay(&plant, &model, "normal");
        assert!(r.events > 1000, "{} events", r.events);
        assert!(r.end > r.start);
        assert!(
            r.verdicts.iter().all(|v| v.verdict == VerdictKind::Normal),
            "{:?}",
            r.verdicts
        );
        assert!(r.detections.is_empty());
        assert!(r.rewrites.is_empty());
        assert_eq!(r.summary.len(), plant.parts.len() + 1);
        assert!(
            r.summary
                .iter()
                .all(|s| s.verdict == VerdictKind::Normal && s.detected.is_none()),
            "{:?}",
            r.summary
        );
        // The safe control never lets a safety constraint hold.
        assert!(r.trips.is_empty());
        assert!(r.trip_counts.iter().all(|c| c.1 == 0));
        // Every edge lies within the log, in order, on the timeline's tick.
        for edges in &r.edges {
            assert!(edges.windows(2).all(|w| w[0] < w[1]));
            assert!(edges.iter().all(|&t| r.start <= t && t <= r.end));
            assert!(edges.iter().all(|&t| (t - r.start) % r.tick == 0));
        }
        assert_eq!(r.tick, 1_000_000, "a log in whole milliseconds");
    }
}
