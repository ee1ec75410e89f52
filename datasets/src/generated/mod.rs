//! Generated plants: a parametric plant and its control program, drawn from a
//! seed, to measure diagnosis on plants nobody tuned it for.
//!
//! A plant is a line of stations built from the components of real assembly
//! and handling lines: single- and double-acting cylinders with one or two end
//! switches, swivel arms and rotary tables with position sensors, vacuum and
//! mechanical grippers with a "holding" sensor, conveyors whose sensors follow
//! the workpieces, magazines that an operator refills at random times, and
//! neighbouring machines that feed and take workpieces after random delays
//! ([`layout`]). Each station runs a step chain that waits for its sensors,
//! with parallel branches, and optionally timeouts to a safe stop
//! ([`program`]). Safety constraints forbid the obvious hazards, and the
//! physics records damage when one happens ([`physics`]). The plant file says
//! all of it as a user would ([`plant_file`]).
//!
//! That is the [`Family::Assembly`]. Other families ([`Family`]) draw process
//! units instead ([`process`]: tanks with level switches, valves or pumps on a
//! drifting supply, heaters or coolers with thermostats), positioning cells
//! ([`positioning`]: electric axes passing cam switches, with a creep speed, a
//! brake, a clamp and recipes), or both beside an assembly line
//! ([`GeneratedPlant::generate_family`]).
//!
//! ```
//! use datasets::generated::{GeneratedPlant, Size};
//! use datasets::sim::SimConfig;
//! use vocabulary::SECOND;
//!
//! let plant = GeneratedPlant::generate(17, Size::Small).expect("a valid plant");
//! let config = SimConfig {
//!     duration: 600 * SECOND,
//!     scan_period: plant.plant().scan_period,
//!     seed: 1,
//!     faults: Vec::new(),
//! };
//! let (log, report) = plant.simulate_in_memory(&config).expect("runs");
//! assert!(report.damage.is_empty());
//! assert!(!log.events.is_empty());
//! ```
//!
//! The same plant seed, size and family give the same plant, byte for byte
//! (and [`GeneratedPlant::generate`] the assembly plants it always gave); the run
//! seed ([`SimConfig::seed`]) draws the run: the drift of each component's
//! timing, each stroke's jitter, the refills, arrivals and departures.

pub mod layout;
pub mod physics;
pub mod plant_file;
pub mod positioning;
pub mod process;
pub mod program;

use std::path::Path;
use std::sync::Arc;

use vocabulary::Plant;

pub use layout::{Family, Layout, Size};
pub use physics::GeneratedPhysics;
pub use program::StepChains;

use crate::sim::{MemorySink, SimConfig, SimReport};

/// A generated plant: its layout, its plant file and the parsed plant.
#[derive(Debug, Clone)]
pub struct GeneratedPlant {
    layout: Arc<Layout>,
    plant: Arc<Plant>,
    toml: Arc<str>,
}

impl GeneratedPlant {
    /// The plant of `seed` and `size`. An error is a bug of the generator: the
    /// plant file it wrote does not load.
    pub fn generate(seed: u64, size: Size) -> Result<GeneratedPlant, String> {
        GeneratedPlant::generate_family(seed, size, Family::Assembly)
    }

    /// The plant of `seed` and `size` in `family`; [`Family::Assembly`] gives
    /// the plants of [`GeneratedPlant::generate`].
    pub fn generate_family(
        seed: u64,
        size: Size,
        family: Family,
    ) -> Result<GeneratedPlant, String> {
        let layout = Layout::generate_family(seed, size, family);
        let toml = plant_file::plant_toml(&layout);
        let path = match family {
            Family::Assembly => format!("generated plant {seed} ({})", size.name()),
            f => format!("generated plant {seed} ({}, {})", size.name(), f.name()),
        };
        let plant = Plant::parse(&toml, Path::new(&path)).map_err(|e| e.to_string())?;
        Ok(GeneratedPlant {
            layout: Arc::new(layout),
            plant: Arc::new(plant),
            toml: toml.into(),
        })
    }

    /// Its structure.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The parsed plant file.
    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// The plant file's text.
    pub fn plant_toml(&self) -> &str {
        &self.toml
    }

    /// The plant at rest, before a run.
    pub fn physics(&self) -> GeneratedPhysics {
        GeneratedPhysics::new(
            Arc::clone(&self.layout),
            Arc::clone(&self.plant),
            Arc::clone(&self.toml),
        )
    }

    /// Its control program, every station at the start of its cycle.
    pub fn program(&self) -> StepChains {
        StepChains::new(&self.layout)
    }

    /// Runs the plant under its program, keeping the log in memory.
    pub fn simulate_in_memory(
        &self,
        config: &SimConfig,
    ) -> std::io::Result<(MemorySink, SimReport)> {
        let mut physics = self.physics();
        let mut program = self.program();
        let mut sink = MemorySink::default();
        let report = crate::sim::run(&mut physics, &mut program, config, &mut sink, |_| {})?;
        Ok((sink, report))
    }
}
