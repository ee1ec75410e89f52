//! Active diagnosis: a probing move of a part whose verdict stays ambiguous
//! while its control waits.
//!
//! A move is a candidate probe when it passes two checks, both made on copies
//! of what runs in the loop, so that nothing is written per plant:
//!
//! 1. **Safe under every remaining candidate.** The filter, with the
//!    suspected partitions' sensors read conservatively (the union of reading
//!    and estimate, see `filter_coupling::rewrite`), accepts the move in the
//!    next scan: no safety constraint forbids it. A constraint that forbids it
//!    under one candidate forbids it under the union. The other orders of
//!    that scan are those safe control computes in the closed loop, and those
//!    the PLC keeps beside a real one (the monitor's `--probe`, see
//!    [`Prober::proposed_by`]).
//! 2. **It separates candidates.** The part's diagnoser, copied, is given the
//!    move and then silence: deadline after deadline, up to [`HORIZON`]. The
//!    move separates if silence rules out some candidates but not all: then
//!    either the edges the ruled-out candidates predict come, or they do not,
//!    and the real diagnoser tells which.
//!
//! The move is a change of one of the part's outputs from the order the
//! control keeps. While it runs, the filter checks it again in every scan
//! ([`Filter::request`]) and keeps the control's order where a constraint
//! forbids it. It ends when the part's verdict changes, or when silence has
//! had its time.

use diagnoser::diagnosis::{PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::plant::Part;
use diagnoser::{Event, MS, Plant, SECOND, SignalId, Time};
use filter_coupling::filter::{Filter, Mode, Request};

/// How long an ambiguous part's verdict and orders must stay unchanged before
/// a probe: the control is waiting.
pub const PATIENCE: Time = 2 * SECOND;
/// How far the diagnoser's copy is run in silence after a move.
pub const HORIZON: Time = 60 * SECOND;

/// A probing move chosen for a part.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// The part.
    pub part: String,
    /// The output moved.
    pub actuator: String,
    /// The value it is moved to.
    pub value: bool,
    /// The part's candidates when the move began.
    pub candidates: Vec<String>,
    /// When the move began.
    pub from: Time,
    /// When silence would have told.
    pub until: Time,
}

impl Probe {
    /// `released A4 to tell F3 from F11`.
    pub fn describe(&self) -> String {
        let verb = if self.value { "set" } else { "released" };
        format!(
            "{verb} {} to tell {} apart",
            self.actuator,
            self.candidates.join(", ")
        )
    }

    /// The reason of the verdict the probe led to: `released A4 to tell F3,
    /// F11 apart: RE(C4) …, so F3`.
    pub fn outcome(&self, verdict: &Verdict) -> String {
        let after = (verdict.t - self.from) as f64 / SECOND as f64;
        format!(
            "{} ({after:.1} s after the move: {}), so {}",
            self.describe(),
            verdict.reason,
            verdict.labels.join(", ")
        )
    }
}

/// A probing move and what it told.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeRecord {
    /// When the move began.
    pub t: Time,
    /// The part.
    pub part: String,
    /// `released A4 to tell F3, F11 apart (2.9 s after the move: …), so F3`.
    pub reason: String,
}

/// Probing over a run: per part, its last verdict, since when it and the
/// part's orders are unchanged, and whether it was searched; the probe under
/// way, and what probing found.
///
/// The closed loop and the monitor both drive one: [`Prober::note_verdict`]
/// for every verdict, [`Prober::scan`] after every scan's orders and
/// diagnosis. It moves the plant only through [`Filter::request`], which the
/// filter checks again in every scan.
#[derive(Clone)]
pub struct Prober {
    plant: Plant,
    parts: Vec<PartWatch>,
    active: Option<Probe>,
    probes: Vec<ProbeRecord>,
    no_probe: Vec<String>,
    /// Where the orders of the scan a move is checked in come from.
    mode: Mode,
}

#[derive(Clone, Default)]
struct PartWatch {
    verdict: Option<Verdict>,
    since: Time,
    orders: Vec<bool>,
    orders_since: Time,
    searched: bool,
    /// The candidate sets already probed: each is probed once, so that a
    /// move whose outcome left the part ambiguous (or unexplained) again is
    /// not repeated for ever.
    probed: Vec<Vec<String>>,
}

impl Prober {
    /// Probing on `plant`'s parts, nothing watched yet.
    pub fn new(plant: &Plant) -> Prober {
        Prober {
            plant: plant.clone(),
            parts: vec![PartWatch::default(); plant.parts.len()],
            active: None,
            probes: Vec::new(),
            no_probe: Vec::new(),
            mode: Mode::Control,
        }
    }

    /// Checks each move on a filter scanning in `mode`. The closed loop's
    /// filter computes the orders (safe control, [`Mode::Control`], the
    /// default); beside a real PLC its program proposes them, and the copy the
    /// monitor keeps takes the orders it read as the proposal
    /// ([`Mode::Filter`]): a move is then checked against the orders the PLC
    /// keeps, not against those safe control would compute.
    pub fn proposed_by(mut self, mode: Mode) -> Prober {
        self.mode = mode;
        self
    }

    /// The probe under way, if any.
    pub fn active(&self) -> Option<&Probe> {
        self.active.as_ref()
    }

    /// The probes made so far, each with what it told.
    pub fn probes(&self) -> &[ProbeRecord] {
        &self.probes
    }

    /// Why no probe was made for an ambiguous, waiting part, once per reason.
    pub fn no_probe(&self) -> &[String] {
        &self.no_probe
    }

    /// The probes made and the reasons for none, to keep after the run.
    pub fn into_findings(self) -> (Vec<ProbeRecord>, Vec<String>) {
        (self.probes, self.no_probe)
    }

    /// Ends the probe under way, if any, without waiting for its answer
    /// (silence has had its time, the plant is no longer seen, or the run
    /// stops): the output goes back to the control, and `why` is what the
    /// record says.
    pub fn abandon(&mut self, why: &str, filter: &mut Filter) -> Option<&ProbeRecord> {
        let probe = self.active.take()?;
        filter.request(&probe.actuator, None);
        self.probes.push(ProbeRecord {
            t: probe.from,
            part: probe.part.clone(),
            reason: format!("{}: {why}", probe.describe()),
        });
        self.probes.last()
    }

    /// A part's new verdict: it answers the probe under way if its labels
    /// changed, and the part's wait starts again.
    pub fn note_verdict(&mut self, v: &Verdict, filter: &mut Filter) {
        let Some(i) = self.plant.parts.iter().position(|p| p.name == v.part) else {
            return;
        };
        if let Some(probe) = &self.active
            && probe.part == v.part
            && v.t >= probe.from
            && v.labels != probe.candidates
        {
            self.probes.push(ProbeRecord {
                t: probe.from,
                part: probe.part.clone(),
                reason: probe.outcome(v),
            });
            filter.request(&probe.actuator, None);
            self.active = None;
        }
        let w = &mut self.parts[i];
        w.verdict = Some(v.clone());
        w.since = v.t;
        w.searched = false;
    }

    /// After a scan's orders and diagnosis: ends a probe that silence has
    /// left unanswered, or looks for one where a part waits, ambiguous.
    pub fn scan(&mut self, t: Time, io: &[bool], filter: &mut Filter, diagnoser: &PlantDiagnoser) {
        for (w, part) in self.parts.iter_mut().zip(&self.plant.parts) {
            let now = part.actuators.iter().map(|a| io[a.index()]);
            if w.orders.len() != part.actuators.len() || !now.clone().eq(w.orders.iter().copied()) {
                // The situation moved on: once it waits again, search again.
                w.orders.clear();
                w.orders.extend(now);
                w.orders_since = t;
                w.searched = false;
            }
        }
        if let Some(probe) = &self.active {
            if t > probe.until + PATIENCE {
                self.abandon("no verdict change", filter);
            }
            return;
        }
        for (w, part) in self.parts.iter_mut().zip(&self.plant.parts) {
            let Some(v) = &w.verdict else { continue };
            let waiting = t >= w.since + PATIENCE && t >= w.orders_since + PATIENCE;
            if w.searched || !waiting || !worth_probing(v) || w.probed.contains(&v.labels) {
                continue;
            }
            w.searched = true;
            match search(&self.plant, part, filter, self.mode, diagnoser, v, t, io) {
                Ok(p) => {
                    w.probed.push(v.labels.clone());
                    filter.request(&p.actuator, Some(p.value));
                    self.active = Some(p);
                    return;
                }
                Err(reasons) => {
                    for r in reasons {
                        let line = format!("{} ({}): {r}", part.name, v.labels.join(", "));
                        if !self.no_probe.contains(&line) {
                            self.no_probe.push(line);
                        }
                    }
                }
            }
        }
    }
}

/// Searches `part`'s outputs for a probe at `t`, the scan whose orders and
/// sensors `io` holds, each move checked on `filter` scanning in `mode`.
/// `Err` gives, per output, why it is no probe.
#[allow(clippy::too_many_arguments)] // the scan a move is checked in, whole
pub fn search(
    plant: &Plant,
    part: &Part,
    filter: &Filter,
    mode: Mode,
    diagnoser: &PlantDiagnoser,
    verdict: &Verdict,
    t: Time,
    io: &[bool],
) -> Result<Probe, Vec<String>> {
    let next = t + plant.scan_period;
    let mut refused = Vec::new();
    for &a in &part.actuators {
        let name = plant.signals.name(a);
        let value = !io[a.index()];
        if let Err(why) = accepted(plant, filter, mode, name, value, next, io) {
            refused.push(format!("{name} = {}: {why}", u8::from(value)));
            continue;
        }
        match separation(diagnoser, &part.name, &verdict.labels, a, value, next) {
            Some(until) => {
                return Ok(Probe {
                    part: part.name.clone(),
                    actuator: name.to_string(),
                    value,
                    candidates: verdict.labels.clone(),
                    from: next,
                    until,
                });
            }
            None => refused.push(format!(
                "{name} = {}: no candidate is ruled out by silence after it",
                u8::from(value)
            )),
        }
    }
    Err(refused)
}

/// Whether the filter, scanning in `mode`, would take `actuator` at `value`
/// in the next scan; if not, the constraints that forbid it, as the plant
/// file writes them.
fn accepted(
    plant: &Plant,
    filter: &Filter,
    mode: Mode,
    actuator: &str,
    value: bool,
    t: Time,
    io: &[bool],
) -> Result<(), String> {
    let mut f = filter.clone();
    f.request(actuator, Some(value));
    let mut next = io.to_vec();
    let outcome = f.scan(t, &mut next, mode);
    match outcome
        .requests
        .into_iter()
        .find(|(a, _)| a == actuator)
        .map(|(_, r)| r)
    {
        Some(Request::Refused(violated)) => {
            let names: Vec<String> = violated
                .iter()
                .map(|v| {
                    let written = plant.constraints.iter().find(|c| c.name == v.constraint);
                    written.map_or(v.constraint.clone(), |c| format!("{} ({})", c.name, c.expr))
                })
                .collect();
            Err(format!("forbidden by {}", names.join(" and ")))
        }
        Some(Request::Applied) => Ok(()),
        None => Err("not an output of the filter".into()),
    }
}

/// When silence after the move has ruled out some candidates but not all, if
/// it does within [`HORIZON`].
fn separation(
    diagnoser: &PlantDiagnoser,
    part: &str,
    candidates: &[String],
    actuator: SignalId,
    value: bool,
    t: Time,
) -> Option<Time> {
    let mut d = diagnoser.clone();
    let mut labels: Option<Vec<String>> = None;
    let event = Event {
        t,
        signal: actuator,
        value,
    };
    d.push(event, &mut |v: Verdict| keep(&mut labels, part, v));
    d.advance_to(t, &mut |v: Verdict| keep(&mut labels, part, v));
    let mut now = t;
    loop {
        if let Some(l) = labels.take() {
            if !l.iter().all(|x| candidates.contains(x)) {
                // An unknown or a new candidate: silence tells nothing useful.
                return None;
            }
            if !l.is_empty() && l.len() < candidates.len() {
                return Some(now);
            }
        }
        let deadline = d.next_deadline()?;
        if deadline > t + HORIZON {
            return None;
        }
        now = deadline.max(now + MS);
        d.advance_to(now, &mut |v: Verdict| keep(&mut labels, part, v));
    }
}

/// Keeps `part`'s latest labels.
fn keep(labels: &mut Option<Vec<String>>, part: &str, v: Verdict) {
    if v.part == part {
        *labels = Some(v.labels);
    }
}

/// Whether `v` is a verdict a probe can act on: ambiguous between modelled
/// faults.
pub fn worth_probing(v: &Verdict) -> bool {
    v.verdict == VerdictKind::Ambiguous
        && v.labels.len() > 1
        && !v
            .labels
            .iter()
            .any(|l| l == diagnoser::diagnosis::UNKNOWN_LABEL)
}
