//! Modbus TCP (placeholder).

use diagnoser::{Plant, TimeFormat};

use super::source::{Link, Source};
use crate::Failure;

/// A PLC polled over Modbus TCP.
pub struct ModbusSource;

impl ModbusSource {
    /// Not available yet.
    pub fn new(_addr: &str, _unit: u8, _plant: &Plant, _speed: f64) -> Result<ModbusSource, Failure> {
        Err(Failure::BadInput("--modbus: not available yet".into()))
    }
}

impl Source for ModbusSource {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Rfc3339
    }
    fn spawn(self: Box<Self>, _link: Link) {}
}
