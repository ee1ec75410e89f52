//! Local timed diagnosers (seed 002 §3): one per plant part, built from the
//! part's learned model and the plant's fault templates, run on-line over the
//! part's events and the passing of time.
//!
//! - [`part`]: the fault modes of a part and the semantics of its hypotheses
//!   (mode, physical state), including hidden transitions and deadlines.
//! - [`engine`]: the diagnoser automaton whose states are sets of hypotheses,
//!   built on the fly and memoised, so a replay is a table lookup per scan.
//! - [`run`]: every part's diagnoser fed with a plant's events, giving the
//!   verdict changes of SPEC §3.
//! - [`partwise`]: the same over a recorded log, each part on its own
//!   events, on several threads, with the same output.
//! - [`snapshot`]: the diagnosers as data between two scans, to checkpoint
//!   and take over from.
//! - [`verdict`]: a part's verdict and its JSON line.
//! - [`fusion`]: the coordinator, combining the parts' verdicts into a plant view.
//!
//! Labels, verdicts and flags follow SPEC §3: the verdict is normal while the
//! normal hypothesis survives; otherwise the labels are the remaining fault
//! modes, `def_<partition>` is raised when they all lie in one partition, and the
//! suspects are the partitions they touch.

pub mod compile;
pub mod diagnosability;
pub mod engine;
mod explain;
pub mod fusion;
pub mod part;
mod part_run;
pub mod partwise;
pub mod run;
pub mod snapshot;
pub mod verdict;

pub use engine::{Engine, Labels};
pub use part::{Hypothesis, ModeKind, PartDiagnoser};
pub use partwise::PartwiseReplay;
pub use run::{DiagnoserOptions, PartSummary, PlantDiagnoser};
pub use snapshot::Snapshot;
pub use verdict::{UNKNOWN_LABEL, Verdict, VerdictKind};
