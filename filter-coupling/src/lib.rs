//! The PLC safety filter and its coupling with the diagnosers.
//!
//! - [`eval`]: evaluating constraint expressions in one PLC scan, and the
//!   literals that made a violated constraint true.
//! - [`rewrite`]: seed 002's rewriting of constraints with fault flags and
//!   temporal estimates, made conservative in the estimates' uncertain intervals.
//!
//! The expression syntax itself is parsed by [`diagnoser::expr`], because plant
//! files carry constraints. Safe control synthesis, the fallback, Structured Text
//! generation and the filter-based simplification of diagnosers are to come.
//!
//! It is not for: learning models, running diagnosers, or simulating plants.

pub mod eval;
pub mod rewrite;
