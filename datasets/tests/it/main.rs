//! The integration tests of `datasets`, in one test binary: one module per concern.

mod cylinders;
mod generated;
mod sorting;
