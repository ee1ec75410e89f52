//! Simulated logs of a generated plant: fault-free runs, and faulty runs that
//! branch off one fault-free run at each fault's onset.
//!
//! A faulty run is the fault-free run until its onset, so it needs to be
//! simulated only from there: the fault-free run is paused at the onset,
//! copied, given the fault, and the copy runs on to its end. The log is the
//! same, byte for byte, as that of a run that had the fault from the start
//! (`gardefou simulate --fault LABEL@ONSET` with the same seed).

use datasets::generated::GeneratedPlant;
use datasets::inject::Injection;
use datasets::sim::{ScanSink, SimConfig, Stepper};
use diagnoser::{Event, FaultTemplate, Plant, SignalId, Time};

use crate::judge::part_of;

/// A log in memory: the values of the first scan, then every change.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Log {
    /// Time of the first scan.
    pub start: Time,
    /// Values of the first scan, indexed like the plant's signals.
    pub initial: Vec<bool>,
    /// Every change after it, in order.
    pub events: Vec<Event>,
    /// Time of the last scan.
    pub end: Time,
}

/// Records changes, from the first scan or from a known state.
#[derive(Debug, Clone, Default)]
struct Recorder {
    log: Log,
    last: Vec<bool>,
}

impl ScanSink for Recorder {
    fn scan(&mut self, t: Time, values: &[bool]) -> std::io::Result<()> {
        if self.last.is_empty() {
            self.log.start = t;
            self.log.initial = values.to_vec();
            self.last = values.to_vec();
        }
        for (i, (old, &new)) in self.last.iter_mut().zip(values).enumerate() {
            if *old != new {
                *old = new;
                self.log.events.push(Event {
                    t,
                    signal: SignalId(i as u32),
                    value: new,
                });
            }
        }
        self.log.end = t;
        Ok(())
    }
}

/// A fault-free run of `duration` with run seed `seed`.
pub fn fault_free(plant: &GeneratedPlant, seed: u64, duration: Time) -> std::io::Result<Log> {
    let config = SimConfig {
        duration,
        scan_period: plant.plant().scan_period,
        seed,
        faults: Vec::new(),
    };
    let mut recorder = Recorder::default();
    let (mut physics, mut program) = (plant.physics(), plant.program());
    datasets::sim::run(&mut physics, &mut program, &config, &mut recorder, |_| {})?;
    Ok(recorder.log)
}

/// One faulty run: its log, and when the fault first showed in it.
#[derive(Debug, Clone)]
pub struct FaultyRun<'a> {
    /// The fault.
    pub fault: &'a Injection,
    /// The whole log, from the start of the fault-free run.
    pub log: Log,
    /// The first scan, from the onset, where the log differs from the
    /// fault-free one; `None` if it never does.
    pub showed: Option<Time>,
    /// Whether, from the onset on, the fault's part made the same edges in the
    /// same order as without the fault, at other times only (a pulse that
    /// delays an edge by 50 ms): it then shows only where a time leaves the
    /// normal spread.
    pub timing_only: bool,
}

/// Runs each fault of `faults` for `horizon` after its onset, branching off
/// one fault-free run with seed `seed`, and hands each run to `each` (in the
/// order of the onsets).
pub fn faulty_runs<'a>(
    plant: &GeneratedPlant,
    seed: u64,
    faults: &'a [Injection],
    horizon: Time,
    mut each: impl FnMut(FaultyRun<'a>),
) -> std::io::Result<()> {
    let mut order: Vec<&Injection> = faults.iter().collect();
    order.sort_by_key(|f| f.onset);
    let Some(last) = order.last() else {
        return Ok(());
    };
    let config = SimConfig {
        duration: last.onset + horizon,
        scan_period: plant.plant().scan_period,
        seed,
        faults: Vec::new(),
    };
    // The fault-free run to the end, to tell when each fault shows.
    let reference = {
        let mut recorder = Recorder::default();
        let (mut physics, mut program) = (plant.physics(), plant.program());
        datasets::sim::run(&mut physics, &mut program, &config, &mut recorder, |_| {})?;
        recorder.log
    };
    // The same run again, paused at each onset to branch off.
    let (mut physics, mut program) = (plant.physics(), plant.program());
    let mut stepper = Stepper::new(plant.plant(), &config);
    let mut recorder = Recorder::default();
    for fault in order {
        while stepper.next_scan().is_some_and(|t| t < fault.onset) {
            if let Some((t, values)) = stepper.step(&mut physics, &mut program)? {
                recorder.scan(t, values)?;
            }
        }
        let end = fault.onset + horizon;
        let (mut s, mut p, mut c, mut r) = (
            stepper.clone(),
            physics.clone(),
            program.clone(),
            recorder.clone(),
        );
        s.inject(plant.plant(), fault.clone());
        while s.next_scan().is_some_and(|t| t <= end) {
            if let Some((t, values)) = s.step(&mut p, &mut c)? {
                r.scan(t, values)?;
            }
        }
        let showed = first_difference(&reference.events, &r.log.events, fault.onset, end);
        let signals = part_signals(plant.plant(), &fault.template);
        let timing_only = same_edges(&reference.events, &r.log.events, fault.onset, end, &signals);
        each(FaultyRun {
            fault,
            log: r.log,
            showed,
            timing_only,
        });
    }
    Ok(())
}

/// The signals of the part `template` is a fault of.
fn part_signals(plant: &Plant, template: &FaultTemplate) -> Vec<SignalId> {
    let name = part_of(plant, template);
    plant
        .parts
        .iter()
        .filter(|p| Some(&p.name) == name.as_ref())
        .flat_map(|p| p.actuators.iter().chain(&p.sensors).copied())
        .collect()
}

/// Whether two logs make the same edges of `signals`, in the same order, in
/// `[from, to]` (at the same times or not).
pub fn same_edges(a: &[Event], b: &[Event], from: Time, to: Time, signals: &[SignalId]) -> bool {
    let edges = |l: &[Event]| {
        window(l, from, to)
            .iter()
            .filter(|e| signals.contains(&e.signal))
            .map(|e| (e.signal, e.value))
            .collect::<Vec<_>>()
    };
    edges(a) == edges(b)
}

/// The events of `log` in `[from, to]`.
fn window(log: &[Event], from: Time, to: Time) -> &[Event] {
    let lo = log.partition_point(|e| e.t < from);
    let hi = log.partition_point(|e| e.t <= to);
    &log[lo..hi.max(lo)]
}

/// The time of the first event, in `[from, to]`, where two logs of the same
/// run differ (a change added, missing or different).
pub fn first_difference(a: &[Event], b: &[Event], from: Time, to: Time) -> Option<Time> {
    let (a, b) = (window(a, from, to), window(b, from, to));
    let differs = a
        .iter()
        .zip(b)
        .find(|(x, y)| x != y)
        .map(|(x, y)| x.t.min(y.t));
    differs.or_else(|| match a.len().cmp(&b.len()) {
        std::cmp::Ordering::Less => Some(b[a.len()].t),
        std::cmp::Ordering::Greater => Some(a[b.len()].t),
        std::cmp::Ordering::Equal => None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(t: Time, s: u32, v: bool) -> Event {
        Event {
            t,
            signal: SignalId(s),
            value: v,
        }
    }

    #[test]
    fn the_first_difference_is_the_earliest_changed_added_or_missing_event() {
        let a = [e(1, 0, true), e(5, 1, true), e(9, 0, false)];
        assert_eq!(first_difference(&a, &a, 0, 10), None);
        // A change that comes later.
        let b = [e(1, 0, true), e(7, 1, true), e(9, 0, false)];
        assert_eq!(first_difference(&a, &b, 0, 10), Some(5));
        // A change missing at the end.
        assert_eq!(first_difference(&a, &a[..2], 0, 10), Some(9));
        // Differences before the window do not count.
        assert_eq!(first_difference(&a, &b[1..], 6, 10), Some(7));
        assert_eq!(first_difference(&a[..1], &b[..1], 2, 10), None);
    }

    #[test]
    fn edges_are_the_same_when_only_their_times_differ_on_the_part_s_signals() {
        let part = [SignalId(0), SignalId(1)];
        let a = [e(1, 0, true), e(5, 1, true), e(9, 0, false)];
        // One edge later: the same edges.
        let later = [e(1, 0, true), e(7, 1, true), e(9, 0, false)];
        assert!(same_edges(&a, &later, 0, 10, &part));
        // Two edges swapped, an edge missing: not.
        let swapped = [e(1, 0, true), e(5, 0, false), e(9, 1, true)];
        assert!(!same_edges(&a, &swapped, 0, 10, &part));
        assert!(!same_edges(&a, &a[..2], 0, 10, &part));
        // Another part's edges, and edges before the window, do not count.
        let other = [e(1, 0, true), e(3, 2, true), e(5, 1, true), e(9, 0, false)];
        assert!(same_edges(&a, &other, 0, 10, &part));
        assert!(same_edges(&a[1..], &a, 2, 10, &part));
    }
}
