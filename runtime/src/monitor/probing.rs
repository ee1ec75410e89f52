//! `monitor --probe`: active diagnosis beside a live PLC ([`crate::probe`]).
//!
//! The monitor keeps a copy of the PLC's safety filter, fed with every scan it
//! reads (the orders as the PLC wrote them, [`Filter::violations`]) and with
//! the flags it writes, and a [`Prober`] driven as the closed loop drives one.
//! A move is checked on that copy with the orders the PLC keeps
//! ([`Mode::Filter`]): its program proposes them, not safe control. A move
//! found goes to the source as a [`ProbeImage`]: the Modbus source writes it
//! to the PLC's probe coils, whose filter checks it again in every scan.
//!
//! A probe ends when the part's verdict changes (that verdict line's reason
//! is the probe's outcome), when silence has had its time, when the source
//! loses the plant or falls behind it (any doubt), or when the monitor stops.
//! No move starts while the plant is not observed.

use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::diagnosis::{PlantDiagnoser, Verdict};
use std::sync::{Arc, Mutex};

use diagnoser::{Event, Plant, SignalKind, Time, TimeFormat};
use filter_coupling::filter::{Filter, Mode};
use tokio::sync::watch;

use super::source::{FlagImage, ProbeImage};
use super::status::Status;
use crate::probe::Prober;

/// Probing beside the PLC: the filter's copy, the prober, and what goes to
/// the source.
pub(super) struct Probing {
    plant: Plant,
    prober: Prober,
    /// The copy of the PLC's filter, fed with the scans read and the flags.
    filter: Filter,
    /// The copy as built, to start again from after a gap.
    fresh: Filter,
    /// Every signal's value as last read (none before the first values).
    values: Vec<bool>,
    /// The flags last written, in [`Plant::flags`] order.
    flags: FlagImage,
    /// The plant's actuators in plant-file order: the probe image's order.
    actuators: Vec<String>,
    /// The moves to write, to the source.
    tx: watch::Sender<ProbeImage>,
    /// Whether the PLC may hold a move: one was sent, and no image without
    /// one has been acknowledged since.
    on_plc: bool,
    /// How many of the prober's reasons for no probe were said.
    said: usize,
    time: TimeFormat,
    /// Where `/status` and `/metrics` read the move under way.
    status: Arc<Mutex<Status>>,
}

impl Probing {
    /// Probing on `plant` with `filter`, the copy of the PLC's; the moves
    /// go to `tx` and to `status`, times are printed in `time`.
    pub(super) fn new(
        plant: &Plant,
        filter: Filter,
        tx: watch::Sender<ProbeImage>,
        time: TimeFormat,
        status: Arc<Mutex<Status>>,
    ) -> Probing {
        let actuators = plant
            .signals
            .of_kind(SignalKind::Actuator)
            .map(|a| plant.signals.name(a).to_string())
            .collect();
        Probing {
            plant: plant.clone(),
            prober: Prober::new(plant).proposed_by(Mode::Filter),
            fresh: filter.clone(),
            filter,
            values: Vec::new(),
            flags: vec![false; plant.flags().len()],
            actuators,
            tx,
            on_plc: false,
            said: 0,
            time,
            status,
        }
    }

    /// The values read on (re)connecting: the copy of the filter and the
    /// prober start afresh, as the diagnosers do, with the flags written.
    pub(super) fn start(&mut self, initial: &[bool]) {
        self.abandon("the plant was seen again");
        self.values = initial.to_vec();
        self.filter = self.fresh.clone();
        for (flag, &up) in self.plant.flags().iter().zip(&self.flags) {
            self.filter.set(&flag.to_string(), up);
        }
        self.prober = Prober::new(&self.plant).proposed_by(Mode::Filter);
        self.said = 0;
    }

    /// One scan's changes.
    pub(super) fn changes(&mut self, scan: &[Event]) {
        for e in scan {
            if let Some(v) = self.values.get_mut(e.signal.index()) {
                *v = e.value;
            }
        }
    }

    /// The PLC as read at `t` (a scan or a watermark), once the diagnosers
    /// are done with it: the filter's copy reads it, and if `may_move` the
    /// prober ends a probe that silence has left unanswered or looks for one.
    pub(super) fn scan(&mut self, t: Time, diagnoser: &PlantDiagnoser, may_move: bool) {
        if self.values.is_empty() {
            return;
        }
        // The orders as the PLC wrote them: the copy takes no request of its
        // own, so its clocks and edges stay the PLC's.
        let _ = self.filter.violations(t, &self.values);
        if !may_move {
            return;
        }
        let before = self.prober.probes().len();
        let was_active = self.prober.active().is_some();
        self.prober
            .scan(t, &self.values, &mut self.filter, diagnoser);
        if self.prober.probes().len() > before {
            self.ended(t);
        }
        if let Some(p) = self.prober.active().filter(|_| !was_active) {
            eprintln!(
                "monitor: probing {} at {}: {} (writing {}{} = {}, then {}{} = 1)",
                p.part,
                self.time.format(t),
                p.describe(),
                p.actuator,
                diagnoser::plant::ProbeCoil::Value.suffix(),
                u8::from(p.value),
                p.actuator,
                diagnoser::plant::ProbeCoil::Probe.suffix(),
            );
            self.publish();
        }
        for r in &self.prober.no_probe()[self.said..] {
            eprintln!("monitor: no probe: {r}");
        }
        self.said = self.prober.no_probe().len();
    }

    /// A verdict: if it answers the probe under way, the probe ends and its
    /// outcome is the reason the verdict line gives.
    pub(super) fn verdict(&mut self, v: &Verdict) -> Option<String> {
        if v.part == PLANT_VIEW {
            return None;
        }
        let before = self.prober.probes().len();
        self.prober.note_verdict(v, &mut self.filter);
        if self.prober.probes().len() == before {
            return None;
        }
        self.ended(v.t);
        self.prober.probes().last().map(|r| r.reason.clone())
    }

    /// The flags written to the PLC, which its filter reads.
    pub(super) fn flags(&mut self, image: &FlagImage) {
        for (flag, &up) in self.plant.flags().iter().zip(image) {
            self.filter.set(&flag.to_string(), up);
        }
        self.flags.clone_from(image);
    }

    /// Ends the probe under way, if any: the source lost the plant, fell
    /// behind it, or the monitor stops.
    pub(super) fn abandon(&mut self, why: &str) {
        if let Some(r) = self.prober.abandon(why, &mut self.filter) {
            eprintln!("monitor: probe of {} ended: {}", r.part, r.reason);
            self.publish();
        }
    }

    /// The moves the PLC has acknowledged.
    pub(super) fn written(&mut self, image: &ProbeImage) {
        if image.iter().all(Option::is_none) && self.tx.borrow().iter().all(Option::is_none) {
            self.on_plc = false;
        }
    }

    /// Whether the PLC may still hold a move the monitor wrote.
    pub(super) fn on_plc(&self) -> bool {
        self.on_plc
    }

    /// The probe that just ended, on stderr, and the move's end to the PLC.
    fn ended(&mut self, t: Time) {
        if let Some(r) = self.prober.probes().last() {
            eprintln!(
                "monitor: probe of {} ended at {}: {}",
                r.part,
                self.time.format(t),
                r.reason
            );
        }
        self.publish();
    }

    /// The move under way, if any, to the source.
    fn publish(&mut self) {
        let active = self.prober.active();
        let image: ProbeImage = self
            .actuators
            .iter()
            .map(|a| active.filter(|p| p.actuator == *a).map(|p| p.value))
            .collect();
        self.on_plc |= image.iter().any(Option::is_some);
        self.tx.send_replace(image);
        if let Ok(mut s) = self.status.lock() {
            let now = active.map(|p| p.describe());
            s.probes += u64::from(now.is_some() && s.probe != now);
            s.probe = now;
        }
    }
}
