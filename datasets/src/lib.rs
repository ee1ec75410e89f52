//! Plant simulators with fault injection, and the reference logs shipped with
//! gardefou.
//!
//! A simulator steps once per PLC scan over a physical model of a plant. In each
//! scan the PLC reads the sensors (through any injected sensor fault), runs a
//! [`Controller`], and writes its orders (through any injected actuator fault) to
//! the plant. What the PLC saw and ordered is recorded as a log, beside the ground
//! truth of the injected faults and a record of any physical damage.
//!
//! Two reference plants are modelled from the seeds: the box-sorting line
//! ([`sorting`]) and the four-cylinder teaching rig ([`cylinders`]). Any number
//! of other plants are generated from a seed ([`generated`]): lines of
//! stations with cylinders, arms, tables, grippers, conveyors and magazines,
//! their step-chain programs and their safety constraints.
//!
//! It is not for: learning, diagnosis or filter evaluation; those read the logs
//! this crate writes.

pub mod cylinders;
pub mod generated;
pub mod inject;
pub mod output;
pub mod sim;
pub mod sorting;

pub use inject::{FaultSpec, Injection};
pub use sim::{Controller, Damage, Physics, ScanSink, SimConfig, SimReport, run};
