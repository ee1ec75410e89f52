//! Sparkplug B on the wire: topics (`spBv1.0/GROUP/TYPE/EDGE[/DEVICE]`) and
//! the protobuf payload, as far as the monitor reads and writes it.
//!
//! The messages mirror Eclipse Tahu's `sparkplug_b.proto`. Only the fields
//! read here are declared; protobuf skips the others (metadata, property
//! sets, datasets, templates), so a payload carrying them decodes all the
//! same. A `oneof` is a set of optional fields on the wire, so the value
//! fields are plain options.
//!
//! ```
//! use prost::Message;
//! use runtime::monitor::sparkplug::payload::{Metric, Payload};
//!
//! let sent = Payload {
//!     timestamp: Some(1_200),
//!     seq: Some(3),
//!     metrics: vec![Metric::new_boolean("C4", true)],
//! };
//! let got = Payload::decode(sent.encode_to_vec().as_slice()).unwrap();
//! assert_eq!(got.metrics[0].boolean(), Some(true));
//! assert_eq!(got.seq, Some(3));
//! ```

/// The Sparkplug B namespace, the first level of every topic.
pub const NAMESPACE: &str = "spBv1.0";

/// Sparkplug B's data type of a boolean metric.
pub const BOOLEAN: u32 = 11;

/// The node control metric that asks an edge node to publish its births
/// again.
pub const REBIRTH: &str = "Node Control/Rebirth";

/// The birth/death sequence metric of NBIRTH and NDEATH.
pub const BD_SEQ: &str = "bdSeq";

/// A Sparkplug B payload.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// When the message was made, in milliseconds since the epoch.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    /// The metrics.
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// The edge node's message sequence number, 0 to 255.
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
}

/// One metric of a payload.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    /// Its name (always in a birth; in data, the alias may stand for it).
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    /// The number standing for the name after the birth.
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// When the value was seen, in milliseconds since the epoch.
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// Sparkplug data type (given in births).
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// Data from the past (store and forward), not a live value.
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    /// The value is null.
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    /// Value of the integer types up to 32 bits.
    #[prost(uint32, optional, tag = "10")]
    pub int_value: Option<u32>,
    /// Value of the 64-bit integer types.
    #[prost(uint64, optional, tag = "11")]
    pub long_value: Option<u64>,
    /// Value of a boolean.
    #[prost(bool, optional, tag = "14")]
    pub boolean_value: Option<bool>,
}

impl Metric {
    /// A boolean metric by name, as a command carries it.
    pub fn new_boolean(name: &str, value: bool) -> Metric {
        Metric {
            name: Some(name.to_string()),
            datatype: Some(BOOLEAN),
            boolean_value: Some(value),
            ..Metric::default()
        }
    }

    /// Its value as a boolean: a boolean, or an integer 0 or 1 (a PLC's
    /// bit often travels as an integer); `None` for anything else.
    pub fn boolean(&self) -> Option<bool> {
        if self.is_null == Some(true) {
            return None;
        }
        let integer = self.int_value.map(u64::from).or(self.long_value);
        match (self.boolean_value, integer) {
            (Some(b), _) => Some(b),
            (None, Some(0)) => Some(false),
            (None, Some(1)) => Some(true),
            _ => None,
        }
    }

    /// Whether it is historical data, not a live value.
    pub fn historical(&self) -> bool {
        self.is_historical == Some(true)
    }
}

/// The message types of a Sparkplug B topic that the monitor tells apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The edge node's birth: every node metric, its aliases, seq 0.
    NBirth,
    /// The edge node's death (its MQTT will, or a clean disconnect).
    NDeath,
    /// Node metrics that changed.
    NData,
    /// A device's birth.
    DBirth,
    /// A device's death.
    DDeath,
    /// Device metrics that changed.
    DData,
    /// A command to the node or a device, or the host's state: not the
    /// edge node's own report.
    Other,
}

/// A topic read: `spBv1.0/GROUP/TYPE/EDGE[/DEVICE]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topic<'a> {
    /// The group.
    pub group: &'a str,
    /// The message type.
    pub kind: Kind,
    /// The edge node.
    pub edge: &'a str,
    /// The device, for device messages.
    pub device: Option<&'a str>,
}

impl<'a> Topic<'a> {
    /// Reads a topic; `None` if it is not a Sparkplug B node or device
    /// topic.
    pub fn parse(topic: &'a str) -> Option<Topic<'a>> {
        let mut parts = topic.split('/');
        if parts.next()? != NAMESPACE {
            return None;
        }
        let group = parts.next()?;
        let kind = match parts.next()? {
            "NBIRTH" => Kind::NBirth,
            "NDEATH" => Kind::NDeath,
            "NDATA" => Kind::NData,
            "DBIRTH" => Kind::DBirth,
            "DDEATH" => Kind::DDeath,
            "DDATA" => Kind::DData,
            _ => Kind::Other,
        };
        let edge = parts.next()?;
        let device = parts.next();
        if parts.next().is_some() {
            return None;
        }
        Some(Topic {
            group,
            kind,
            edge,
            device,
        })
    }
}

/// The topic of a command to the edge node (`NCMD`) or, with `device`, to
/// one of its devices (`DCMD`).
pub fn command_topic(group: &str, edge: &str, device: Option<&str>) -> String {
    match device {
        Some(d) => format!("{NAMESPACE}/{group}/DCMD/{edge}/{d}"),
        None => format!("{NAMESPACE}/{group}/NCMD/{edge}"),
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use prost::Message;

    use super::*;

    #[test]
    fn topics_are_read_by_level() {
        let t = Topic::parse("spBv1.0/line/DDATA/plc7/io").expect("a device topic");
        assert_eq!(
            (t.group, t.kind, t.edge, t.device),
            ("line", Kind::DData, "plc7", Some("io"))
        );
        let t = Topic::parse("spBv1.0/line/NBIRTH/plc7").expect("a node topic");
        assert_eq!((t.kind, t.device), (Kind::NBirth, None));
        assert_eq!(
            Topic::parse("spBv1.0/line/NCMD/plc7").map(|t| t.kind),
            Some(Kind::Other)
        );
        assert!(Topic::parse("spAv1.0/line/NDATA/plc7").is_none());
        assert!(Topic::parse("spBv1.0/line/DDATA/plc7/io/extra").is_none());
        assert!(Topic::parse("spBv1.0/line").is_none());
    }

    /// The bytes of a payload with fields the monitor does not declare
    /// (metric metadata, field 8; a property set, field 9; a string value,
    /// field 15; the payload's uuid, field 4): they are skipped.
    #[test]
    fn unknown_fields_are_skipped() {
        let metric = Metric::new_boolean("C4", true).encode_to_vec();
        let mut m = metric.clone();
        m.extend_from_slice(&[0x42, 0x02, 0x08, 0x01]); // metadata { is_multi_part: true }
        m.extend_from_slice(&[0x7a, 0x01, b'x']); // string_value "x"
        let mut payload = vec![0x08, 0x05]; // timestamp 5
        payload.extend_from_slice(&[0x12, m.len() as u8]);
        payload.extend_from_slice(&m);
        payload.extend_from_slice(&[0x22, 0x02, b'i', b'd']); // uuid "id"
        let got = Payload::decode(payload.as_slice()).expect("decodes");
        assert_eq!(got.timestamp, Some(5));
        assert_eq!(got.metrics[0].name.as_deref(), Some("C4"));
        assert_eq!(got.metrics[0].boolean(), Some(true));
    }

    #[test]
    fn values_read_as_booleans() {
        let int = |v| Metric {
            int_value: Some(v),
            ..Metric::default()
        };
        assert_eq!(int(0).boolean(), Some(false));
        assert_eq!(int(1).boolean(), Some(true));
        assert_eq!(int(2).boolean(), None);
        let null = Metric {
            is_null: Some(true),
            boolean_value: Some(true),
            ..Metric::default()
        };
        assert_eq!(null.boolean(), None);
        assert_eq!(Metric::default().boolean(), None);
    }

    proptest! {
        /// Whatever the bytes, decoding ends without a panic.
        #[test]
        fn any_bytes_decode_or_fail(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = Payload::decode(bytes.as_slice());
        }

        /// What is encoded decodes to itself.
        #[test]
        fn payloads_round_trip(
            timestamp in proptest::option::of(any::<u64>()),
            seq in proptest::option::of(0u64..256),
            metrics in proptest::collection::vec(
                ("[A-Za-z0-9_/]{1,12}", proptest::option::of(any::<u64>()), any::<bool>()),
                0..20,
            ),
        ) {
            let sent = Payload {
                timestamp,
                seq,
                metrics: metrics
                    .iter()
                    .map(|(n, alias, v)| Metric { alias: *alias, ..Metric::new_boolean(n, *v) })
                    .collect(),
            };
            let got = Payload::decode(sent.encode_to_vec().as_slice()).expect("decodes");
            prop_assert_eq!(got, sent);
        }
    }
}
