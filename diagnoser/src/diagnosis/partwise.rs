//! A recorded log replayed part by part, on several threads.
//!
//! Parts are independent given the events: a part's verdicts depend on its
//! own signals and on time only, which is the point of decentralised
//! diagnosis. [`PartwiseReplay`] splits each batch of events into every
//! part's scans, runs the parts side by side, then merges their verdicts in
//! the order [`PlantDiagnoser`] gives them, and only then runs the
//! coordinator's plant view over them, in that order. Its output is the
//! plant diagnoser's, line for line, whatever the number of threads.
//!
//! Each part's scan is gathered as its events are read (an `OpenScan` per
//! part), so that a part then runs through its own scans alone, its tables
//! hot in the cache. On one thread, a batch is read and run in slices of a
//! few thousand events, so that the scans are still in the cache when they
//! are run.
//!
//! ```
//! # use diagnoser::diagnosis::{DiagnoserOptions, PartwiseReplay, PlantDiagnoser};
//! # fn replay(plant: &diagnoser::Plant, model: &diagnoser::model::Model,
//! #           log: &[diagnoser::Event], initial: &[bool]) -> Result<(), String> {
//! let diagnoser = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default())?;
//! let mut replay = PartwiseReplay::new(diagnoser, 2);
//! let mut lines = Vec::new();
//! replay.start(0, initial);
//! replay.push_batch(log, &mut |v| lines.push(v));
//! let end = log.last().map_or(0, |e| e.t);
//! let summaries = replay.finish(end, &mut |v| lines.push(v));
//! # Ok(()) }
//! ```

use std::sync::Mutex;

use super::fusion::Coordinator;
use super::part_run::PartRun;
use super::run::{PartSummary, PlantDiagnoser, Route, Routes, plant_summary};
use super::verdict::Verdict;
use crate::{Event, Time};

/// One part's scan: its time, its place among the parts' scans at that time
/// (the first event routed to the part), and the bits it changed.
#[derive(Debug, Clone, Copy)]
struct PartScan {
    t: Time,
    order: u64,
    changed: u32,
}

/// The scan of a part being read: its time ([`NO_SCAN`]: none yet), its
/// order, the bits changed so far, and the part's observed vector before it.
#[derive(Debug, Clone, Copy)]
struct OpenScan {
    t: Time,
    order: u64,
    changed: u32,
    obs: u32,
}

/// Events read before the parts run (on one thread).
const SLICE: usize = 4096;

/// The time of an open scan not begun.
const NO_SCAN: Time = Time::MIN;

impl OpenScan {
    fn new(obs: u32) -> Self {
        OpenScan {
            t: NO_SCAN,
            order: 0,
            changed: 0,
            obs,
        }
    }

    /// Event `e`, the `seen`-th of the log, at bit `bit` of part `part`,
    /// whose complete scans go to `scans`.
    #[inline(always)]
    fn read(&mut self, e: &Event, seen: u64, part: u16, bit: u8, scans: &mut Vec<PartScan>) {
        if self.t != e.t {
            self.close(scans);
            self.t = e.t;
            self.order = seen << 16 | u64::from(part);
        }
        let mask = 1u32 << bit;
        if ((self.obs ^ self.changed) & mask != 0) != e.value {
            self.changed ^= mask;
        }
    }

    /// The scan is complete: it goes to `scans` if it changed anything.
    #[inline(always)]
    fn close(&mut self, scans: &mut Vec<PartScan>) {
        if self.changed != 0 {
            scans.push(PartScan {
                t: self.t,
                order: self.order,
                changed: self.changed,
            });
            self.obs ^= self.changed;
            self.changed = 0;
        }
        self.t = NO_SCAN;
    }
}

/// Where a verdict falls in the plant diagnoser's output: deadlines at a
/// time come before the scans at that time, deadlines in part order, scans
/// in the order of their parts' first events.
type Place = (Time, u8, u64);

/// Every part's diagnoser over a recorded log, each part on its own events,
/// on up to `threads` threads. See the [module](self).
#[derive(Debug)]
pub struct PartwiseReplay {
    parts: Vec<PartRun>,
    /// Per plant signal, the parts that read it and at which bit.
    routes: Routes,
    coordinator: Coordinator,
    threads: usize,
    /// Per part, its scan being read.
    open: Vec<OpenScan>,
    /// Per part, its complete scans not run yet, in time order.
    scans: Vec<Vec<PartScan>>,
    /// Time of the last event read: its scan may go on in the next batch.
    scan: Option<Time>,
    /// Time of the last complete scan: deadlines up to it are due.
    complete: Option<Time>,
    /// Events read, for the parts' order in a scan.
    seen: u64,
}

impl PartwiseReplay {
    /// The parts of `diagnoser`, replayed on up to `threads` threads (at
    /// least one).
    pub fn new(diagnoser: PlantDiagnoser, threads: usize) -> Self {
        let (parts, routes, coordinator) = diagnoser.into_parts();
        let n = parts.len();
        PartwiseReplay {
            parts,
            routes,
            coordinator,
            threads: threads.max(1),
            open: vec![OpenScan::new(0); n],
            scans: vec![Vec::new(); n],
            scan: None,
            complete: None,
            seen: 0,
        }
    }

    /// Starts a replay with every signal's initial value, as
    /// [`PlantDiagnoser::start`].
    pub fn start(&mut self, _t0: Time, initial: &[bool]) {
        self.coordinator.reset();
        for (p, r) in self.parts.iter_mut().enumerate() {
            r.start(initial);
            self.open[p] = OpenScan::new(r.obs());
            self.scans[p].clear();
        }
        self.scan = None;
        self.complete = None;
        self.seen = 0;
    }

    /// Feeds a batch of events in time order; the verdicts of every scan the
    /// batch completes go to `out`. The last time's events wait for the next
    /// batch, which may hold more of that scan.
    pub fn push_batch(&mut self, events: &[Event], out: &mut impl FnMut(Verdict)) {
        // On one thread, in slices small enough that their scans stay in the
        // cache between being read and being run; on more, whole, so that
        // the threads start once per batch.
        let size = if self.threads == 1 {
            SLICE
        } else {
            events.len()
        };
        for slice in events.chunks(size.max(1)) {
            self.push_slice(slice, out);
        }
    }

    fn push_slice(&mut self, events: &[Event], out: &mut impl FnMut(Verdict)) {
        let Some(last) = events.last().map(|e| e.t) else {
            return;
        };
        let (routes, open, scans) = (&self.routes, &mut self.open, &mut self.scans);
        let mut read = |part: u16, e: &Event, seen: u64, bit: u8| {
            let p = part as usize;
            if let (Some(open), Some(scans)) = (open.get_mut(p), scans.get_mut(p)) {
                open.read(e, seen, part, bit, scans);
            }
        };
        for (i, e) in events.iter().enumerate() {
            let seen = self.seen + i as u64;
            let s = e.signal.index();
            match routes.route(s) {
                Route::One(part, bit) => read(part, e, seen, bit),
                Route::None => {}
                Route::Several => {
                    for &(part, bit) in routes.of(s) {
                        read(part, e, seen, bit);
                    }
                }
            }
        }
        self.seen += events.len() as u64;
        // Every scan before the last time read is complete.
        let before = events.iter().rev().find(|e| e.t != last).map(|e| e.t);
        if let Some(t) = before.or(self.scan.filter(|&t| t != last)) {
            self.complete = Some(t);
        }
        self.scan = Some(last);
        if let Some(t) = self.complete {
            self.run(t, out);
        }
    }

    /// Ends the replay at `end`, as [`PlantDiagnoser::finish`].
    pub fn finish(&mut self, end: Time, out: &mut impl FnMut(Verdict)) -> Vec<PartSummary> {
        if let Some(t) = self.scan.take() {
            self.complete = Some(t);
        }
        let upto = self.complete.map_or(end, |t| t.max(end));
        self.run(upto, out);
        self.parts.iter().map(PartRun::summary).collect()
    }

    /// The plant view at `t` as a summary row, as
    /// [`PlantDiagnoser::plant_summary`].
    pub fn plant_summary(&mut self, t: Time, summaries: &[PartSummary]) -> PartSummary {
        plant_summary(&mut self.coordinator, t, summaries)
    }

    /// Runs every part through its scans and its deadlines up to `upto`,
    /// then gives their verdicts in the plant diagnoser's order.
    fn run(&mut self, upto: Time, out: &mut impl FnMut(Verdict)) {
        for (open, scans) in self.open.iter_mut().zip(&mut self.scans) {
            if open.t != NO_SCAN && open.t <= upto {
                open.close(scans);
            }
        }
        let mut verdicts = self.run_parts(upto);
        verdicts.sort_by_key(|(place, _, _)| *place);
        for (_, p, v) in verdicts {
            let view = self.coordinator.update(p, &v);
            out(v);
            if let Some(view) = view {
                out(view);
            }
        }
    }

    /// Each part's verdicts, with their places, from its complete scans and
    /// its deadlines up to `upto`.
    fn run_parts(&mut self, upto: Time) -> Vec<(Place, usize, Verdict)> {
        let mut work: Vec<_> = self
            .parts
            .iter_mut()
            .zip(self.scans.iter_mut())
            .enumerate()
            .filter(|(_, (r, scans))| !scans.is_empty() || r.deadline() <= upto)
            .map(|(p, (r, scans))| (p, r, scans))
            .collect();
        let threads = self.threads.min(work.len());
        if threads <= 1 {
            let mut verdicts = Vec::new();
            for (p, r, scans) in &mut work {
                run_part(*p, r, scans, upto, &mut verdicts);
            }
            return verdicts;
        }
        // Taken heaviest first (from the end), so that the threads finish
        // together.
        work.sort_by_key(|(_, _, scans)| scans.len());
        let queue = Mutex::new(work);
        let results = Mutex::new(Vec::new());
        std::thread::scope(|s| {
            for _ in 0..threads {
                s.spawn(|| {
                    let mut verdicts = Vec::new();
                    loop {
                        let next = queue.lock().ok().and_then(|mut q| q.pop());
                        let Some((p, r, scans)) = next else { break };
                        run_part(p, r, scans, upto, &mut verdicts);
                    }
                    if let Ok(mut all) = results.lock() {
                        all.append(&mut verdicts);
                    }
                });
            }
        });
        results.into_inner().unwrap_or_default()
    }
}

/// Part `p` through its `scans`, then its deadlines up to `upto`; its
/// verdicts go to `verdicts` with their places.
fn run_part(
    p: usize,
    run: &mut PartRun,
    scans: &mut Vec<PartScan>,
    upto: Time,
    verdicts: &mut Vec<(Place, usize, Verdict)>,
) {
    for scan in scans.drain(..) {
        fire_until(p, run, scan.t, verdicts);
        if let Some(v) = run.scan(scan.t, scan.changed) {
            verdicts.push(((scan.t, 1, scan.order), p, v));
        }
    }
    fire_until(p, run, upto, verdicts);
}

/// Part `p`'s deadlines up to `t` pass.
#[inline(always)]
fn fire_until(p: usize, run: &mut PartRun, t: Time, verdicts: &mut Vec<(Place, usize, Verdict)>) {
    if run.deadline() <= t {
        fire_due(p, run, t, verdicts);
    }
}

/// Part `p`'s deadlines up to `t`, at least one, pass.
#[inline(never)]
fn fire_due(p: usize, run: &mut PartRun, t: Time, verdicts: &mut Vec<(Place, usize, Verdict)>) {
    loop {
        let x = run.deadline();
        if x > t {
            return;
        }
        if let Some(v) = run.fire(x) {
            verdicts.push(((x, 0, p as u64), p, v));
        }
    }
}
