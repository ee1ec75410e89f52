//! Learning of timed part models from PLC logs.
//!
//! This crate is where log ingestion at scale (CSV, Parquet, candump, VCD) and the
//! learning of one timed model per plant part will live. It depends on
//! [`diagnoser`] for the core types and never the other way round.
//!
//! It is not for: running diagnosers, the filter, or simulating plants.
//!
//! Status: the crate is reserved in the workspace; its contents arrive with the
//! learning work (see `ARCHITECTURE.md`).
