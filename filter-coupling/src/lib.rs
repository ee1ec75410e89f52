//! The PLC safety filter and its coupling with the diagnosers.
//!
//! - [`eval`]: evaluating constraint expressions in one PLC scan, and the
//!   literals that made a violated constraint true.
//! - [`rewrite`]: seed 002's rewriting of constraints with fault flags and
//!   temporal estimates, made conservative in the estimates' uncertain intervals.
//! - [`filter`]: the filter as the PLC runs it once per scan: observers,
//!   estimate intervals, flags, violated constraints, the fallback, and safe
//!   control by constraints (seed 001 §4).
//! - [`synthesis`]: the same safe control law in closed form, as expressions.
//! - [`st`]: the filter as IEC 61131-3 Structured Text.
//! - [`simplify`]: removing the diagnoser branches the filter makes impossible.
//!
//! The expression syntax itself is parsed by [`diagnoser::expr`], because plant
//! files carry constraints.
//!
//! It is not for: learning models, running diagnosers, or simulating plants.

pub mod eval;
pub mod filter;
pub mod rewrite;
pub mod simplify;
pub mod st;
pub mod synthesis;
