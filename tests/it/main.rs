//! The end-to-end tests of the `gardefou` binary, in one test binary.
//!
//! Each module is one verb or one scenario. They run the real binary
//! (`CARGO_BIN_EXE_gardefou`) against real peers on loopback (pymodbus,
//! Chromium, Graphviz), with helpers shared through [`support`] and [`st`].
//! One binary links the workspace once instead of once per file.
//!
//! Two files stay binaries of their own, so that nothing runs beside them:
//! `tests/monitor_http.rs` raises this process's descriptor limit and floods a
//! monitor with nearly as many connections as the process may open, which
//! would starve the tests beside it; `tests/monitor_modbus.rs` runs the monitor
//! in real time (4× the plant's speed) through a slow, lossy network, one test
//! at a time, and a loaded machine changes what it sees.

mod support;

mod check_filter;
mod checkpoint;
mod control_law;
mod cylinders_loop;
mod demo_cli;
mod diagnose_cli;
mod diagnosis_soundness;
mod filter_cli;
mod filter_st;
mod fleet;
mod learn_cli;
mod learned_models;
mod monitor_can;
mod monitor_cli;
mod monitor_nats;
mod monitor_opcua;
mod monitor_sparkplug;
mod netfault;
mod probing;
mod replay_identity;
mod report_browser;
mod report_cli;
mod shipped_datasets;
mod simulate_cli;
mod slow_turntable;
mod st;
mod virtual_plc;
