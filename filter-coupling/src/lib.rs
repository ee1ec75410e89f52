//! The PLC safety filter and its coupling with the diagnosers.
//!
//! This crate is where the constraint language's evaluation, observers, safe control
//! synthesis, rewriting of constraints with fault flags and temporal estimates, and
//! Structured Text generation will live. The expression syntax itself is parsed by
//! [`diagnoser::expr`], because plant files carry constraints.
//!
//! It is not for: learning models, running diagnosers, or simulating plants.
//!
//! Status: the crate is reserved in the workspace; its contents arrive with the
//! filter work (see `ARCHITECTURE.md`).
