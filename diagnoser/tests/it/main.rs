//! The integration tests of `diagnoser`, in one test binary: one module per concern.

mod diagnosis;
mod faudes;
mod faudes_product;
mod fusion;
mod partwise;
