//! Log ingestion and learning of timed part models.
//!
//! The learner turns streams of time-ordered events (a `logs::LogStream`, read
//! batch by batch from any log form, so that memory does not grow with the log) into one timed model per plant part: states, transitions, interval
//! guards measured on the part's command clock, and the temporal estimate of each
//! sensor that the filter coupling substitutes for a failed sensor.
//!
//! It depends on [`diagnoser`] for the core types and never the other way round.
//!
//! It is not for: running diagnosers on-line, evaluating the filter, or simulating.

pub mod conformance;
pub mod graph;
pub mod learn;
mod replay;
pub mod suggest;
