//! The random structure of a generated plant: stations, their components, the
//! places workpieces go through, the signals, the hazards and the parts.
//!
//! A station moves one workpiece at a time along a chain of places, from its
//! input to its output, by *stages*: a cylinder pushes it to the next place, a
//! conveyor carries it, a swivel arm with a gripper picks and places it, a
//! rotary table turns it to the next position, a tool cylinder works on it.
//! Three station templates chain these stages, each with random options
//! (drives, which end switches exist, timings, optional tools and sensors):
//!
//! - *distribution* / *handling*: an ejector (or separator) pushes the workpiece
//!   from the input (a gravity magazine or the previous station) to a pick-up
//!   point, where a swivel arm with a vacuum or mechanical gripper picks it up
//!   and places it on the output;
//! - *transport*: a conveyor carries the workpiece from its entry to its end
//!   stop, where a pusher cylinder pushes it to the output;
//! - *processing*: a loader pushes the workpiece onto a rotary table, which turns
//!   it to the work position; a tool cylinder (press, drill, stamp…) works on it
//!   and an unloader pushes it off to the output.
//!
//! A station's output is the next station's input; the first station is fed by
//! a magazine that an operator refills, or by an upstream machine; the last one
//! hands over to a next machine that accepts a workpiece after a random delay.
//! Everything is drawn from one seed, so a seed names a plant.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use vocabulary::{MS, SECOND, Time};

pub use super::positioning::{Cell, CellPosition, Recipe};
pub use super::process::{Tank, TankFeed, Thermal};

/// How large a generated plant is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Size {
    /// 2 to 5 parts: one or two stations.
    Small,
    /// 6 to 11 parts: about three stations.
    Medium,
    /// 12 to 20 parts: five stations or more.
    Large,
}

impl Size {
    /// Every size, smallest first.
    pub const ALL: [Size; 3] = [Size::Small, Size::Medium, Size::Large];

    /// The size's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Size::Small => "small",
            Size::Medium => "medium",
            Size::Large => "large",
        }
    }

    /// The fewest and most parts a plant of this size has.
    pub fn parts(self) -> (usize, usize) {
        match self {
            Size::Small => (2, 5),
            Size::Medium => (6, 11),
            Size::Large => (12, 20),
        }
    }
}

impl std::str::FromStr for Size {
    type Err = String;
    fn from_str(text: &str) -> Result<Size, String> {
        Size::ALL
            .into_iter()
            .find(|s| s.name() == text)
            .ok_or_else(|| format!("unknown size '{text}' (expected small, medium or large)"))
    }
}

/// What a generated plant is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Family {
    /// A line of assembly and handling stations: cylinders, swivel arms,
    /// grippers, rotary tables, conveyors.
    Assembly,
    /// Process units: tanks filled and drained through valves and pumps,
    /// heated or cooled to a thermostat.
    Process,
    /// Positioning cells: electric axes passing cam switches in sequence,
    /// with a creep speed, a brake, a clamp and recipes.
    Axes,
    /// An assembly line beside process units and positioning cells.
    Mixed,
}

impl Family {
    /// Every family, the assembly lines first.
    pub const ALL: [Family; 4] = [
        Family::Assembly,
        Family::Process,
        Family::Axes,
        Family::Mixed,
    ];

    /// The family's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Family::Assembly => "assembly",
            Family::Process => "process",
            Family::Axes => "axes",
            Family::Mixed => "mixed",
        }
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Family {
    type Err = String;
    fn from_str(text: &str) -> Result<Family, String> {
        Family::ALL
            .into_iter()
            .find(|f| f.name() == text)
            .ok_or_else(|| {
                format!("unknown family '{text}' (expected assembly, process, axes or mixed)")
            })
    }
}

/// Run-to-run drift of every travel time: each run scales a component's
/// nominal times by a factor drawn in `1 ± DRIFT`.
pub const DRIFT: f64 = 0.05;
/// Largest stroke-to-stroke jitter of a component (its own is drawn up to this).
pub const MAX_JITTER: f64 = 0.04;

/// One signal of the plant, in plant-file order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SignalSpec {
    /// Its tag, e.g. `B103`.
    pub name: String,
    /// A sensor (PLC input), or else an actuator order (PLC output).
    pub sensor: bool,
    /// What it means, for people.
    pub description: String,
}

/// What an axis is for; it decides its names and its rest position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisRole {
    /// Pushes the lowest workpiece out of a gravity magazine.
    Ejector,
    /// Pushes a workpiece from the station's input to its pick-up point.
    Separator,
    /// Pushes a workpiece from a conveyor's end stop to the output.
    Pusher,
    /// Pushes a workpiece from the input onto a rotary table.
    Loader,
    /// Pushes a workpiece off a rotary table to the output.
    Unloader,
    /// Works on the workpiece in place (press, drill, stamp…).
    Tool(ToolKind),
    /// A swivel arm carrying a gripper between a pick and a place position.
    Arm,
    /// A rotary table turning its nest between a loading and a work position.
    Table,
    /// A clamp on the carriage of an electric axis, holding the workpiece it
    /// carries (end 1: closed).
    Clamp,
}

/// What a tool cylinder does to a workpiece.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ToolKind {
    /// Presses a bearing in.
    Press,
    /// Feeds a drill down.
    Drill,
    /// Stamps a mark.
    Stamp,
    /// Sets a rivet.
    Rivet,
}

impl ToolKind {
    /// The name of a station built around this tool.
    pub fn station(self) -> &'static str {
        match self {
            ToolKind::Press => "pressing",
            ToolKind::Drill => "drilling",
            ToolKind::Stamp => "stamping",
            ToolKind::Rivet => "riveting",
        }
    }
}

impl AxisRole {
    /// The component's name in descriptions.
    pub fn noun(self) -> &'static str {
        match self {
            AxisRole::Ejector => "ejector cylinder",
            AxisRole::Separator => "separator cylinder",
            AxisRole::Pusher => "pusher cylinder",
            AxisRole::Loader => "loader cylinder",
            AxisRole::Unloader => "unloader cylinder",
            AxisRole::Tool(k) => match k {
                ToolKind::Press => "press cylinder",
                ToolKind::Drill => "drill feed cylinder",
                ToolKind::Stamp => "stamp cylinder",
                ToolKind::Rivet => "riveting cylinder",
            },
            AxisRole::Arm => "swivel arm",
            AxisRole::Table => "rotary table",
            AxisRole::Clamp => "carriage clamp",
        }
    }

    /// The word used in part names.
    pub fn part_word(self) -> &'static str {
        match self {
            AxisRole::Ejector => "ejector",
            AxisRole::Separator => "separator",
            AxisRole::Pusher => "pusher",
            AxisRole::Loader => "loader",
            AxisRole::Unloader => "unloader",
            AxisRole::Tool(k) => match k {
                ToolKind::Press => "press",
                ToolKind::Drill => "drill",
                ToolKind::Stamp => "stamp",
                ToolKind::Rivet => "riveter",
            },
            AxisRole::Arm => "arm",
            AxisRole::Table => "table",
            AxisRole::Clamp => "clamp",
        }
    }

    /// Names of end 0 and end 1, e.g. ("retracted", "extended").
    pub fn ends(self) -> (&'static str, &'static str) {
        match self {
            AxisRole::Arm => ("at the pick position", "at the place position"),
            AxisRole::Table => ("at the loading position", "at the work position"),
            AxisRole::Clamp => ("open", "closed"),
            _ => ("retracted", "extended"),
        }
    }

    /// What its order towards `end` does, e.g. "extend ejector cylinder A11"
    /// or "swivel arm A12 to the place position".
    pub fn order(self, tag: &str, end: bool) -> String {
        let (end0, end1) = self.ends();
        let place = if end { end1 } else { end0 };
        let place = place.trim_start_matches("at ");
        match self {
            AxisRole::Arm => format!("swivel arm {tag} to {place}"),
            AxisRole::Table => format!("rotate table {tag} to {place}"),
            AxisRole::Clamp => format!("{} clamp {tag}", if end { "close" } else { "open" }),
            _ => format!(
                "{} {} {tag}",
                if end { "extend" } else { "retract" },
                self.noun()
            ),
        }
    }

    /// The end the axis rests at between cycles: 1 for an arm (clear of the
    /// pick-up point), 0 for everything else.
    pub fn rest(self) -> bool {
        self == AxisRole::Arm
    }
}

/// A linear or rotary axis: a cylinder, a swivel arm or a rotary table. Its
/// position runs from end 0 (retracted, pick, loading) to end 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// Its tag, also the element name of its faults, e.g. `A11`.
    pub tag: String,
    /// What it is for.
    pub role: AxisRole,
    /// Index of its station.
    pub station: usize,
    /// Order moving it to end 1 (single-acting: held to stay there, the spring
    /// returns it when released).
    pub out: usize,
    /// Double-acting: order moving it to end 0; the valve keeps its last position
    /// when both orders are off.
    pub back: Option<usize>,
    /// End switch at end 0.
    pub at0: Option<usize>,
    /// End switch at end 1.
    pub at1: Option<usize>,
    /// Nominal travel time to end 1.
    pub out_time: Time,
    /// Nominal travel time to end 0.
    pub back_time: Time,
    /// Stroke-to-stroke relative jitter of its travel times.
    pub jitter: f64,
}

impl Axis {
    /// Whether a switch senses end `end`.
    pub fn switch(&self, end: bool) -> Option<usize> {
        if end { self.at1 } else { self.at0 }
    }
}

/// A vacuum or mechanical gripper on a swivel arm.
#[derive(Debug, Clone, PartialEq)]
pub struct Gripper {
    /// Its tag, e.g. `G12`.
    pub tag: String,
    /// Index of its station.
    pub station: usize,
    /// Suction cup with a vacuum switch, or else mechanical jaws.
    pub vacuum: bool,
    /// Order: vacuum on / close the jaws.
    pub order: usize,
    /// Sensor: the gripper holds a workpiece.
    pub holding: Option<usize>,
    /// Index of the arm it is mounted on.
    pub arm: usize,
    /// Nominal time to grip (vacuum built up, jaws closed).
    pub grip_time: Time,
    /// Nominal time to let go.
    pub release_time: Time,
}

/// A sensor in the middle of a conveyor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Middle {
    /// Sees any workpiece passing.
    Presence(usize),
    /// An inductive sensor: sees only metallic workpieces passing.
    Metal(usize),
}

/// A conveyor belt whose sensors follow the workpieces on it.
#[derive(Debug, Clone, PartialEq)]
pub struct Conveyor {
    /// Its tag, e.g. `C21`.
    pub tag: String,
    /// Index of its station.
    pub station: usize,
    /// Order: belt motor on.
    pub motor: usize,
    /// Sensor: a workpiece at the entry.
    pub entry: usize,
    /// Optional sensor half-way.
    pub middle: Option<Middle>,
    /// Sensor: a workpiece at the end stop.
    pub exit: usize,
    /// Nominal time for a workpiece from entry to end stop.
    pub travel_time: Time,
}

/// A gravity magazine that an operator refills when it runs empty.
#[derive(Debug, Clone, PartialEq)]
pub struct Magazine {
    /// Index of its station.
    pub station: usize,
    /// Sensor: the magazine is empty (no workpiece left, none in the outlet).
    pub empty: usize,
    /// The place its lowest workpiece drops into.
    pub outlet: usize,
}

/// Where a place is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaceKind {
    /// A fixed position (a slide, a pick-up point, a station's input).
    Fixed,
    /// The outlet of a magazine.
    Outlet(usize),
    /// Fed by an upstream machine at random times.
    Feed,
    /// The entry of a conveyor.
    BeltEntry(usize),
    /// The end stop of a conveyor.
    BeltExit(usize),
    /// The nest of a rotary table when the table is at end `end`.
    Nest {
        /// Index of the table's axis.
        table: usize,
        /// The table's end.
        end: bool,
    },
    /// The next machine, which takes a workpiece and is busy for a while.
    Downstream,
}

/// A position a workpiece can be at.
#[derive(Debug, Clone, PartialEq)]
pub struct Place {
    /// Words for it, e.g. "the pick-up point of station 1".
    pub name: String,
    /// Where it is.
    pub kind: PlaceKind,
    /// A sensor that sees a workpiece there (for the downstream place: the
    /// next machine's "ready" signal, which reads 1 when it can accept one).
    pub sensor: Option<usize>,
}

/// One transfer of a workpiece, or work done on it, in a station's cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// An axis (cylinder) pushes the workpiece from `from` to `to`.
    Push {
        /// The axis.
        axis: usize,
        /// Place it takes the workpiece from.
        from: usize,
        /// Place it delivers to.
        to: usize,
    },
    /// A conveyor carries the workpiece from its entry to its end stop.
    Carry {
        /// The conveyor.
        conveyor: usize,
        /// Its entry place.
        from: usize,
        /// Its end-stop place.
        to: usize,
    },
    /// A swivel arm with a gripper picks at end 0 and places at end 1.
    PickPlace {
        /// The arm's axis.
        arm: usize,
        /// The gripper.
        gripper: usize,
        /// The pick place.
        from: usize,
        /// The place place.
        to: usize,
    },
    /// A rotary table turns its nest from the loading to the work position.
    Rotate {
        /// The table's axis.
        table: usize,
        /// Its nest at the loading position.
        from: usize,
        /// Its nest at the work position.
        to: usize,
    },
    /// A tool cylinder works on the workpiece at `at` for `dwell`.
    Process {
        /// The tool's axis.
        tool: usize,
        /// Where it works.
        at: usize,
        /// How long it stays down.
        dwell: Time,
    },
}

/// What a station does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Template {
    /// Ejector (or separator), then a swivel arm with a gripper.
    Distribution,
    /// A conveyor, then a pusher.
    Transport,
    /// Loader, rotary table, optional tool, unloader.
    Processing,
}

/// A station: a chain of stages from its input place to its output place.
#[derive(Debug, Clone, PartialEq)]
pub struct Station {
    /// 1-based number, used in tags.
    pub number: usize,
    /// Its name, e.g. `distribution`.
    pub name: String,
    /// Its template.
    pub template: Template,
    /// The stages of one cycle, in order.
    pub stages: Vec<Stage>,
    /// Where its workpieces come from.
    pub input: usize,
    /// Where they go.
    pub output: usize,
}

/// A physical hazard, with the safety constraints that forbid it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hazard {
    /// A cylinder's rod reaches, when extended, where a swivel arm is at end
    /// `end`: the two collide.
    RodVsArm {
        /// The cylinder's axis.
        rod: usize,
        /// The arm's axis.
        arm: usize,
        /// The arm's end over the rod's reach.
        end: bool,
    },
    /// A cylinder's rod reaches into a rotary table's nest at end `end`: the table
    /// must not turn while the rod is in it.
    RodInNest {
        /// The cylinder's axis.
        rod: usize,
        /// The table's axis.
        table: usize,
        /// The table's end where the rod reaches.
        end: bool,
    },
    /// A gripper that lets go while its arm is between positions drops the
    /// workpiece.
    ReleaseInTransit {
        /// The gripper.
        gripper: usize,
        /// Its arm.
        arm: usize,
    },
    /// Delivering a workpiece onto an occupied place jams it.
    Delivery {
        /// Index of the stage that delivers (in its station).
        station: usize,
        /// The stage.
        stage: usize,
        /// The place, which has a sensor.
        place: usize,
    },
}

/// A part as the plant file declares it.
#[derive(Debug, Clone, PartialEq)]
pub struct PartSpec {
    /// Its name, e.g. `st1_ejector`.
    pub name: String,
    /// Its actuators (signal indices).
    pub actuators: Vec<usize>,
    /// Its sensors.
    pub sensors: Vec<usize>,
    /// Its moving element, target of element faults.
    pub element: Option<Element>,
    /// Sensors whose edges its orders do not cause (the surroundings move
    /// them); the plant file's `inputs`, written when there are some.
    pub inputs: Vec<usize>,
}

/// A part's moving element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Element {
    /// A cylinder, swivel arm, rotary table or clamp (index in the axes).
    Axis(usize),
    /// The carriage of a positioning cell's electric axis (index in the cells).
    Carriage(usize),
}

/// Random delays of the plant's surroundings, in nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surroundings {
    /// The operator refills an empty magazine after a delay drawn in this range.
    pub refill: (Time, Time),
    /// ...with a number of workpieces drawn in this range.
    pub refill_count: (u32, u32),
    /// An upstream machine puts the next workpiece on a free feed place after
    /// a delay drawn in this range.
    pub feed: (Time, Time),
    /// The next machine is busy for a delay drawn in this range after taking a
    /// workpiece.
    pub downstream: (Time, Time),
    /// Share of workpieces that are metallic.
    pub metallic: f64,
}

impl Default for Surroundings {
    fn default() -> Self {
        Surroundings {
            refill: (500 * MS, 90 * SECOND),
            refill_count: (3, 10),
            feed: (500 * MS, 20 * SECOND),
            downstream: (SECOND, 30 * SECOND),
            metallic: 0.4,
        }
    }
}

/// The whole structure of a generated plant.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// The seed it was drawn from.
    pub seed: u64,
    /// Its size.
    pub size: Size,
    /// The plant's name, e.g. `generated-17-medium`.
    pub name: String,
    /// PLC scan period.
    pub scan_period: Time,
    /// Whether the control program has step timeouts (else it waits for ever).
    pub timeouts: bool,
    /// Signals, in plant-file order.
    pub signals: Vec<SignalSpec>,
    /// Stations, upstream first.
    pub stations: Vec<Station>,
    /// Axes of every station.
    pub axes: Vec<Axis>,
    /// Grippers.
    pub grippers: Vec<Gripper>,
    /// Conveyors.
    pub conveyors: Vec<Conveyor>,
    /// Magazines.
    pub magazines: Vec<Magazine>,
    /// Places.
    pub places: Vec<Place>,
    /// Hazards, each forbidden by safety constraints.
    pub hazards: Vec<Hazard>,
    /// Parts, as the plant file declares them.
    pub parts: Vec<PartSpec>,
    /// The surroundings' random delays.
    pub surroundings: Surroundings,
    /// What it is made of.
    pub family: Family,
    /// Process units (tanks), after the line's stations.
    pub tanks: Vec<Tank>,
    /// Positioning cells (electric axes), after the tanks.
    pub cells: Vec<Cell>,
}

impl Layout {
    /// Draws the assembly plant of `seed` and `size`.
    pub fn generate(seed: u64, size: Size) -> Layout {
        Layout::generate_family(seed, size, Family::Assembly)
    }

    /// Draws the plant of `seed` and `size` in `family`.
    pub fn generate_family(seed: u64, size: Size, family: Family) -> Layout {
        Builder::new(seed, size, family).build()
    }

    /// Number of units (stations, tanks, cells): the next unit's number is
    /// one more.
    pub fn units(&self) -> usize {
        self.stations.len() + self.tanks.len() + self.cells.len()
    }

    /// Number of sensors.
    pub fn sensors(&self) -> usize {
        self.signals.iter().filter(|s| s.sensor).count()
    }

    /// The station a place belongs to as an input, if any.
    pub fn station_with_input(&self, place: usize) -> Option<usize> {
        self.stations.iter().position(|s| s.input == place)
    }
}

/// The axes of a processing station: loader, rotary table, optional tool
/// (with its dwell time) and unloader.
#[derive(Clone, Copy)]
struct ProcessingAxes {
    loader: usize,
    table: usize,
    tool: Option<(usize, Time)>,
    unloader: usize,
}

/// Log-uniform draw in `[lo, hi]`: travel times spread over decades.
pub(super) fn log_uniform(rng: &mut ChaCha8Rng, lo: Time, hi: Time) -> Time {
    let (a, b) = ((lo as f64).ln(), (hi as f64).ln());
    rng.random_range(a..=b).exp().round() as Time
}

/// Draws the layout, station by station.
pub(super) struct Builder {
    pub(super) rng: ChaCha8Rng,
    pub(super) layout: Layout,
    /// Tags given so far per (letter, station): the next number.
    tags: std::collections::BTreeMap<(char, usize), usize>,
    /// Per station, the part of the component delivering to its output.
    deliverer: Vec<usize>,
    /// The name of the unit (tank, cell) being drawn, for descriptions.
    pub(super) unit_name: String,
}

impl Builder {
    fn new(seed: u64, size: Size, family: Family) -> Builder {
        // The size takes part in the seed, so that `--size` changes the plant
        // and not only its length; so does the family (the assembly lines
        // keep the seeds they always had).
        let salt = match size {
            Size::Small => 0x5111,
            Size::Medium => 0x3ed1,
            Size::Large => 0x1a76,
        } ^ match family {
            Family::Assembly => 0,
            Family::Process => 0x7a_0000,
            Family::Axes => 0x3c_0000,
            Family::Mixed => 0x55_0000,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ salt);
        let periods = [2, 4, 5, 8, 10, 12, 16, 20];
        let scan_period = periods[rng.random_range(0..periods.len())] * MS;
        let timeouts = rng.random_bool(0.3);
        Builder {
            rng,
            layout: Layout {
                seed,
                size,
                name: match family {
                    Family::Assembly => format!("generated-{seed}-{}", size.name()),
                    f => format!("generated-{}-{seed}-{}", f.name(), size.name()),
                },
                scan_period,
                timeouts,
                signals: Vec::new(),
                stations: Vec::new(),
                axes: Vec::new(),
                grippers: Vec::new(),
                conveyors: Vec::new(),
                magazines: Vec::new(),
                places: Vec::new(),
                hazards: Vec::new(),
                parts: Vec::new(),
                surroundings: Surroundings::default(),
                family,
                tanks: Vec::new(),
                cells: Vec::new(),
            },
            tags: Default::default(),
            deliverer: Vec::new(),
            unit_name: String::new(),
        }
    }

    fn build(mut self) -> Layout {
        let (least, most) = self.layout.size.parts();
        let target = self.rng.random_range(least..=most);
        match self.layout.family {
            Family::Assembly => self.line(target, most),
            Family::Process | Family::Axes => self.units(target, most),
            Family::Mixed => {
                // About half the parts in a line, the rest in units beside it.
                self.line((target / 2).max(2), target);
                self.units(target, most);
            }
        }
        self.layout
    }

    /// Adds units (tanks, positioning cells) of the family until the plant
    /// has `target` parts, never more than `most`.
    fn units(&mut self, target: usize, most: usize) {
        while self.layout.parts.len() < target {
            let room = most - self.layout.parts.len();
            let tank = match self.layout.family {
                Family::Process => true,
                Family::Axes => false,
                _ => self.rng.random_bool(0.5),
            };
            // A tank is one part, a cell two.
            if tank || (room < 2 && self.layout.family != Family::Axes) {
                self.tank();
            } else if room >= 2 {
                self.cell();
            } else {
                break;
            }
        }
    }

    /// An assembly line of stations with `target` parts, at most `most`.
    fn line(&mut self, target: usize, most: usize) {
        let mut input = None;
        loop {
            let template = self.template(input.is_none(), most - self.layout.parts.len());
            let station = self.station(template, input);
            input = Some(self.layout.stations[station].output);
            let parts = self.layout.parts.len();
            // The smallest station has two parts.
            if parts >= target || most - parts < 2 {
                break;
            }
        }
        self.finish_output();
    }

    /// A template for the next station, with at most `room` parts.
    fn template(&mut self, first: bool, room: usize) -> Template {
        let mut choices = Vec::new();
        if room >= 3 {
            choices.push(Template::Distribution);
        }
        if first && room >= 3 {
            // A magazine needs an ejector: it is more often a distribution.
            choices.push(Template::Distribution);
        }
        choices.push(Template::Transport);
        // A processing station has up to four parts.
        if room >= 4 {
            choices.push(Template::Processing);
        }
        choices[self.rng.random_range(0..choices.len())]
    }

    pub(super) fn signal(
        &mut self,
        letter: char,
        station: usize,
        sensor: bool,
        description: String,
    ) -> usize {
        let n = self.tags.entry((letter, station)).or_insert(0);
        *n += 1;
        let name = format!("{letter}{station}{:02}", *n);
        self.layout.signals.push(SignalSpec {
            name,
            sensor,
            description,
        });
        self.layout.signals.len() - 1
    }

    pub(super) fn sensor(&mut self, station: usize, description: String) -> usize {
        self.signal('B', station, true, description)
    }

    pub(super) fn tag(&mut self, letter: char, station: usize) -> String {
        let n = self.tags.entry((letter, station)).or_insert(0);
        *n += 1;
        format!("{letter}{station}{n}")
    }

    fn place(&mut self, name: String, kind: PlaceKind, sensor: Option<usize>) -> usize {
        self.layout.places.push(Place { name, kind, sensor });
        self.layout.places.len() - 1
    }

    pub(super) fn label(&self, number: usize) -> String {
        match self.layout.stations.get(number - 1) {
            Some(s) => format!("station {number}, {}", s.name),
            None => format!("unit {number}, {}", self.unit_name),
        }
    }

    /// Adds a station of `template` taking its workpieces from `input` (or
    /// from a magazine or a feed for the first one); returns its index.
    fn station(&mut self, template: Template, input: Option<usize>) -> usize {
        let number = self.layout.stations.len() + 1;
        self.layout.stations.push(Station {
            number,
            name: String::new(),
            template,
            stages: Vec::new(),
            input: usize::MAX,
            output: usize::MAX,
        });
        match template {
            Template::Distribution => self.distribution(number, input),
            Template::Transport => self.transport(number, input),
            Template::Processing => self.processing(number, input),
        }
        number - 1
    }

    fn name_station(&mut self, number: usize, name: &str) {
        self.layout.stations[number - 1].name = name.to_string();
    }

    /// The station's input: the previous station's output, or a magazine or
    /// a feed for the first station. Returns the place and the sensors the
    /// part taking from it reads.
    fn input(
        &mut self,
        number: usize,
        input: Option<usize>,
        magazine: bool,
    ) -> (usize, Vec<usize>) {
        let label = self.label(number);
        if let Some(place) = input {
            let sensor = self.sensor(number, format!("workpiece at the input ({label})"));
            let p = &mut self.layout.places[place];
            p.sensor = Some(sensor);
            p.name = format!("the input of station {number}");
            return (place, vec![sensor]);
        }
        if magazine {
            let empty = self.sensor(number, format!("magazine empty ({label})"));
            let outlet = self.place(
                format!("the magazine outlet of station {number}"),
                PlaceKind::Outlet(self.layout.magazines.len()),
                None,
            );
            self.layout.magazines.push(Magazine {
                station: number - 1,
                empty,
                outlet,
            });
            return (outlet, vec![empty]);
        }
        let sensor = self.sensor(
            number,
            format!("workpiece delivered by the upstream machine ({label})"),
        );
        let place = self.place(
            format!("the feed place of station {number}"),
            PlaceKind::Feed,
            Some(sensor),
        );
        (place, vec![sensor])
    }

    /// A new place for the station's output, without a sensor yet: the next
    /// station gives it one (its input sensor), or [`Builder::finish_output`]
    /// makes it the next machine.
    fn output(&mut self, number: usize) -> usize {
        let output = self.place(
            format!("the output of station {number}"),
            PlaceKind::Fixed,
            None,
        );
        let station = &mut self.layout.stations[number - 1];
        station.output = output;
        output
    }

    /// The last station hands over to the next machine, whose "ready" signal
    /// the delivering part reads.
    fn finish_output(&mut self) {
        let Some(last) = self.layout.stations.last() else {
            return;
        };
        let (number, output) = (last.number, last.output);
        let label = self.label(number);
        let ready = self.sensor(
            number,
            format!("next machine ready to accept a workpiece ({label})"),
        );
        let p = &mut self.layout.places[output];
        p.kind = PlaceKind::Downstream;
        p.sensor = Some(ready);
        p.name = "the next machine".to_string();
        self.add_delivery_hazard(number - 1);
        let part = self.deliverer[number - 1];
        self.layout.parts[part].sensors.push(ready);
    }

    /// Draws an axis with its orders and switches; `need` says which end
    /// switches the program or a constraint needs.
    pub(super) fn axis(
        &mut self,
        number: usize,
        role: AxisRole,
        double: bool,
        need: (bool, bool),
        times: (Time, Time),
    ) -> usize {
        let tag = self.tag('A', number);
        let label = self.label(number);
        let noun = role.noun();
        let (end0, end1) = role.ends();
        let valve = if double {
            "double-acting valve"
        } else {
            "single-acting: a spring returns it when released"
        };
        let out = format!("{} ({label}; {valve})", role.order(&tag, true));
        let out = self.signal('Y', number, false, out);
        let back = double.then(|| {
            let text = format!("{} ({label}; double-acting valve)", role.order(&tag, false));
            self.signal('Y', number, false, text)
        });
        // Every axis has at least one end switch; those the program or a
        // constraint needs always exist.
        let has0 = need.0 || self.rng.random_bool(0.8);
        let has1 = need.1 || self.rng.random_bool(0.75) || !has0;
        let at0 = has0.then(|| self.sensor(number, format!("{noun} {tag} {end0} ({label})")));
        let at1 = has1.then(|| self.sensor(number, format!("{noun} {tag} {end1} ({label})")));
        let out_time = log_uniform(&mut self.rng, times.0, times.1);
        // The return stroke has its own speed (a spring, another air flow).
        let back_time = (out_time as f64 * self.rng.random_range(0.6..1.4)).round() as Time;
        let jitter = self.rng.random_range(0.01..MAX_JITTER);
        self.layout.axes.push(Axis {
            tag,
            role,
            station: number - 1,
            out,
            back,
            at0,
            at1,
            out_time,
            back_time: back_time.clamp(50 * MS, 5 * SECOND),
            jitter,
        });
        self.layout.axes.len() - 1
    }

    /// A part for one axis, with `extra` sensors it reads.
    pub(super) fn axis_part(&mut self, axis: usize, extra: &[usize]) -> usize {
        let a = &self.layout.axes[axis];
        let name = format!("st{}_{}", a.station + 1, a.role.part_word());
        let actuators = std::iter::once(a.out).chain(a.back).collect();
        let mut sensors: Vec<usize> = a.at0.into_iter().chain(a.at1).collect();
        sensors.extend_from_slice(extra);
        self.layout.parts.push(PartSpec {
            name,
            actuators,
            sensors,
            element: Some(Element::Axis(axis)),
            inputs: Vec::new(),
        });
        self.layout.parts.len() - 1
    }

    fn stage(&mut self, number: usize, stage: Stage) {
        self.layout.stations[number - 1].stages.push(stage);
    }

    fn distribution(&mut self, number: usize, input: Option<usize>) {
        let magazine = input.is_none() && self.rng.random_bool(0.7);
        self.name_station(
            number,
            if input.is_none() {
                "distribution"
            } else {
                "handling"
            },
        );
        let (from, input_sensors) = self.input(number, input, magazine);
        let role = if magazine {
            AxisRole::Ejector
        } else {
            AxisRole::Separator
        };
        let double = self.rng.random_bool(0.4);
        // The arm comes over the pick-up point only once the rod is back.
        let ejector = self.axis(number, role, double, (true, false), (100 * MS, 1500 * MS));
        let pick_sensor = self.rng.random_bool(0.5).then(|| {
            let label = self.label(number);
            self.sensor(number, format!("workpiece at the pick-up point ({label})"))
        });
        let pick = self.place(
            format!("the pick-up point of station {number}"),
            PlaceKind::Fixed,
            pick_sensor,
        );
        let arm = self.axis(
            number,
            AxisRole::Arm,
            true,
            (true, true),
            (300 * MS, 3 * SECOND),
        );
        let gripper = self.gripper(number, arm);
        let output = self.output(number);
        self.layout.stations[number - 1].input = from;
        self.stage(
            number,
            Stage::Push {
                axis: ejector,
                from,
                to: pick,
            },
        );
        self.stage(
            number,
            Stage::PickPlace {
                arm,
                gripper,
                from: pick,
                to: output,
            },
        );
        self.layout.hazards.push(Hazard::RodVsArm {
            rod: ejector,
            arm,
            end: false,
        });
        self.layout
            .hazards
            .push(Hazard::ReleaseInTransit { gripper, arm });
        self.add_input_hazard(number - 1);

        self.axis_part(ejector, &input_sensors);
        let arm_part = self.axis_part(arm, &pick_sensor.into_iter().collect::<Vec<_>>());
        let g = self.layout.grippers[gripper].clone();
        // One pick-and-place part, the arm and its gripper, when the gripper
        // has no sensor of its own, and else one time in two.
        if g.holding.is_none() || self.rng.random_bool(0.5) {
            let part = &mut self.layout.parts[arm_part];
            part.actuators.push(g.order);
            part.sensors.extend(g.holding);
            part.name = format!("st{number}_pick_and_place");
        } else {
            self.layout.parts.push(PartSpec {
                name: format!("st{number}_gripper"),
                actuators: vec![g.order],
                sensors: g.holding.into_iter().collect(),
                element: None,
                inputs: Vec::new(),
            });
        }
        self.deliverer.push(arm_part);
    }

    fn gripper(&mut self, number: usize, arm: usize) -> usize {
        let vacuum = self.rng.random_bool(0.6);
        let tag = self.tag('G', number);
        let label = self.label(number);
        let arm_tag = self.layout.axes[arm].tag.clone();
        let (order, holding) = if vacuum {
            (
                format!("vacuum on, suction gripper {tag} on arm {arm_tag} ({label})"),
                format!("vacuum switch: suction gripper {tag} holds a workpiece ({label})"),
            )
        } else {
            (
                format!("close gripper {tag} on arm {arm_tag} ({label}; it opens when released)"),
                format!("gripper {tag} closed on a workpiece ({label})"),
            )
        };
        let order = self.signal('Y', number, false, order);
        // A mechanical gripper may have no sensor: the program then waits a time.
        let holding = (vacuum || self.rng.random_bool(0.6)).then(|| self.sensor(number, holding));
        let grip_time = log_uniform(&mut self.rng, 50 * MS, 400 * MS);
        let release_time = log_uniform(&mut self.rng, 50 * MS, 300 * MS);
        self.layout.grippers.push(Gripper {
            tag,
            station: number - 1,
            vacuum,
            order,
            holding,
            arm,
            grip_time,
            release_time,
        });
        self.layout.grippers.len() - 1
    }

    fn conveyor(&mut self, number: usize) -> usize {
        let tag = self.tag('C', number);
        let label = self.label(number);
        let motor = self.signal(
            'M',
            number,
            false,
            format!("belt motor of conveyor {tag} on ({label})"),
        );
        let entry = self.sensor(
            number,
            format!("workpiece at the entry of conveyor {tag} ({label})"),
        );
        let middle = match self.rng.random_range(0..4) {
            0 => Some(Middle::Metal(self.sensor(
                number,
                format!("inductive sensor half-way along conveyor {tag}: a metallic workpiece passes ({label})"),
            ))),
            1 => Some(Middle::Presence(
                self.sensor(number, format!("workpiece half-way along conveyor {tag} ({label})")),
            )),
            _ => None,
        };
        let exit = self.sensor(
            number,
            format!("workpiece at the end stop of conveyor {tag} ({label})"),
        );
        let travel_time = log_uniform(&mut self.rng, 500 * MS, 5 * SECOND);
        self.layout.conveyors.push(Conveyor {
            tag,
            station: number - 1,
            motor,
            entry,
            middle,
            exit,
            travel_time,
        });
        self.layout.conveyors.len() - 1
    }

    fn transport(&mut self, number: usize, input: Option<usize>) {
        self.name_station(number, "transport");
        let c = self.conveyor(number);
        let conveyor = self.layout.conveyors[c].clone();
        // The entry is the input: the previous station, or the upstream
        // machine, puts workpieces on the belt.
        let from = match input {
            Some(place) => place,
            None => self.place(String::new(), PlaceKind::Feed, None),
        };
        let p = &mut self.layout.places[from];
        p.kind = PlaceKind::BeltEntry(c);
        p.sensor = Some(conveyor.entry);
        p.name = format!("the entry of conveyor {}", conveyor.tag);
        let end = self.place(
            format!("the end stop of conveyor {}", conveyor.tag),
            PlaceKind::BeltExit(c),
            Some(conveyor.exit),
        );
        let double = self.rng.random_bool(0.4);
        let pusher = self.axis(
            number,
            AxisRole::Pusher,
            double,
            (false, false),
            (100 * MS, 1500 * MS),
        );
        let output = self.output(number);
        self.layout.stations[number - 1].input = from;
        self.stage(
            number,
            Stage::Carry {
                conveyor: c,
                from,
                to: end,
            },
        );
        self.stage(
            number,
            Stage::Push {
                axis: pusher,
                from: end,
                to: output,
            },
        );
        self.add_input_hazard(number - 1);

        let mut sensors = vec![conveyor.entry];
        if let Some(Middle::Metal(s) | Middle::Presence(s)) = conveyor.middle {
            sensors.push(s);
        }
        sensors.push(conveyor.exit);
        self.layout.parts.push(PartSpec {
            name: format!("st{number}_conveyor"),
            actuators: vec![conveyor.motor],
            sensors,
            element: None,
            inputs: Vec::new(),
        });
        let part = self.axis_part(pusher, &[]);
        self.deliverer.push(part);
    }

    fn processing(&mut self, number: usize, input: Option<usize>) {
        let kinds = [
            ToolKind::Press,
            ToolKind::Drill,
            ToolKind::Stamp,
            ToolKind::Rivet,
        ];
        let tool = self
            .rng
            .random_bool(0.8)
            .then(|| kinds[self.rng.random_range(0..kinds.len())]);
        self.name_station(number, tool.map_or("processing", ToolKind::station));
        let magazine = input.is_none() && self.rng.random_bool(0.5);
        let (from, input_sensors) = self.input(number, input, magazine);
        let role = if magazine {
            AxisRole::Ejector
        } else {
            AxisRole::Loader
        };
        let double = self.rng.random_bool(0.4);
        let loader = self.axis(number, role, double, (true, false), (100 * MS, 1500 * MS));
        let table = self.axis(
            number,
            AxisRole::Table,
            true,
            (true, true),
            (500 * MS, 5 * SECOND),
        );
        let tag = self.layout.axes[table].tag.clone();
        let nest0 = self.place(
            format!("the nest of table {tag} at the loading position"),
            PlaceKind::Nest { table, end: false },
            None,
        );
        let nest1 = self.place(
            format!("the nest of table {tag} at the work position"),
            PlaceKind::Nest { table, end: true },
            None,
        );
        let tool = tool.map(|kind| {
            let double = self.rng.random_bool(0.3);
            let axis = self.axis(
                number,
                AxisRole::Tool(kind),
                double,
                (true, false),
                (50 * MS, 2 * SECOND),
            );
            (axis, log_uniform(&mut self.rng, 100 * MS, 1500 * MS))
        });
        let double = self.rng.random_bool(0.4);
        let unloader = self.axis(
            number,
            AxisRole::Unloader,
            double,
            (true, false),
            (100 * MS, 1500 * MS),
        );
        self.output(number);
        self.layout.stations[number - 1].input = from;
        let axes = ProcessingAxes {
            loader,
            table,
            tool,
            unloader,
        };
        self.processing_stages(number, &axes, from, (nest0, nest1), &input_sensors);
    }

    /// A processing station's stages, hazards and parts, once its axes and
    /// places are drawn.
    fn processing_stages(
        &mut self,
        number: usize,
        axes: &ProcessingAxes,
        from: usize,
        (nest0, nest1): (usize, usize),
        input_sensors: &[usize],
    ) {
        let ProcessingAxes {
            loader,
            table,
            tool,
            unloader,
        } = *axes;
        let output = self.layout.stations[number - 1].output;
        self.stage(
            number,
            Stage::Push {
                axis: loader,
                from,
                to: nest0,
            },
        );
        self.stage(
            number,
            Stage::Rotate {
                table,
                from: nest0,
                to: nest1,
            },
        );
        self.layout.hazards.push(Hazard::RodInNest {
            rod: loader,
            table,
            end: false,
        });
        if let Some((tool, dwell)) = tool {
            self.stage(
                number,
                Stage::Process {
                    tool,
                    at: nest1,
                    dwell,
                },
            );
            self.layout.hazards.push(Hazard::RodInNest {
                rod: tool,
                table,
                end: true,
            });
        }
        self.stage(
            number,
            Stage::Push {
                axis: unloader,
                from: nest1,
                to: output,
            },
        );
        self.layout.hazards.push(Hazard::RodInNest {
            rod: unloader,
            table,
            end: true,
        });
        self.add_input_hazard(number - 1);

        self.axis_part(loader, input_sensors);
        self.axis_part(table, &[]);
        if let Some((tool, _)) = tool {
            self.axis_part(tool, &[]);
        }
        let part = self.axis_part(unloader, &[]);
        self.deliverer.push(part);
    }

    /// The previous station's last stage delivers onto this station's input,
    /// which now has a sensor: a delivery onto it while occupied is a hazard.
    fn add_input_hazard(&mut self, station: usize) {
        if station > 0 {
            self.add_delivery_hazard(station - 1);
        }
    }

    fn add_delivery_hazard(&mut self, station: usize) {
        let s = &self.layout.stations[station];
        let stage = s.stages.len() - 1;
        let place = s.output;
        self.layout.hazards.push(Hazard::Delivery {
            station,
            stage,
            place,
        });
    }
}
