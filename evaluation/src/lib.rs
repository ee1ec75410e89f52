//! Diagnosis quality over generated plants: how often gardefou raises a false
//! alarm, keeps the true fault among its labels, detects and isolates faults,
//! and how fast, measured as rates over many plants nobody tuned it for.
//!
//! For each plant drawn by [`datasets::generated`], [`evaluate`] learns a
//! model from fault-free logs, replays a fresh fault-free log (false alarms),
//! replays every declared fault once from a random onset ([`runs`] branches
//! each faulty run off one fault-free run), judges each replay against the
//! simulator's ground truth ([`judge`]), and runs the diagnosability check.
//! [`summary`] turns the outcomes into the benchmark's table and lists the
//! faults where `check` and the replays disagree.
//!
//! The benchmark itself is `cargo bench -p evaluation --bench generality`
//! (`-- --quick` for a short run); `benches/generality-rerun.sh` replays one
//! faulty run with the command line alone.
//!
//! It is not for: diagnosing, learning or simulating; it only calls the crates
//! that do.

pub mod evaluate;
pub mod judge;
pub mod runs;
pub mod summary;

pub use evaluate::{PlantOutcome, Settings, evaluate, evaluate_family};
