//! Core types of gardefou (time, signals, events, plant files, fault templates,
//! models) and the diagnosers that run on them.
//!
//! Every other crate of the workspace depends on this one; it depends on none of
//! them. It is kept free of heavy dependencies (no polars, no tokio) so that it
//! builds and tests fast.
//!
//! It is not for: reading or writing logs (that is `logs`), evaluating or
//! rewriting the safety filter (`filter-coupling`), or simulating plants
//! (`datasets`).

pub mod diagnosis;
pub mod error;
pub mod expr;
pub mod faudes;
pub mod fault;
pub mod flag;
pub mod model;
pub mod plant;
pub mod signal;
pub mod time;

pub use error::{Failure, Located, Location};
pub use fault::FaultTemplate;
pub use flag::{Flag, FlagKind};
pub use plant::Plant;
pub use signal::{Event, Signal, SignalId, SignalKind, SignalTable};
pub use time::{MS, SECOND, Time, TimeFormat, TimeUnit};
