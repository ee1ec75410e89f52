//! The integration tests of `logs`, in one test binary: one module per concern.

mod ingest;
mod log_fixtures;
mod log_props;
mod log_streams;
mod plain_rows;
mod stream;
mod text_forms;
