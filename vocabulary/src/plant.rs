//! The plant file, `plant.toml`: signals, parts, faults, partitions, observers and
//! constraints (SPEC §3).
//!
//! Parsing checks every cross-reference (a part's sensors exist and are sensors, a
//! fault's template fits its target, a constraint names known variables...) and
//! reports the first problem as `file:line:column: field 'x': message`.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt;
use std::ops::Range;
use std::path::Path;

use serde::Deserialize;
use serde::de::{Deserializer, MapAccess, Visitor};
use toml::Spanned;

use crate::error::{Located, Location, line_column};
use crate::expr::Expr;
use crate::fault::{FaultTarget, FaultTemplate};
use crate::flag::Flag;
use crate::signal::{Signal, SignalId, SignalKind, SignalTable};
use crate::time::{MS, Time, TimeUnit};

/// A parsed and checked plant file.
#[derive(Debug, Clone, PartialEq)]
pub struct Plant {
    /// Plant name (e.g. `sorting`).
    pub name: String,
    /// PLC scan period.
    pub scan_period: Time,
    /// Unit of numeric timestamps in this plant's logs.
    pub time_unit: TimeUnit,
    /// Declared signals, in file order.
    pub signals: SignalTable,
    /// Internal PLC variables (e.g. GRAFCET steps `X1`) that functional constraints read.
    pub variables: Vec<String>,
    /// Parts of the plant, each with its own local diagnoser.
    pub parts: Vec<Part>,
    /// Fault labels and their templates, in file order (or generated, see [`Plant::parse`]).
    pub faults: Vec<FaultDef>,
    /// Fault partitions; partition `X` has the flag `def_X`.
    pub partitions: Vec<Partition>,
    /// Observers: sequential functions of the inputs.
    pub observers: Vec<Observer>,
    /// Safety constraints (must evaluate to 0 in every scan).
    pub constraints: Vec<Constraint>,
    /// Functional constraints (seed 001).
    pub functional: Vec<Constraint>,
    /// Where each signal sits in the CAN process image (for `candump` logs).
    pub can: Vec<CanBit>,
    /// Modbus addresses written in `[modbus]`, overriding the default map (see
    /// [`Plant::modbus_map`]).
    pub modbus: Vec<ModbusEntry>,
    /// OPC UA NodeIds written in `[opcua]`; a signal or flag without one is
    /// found on the server by its browse name.
    pub opcua: Vec<OpcuaEntry>,
}

/// One signal's place in a CANopen (CiA 401) process image: bit `bit` of the
/// payload of frames with identifier `cob_id`, bit 0 being the least significant
/// bit of data byte 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanBit {
    /// The signal carried.
    pub signal: SignalId,
    /// CAN identifier of the PDO (e.g. `0x181`, TPDO1 of node 1).
    pub cob_id: u32,
    /// Bit index in the payload, from 0 (byte 0, LSB) to 63.
    pub bit: u8,
}

/// A Modbus data table a signal or flag can live in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ModbusTable {
    /// Read-only bits (function 2): the PLC's inputs.
    DiscreteInput,
    /// Read-write bits (functions 1, 5, 15): the PLC's outputs and flags.
    Coil,
}

impl fmt::Display for ModbusTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ModbusTable::DiscreteInput => "discrete input",
            ModbusTable::Coil => "coil",
        })
    }
}

/// One address written in `[modbus]`: `C4 = { discrete_input = 4 }`,
/// `A4 = { coil = 0 }` or `def_C4 = { coil = 100 }`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModbusEntry {
    /// A signal, or a flag `def_<partition>` / `suspect_<partition>`.
    pub name: String,
    /// Where it lives.
    pub table: ModbusTable,
    /// Its address in that table (0-based, as on the wire).
    pub address: u16,
}

/// One NodeId written in `[opcua]`: `C4 = "ns=2;s=Line.C4"`, or with the
/// namespace by its URI, `def_C4 = "nsu=urn:line;s=Flags.def_C4"`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpcuaEntry {
    /// A signal, or a flag `def_<partition>` / `suspect_<partition>`.
    pub name: String,
    /// Its NodeId in OPC UA's text form (Part 6, 5.3.1.10): `ns=N;` or
    /// `nsu=URI;` (none: namespace 0), then `i=`, `s=`, `g=` or `b=` and the
    /// identifier.
    pub node_id: String,
}

/// Where every signal and flag of a plant lives on a Modbus TCP server.
///
/// The default needs no configuration: sensors are discrete inputs 0, 1, … in
/// plant-file order, actuators are coils 0, 1, …, and flags are coils from
/// [`ModbusMap::FLAGS_FROM`] on, in partition order, every `def_` flag first and
/// then every `suspect_` flag. Each actuator's three probe coils
/// ([`ProbeCoil`]) follow from [`ModbusMap::PROBES_FROM`] on, in plant-file
/// order, or from just after the highest signal or flag coil if that is
/// higher. `[modbus]` entries override single addresses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModbusMap {
    /// Each signal's table and address, indexed by [`SignalId`].
    pub signals: Vec<(ModbusTable, u16)>,
    /// Each flag and its coil: every `def_` flag in partition order, then
    /// every `suspect_` flag.
    pub flags: Vec<(Flag, u16)>,
    /// Each actuator's probe coils, in plant-file order.
    pub probes: Vec<ProbeCoils>,
}

impl ModbusMap {
    /// The first flag coil of the default map.
    pub const FLAGS_FROM: u16 = 100;
    /// The first probe coil of the default map, unless a signal or flag sits
    /// at or beyond it (a plant with many partitions, or a `[modbus]` entry):
    /// the probe coils then start just after the highest of them, so that a
    /// default never clashes.
    pub const PROBES_FROM: u16 = 200;

    /// The flag coil of `flag`, if the map has it.
    pub fn flag(&self, flag: &Flag) -> Option<u16> {
        self.flags.iter().find(|f| f.0 == *flag).map(|f| f.1)
    }

    /// The probe coils of `actuator`, if it is one.
    pub fn probe(&self, actuator: SignalId) -> Option<&ProbeCoils> {
        self.probes.iter().find(|p| p.actuator == actuator)
    }
}

/// One of the three coils of an actuator's probing move (`monitor --probe`):
/// the monitor asks the PLC's safety filter for a move of one output, which
/// the filter takes in each scan unless a safety constraint forbids it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ProbeCoil {
    /// `<A>_PROBE`: a probing move of A is requested (written by the monitor).
    Probe,
    /// `<A>_PROBE_VALUE`: the value asked for (written by the monitor).
    Value,
    /// `<A>_PROBE_REFUSED`: the PLC's filter refused the move in its last
    /// scan (set by the PLC; clients may not write it).
    Refused,
}

impl ProbeCoil {
    /// The three, in the order of the default map.
    pub const ALL: [ProbeCoil; 3] = [ProbeCoil::Probe, ProbeCoil::Value, ProbeCoil::Refused];

    /// What follows the actuator's name in the coil's name.
    pub fn suffix(self) -> &'static str {
        match self {
            ProbeCoil::Probe => "_PROBE",
            ProbeCoil::Value => "_PROBE_VALUE",
            ProbeCoil::Refused => "_PROBE_REFUSED",
        }
    }

    /// The coil's name for `actuator`, e.g. `A4_PROBE_VALUE`.
    pub fn name(self, actuator: &str) -> String {
        format!("{actuator}{}", self.suffix())
    }

    /// The actuator's name and the coil, if `name` ends as a probe coil's
    /// does (the actuator is not checked).
    pub fn parse(name: &str) -> Option<(&str, ProbeCoil)> {
        ProbeCoil::ALL.into_iter().find_map(|c| {
            let actuator = name.strip_suffix(c.suffix())?;
            (!actuator.is_empty()).then_some((actuator, c))
        })
    }
}

/// The probe coils of one actuator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProbeCoils {
    /// The actuator.
    pub actuator: SignalId,
    /// `<A>_PROBE`.
    pub probe: u16,
    /// `<A>_PROBE_VALUE`.
    pub value: u16,
    /// `<A>_PROBE_REFUSED`.
    pub refused: u16,
}

impl ProbeCoils {
    /// The address of one of the three.
    pub fn coil(&self, which: ProbeCoil) -> u16 {
        match which {
            ProbeCoil::Probe => self.probe,
            ProbeCoil::Value => self.value,
            ProbeCoil::Refused => self.refused,
        }
    }

    fn coil_mut(&mut self, which: ProbeCoil) -> &mut u16 {
        match which {
            ProbeCoil::Probe => &mut self.probe,
            ProbeCoil::Value => &mut self.value,
            ProbeCoil::Refused => &mut self.refused,
        }
    }
}

/// A part of the plant (PoP): some actuators, the sensors that follow them and
/// optionally the moving element they drive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    /// Part name (e.g. `turntable`).
    pub name: String,
    /// Its actuators.
    pub actuators: Vec<SignalId>,
    /// Its sensors.
    pub sensors: Vec<SignalId>,
    /// Its moving element, target of element faults (e.g. `P`).
    pub element: Option<String>,
    /// The sensors the element moves (`drives`): a blocked element freezes these
    /// and no other. Without `drives`, every sensor of the part but its inputs.
    pub drives: Vec<SignalId>,
    /// Sensors whose edges the part's orders do not cause (an operator's refill, a
    /// workpiece arriving, the next machine), as the plant file's `inputs` says;
    /// `None`: as learned from the logs. Their edges are allowed in any state of
    /// the part's motion.
    pub inputs: Option<Vec<SignalId>>,
}

/// A fault label and what it means.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FaultDef {
    /// The user's label (e.g. `F2`) or a generated one (e.g. `C4.stuck1`).
    pub label: String,
    /// The template it instantiates.
    pub template: FaultTemplate,
}

/// A partition of faults, one per component; its flag is `def_<name>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Partition {
    /// Partition name (e.g. `C4`).
    pub name: String,
    /// Labels of its faults.
    pub faults: Vec<String>,
}

impl Partition {
    /// The flag raised when a fault of this partition is certain: `def_<name>`.
    pub fn flag(&self) -> Flag {
        Flag::def(&self.name)
    }

    /// The flag raised while a fault of this partition is a candidate:
    /// `suspect_<name>`.
    pub fn suspect_flag(&self) -> Flag {
        Flag::suspect(&self.name)
    }
}

/// How an observer evolves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ObserverRule {
    /// Set to 1 when `set` holds, reset to 0 when `reset` holds (reset wins).
    SetReset {
        /// Setting condition.
        set: Expr,
        /// Resetting condition.
        reset: Expr,
    },
    /// Complemented in each scan where the condition holds.
    Toggle(Expr),
}

/// An observer: a memory reconstructing what sensors cannot see.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Observer {
    /// Name (e.g. `P36`).
    pub name: String,
    /// How it evolves.
    pub rule: ObserverRule,
    /// Value before the first scan.
    pub init: bool,
}

/// A named constraint (a monomial that must stay 0, or a functional requirement).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Constraint {
    /// Name (e.g. `CSs5`).
    pub name: String,
    /// The expression.
    pub expr: Expr,
    /// For combined constraints: the output that keeps its value.
    pub priority: Option<SignalId>,
}

/// An error in a plant file.
pub type PlantError = Located;

impl Plant {
    /// A digest of what a learned model depends on: the plant's name, its
    /// signals (names and kinds, in order) and its parts (signals and
    /// inputs). Descriptions, faults, partitions, constraints and observers
    /// are left out: they may change without learning again.
    pub fn learning_digest(&self) -> String {
        let mut text = format!("plant {}\n", self.name);
        for (_, s) in self.signals.iter() {
            text.push_str(&format!("signal {} {:?}\n", s.name, s.kind));
        }
        let names = |ids: &[SignalId]| {
            (ids.iter().map(|&id| self.signals.name(id)))
                .collect::<Vec<_>>()
                .join(",")
        };
        for p in &self.parts {
            let inputs = p.inputs.as_deref().map_or("learned".to_string(), names);
            text.push_str(&format!(
                "part {} actuators {} sensors {} inputs {inputs}\n",
                p.name,
                names(&p.actuators),
                names(&p.sensors)
            ));
        }
        // FNV-1a: stable across builds and platforms, unlike std's hasher.
        let hash = text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
        });
        format!("fnv1a64:{hash:016x}")
    }
    /// Reads and checks a plant file.
    pub fn from_path(path: &Path) -> Result<Plant, PlantError> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            Located::new(
                Location::new(path, 0, 0),
                format!("cannot read plant file: {e}"),
            )
        })?;
        Plant::parse(&text, path)
    }

    /// Parses and checks plant-file text; `path` is only used in error messages.
    ///
    /// Without `[faults]`, every template applicable to each part is generated with
    /// labels such as `C4.stuck1`, `A4.actuator_stuck0` or `P.blocked_at.C4`. Without
    /// `[partitions]`, faults are grouped per sensor and per element; actuator faults
    /// join their part's element, or a partition named after the actuator.
    pub fn parse(text: &str, path: &Path) -> Result<Plant, PlantError> {
        let raw: RawPlant = toml::from_str(text).map_err(|e| {
            let (line, column) = e.span().map_or((0, 0), |s| line_column(text, s.start));
            Located::new(
                Location::new(path, line, column),
                e.message().trim().to_string(),
            )
        })?;
        Checker { text, path }.build(raw)
    }

    /// The same plant with every fault its parts can have (what a plant file
    /// without `[faults]` gets): each sensor stuck at 0 or 1 or pulsing, each
    /// actuator stuck, each element blocked at or between its sensors, in the
    /// default partitions. The listed faults and partitions are replaced.
    pub fn with_every_fault(&self) -> Plant {
        let faults = default_faults(&self.parts, &self.signals);
        let partitions = default_partitions(&faults, &self.parts, &self.signals);
        Plant {
            faults,
            partitions,
            ..self.clone()
        }
    }

    /// The part with this name.
    pub fn part(&self, name: &str) -> Option<&Part> {
        self.parts.iter().find(|p| p.name == name)
    }

    /// The fault with this label.
    pub fn fault(&self, label: &str) -> Option<&FaultDef> {
        self.faults.iter().find(|f| f.label == label)
    }

    /// The partition a fault belongs to.
    pub fn partition_of(&self, label: &str) -> Option<&Partition> {
        self.partitions
            .iter()
            .find(|p| p.faults.iter().any(|f| f == label))
    }

    /// The flags of the partitions, in the order of the default Modbus map:
    /// every `def_<partition>`, then every `suspect_<partition>`.
    pub fn flags(&self) -> Vec<Flag> {
        let def = self.partitions.iter().map(Partition::flag);
        let suspect = self.partitions.iter().map(Partition::suspect_flag);
        def.chain(suspect).collect()
    }

    /// The Modbus register map: the default (see [`ModbusMap`]) with the
    /// plant file's `[modbus]` entries applied. The plant file was checked when
    /// parsed, so no two names share an address.
    pub fn modbus_map(&self) -> ModbusMap {
        let mut inputs = 0u16;
        let mut coils = 0u16;
        let mut signals: Vec<(ModbusTable, u16)> = self
            .signals
            .iter()
            .map(|(_, s)| match s.kind {
                SignalKind::Sensor => {
                    inputs += 1;
                    (ModbusTable::DiscreteInput, inputs - 1)
                }
                SignalKind::Actuator => {
                    coils += 1;
                    (ModbusTable::Coil, coils - 1)
                }
            })
            .collect();
        let mut flags: Vec<(Flag, u16)> = self
            .flags()
            .into_iter()
            .zip(ModbusMap::FLAGS_FROM..)
            .collect();
        for e in &self.modbus {
            if let Some(id) = self.signals.id(&e.name) {
                signals[id.index()] = (e.table, e.address);
            } else if let Some(f) = flags.iter_mut().find(|f| f.0.to_string() == e.name) {
                f.1 = e.address;
            }
        }
        let probes = self.probe_coils(&signals, &flags);
        ModbusMap {
            signals,
            flags,
            probes,
        }
    }

    /// Each actuator's probe coils: three in a row per actuator from
    /// [`ModbusMap::PROBES_FROM`] (or past the highest signal or flag coil),
    /// then the `[modbus]` entries.
    fn probe_coils(
        &self,
        signals: &[(ModbusTable, u16)],
        flags: &[(Flag, u16)],
    ) -> Vec<ProbeCoils> {
        let highest = signals
            .iter()
            .filter(|s| s.0 == ModbusTable::Coil)
            .map(|s| s.1)
            .chain(flags.iter().map(|f| f.1))
            .max();
        let from = highest.map_or(ModbusMap::PROBES_FROM, |h| {
            ModbusMap::PROBES_FROM.max(h.saturating_add(1))
        });
        // Past the last address, coils saturate and clash: the parser says so.
        let at = |k: usize, i: u32| {
            u16::try_from(u32::from(from) + 3 * k as u32 + i).unwrap_or(u16::MAX)
        };
        let mut probes: Vec<ProbeCoils> = self
            .signals
            .of_kind(SignalKind::Actuator)
            .enumerate()
            .map(|(k, actuator)| ProbeCoils {
                actuator,
                probe: at(k, 0),
                value: at(k, 1),
                refused: at(k, 2),
            })
            .collect();
        for e in &self.modbus {
            let Some((actuator, which)) = ProbeCoil::parse(&e.name) else {
                continue;
            };
            if self.signals.id(&e.name).is_some() {
                continue;
            }
            let id = self.signals.id(actuator);
            if let Some(p) = probes.iter_mut().find(|p| Some(p.actuator) == id) {
                *p.coil_mut(which) = e.address;
            }
        }
        probes
    }

    /// Names of all moving elements declared by parts.
    pub fn elements(&self) -> impl Iterator<Item = &str> {
        self.parts.iter().filter_map(|p| p.element.as_deref())
    }
}

impl fmt::Display for ObserverRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ObserverRule::SetReset { set, reset } => write!(f, "set on {set}, reset on {reset}"),
            ObserverRule::Toggle(e) => write!(f, "toggle on {e}"),
        }
    }
}

// ----- raw file form -----

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlant {
    name: String,
    #[serde(default)]
    scan_period_ms: Option<Spanned<f64>>,
    #[serde(default)]
    time_unit: Option<Spanned<String>>,
    #[serde(deserialize_with = "ordered")]
    signals: Vec<(Spanned<String>, RawSignal)>,
    #[serde(default)]
    variables: Vec<Spanned<String>>,
    #[serde(default)]
    parts: Vec<RawPart>,
    #[serde(default, deserialize_with = "ordered_opt")]
    faults: Option<Vec<(Spanned<String>, Spanned<String>)>>,
    #[serde(default, deserialize_with = "ordered_opt")]
    partitions: Option<Vec<RawPartition>>,
    #[serde(default, deserialize_with = "ordered")]
    observers: Vec<(Spanned<String>, RawObserver)>,
    #[serde(default)]
    constraints: Vec<RawConstraint>,
    #[serde(default)]
    functional: Vec<RawConstraint>,
    #[serde(default, deserialize_with = "ordered")]
    can: Vec<(Spanned<String>, Spanned<RawCanBit>)>,
    #[serde(default, deserialize_with = "ordered")]
    modbus: Vec<(Spanned<String>, Spanned<RawModbus>)>,
    #[serde(default, deserialize_with = "ordered")]
    opcua: Vec<(Spanned<String>, Spanned<String>)>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModbus {
    discrete_input: Option<u16>,
    coil: Option<u16>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCanBit {
    cob_id: u32,
    bit: u8,
}

/// A partition name and its fault labels, as written.
type RawPartition = (Spanned<String>, Vec<Spanned<String>>);

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSignal {
    kind: SignalKind,
    #[serde(default)]
    description: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPart {
    name: Spanned<String>,
    #[serde(default)]
    actuators: Vec<Spanned<String>>,
    #[serde(default)]
    sensors: Vec<Spanned<String>>,
    #[serde(default)]
    element: Option<Spanned<String>>,
    #[serde(default)]
    drives: Option<Vec<Spanned<String>>>,
    #[serde(default)]
    inputs: Option<Vec<Spanned<String>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObserver {
    #[serde(default)]
    set: Option<Spanned<String>>,
    #[serde(default)]
    reset: Option<Spanned<String>>,
    #[serde(default)]
    toggle: Option<Spanned<String>>,
    #[serde(default)]
    init: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConstraint {
    name: Spanned<String>,
    expr: Spanned<String>,
    #[serde(default)]
    priority: Option<Spanned<String>>,
}

/// Deserializes a TOML table into its entries in file order.
fn ordered<'de, D, K, V>(d: D) -> Result<Vec<(K, V)>, D::Error>
where
    D: Deserializer<'de>,
    K: Deserialize<'de>,
    V: Deserialize<'de>,
{
    struct Entries<K, V>(std::marker::PhantomData<(K, V)>);
    impl<'de, K: Deserialize<'de>, V: Deserialize<'de>> Visitor<'de> for Entries<K, V> {
        type Value = Vec<(K, V)>;
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("a table")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
            let mut out = Vec::new();
            while let Some(entry) = map.next_entry()? {
                out.push(entry);
            }
            Ok(out)
        }
    }
    d.deserialize_map(Entries(std::marker::PhantomData))
}

fn ordered_opt<'de, D, K, V>(d: D) -> Result<Option<Vec<(K, V)>>, D::Error>
where
    D: Deserializer<'de>,
    K: Deserialize<'de>,
    V: Deserialize<'de>,
{
    ordered(d).map(Some)
}

// ----- checking -----

struct Checker<'a> {
    text: &'a str,
    path: &'a Path,
}

impl Checker<'_> {
    fn at(&self, span: Range<usize>, field: &str, message: impl Into<String>) -> PlantError {
        let (line, column) = line_column(self.text, span.start);
        Located::new(
            Location::new(self.path, line, column).with_field(field),
            message,
        )
    }

    fn build(&self, raw: RawPlant) -> Result<Plant, PlantError> {
        let scan_period = self.scan_period(raw.scan_period_ms.as_ref())?;
        let time_unit = self.time_unit(raw.time_unit.as_ref())?;
        let signals = self.signals(raw.signals)?;
        let variables = self.variables(raw.variables, &signals)?;
        let mut parts: Vec<Part> = Vec::new();
        let mut elements: HashMap<String, usize> = HashMap::new();
        for p in raw.parts {
            let part = self.part(p, &parts, &signals, &mut elements)?;
            parts.push(part);
        }
        let faults = match raw.faults {
            Some(entries) => self.faults(entries, &signals, &parts, &elements)?,
            None => default_faults(&parts, &signals),
        };
        let partitions = match raw.partitions {
            Some(entries) => self.partitions(entries, &faults)?,
            None => default_partitions(&faults, &parts, &signals),
        };
        let known = self.known_names(&raw.observers, &signals, &variables, &partitions)?;
        let observers = self.observers(raw.observers, &known, &signals)?;
        let constraints = self.constraints(raw.constraints, "constraints", &known, &signals)?;
        let functional = self.constraints(raw.functional, "functional", &known, &signals)?;
        let can = self.can(raw.can, &signals)?;

        let mut plant = Plant {
            name: raw.name,
            scan_period,
            time_unit,
            signals,
            variables,
            parts,
            faults,
            partitions,
            observers,
            constraints,
            functional,
            can,
            modbus: Vec::new(),
            opcua: Vec::new(),
        };
        plant.modbus = self.modbus(raw.modbus, &plant)?;
        plant.opcua = self.opcua(raw.opcua, &plant)?;
        Ok(plant)
    }

    /// `scan_period_ms`: positive, at most a minute (default 10 ms).
    fn scan_period(&self, scan_period_ms: Option<&Spanned<f64>>) -> Result<Time, PlantError> {
        Ok(match scan_period_ms {
            None => 10 * MS,
            Some(s) => {
                let ms = *s.get_ref();
                if !(ms.is_finite() && ms > 0.0 && ms <= 60_000.0) {
                    return Err(self.at(
                        s.span(),
                        "scan_period_ms",
                        "must be > 0 and at most 60000",
                    ));
                }
                (ms * MS as f64).round() as Time
            }
        })
    }

    /// `time_unit` of the plant's logs (default ms).
    fn time_unit(&self, time_unit: Option<&Spanned<String>>) -> Result<TimeUnit, PlantError> {
        Ok(match time_unit {
            None => TimeUnit::Ms,
            Some(u) => u
                .get_ref()
                .parse()
                .map_err(|e: String| self.at(u.span(), "time_unit", e))?,
        })
    }

    /// `[signals]`: valid names, each declared once, at least one.
    fn signals(&self, raw: Vec<(Spanned<String>, RawSignal)>) -> Result<SignalTable, PlantError> {
        let mut signals = SignalTable::new();
        for (name, sig) in raw {
            check_name(name.get_ref()).map_err(|m| self.at(name.span(), "signals", m))?;
            let signal = Signal {
                name: name.get_ref().clone(),
                kind: sig.kind,
                description: sig.description,
            };
            if signals.push(signal).is_none() {
                return Err(self.at(
                    name.span(),
                    "signals",
                    format!("signal '{}' declared twice", name.get_ref()),
                ));
            }
        }
        if signals.is_empty() {
            return Err(Located::new(
                Location::new(self.path, 0, 0).with_field("signals"),
                "no signals declared",
            ));
        }
        Ok(signals)
    }

    /// `variables`: valid names, none a signal's, each declared once.
    fn variables(
        &self,
        raw: Vec<Spanned<String>>,
        signals: &SignalTable,
    ) -> Result<Vec<String>, PlantError> {
        let mut variables = Vec::new();
        for v in raw {
            check_name(v.get_ref()).map_err(|m| self.at(v.span(), "variables", m))?;
            if signals.id(v.get_ref()).is_some() || variables.contains(v.get_ref()) {
                return Err(self.at(
                    v.span(),
                    "variables",
                    format!("'{}' is already declared", v.get_ref()),
                ));
            }
            variables.push(v.into_inner());
        }
        Ok(variables)
    }

    /// One `[[parts]]` entry: a new name, its signals of the right kinds, an
    /// element of its own, and `drives`/`inputs` among its sensors. `elements`
    /// gains the part's element.
    fn part(
        &self,
        p: RawPart,
        parts: &[Part],
        signals: &SignalTable,
        elements: &mut HashMap<String, usize>,
    ) -> Result<Part, PlantError> {
        let index = parts.len();
        if parts.iter().any(|q| q.name == *p.name.get_ref()) {
            return Err(self.at(
                p.name.span(),
                "parts.name",
                format!("part '{}' declared twice", p.name.get_ref()),
            ));
        }
        let actuators = self.signal_list(
            signals,
            &p.actuators,
            SignalKind::Actuator,
            "parts.actuators",
        )?;
        let sensors = self.signal_list(signals, &p.sensors, SignalKind::Sensor, "parts.sensors")?;
        let element = match p.element {
            None => None,
            Some(e) => {
                check_name(e.get_ref()).map_err(|m| self.at(e.span(), "parts.element", m))?;
                if signals.id(e.get_ref()).is_some() {
                    return Err(self.at(
                        e.span(),
                        "parts.element",
                        format!("'{}' is a signal, not an element", e.get_ref()),
                    ));
                }
                if elements.insert(e.get_ref().clone(), index).is_some() {
                    return Err(self.at(
                        e.span(),
                        "parts.element",
                        format!("element '{}' belongs to two parts", e.get_ref()),
                    ));
                }
                Some(e.into_inner())
            }
        };
        let inputs = match &p.inputs {
            Some(names) => Some(self.part_sensors(signals, &sensors, names, "parts.inputs")?),
            None => None,
        };
        let declared_input = |s: &SignalId| inputs.as_ref().is_some_and(|i| i.contains(s));
        let drives = match &p.drives {
            None => sensors
                .iter()
                .copied()
                .filter(|s| !declared_input(s))
                .collect(),
            Some(names) => {
                if element.is_none()
                    && let Some(first) = names.first()
                {
                    return Err(self.at(
                        first.span(),
                        "parts.drives",
                        "a part without an `element` drives nothing",
                    ));
                }
                let drives = self.part_sensors(signals, &sensors, names, "parts.drives")?;
                if let Some(n) = names.iter().find(|n| {
                    signals
                        .id(n.get_ref())
                        .is_some_and(|id| declared_input(&id))
                }) {
                    return Err(self.at(
                        n.span(),
                        "parts.drives",
                        format!(
                            "'{}' is an input of the part: the element cannot drive it",
                            n.get_ref()
                        ),
                    ));
                }
                drives
            }
        };
        Ok(Part {
            name: p.name.into_inner(),
            actuators,
            sensors,
            element,
            drives,
            inputs,
        })
    }

    /// `[faults]`: templates on the plant's signals and elements, each label once.
    fn faults(
        &self,
        entries: Vec<(Spanned<String>, Spanned<String>)>,
        signals: &SignalTable,
        parts: &[Part],
        elements: &HashMap<String, usize>,
    ) -> Result<Vec<FaultDef>, PlantError> {
        let mut out: Vec<FaultDef> = Vec::new();
        for (label, template) in entries {
            let t: FaultTemplate = template
                .get_ref()
                .parse()
                .map_err(|m: String| self.at(template.span(), "faults", m))?;
            self.check_template(&t, signals, parts, elements)
                .map_err(|m| self.at(template.span(), "faults", m))?;
            if out.iter().any(|f| f.label == *label.get_ref()) {
                return Err(self.at(
                    label.span(),
                    "faults",
                    format!("fault '{}' declared twice", label.get_ref()),
                ));
            }
            out.push(FaultDef {
                label: label.into_inner(),
                template: t,
            });
        }

        Ok(out)
    }

    /// `[partitions]`: known faults, each in one partition at most.
    fn partitions(
        &self,
        entries: Vec<RawPartition>,
        faults: &[FaultDef],
    ) -> Result<Vec<Partition>, PlantError> {
        let mut out: Vec<Partition> = Vec::new();
        let mut seen: HashSet<String> = HashSet::new();
        for (name, labels) in entries {
            check_name(name.get_ref()).map_err(|m| self.at(name.span(), "partitions", m))?;
            let mut list = Vec::new();
            for l in labels {
                if !faults.iter().any(|f| f.label == *l.get_ref()) {
                    return Err(self.at(
                        l.span(),
                        "partitions",
                        format!("unknown fault '{}'", l.get_ref()),
                    ));
                }
                if !seen.insert(l.get_ref().clone()) {
                    return Err(self.at(
                        l.span(),
                        "partitions",
                        format!("fault '{}' is in two partitions", l.get_ref()),
                    ));
                }
                list.push(l.into_inner());
            }
            out.push(Partition {
                name: name.into_inner(),
                faults: list,
            });
        }

        Ok(out)
    }

    /// The names an expression may read: signals, variables, flags and the
    /// observers (each a new name).
    fn known_names(
        &self,
        observers: &[(Spanned<String>, RawObserver)],
        signals: &SignalTable,
        variables: &[String],
        partitions: &[Partition],
    ) -> Result<HashSet<String>, PlantError> {
        let mut known: HashSet<String> = signals.iter().map(|(_, s)| s.name.clone()).collect();
        known.extend(variables.iter().cloned());
        for p in partitions {
            known.insert(p.flag().to_string());
            known.insert(p.suspect_flag().to_string());
        }
        for (name, _) in observers {
            check_name(name.get_ref()).map_err(|m| self.at(name.span(), "observers", m))?;
            if !known.insert(name.get_ref().clone()) {
                return Err(self.at(
                    name.span(),
                    "observers",
                    format!("'{}' is already declared", name.get_ref()),
                ));
            }
        }
        Ok(known)
    }

    /// `[observers]`: `set` and `reset`, or `toggle`, over known names.
    fn observers(
        &self,
        raw: Vec<(Spanned<String>, RawObserver)>,
        known: &HashSet<String>,
        signals: &SignalTable,
    ) -> Result<Vec<Observer>, PlantError> {
        let mut observers = Vec::new();
        for (name, o) in raw {
            let field = format!("observers.{}", name.get_ref());
            let rule = match (o.set, o.reset, o.toggle) {
                (Some(set), Some(reset), None) => ObserverRule::SetReset {
                    set: self.expr(&set, &field, known, signals)?,
                    reset: self.expr(&reset, &field, known, signals)?,
                },
                (None, None, Some(toggle)) => {
                    ObserverRule::Toggle(self.expr(&toggle, &field, known, signals)?)
                }
                _ => {
                    return Err(self.at(
                        name.span(),
                        &field,
                        "an observer needs either `set` and `reset`, or `toggle`",
                    ));
                }
            };
            observers.push(Observer {
                name: name.into_inner(),
                rule,
                init: o.init,
            });
        }
        Ok(observers)
    }

    /// `[can]`: known signals, each mapped once, to a valid identifier and bit.
    fn can(
        &self,
        raw: Vec<(Spanned<String>, Spanned<RawCanBit>)>,
        signals: &SignalTable,
    ) -> Result<Vec<CanBit>, PlantError> {
        let mut can = Vec::new();
        for (name, bit) in raw {
            let id = signals.id(name.get_ref()).ok_or_else(|| {
                self.at(
                    name.span(),
                    "can",
                    format!("unknown signal '{}'", name.get_ref()),
                )
            })?;
            let b = bit.get_ref();
            if b.bit > 63 || b.cob_id > 0x1FFF_FFFF {
                return Err(self.at(
                    bit.span(),
                    "can",
                    "bit must be 0-63 and cob_id a CAN identifier (at most 29 bits)",
                ));
            }
            if can.iter().any(|c: &CanBit| c.signal == id) {
                return Err(self.at(
                    name.span(),
                    "can",
                    format!("signal '{}' mapped twice", name.get_ref()),
                ));
            }
            can.push(CanBit {
                signal: id,
                cob_id: b.cob_id,
                bit: b.bit,
            });
        }
        Ok(can)
    }

    /// Checks `[modbus]`: known names, one table each (flags in coils), and no
    /// two names at one address once the defaults are filled in.
    fn modbus(
        &self,
        raw: Vec<(Spanned<String>, Spanned<RawModbus>)>,
        plant: &Plant,
    ) -> Result<Vec<ModbusEntry>, PlantError> {
        let flags = plant.flags();
        let mut entries: Vec<ModbusEntry> = Vec::new();
        let mut spans = Vec::new();
        for (name, at) in raw {
            let n = name.get_ref();
            let signal = plant.signals.id(n);
            let probe = ProbeCoil::parse(n)
                .filter(|(a, _)| {
                    plant
                        .signals
                        .id(a)
                        .is_some_and(|id| plant.signals.get(id).kind == SignalKind::Actuator)
                })
                .map(|(_, which)| which);
            if signal.is_none()
                && probe.is_none()
                && !Flag::parse(n).is_some_and(|f| flags.contains(&f))
            {
                return Err(self.at(
                    name.span(),
                    "modbus",
                    format!("unknown signal, flag or probe coil '{n}' (flags are def_<partition> and suspect_<partition>; probe coils <actuator>_PROBE, <actuator>_PROBE_VALUE and <actuator>_PROBE_REFUSED)"),
                ));
            }
            let (table, address) = match (at.get_ref().discrete_input, at.get_ref().coil) {
                (Some(a), None) => (ModbusTable::DiscreteInput, a),
                (None, Some(a)) => (ModbusTable::Coil, a),
                _ => {
                    return Err(self.at(
                        at.span(),
                        "modbus",
                        format!("'{n}' needs exactly one of discrete_input = N or coil = N"),
                    ));
                }
            };
            if signal.is_none() && table != ModbusTable::Coil {
                let what = match probe {
                    Some(ProbeCoil::Refused) => {
                        format!("probe coil '{n}' must be a coil: the PLC writes it")
                    }
                    Some(_) => format!("probe coil '{n}' must be a coil: the monitor writes it"),
                    None => format!("flag '{n}' must be a coil: the monitor writes it"),
                };
                return Err(self.at(at.span(), "modbus", what));
            }
            if entries.iter().any(|e| e.name == *n) {
                return Err(self.at(name.span(), "modbus", format!("'{n}' mapped twice")));
            }
            entries.push(ModbusEntry {
                name: n.clone(),
                table,
                address,
            });
            spans.push(name.span());
        }
        let mut with = plant.clone();
        with.modbus = entries;
        let map = with.modbus_map();
        let mut taken: HashMap<(ModbusTable, u16), String> = HashMap::new();
        let named = plant
            .signals
            .iter()
            .map(|(_, s)| s.name.clone())
            .zip(map.signals.iter().copied())
            .chain(
                map.flags
                    .iter()
                    .map(|(f, a)| (f.to_string(), (ModbusTable::Coil, *a))),
            )
            .chain(map.probes.iter().flat_map(|p| {
                let actuator = plant.signals.name(p.actuator);
                ProbeCoil::ALL
                    .map(|which| (which.name(actuator), (ModbusTable::Coil, p.coil(which))))
            }));
        for (name, place) in named {
            if let Some(other) = taken.insert(place, name.clone()) {
                // Point at whichever of the two the file wrote.
                let span = with
                    .modbus
                    .iter()
                    .position(|e| e.name == name || e.name == other)
                    .map_or(0..0, |i| spans[i].clone());
                return Err(self.at(
                    span,
                    "modbus",
                    format!(
                        "'{other}' and '{name}' are both at {} {}; give one of them another address",
                        place.0, place.1
                    ),
                ));
            }
        }
        Ok(with.modbus)
    }

    /// `[opcua]`: known signals and flags, each a well-formed NodeId, no two
    /// names at one node.
    fn opcua(
        &self,
        raw: Vec<(Spanned<String>, Spanned<String>)>,
        plant: &Plant,
    ) -> Result<Vec<OpcuaEntry>, PlantError> {
        let flags = plant.flags();
        let mut entries: Vec<OpcuaEntry> = Vec::new();
        for (name, node) in raw {
            let n = name.get_ref();
            if plant.signals.id(n).is_none() && !Flag::parse(n).is_some_and(|f| flags.contains(&f))
            {
                return Err(self.at(
                    name.span(),
                    "opcua",
                    format!("unknown signal or flag '{n}' (flags are def_<partition> and suspect_<partition>)"),
                ));
            }
            if entries.iter().any(|e| e.name == *n) {
                return Err(self.at(name.span(), "opcua", format!("'{n}' mapped twice")));
            }
            let id = node.get_ref().as_str();
            check_node_id(id).map_err(|m| self.at(node.span(), "opcua", format!("'{n}': {m}")))?;
            if let Some(other) = entries.iter().find(|e| e.node_id == id) {
                return Err(self.at(
                    node.span(),
                    "opcua",
                    format!(
                        "'{}' and '{n}' are both at {id}; give one of them another node",
                        other.name
                    ),
                ));
            }
            entries.push(OpcuaEntry {
                name: n.clone(),
                node_id: id.to_string(),
            });
        }
        Ok(entries)
    }

    fn signal_list(
        &self,
        signals: &SignalTable,
        names: &[Spanned<String>],
        kind: SignalKind,
        field: &str,
    ) -> Result<Vec<SignalId>, PlantError> {
        names
            .iter()
            .map(|n| {
                let id = signals.id(n.get_ref()).ok_or_else(|| {
                    self.at(n.span(), field, format!("unknown signal '{}'", n.get_ref()))
                })?;
                if signals.get(id).kind != kind {
                    return Err(self.at(
                        n.span(),
                        field,
                        format!("'{}' is not {}", n.get_ref(), kind.with_article()),
                    ));
                }
                Ok(id)
            })
            .collect()
    }

    /// Sensors named in a part's `field`, each one of the part's `sensors`.
    fn part_sensors(
        &self,
        signals: &SignalTable,
        sensors: &[SignalId],
        names: &[Spanned<String>],
        field: &str,
    ) -> Result<Vec<SignalId>, PlantError> {
        let ids = self.signal_list(signals, names, SignalKind::Sensor, field)?;
        for (n, id) in names.iter().zip(&ids) {
            if !sensors.contains(id) {
                return Err(self.at(
                    n.span(),
                    field,
                    format!("'{}' is not one of the part's sensors", n.get_ref()),
                ));
            }
        }
        Ok(ids)
    }

    fn check_template(
        &self,
        t: &FaultTemplate,
        signals: &SignalTable,
        parts: &[Part],
        elements: &HashMap<String, usize>,
    ) -> Result<(), String> {
        let want_kind = |name: &str, kind: SignalKind| -> Result<(), String> {
            match signals.id(name) {
                None => Err(format!("unknown signal '{name}' in {t}")),
                Some(id) if signals.get(id).kind != kind => {
                    Err(format!("'{name}' in {t} is not {}", kind.with_article()))
                }
                Some(_) => Ok(()),
            }
        };
        match t.target() {
            FaultTarget::Sensor => want_kind(t.arguments()[0], SignalKind::Sensor),
            FaultTarget::Actuator => want_kind(t.arguments()[0], SignalKind::Actuator),
            FaultTarget::Element => {
                let args = t.arguments();
                let part = elements.get(args[0]).map(|&i| &parts[i]).ok_or_else(|| {
                    format!(
                        "unknown element '{}' in {t} (declare it as a part's `element`)",
                        args[0]
                    )
                })?;
                for s in &args[1..] {
                    want_kind(s, SignalKind::Sensor)?;
                    if !part.sensors.iter().any(|&id| signals.name(id) == *s) {
                        return Err(format!(
                            "'{s}' in {t} is not a sensor of part '{}'",
                            part.name
                        ));
                    }
                    if !part.drives.iter().any(|&id| signals.name(id) == *s) {
                        return Err(format!(
                            "'{s}' in {t} is not a sensor that element '{}' drives (its `drives`)",
                            args[0]
                        ));
                    }
                }
                if args.len() == 3 && args[1] == args[2] {
                    return Err(format!("{t}: the two positions must differ"));
                }
                Ok(())
            }
            FaultTarget::Motion => {
                let x = t.arguments()[0];
                let actuator = signals
                    .id(x)
                    .is_some_and(|id| signals.get(id).kind == SignalKind::Actuator);
                if elements.contains_key(x) || actuator {
                    Ok(())
                } else {
                    Err(format!(
                        "'{x}' in {t} is neither an element (a part's `element`) nor an actuator"
                    ))
                }
            }
        }
    }

    fn expr(
        &self,
        text: &Spanned<String>,
        field: &str,
        known: &HashSet<String>,
        signals: &SignalTable,
    ) -> Result<Expr, PlantError> {
        // The value's span includes its opening quote.
        let start = text.span().start + 1;
        let e = Expr::parse(text.get_ref()).map_err(|err| {
            self.at(
                start + err.offset..start + err.offset,
                field,
                format!("bad expression: {}", err.message),
            )
        })?;
        check_expr_names(&e, known, signals).map_err(|name| {
            // Point at the name itself in the expression.
            let offset = word_offset(text.get_ref(), &name).unwrap_or(0);
            self.at(
                start + offset..start + offset,
                field,
                format!("unknown name '{name}'"),
            )
        })?;
        Ok(e)
    }

    fn constraints(
        &self,
        raw: Vec<RawConstraint>,
        section: &str,
        known: &HashSet<String>,
        signals: &SignalTable,
    ) -> Result<Vec<Constraint>, PlantError> {
        let mut out: Vec<Constraint> = Vec::new();
        for c in raw {
            let field = format!("{section}.{}", c.name.get_ref());
            if out.iter().any(|o| o.name == *c.name.get_ref()) {
                return Err(self.at(
                    c.name.span(),
                    &field,
                    format!("constraint '{}' declared twice", c.name.get_ref()),
                ));
            }
            let expr = self.expr(&c.expr, &field, known, signals)?;
            let priority = match c.priority {
                None => None,
                Some(p) => {
                    let id = signals
                        .id(p.get_ref())
                        .filter(|&id| signals.get(id).kind == SignalKind::Actuator)
                        .ok_or_else(|| {
                            self.at(
                                p.span(),
                                &field,
                                format!("priority '{}' is not an actuator", p.get_ref()),
                            )
                        })?;
                    if !expr.names().contains(&p.get_ref().as_str()) {
                        return Err(self.at(
                            p.span(),
                            &field,
                            format!(
                                "priority '{}' does not appear in the constraint",
                                p.get_ref()
                            ),
                        ));
                    }
                    Some(id)
                }
            };
            out.push(Constraint {
                name: c.name.into_inner(),
                expr,
                priority,
            });
        }
        Ok(out)
    }
}

fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!(
            "'{name}' is not a valid name (letters, digits and _ only)"
        ));
    }
    if name.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!("'{name}' is not a valid name (it is a number)"));
    }
    if matches!(name, "RE" | "FE" | "prev") {
        return Err(format!("'{name}' is reserved"));
    }
    Ok(())
}

/// Checks a NodeId in OPC UA's text form (Part 6, 5.3.1.10): an optional
/// `ns=<0..65535>;` or `nsu=<URI>;`, then `i=<0..4294967295>`, `s=<text>`,
/// `g=<GUID>` or `b=<base64>`.
fn check_node_id(text: &str) -> Result<(), String> {
    let form = "expected a NodeId such as ns=2;s=Line.C4, ns=3;i=1042 or nsu=URI;s=NAME";
    let bad = |why: &str| format!("'{text}' is not a NodeId ({why}); {form}");
    let rest = if let Some(r) = text.strip_prefix("ns=") {
        let (ns, r) = r.split_once(';').ok_or_else(|| bad("no ';' after ns="))?;
        ns.parse::<u16>()
            .map_err(|_| bad(&format!("namespace '{ns}' is not a number from 0 to 65535")))?;
        r
    } else if let Some(r) = text.strip_prefix("nsu=") {
        let (uri, r) = r.split_once(';').ok_or_else(|| bad("no ';' after nsu="))?;
        if uri.is_empty() {
            return Err(bad("empty namespace URI"));
        }
        r
    } else {
        text
    };
    let (kind, id) = rest
        .split_once('=')
        .ok_or_else(|| bad("no identifier: i=, s=, g= or b="))?;
    if id.is_empty() {
        return Err(bad("empty identifier"));
    }
    let fits = match kind {
        "i" => id.parse::<u32>().is_ok(),
        "s" => true,
        "g" => {
            let groups: Vec<&str> = id.split('-').collect();
            groups.iter().map(|g| g.len()).eq([8, 4, 4, 4, 12])
                && groups
                    .iter()
                    .all(|g| g.bytes().all(|b| b.is_ascii_hexdigit()))
        }
        "b" => id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'+' | b'/' | b'=')),
        _ => return Err(bad(&format!("unknown identifier type '{kind}='"))),
    };
    if !fits {
        let what = match kind {
            "i" => "a numeric identifier is a number from 0 to 4294967295",
            "g" => "a GUID is written 8-4-4-4-12 hexadecimal digits",
            _ => "an opaque identifier is base64",
        };
        return Err(bad(what));
    }
    Ok(())
}

/// Byte offset of the first whole-word occurrence of `word` in `text`.
fn word_offset(text: &str, word: &str) -> Option<usize> {
    let is_name = |c: char| c.is_ascii_alphanumeric() || c == '_';
    text.match_indices(word).map(|(i, _)| i).find(|&i| {
        !text[..i].chars().next_back().is_some_and(is_name)
            && !text[i + word.len()..].chars().next().is_some_and(is_name)
    })
}

/// The first name `e` reads that is neither known nor a signal, as `Err`.
fn check_expr_names(
    e: &Expr,
    known: &HashSet<String>,
    signals: &SignalTable,
) -> Result<(), String> {
    fn walk(e: &Expr, known: &HashSet<String>, signals: &SignalTable) -> Result<(), String> {
        match e {
            Expr::Const(_) => Ok(()),
            Expr::Var(n) => {
                if known.contains(n) {
                    Ok(())
                } else {
                    Err(n.clone())
                }
            }
            Expr::Rise(n) | Expr::Fall(n) | Expr::Prev(n) => {
                if known.contains(n) || signals.id(n).is_some() {
                    Ok(())
                } else {
                    Err(n.clone())
                }
            }
            Expr::Not(x) => walk(x, known, signals),
            Expr::And(xs) | Expr::Or(xs) => xs.iter().try_for_each(|x| walk(x, known, signals)),
        }
    }
    walk(e, known, signals)
}

/// Every template applicable to each part, labelled `<target>.<template>`.
fn default_faults(parts: &[Part], signals: &SignalTable) -> Vec<FaultDef> {
    let mut out = Vec::new();
    let mut seen = BTreeSet::new();
    let mut push = |label: String, template: FaultTemplate, out: &mut Vec<FaultDef>| {
        if seen.insert(label.clone()) {
            out.push(FaultDef { label, template });
        }
    };
    for part in parts {
        for &s in &part.sensors {
            let n = signals.name(s).to_string();
            push(
                format!("{n}.stuck0"),
                FaultTemplate::Stuck0(n.clone()),
                &mut out,
            );
            push(
                format!("{n}.stuck1"),
                FaultTemplate::Stuck1(n.clone()),
                &mut out,
            );
            push(
                format!("{n}.unexpected_rise"),
                FaultTemplate::UnexpectedRise(n.clone()),
                &mut out,
            );
            push(
                format!("{n}.unexpected_fall"),
                FaultTemplate::UnexpectedFall(n.clone()),
                &mut out,
            );
        }
        for &a in &part.actuators {
            let n = signals.name(a).to_string();
            push(
                format!("{n}.actuator_stuck0"),
                FaultTemplate::ActuatorStuck0(n.clone()),
                &mut out,
            );
            push(
                format!("{n}.actuator_stuck1"),
                FaultTemplate::ActuatorStuck1(n.clone()),
                &mut out,
            );
        }
        // A degraded motion: the element's, or else each order's.
        match &part.element {
            Some(e) => push(
                format!("{e}.slow"),
                FaultTemplate::Slow(e.clone()),
                &mut out,
            ),
            None => {
                for &a in &part.actuators {
                    let n = signals.name(a).to_string();
                    push(
                        format!("{n}.slow"),
                        FaultTemplate::Slow(n.clone()),
                        &mut out,
                    );
                }
            }
        }
        if let Some(e) = &part.element {
            for &s in &part.drives {
                let at = signals.name(s).to_string();
                push(
                    format!("{e}.blocked_at.{at}"),
                    FaultTemplate::BlockedAt {
                        element: e.clone(),
                        at,
                    },
                    &mut out,
                );
            }
            for &from in &part.drives {
                for &to in &part.drives {
                    if from != to {
                        let (from, to) =
                            (signals.name(from).to_string(), signals.name(to).to_string());
                        push(
                            format!("{e}.blocked_between.{from}.{to}"),
                            FaultTemplate::BlockedBetween {
                                element: e.clone(),
                                from,
                                to,
                            },
                            &mut out,
                        );
                    }
                }
            }
        }
    }
    out
}

/// One partition per faulty sensor and per element; actuator faults join their
/// part's element, or a partition named after the actuator.
fn default_partitions(
    faults: &[FaultDef],
    parts: &[Part],
    signals: &SignalTable,
) -> Vec<Partition> {
    let mut out: Vec<Partition> = Vec::new();
    for f in faults {
        let name = match (&f.template, f.template.target()) {
            (FaultTemplate::BlockedAt { element, .. }, _)
            | (FaultTemplate::BlockedBetween { element, .. }, _) => element.clone(),
            (t, FaultTarget::Actuator | FaultTarget::Motion) => {
                let a = t.arguments()[0];
                parts
                    .iter()
                    .find(|p| p.actuators.iter().any(|&id| signals.name(id) == a))
                    .and_then(|p| p.element.clone())
                    .unwrap_or_else(|| a.to_string())
            }
            (t, _) => t.arguments()[0].to_string(),
        };
        match out.iter_mut().find(|p| p.name == name) {
            Some(p) => p.faults.push(f.label.clone()),
            None => out.push(Partition {
                name,
                faults: vec![f.label.clone()],
            }),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::check_node_id;

    #[test]
    fn node_ids_are_checked_in_their_text_form() {
        for good in [
            "i=85",
            "ns=2;s=Line.C4",
            "ns=0;i=4294967295",
            "nsu=urn:example:line;s=C4",
            "ns=1;g=72962B91-FA75-4AE6-8D28-B404DC7DAF63",
            "ns=1;b=M/RbKBsRVkePCePcx24oRA==",
            "ns=2;s=a=b;c",
        ] {
            assert_eq!(check_node_id(good), Ok(()), "{good}");
        }
        for (bad, why) in [
            ("C4", "no identifier"),
            ("ns=2;x=C4", "unknown identifier type 'x='"),
            ("ns=2;s=", "empty identifier"),
            ("ns=-1;s=C4", "namespace '-1'"),
            ("ns=2s=C4", "no ';' after ns="),
            ("nsu=;s=C4", "empty namespace URI"),
            ("i=4294967296", "a number from 0 to 4294967295"),
            ("g=72962b91-fa75-4ae6-8d28", "8-4-4-4-12"),
            ("b=not base64!", "base64"),
        ] {
            let m = check_node_id(bad).expect_err(bad);
            assert!(m.contains(why), "{bad}: {m}");
        }
    }
}
