//! The vocabulary's integration tests, in one binary.

mod model_validity;
mod plant_fixtures;
