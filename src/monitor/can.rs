//! CANopen PDOs from SocketCAN (placeholder until the transport lands).

use diagnoser::{Plant, TimeFormat};

use super::source::{Link, Source};
use crate::Failure;

/// PDOs read from a CAN interface.
pub struct CanSource;

impl CanSource {
    /// Not available yet.
    pub fn new(_iface: &str, _plant: &Plant, _speed: f64) -> Result<CanSource, Failure> {
        Err(Failure::BadInput("--can: not available yet".into()))
    }
}

impl Source for CanSource {
    fn time_format(&self) -> TimeFormat {
        TimeFormat::Rfc3339
    }
    fn spawn(self: Box<Self>, _link: Link) {}
}
