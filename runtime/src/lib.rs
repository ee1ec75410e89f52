//! What runs beside a live PLC, or in closed loop with a simulated one, in
//! real time or in event time.
//!
//! - [`monitor`]: online diagnosis (`gardefou monitor`): events from a live
//!   source (Modbus TCP, SocketCAN, MQTT Sparkplug B, JSON lines on stdin) or a replay paced on
//!   the wall clock, deadlines fired in event time, verdict lines out, flags
//!   back to the PLC, `/status` and `/metrics` over HTTP.
//! - [`jetstream`]: a monitor's plant on NATS JetStream (`monitor --nats`):
//!   its events, verdicts and flags published in order, kept through a
//!   broker's absence.
//! - [`fleet`]: fleet workers (`gardefou fleet`): many plants diagnosed
//!   from their streams, shared between workers through leases, checkpointed
//!   and taken over when a worker dies; the fleet view.
//! - [`virtual_plc`]: the simulated sorting line scanning in real time under
//!   safe control through the safety filter, behind a Modbus TCP server
//!   (`gardefou simulate --serve-modbus`).
//! - [`flags`]: verdicts to the `def_` and `suspect_` flags a PLC's filter
//!   reads, shared by the monitor and the closed loop.
//! - [`closed_loop`]: the demo's loop (`gardefou demo`): a simulated plant
//!   (the sorting line, or the cylinder rig under its GRAFCETs), safe control
//!   through the rewritten filter, the diagnosers, and their flags back to
//!   the filter.
//! - [`probe`]: active diagnosis: a move of an ambiguous, waiting part that the
//!   filter allows under every candidate and whose outcome separates them.
//!
//! It takes plain settings (no command-line parsing) and returns
//! [`diagnoser::Failure`].
//!
//! It is not for: replaying logs offline (`diagnose`, `report`), learning
//! models, or the filter's rewriting and Structured Text; it calls the crates
//! that do.

pub mod closed_loop;
pub mod flags;
pub mod fleet;
pub mod jetstream;
pub mod monitor;
pub mod probe;
pub mod virtual_plc;
