//! The vocabulary of gardefou: the types every other crate speaks in.
//!
//! - [`time`]: [`Time`] (nanoseconds), units and the two ways logs write times;
//! - [`signal`]: sensors and actuators, their table, and the [`Event`] (one
//!   signal changing value);
//! - [`plant`]: the `plant.toml` file (SPEC §3): parts, partitions, faults,
//!   constraints, observers, the Modbus map, every cross-reference checked;
//! - [`expr`]: the boolean expressions of constraints and observers;
//! - [`fault`]: the fault templates (seed 002's table 1, element faults);
//! - [`flag`]: the flags the diagnosers raise for the filter;
//! - [`model`]: the learned timed part models (`model.json`);
//! - [`error`]: located one-line errors (`file:line:column: field 'x': message`)
//!   and the `Failure` a command reports.
//!
//! It depends on no other crate of the workspace, and on nothing heavy (no
//! polars, no tokio, no petgraph), so that everything above it builds fast and
//! an edit to a diagnoser rebuilds neither the log layer, the learner nor the
//! simulators.
//!
//! It is not for: what runs on these types — reading logs (`logs`), diagnosing
//! (`diagnoser`), learning (`learning`), filtering (`filter-coupling`).

pub mod error;
pub mod expr;
pub mod fault;
pub mod flag;
pub mod model;
pub mod output;
pub mod panics;
pub mod plant;
pub mod signal;
pub mod time;

pub use error::{Failure, Located, Location};
pub use fault::FaultTemplate;
pub use flag::{Flag, FlagKind};
pub use plant::Plant;
pub use signal::{Event, Signal, SignalId, SignalKind, SignalTable};
pub use time::{MS, SECOND, Time, TimeFormat, TimeUnit};
