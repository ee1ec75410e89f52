//! The integration tests of `learning`, in one test binary: one module per concern.

mod learn;
mod suggest;
