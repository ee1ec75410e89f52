//! The diagnosers of gardefou: one timed diagnoser per plant part, over the
//! fault modes of its learned model, run on-line event by event; their verdicts
//! (normal, certain fault, ambiguous) and flags; the fusion of the parts'
//! verdicts into the plant's; the compiled diagnoser automaton and
//! diagnosability ([`diagnosis`]); and libFAUDES generators, read and checked
//! for event-diagnosability ([`faudes`]).
//!
//! It speaks the [`vocabulary`] crate's types, re-exported here (`diagnoser::Plant`
//! is `vocabulary::Plant`) so that callers of the diagnosers need one import.
//! It is kept free of heavy dependencies (no polars, no tokio) so that it
//! builds and tests fast.
//!
//! It is not for: reading or writing logs (`logs`), learning models
//! (`learning`), evaluating or rewriting the safety filter (`filter-coupling`),
//! or simulating plants (`datasets`).

pub mod diagnosis;
pub mod faudes;

pub use vocabulary::{
    Event, Failure, FaultTemplate, Flag, FlagKind, Located, Location, MS, Plant, SECOND, Signal,
    SignalId, SignalKind, SignalTable, Time, TimeFormat, TimeUnit, error, expr, fault, flag, model,
    output, panics, plant, signal, time,
};
