//! Log ingestion and learning of timed part models.
//!
//! [`ingest`] turns PLC logs of any supported form (events, intervals or scans as
//! CSV or Parquet, `candump -L`, VCD) into one stream of time-ordered events,
//! batch by batch, so that memory does not grow with the log. The learner turns
//! such streams into one timed model per plant part: states, transitions, interval
//! guards measured on the part's command clock, and the temporal estimate of each
//! sensor that the filter coupling substitutes for a failed sensor.
//!
//! It depends on [`diagnoser`] for the core types and never the other way round.
//! polars is used here, and only here, for columnar ingestion.
//!
//! It is not for: running diagnosers on-line, evaluating the filter, or simulating.

pub mod check;
pub mod dot;
pub mod ingest;
pub mod learn;
mod replay;
pub mod suggest;
