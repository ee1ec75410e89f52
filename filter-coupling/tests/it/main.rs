//! The integration tests of `filter-coupling`, in one test binary: one module per concern.

mod filter;
mod rewrite;
mod simplify;
