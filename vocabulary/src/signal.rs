//! Signals: the PLC's boolean inputs (sensors) and outputs (actuator orders).

use std::collections::HashMap;
use std::fmt;
use std::hash::{BuildHasherDefault, Hasher};

/// Whether a signal is read by the PLC from the plant or written by it to the plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SignalKind {
    /// A PLC input: a sensor of the plant (e.g. `C4`, turntable at loading position).
    Sensor,
    /// A PLC output: an actuator order (e.g. `A4`, rotate the turntable).
    Actuator,
}

impl SignalKind {
    /// The kind with its indefinite article, for messages: `a sensor`, `an actuator`.
    pub fn with_article(self) -> &'static str {
        match self {
            SignalKind::Sensor => "a sensor",
            SignalKind::Actuator => "an actuator",
        }
    }
}

impl fmt::Display for SignalKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SignalKind::Sensor => "sensor",
            SignalKind::Actuator => "actuator",
        })
    }
}

/// Index of a signal in its [`SignalTable`]; stable for the life of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SignalId(pub u32);

impl SignalId {
    /// The index as a `usize`, for indexing vectors of signal values.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// One declared signal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Signal {
    /// Name as written in the plant file and the logs (e.g. `C4`).
    pub name: String,
    /// Sensor or actuator.
    pub kind: SignalKind,
    /// Free text for people.
    pub description: String,
}

/// The signals of a plant, in declaration order, with lookup by name.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SignalTable {
    signals: Vec<Signal>,
    by_name: HashMap<String, SignalId, BuildHasherDefault<NameHasher>>,
}

/// FNV-1a, the hash of the name lookup: log readers look a name up per row,
/// names are short, and the keys come from the plant file, so SipHash's
/// defence against chosen collisions buys nothing here.
struct NameHasher(u64);

impl Default for NameHasher {
    fn default() -> Self {
        NameHasher(0xcbf2_9ce4_8422_2325)
    }
}

impl Hasher for NameHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }

    fn finish(&self) -> u64 {
        // The table takes its bucket from the low bits: fold the high ones in.
        self.0 ^ (self.0 >> 29)
    }
}

impl SignalTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a signal; returns `None` if its name is already taken.
    pub fn push(&mut self, signal: Signal) -> Option<SignalId> {
        if self.by_name.contains_key(&signal.name) {
            return None;
        }
        let id = SignalId(self.signals.len() as u32);
        self.by_name.insert(signal.name.clone(), id);
        self.signals.push(signal);
        Some(id)
    }

    /// The id of the signal named `name`.
    pub fn id(&self, name: &str) -> Option<SignalId> {
        self.by_name.get(name).copied()
    }

    /// The signal with this id.
    ///
    /// # Panics
    /// If `id` does not come from this table.
    pub fn get(&self, id: SignalId) -> &Signal {
        &self.signals[id.index()]
    }

    /// The name of the signal with this id.
    pub fn name(&self, id: SignalId) -> &str {
        &self.signals[id.index()].name
    }

    /// Number of signals.
    pub fn len(&self) -> usize {
        self.signals.len()
    }

    /// Whether the table is empty.
    pub fn is_empty(&self) -> bool {
        self.signals.is_empty()
    }

    /// Signals with their ids, in declaration order.
    pub fn iter(&self) -> impl Iterator<Item = (SignalId, &Signal)> {
        self.signals
            .iter()
            .enumerate()
            .map(|(i, s)| (SignalId(i as u32), s))
    }

    /// Ids of the signals of one kind, in declaration order.
    pub fn of_kind(&self, kind: SignalKind) -> impl Iterator<Item = SignalId> + '_ {
        self.iter()
            .filter(move |(_, s)| s.kind == kind)
            .map(|(id, _)| id)
    }
}

/// One change of one signal, as seen by the PLC at the scan starting at `t`.
///
/// Events with equal `t` belong to the same scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Event {
    /// Time of the scan in which the change was seen.
    pub t: crate::Time,
    /// The signal that changed.
    pub signal: SignalId,
    /// Its new value.
    pub value: bool,
}
