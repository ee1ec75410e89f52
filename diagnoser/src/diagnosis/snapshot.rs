//! A plant's diagnosers as data, between two scans: what a fleet worker
//! checkpoints, and what another worker takes over from.
//!
//! A [`Snapshot`] holds what the verdicts to come depend on, and nothing of
//! the automaton built so far: per part, the observed vector, the
//! hypotheses, each clock's origin, the flags raised, the labels last shown,
//! the unknown episode; and the coordinator's latest verdicts. Restored into
//! diagnosers built from the same plant and model, the run goes on as if it
//! had never stopped: the same verdict lines follow (the automaton's states
//! are built again on the way, from their hypotheses).
//!
//! ```
//! use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
//! use diagnoser::{Plant, model::Model};
//!
//! let plant = Plant::from_path("../datasets/data/sorting/F2/plant.toml".as_ref()).unwrap();
//! let model = Model::from_path("tests/fixtures/diagnosis/sorting-model.json".as_ref()).unwrap();
//! let options = DiagnoserOptions::default();
//! let mut running = PlantDiagnoser::new(&plant, &model, &options).unwrap();
//! running.start(0, &vec![false; plant.signals.len()]);
//! running.advance_to(60_000_000_000, &mut |_| {});
//!
//! // Between two scans, the state goes out as JSON...
//! let saved = serde_json::to_string(&running.snapshot().unwrap()).unwrap();
//! // ...and into diagnosers built afresh, elsewhere.
//! let mut taken_over = PlantDiagnoser::new(&plant, &model, &options).unwrap();
//! taken_over.restore(&serde_json::from_str(&saved).unwrap()).unwrap();
//! assert_eq!(taken_over.now(), running.now());
//! assert_eq!(taken_over.snapshot(), running.snapshot());
//! ```

use serde::{Deserialize, Serialize};

use super::engine::Labels;
use super::part::Hypothesis;
use super::part_run::{Episode, WatchSnapshot};
use super::run::PlantDiagnoser;
use super::verdict::Verdict;
use crate::Time;

/// Every part's diagnoser and the coordinator, between two scans.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    pub(crate) parts: Vec<PartSnapshot>,
    /// The time the diagnosers had reached.
    pub(crate) now: Time,
    pub(crate) earliest: Option<Time>,
    /// Per part, its latest verdict and its time.
    pub(crate) latest: Vec<Option<(Time, Verdict)>>,
    /// The plant view's `def_` flags, in the order raised.
    pub(crate) flags: Vec<String>,
    /// The plant view last given: labels and flags.
    pub(crate) shown: Option<(Vec<String>, Vec<String>)>,
}

/// One part's diagnoser, between two scans.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartSnapshot {
    pub(crate) part: String,
    pub(crate) obs: u32,
    pub(crate) hypotheses: Vec<Hypothesis>,
    /// Per clock, when it last restarted (`None`: not yet).
    pub(crate) origins: Vec<Option<Time>>,
    pub(crate) flags: u32,
    pub(crate) shown: Labels,
    pub(crate) next_timer: Option<Time>,
    pub(crate) last_command: Option<(u32, u32)>,
    pub(crate) detected: Option<Time>,
    pub(crate) episode: Option<Episode>,
    /// Normal after a glitch, while it is followed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) watch: Option<WatchSnapshot>,
    pub(crate) changes: u64,
}

impl Snapshot {
    /// The time the diagnosers had reached.
    pub fn now(&self) -> Time {
        self.now
    }
}

impl PlantDiagnoser {
    /// The diagnosers as data, or `None` in the middle of a scan (after
    /// [`PlantDiagnoser::push`], before the scan is completed by a later
    /// event or [`PlantDiagnoser::advance_to`]).
    pub fn snapshot(&self) -> Option<Snapshot> {
        if self.scan.is_some() {
            return None;
        }
        let (latest, flags, shown) = self.coordinator.state();
        Some(Snapshot {
            parts: self.parts.iter().map(|r| r.snapshot()).collect(),
            now: self.now,
            earliest: self.earliest,
            latest: latest
                .iter()
                .map(|v| v.as_ref().map(|v| (v.t, v.clone())))
                .collect(),
            flags: flags.to_vec(),
            shown: shown.clone(),
        })
    }

    /// Puts the diagnosers where `snapshot` says, as if they had run up to
    /// it. An error, and the diagnosers left as they were, when it was not
    /// taken from diagnosers of the same plant and model.
    pub fn restore(&mut self, snapshot: &Snapshot) -> Result<(), String> {
        let mut restored = self.clone();
        restored.restore_into(snapshot)?;
        *self = restored;
        Ok(())
    }

    fn restore_into(&mut self, snapshot: &Snapshot) -> Result<(), String> {
        let s = snapshot;
        if s.parts.len() != self.parts.len() || s.latest.len() != self.parts.len() {
            return Err(format!(
                "{} parts where the model has {}",
                s.parts.len(),
                self.parts.len()
            ));
        }
        for (run, part) in self.parts.iter_mut().zip(&s.parts) {
            run.restore(part)?;
        }
        self.touched.clear();
        self.scan = None;
        for (p, r) in self.parts.iter().enumerate() {
            self.obs[p] = r.obs();
            self.open[p] = 0;
            self.timers[p] = r.next_timer().unwrap_or(Time::MAX);
        }
        self.now = s.now;
        self.earliest = s.earliest;
        let latest = s
            .latest
            .iter()
            .map(|v| v.as_ref().map(|(t, v)| Verdict { t: *t, ..v.clone() }))
            .collect();
        self.coordinator
            .set_state(latest, s.flags.clone(), s.shown.clone());
        Ok(())
    }
}
