//! Generated plants of every family: their plant files load and fit their
//! size, each runs ten fault-free hours with no damage, no deadlock and no
//! violated constraint, a reckless program does damage of every kind, and
//! faults act on the physics as their templates say (a slowed motion takes
//! longer by its factor), showing in the log when `truth.json` says they do.

use std::collections::BTreeSet;

use datasets::generated::{Family, GeneratedPlant, Size};
use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{Controller, MemorySink, ScanSink, SimConfig, Stepper, run_with_showing};
use diagnoser::diagnosis::part::MAX_PART_SIGNALS;
use filter_coupling::filter::{Coupling, Filter};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use vocabulary::fault::Factor;
use vocabulary::{FaultTemplate, SECOND, Time};

const HOUR: Time = 3600 * SECOND;

fn generate(seed: u64, size: Size) -> GeneratedPlant {
    generate_in(seed, size, Family::Assembly)
}

fn generate_in(seed: u64, size: Size, family: Family) -> GeneratedPlant {
    match GeneratedPlant::generate_family(seed, size, family) {
        Ok(p) => p,
        Err(e) => panic!("plant {seed} ({}, {family}): {e}", size.name()),
    }
}

/// The families besides the assembly lines.
const NEW: [Family; 3] = [Family::Process, Family::Axes, Family::Mixed];

fn config(plant: &GeneratedPlant, seed: u64, duration: Time, faults: Vec<Injection>) -> SimConfig {
    SimConfig {
        duration,
        scan_period: plant.plant().scan_period,
        seed,
        faults,
    }
}

#[test]
fn plant_files_load_and_fit_their_size() {
    let mut largest = (0, 0);
    for size in Size::ALL {
        for seed in 0..60 {
            largest = largest.max(fits(&generate(seed, size)));
        }
    }
    assert!(
        largest.0 >= 18,
        "the largest plant has only {} parts",
        largest.0
    );
    assert_ne!(
        generate(1, Size::Medium).plant_toml(),
        generate(2, Size::Medium).plant_toml()
    );
}

#[test]
fn plants_of_every_family_load_and_fit_their_size() {
    for family in NEW {
        let mut tanks = 0;
        let mut cells = 0;
        let mut stations = 0;
        for size in Size::ALL {
            for seed in 0..20 {
                let g = generate_in(seed, size, family);
                fits(&g);
                let l = g.layout();
                assert_eq!(l.family, family);
                tanks += l.tanks.len();
                cells += l.cells.len();
                stations += l.stations.len();
                assert_eq!(
                    g.plant_toml(),
                    generate_in(seed, size, family).plant_toml(),
                    "not deterministic"
                );
                // A slow fault for every element, or every order of a part without one.
                for part in &g.plant().parts {
                    let targets: Vec<String> = match &part.element {
                        Some(e) => vec![e.clone()],
                        None => part
                            .actuators
                            .iter()
                            .map(|&a| g.plant().signals.name(a).to_string())
                            .collect(),
                    };
                    for x in targets {
                        assert!(
                            g.plant()
                                .faults
                                .iter()
                                .any(|f| f.template == FaultTemplate::Slow(x.clone())),
                            "{}: no slow({x})",
                            l.name
                        );
                    }
                }
            }
        }
        match family {
            Family::Process => assert!(tanks > 0 && cells == 0 && stations == 0),
            Family::Axes => assert!(cells > 0 && tanks == 0 && stations == 0),
            _ => assert!(tanks > 0 && cells > 0 && stations > 0),
        }
    }
    // The assembly family is the assembly plant of old, byte for byte.
    for seed in [0, 17, 42] {
        assert_eq!(
            generate_in(seed, Size::Medium, Family::Assembly).plant_toml(),
            generate(seed, Size::Medium).plant_toml()
        );
    }
    assert_ne!(
        generate_in(1, Size::Medium, Family::Process).plant_toml(),
        generate_in(1, Size::Medium, Family::Mixed).plant_toml()
    );
    for (text, family) in [("assembly", Family::Assembly), ("axes", Family::Axes)] {
        assert_eq!(text.parse::<Family>(), Ok(family));
        assert_eq!(family.name(), text);
    }
    assert!("tanks".parse::<Family>().is_err());
}

/// Checks one plant's file against its size; returns its parts and signals.
fn fits(g: &GeneratedPlant) -> (usize, usize) {
    let size = g.layout().size;
    let (least, most) = size.parts();
    {
        {
            let plant = g.plant();
            let n = plant.parts.len();
            assert!((least..=most).contains(&n), "{}: {n} parts", plant.name);
            // The assembly lines stay under 150 signals; a cell has more.
            let bound = if g.layout().family == Family::Assembly {
                150
            } else {
                200
            };
            assert!(
                plant.signals.len() <= bound,
                "{}: {} signals",
                plant.name,
                plant.signals.len()
            );
            let mut seen = BTreeSet::new();
            for part in &plant.parts {
                let width = part.actuators.len() + part.sensors.len();
                assert!(
                    width <= MAX_PART_SIGNALS,
                    "{}: part {} has {width} signals",
                    plant.name,
                    part.name
                );
                assert!(
                    !part.sensors.is_empty(),
                    "{}: part {} has no sensor",
                    plant.name,
                    part.name
                );
                for id in part.actuators.iter().chain(&part.sensors) {
                    assert!(
                        seen.insert(*id),
                        "{}: {} is in two parts",
                        plant.name,
                        plant.signals.name(*id)
                    );
                }
            }
            assert_eq!(
                seen.len(),
                plant.signals.len(),
                "{}: a signal is in no part",
                plant.name
            );
            assert!(
                !plant.constraints.is_empty(),
                "{}: no constraint",
                plant.name
            );
            // Every fault is in exactly one partition.
            for f in &plant.faults {
                let n = plant
                    .partitions
                    .iter()
                    .filter(|p| p.faults.contains(&f.label))
                    .count();
                assert_eq!(
                    n, 1,
                    "{}: fault {} is in {n} partitions",
                    plant.name, f.label
                );
            }
            (n, plant.signals.len())
        }
    }
}

/// Checks every scan against the plant's safety constraints.
struct Checked {
    filter: Filter,
    violations: Vec<(Time, String)>,
}

impl ScanSink for Checked {
    fn scan(&mut self, t: Time, values: &[bool]) -> std::io::Result<()> {
        for v in self.filter.violations(t, values) {
            if self.violations.len() < 5 {
                self.violations.push((t, v.constraint));
            }
        }
        Ok(())
    }
}

/// Ten fault-free hours of one plant: no damage, no timeout, every station,
/// tank and cell delivers in every hour, and (over the first `checked` hours)
/// no safety constraint is ever violated.
fn ten_hours(seed: u64, size: Size, family: Family, checked: Time) -> Result<(), String> {
    hours(seed, size, family, 10, checked)
}

fn hours(seed: u64, size: Size, family: Family, n: i64, checked: Time) -> Result<(), String> {
    let g = generate_in(seed, size, family);
    let name = &g.layout().name;
    let config = config(&g, seed + 1000, n * HOUR, Vec::new());
    let (mut physics, mut program) = (g.physics(), g.program());
    let mut stepper = Stepper::new(g.plant(), &config);
    let filter =
        Filter::new(g.plant(), None, Coupling::None).map_err(|e| format!("{name}: {e}"))?;
    let mut sink = Checked {
        filter,
        violations: Vec::new(),
    };
    let mut hour_start = physics.unit_cycles();
    let mut next_hour = HOUR;
    while let Some((t, values)) = stepper
        .step(&mut physics, &mut program)
        .map_err(|e| e.to_string())?
    {
        if t < checked {
            sink.scan(t, values).map_err(|e| e.to_string())?;
        }
        if t >= next_hour {
            let now = physics.unit_cycles();
            if let Some(k) = (0..now.len()).find(|&k| now[k] == hour_start[k]) {
                return Err(format!(
                    "{name}: unit {} delivered nothing in hour {} (active steps: {:?})",
                    k + 1,
                    t / HOUR,
                    program.active_steps()
                ));
            }
            hour_start = now;
            next_hour += HOUR;
        }
    }
    if let Some(d) = stepper.damage().first() {
        return Err(format!(
            "{name}: damage {} at {} ms: {}",
            d.cause,
            d.t / 1_000_000,
            d.detail
        ));
    }
    if let Some(s) = program.stopped().first() {
        return Err(format!(
            "{name}: station {} stopped at {} ms in step '{}'",
            s.0 + 1,
            s.1 / 1_000_000,
            s.2
        ));
    }
    if let Some((t, c)) = sink.violations.first() {
        return Err(format!("{name}: {c} violated at {} ms", t / 1_000_000));
    }
    Ok(())
}

#[test]
fn every_plant_runs_ten_fault_free_hours_without_damage_or_deadlock() {
    // 102 assembly plants, 34 of each size, and 8 of each other family, over
    // every core.
    let mut jobs: Vec<(u64, Size, Family)> = Size::ALL
        .into_iter()
        .flat_map(|size| (0..34).map(move |seed| (seed, size, Family::Assembly)))
        .collect();
    for family in NEW {
        for seed in 0..8 {
            jobs.push((seed, Size::ALL[seed as usize % 3], family));
        }
    }
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let failures = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&(seed, size, family)) = jobs.get(i) else {
                        break;
                    };
                    // The constraints are checked over the first two hours.
                    if let Err(e) = ten_hours(seed, size, family, 2 * HOUR) {
                        failures.lock().expect("no worker panicked").push(e);
                    }
                }
            });
        }
    });
    let failures = failures.into_inner().expect("no worker panicked");
    assert!(
        failures.is_empty(),
        "{} of {} plants failed:\n{}",
        failures.len(),
        jobs.len(),
        failures.join("\n")
    );
}

/// Flips a random order now and then, whatever the sensors say.
struct Reckless(ChaCha8Rng, Vec<usize>);

impl Controller for Reckless {
    fn scan(&mut self, _t: Time, io: &mut [bool]) {
        if self.0.random_bool(0.02) {
            let a = self.1[self.0.random_range(0..self.1.len())];
            io[a] = !io[a];
        }
    }
}

/// The plant's own program, with now and then an order flipped behind its
/// back: it reaches states a program flipping orders at random never does (a
/// loaded carriage waiting at the unload position for a blocked outfeed).
struct Meddled(datasets::generated::StepChains, Reckless);

impl Controller for Meddled {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        self.0.scan(t, io);
        if self.1.0.random_bool(0.1) {
            self.1.scan(t, io);
        }
    }
}

/// The damage a reckless program, and a meddled one, do to 12 medium plants
/// of `family`.
fn reckless_damage(family: Family) -> BTreeSet<&'static str> {
    let mut causes = BTreeSet::new();
    for seed in 0..12 {
        let g = generate_in(seed, Size::Medium, family);
        let actuators: Vec<usize> = g
            .plant()
            .signals
            .iter()
            .filter(|(_, s)| s.kind == vocabulary::SignalKind::Actuator)
            .map(|(id, _)| id.index())
            .collect();
        let mut control = Reckless(ChaCha8Rng::seed_from_u64(seed), actuators.clone());
        let config = config(&g, seed, 1800 * SECOND, Vec::new());
        let report = datasets::sim::run(
            &mut g.physics(),
            &mut control,
            &config,
            &mut MemorySink::default(),
            |_| {},
        )
        .expect("runs");
        causes.extend(report.damage.iter().map(|d| d.cause));
        if family != Family::Assembly {
            let reckless = Reckless(ChaCha8Rng::seed_from_u64(seed), actuators);
            let mut control = Meddled(g.program(), reckless);
            let report = datasets::sim::run(
                &mut g.physics(),
                &mut control,
                &config,
                &mut MemorySink::default(),
                |_| {},
            )
            .expect("runs");
            causes.extend(report.damage.iter().map(|d| d.cause));
        }
    }
    causes
}

#[test]
fn a_reckless_program_does_damage_of_every_kind() {
    let all: BTreeSet<&str> = ["collision", "workpiece_dropped", "workpiece_jam"].into();
    assert_eq!(reckless_damage(Family::Assembly), all);
    let tanks: BTreeSet<&str> = ["tank_overflow", "dry_heating", "pump_dry_run", "spill"].into();
    assert_eq!(reckless_damage(Family::Process), tanks);
    let cells: BTreeSet<&str> = [
        "overtravel",
        "brake_drag",
        "reversing_short",
        "workpiece_dropped",
        "workpiece_jam",
    ]
    .into();
    assert_eq!(reckless_damage(Family::Axes), cells);
}

/// Runs one fault; returns the log and when it showed.
fn with_fault(
    g: &GeneratedPlant,
    label: &str,
    onset: Time,
    duration: Time,
) -> (MemorySink, Option<Time>) {
    with_factor(g, label, onset, duration, None)
}

/// Runs one fault, with a factor if it is `slow`.
fn with_factor(
    g: &GeneratedPlant,
    label: &str,
    onset: Time,
    duration: Time,
    factor: Option<Factor>,
) -> (MemorySink, Option<Time>) {
    let spec = FaultSpec {
        what: label.to_string(),
        onset,
        factor,
    };
    let injection = Injection::resolve(&spec, g.plant()).expect("a declared fault");
    let config = config(g, 5, duration, vec![injection]);
    let mut sink = MemorySink::default();
    let (_, showed) = run_with_showing(
        &mut g.physics(),
        &mut g.program(),
        &config,
        &mut sink,
        |_| {},
    )
    .expect("runs");
    (sink, showed[0])
}

/// The values `signal` changes to from `t` on.
fn value_after(log: &MemorySink, signal: usize, t: Time) -> Vec<bool> {
    log.events
        .iter()
        .filter(|e| e.signal.index() == signal && e.t >= t)
        .map(|e| e.value)
        .collect()
}

#[test]
fn faults_act_as_their_templates_say_and_show_when_truth_says() {
    check_faults(&generate(3, Size::Medium));
}

#[test]
fn faults_of_every_family_act_and_show() {
    for family in NEW {
        check_faults(&generate_in(2, Size::Small, family));
    }
}

/// Every declared fault of `g`, from 300 s on in a 900 s run: the log is the
/// fault-free one until it showed, differs where it showed, and the physics
/// does what the template says.
fn check_faults(g: &GeneratedPlant) {
    let g = g.clone();
    let normal = g
        .simulate_in_memory(&config(&g, 5, 900 * SECOND, Vec::new()))
        .expect("runs")
        .0;
    let (onset, end) = (300 * SECOND, 900 * SECOND);
    let mut shown = 0;
    for f in &g.plant().faults {
        let (log, showed) = with_fault(&g, &f.label, onset, end);
        // Before it showed, the log is the fault-free one.
        let until = showed.unwrap_or(end + 1);
        let before = |l: &MemorySink| {
            l.events
                .iter()
                .filter(|e| e.t < until)
                .copied()
                .collect::<Vec<_>>()
        };
        assert_eq!(
            before(&log),
            before(&normal),
            "{}: differs before it showed",
            f.label
        );
        if let Some(t) = showed {
            assert!(t >= onset, "{}: showed before its onset", f.label);
            let at = |l: &MemorySink| {
                l.events
                    .iter()
                    .filter(|e| e.t == t)
                    .copied()
                    .collect::<Vec<_>>()
            };
            assert_ne!(
                at(&log),
                at(&normal),
                "{}: no difference where it showed",
                f.label
            );
            shown += 1;
        }
        let id = |name: &str| g.plant().signals.id(name).expect("a signal").index();
        match &f.template {
            FaultTemplate::Stuck0(s) | FaultTemplate::Stuck1(s) => {
                let after = value_after(&log, id(s), onset + g.plant().scan_period);
                assert!(
                    after.is_empty(),
                    "{}: the stuck sensor still changes: {after:?}",
                    f.label
                );
            }
            FaultTemplate::BlockedAt { at, .. } => {
                // Once at the position, the element never leaves it.
                let changes = value_after(&log, id(at), onset);
                assert!(
                    changes.len() <= 1 && changes.iter().all(|&v| v),
                    "{}: {changes:?}",
                    f.label
                );
            }
            FaultTemplate::BlockedBetween { element, to, .. } => {
                let reached = value_after(&log, id(to), onset);
                // A carriage may pass `to` on its way back once more before
                // it next moves that way and freezes.
                let carriage = g.layout().cells.iter().any(|c| &c.tag == element);
                assert!(
                    reached.len() <= if carriage { 4 } else { 2 },
                    "{}: still reaches {to} again and again: {reached:?}",
                    f.label
                );
            }
            _ => {}
        }
    }
    assert!(
        shown * 10 >= g.plant().faults.len() * 7,
        "only {shown} of {} faults showed",
        g.plant().faults.len()
    );
}

/// Durations from each rising edge of `order` to the next rising edge of
/// `sensor`, split by whether the order rose before `onset`.
fn strokes(log: &MemorySink, order: usize, sensor: usize, onset: Time) -> (Vec<f64>, Vec<f64>) {
    let (mut before, mut after) = (Vec::new(), Vec::new());
    let mut start = None;
    for e in &log.events {
        if e.signal.index() == order && e.value {
            start = Some(e.t);
        } else if e.signal.index() == sensor
            && e.value
            && let Some(s) = start.take()
        {
            let d = (e.t - s) as f64;
            if s < onset {
                before.push(d)
            } else {
                after.push(d)
            }
        }
    }
    (before, after)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[test]
fn a_slowed_motion_takes_longer_by_its_factor() {
    let onset = 600 * SECOND;
    let id = |g: &GeneratedPlant, name: &str| g.plant().signals.id(name).expect("a signal").index();
    // A cylinder with an end switch, a tank's fill, an axis's clamp.
    let g = generate(3, Size::Medium);
    let a = g
        .layout()
        .axes
        .iter()
        .find(|a| a.at1.is_some() && a.back.is_none())
        .expect("a single-acting cylinder with an end switch");
    let axis = (g.clone(), a.tag.clone(), a.out, a.at1.unwrap_or(0), 0.12);
    let p = generate_in(1, Size::Small, Family::Process);
    let tank = &p.layout().tanks[0];
    let name = |g: &GeneratedPlant, s: usize| g.layout().signals[s].name.clone();
    let fill = (
        p.clone(),
        name(&p, tank.inlet),
        tank.inlet,
        tank.full(),
        0.25,
    );
    for (g, target, order, sensor, tolerance) in [axis, fill] {
        let order_name = name(&g, order);
        let sensor_name = name(&g, sensor);
        for factor in ["x1.5", "x2", "x3"] {
            let f: Factor = factor.parse().expect("a factor");
            let (log, showed) = with_factor(
                &g,
                &format!("slow({target})"),
                onset,
                1800 * SECOND,
                Some(f),
            );
            let (order, sensor) = (id(&g, &order_name), id(&g, &sensor_name));
            let (before, after) = strokes(&log, order, sensor, onset);
            assert!(
                !before.is_empty() && !after.is_empty(),
                "slow({target}): no stroke"
            );
            let ratio = mean(&after) / mean(&before);
            assert!(
                (ratio - f.get()).abs() <= tolerance * f.get(),
                "slow({target}) {factor}: strokes {ratio:.2} times longer"
            );
            assert!(
                showed.is_some_and(|t| t >= onset),
                "slow({target}) {factor} never showed"
            );
        }
    }
}

#[test]
fn every_slow_fault_of_the_new_families_shows_at_every_factor() {
    let (onset, end) = (300 * SECOND, 1200 * SECOND);
    for family in NEW {
        let g = generate_in(4, Size::Small, family);
        let slows: Vec<String> = g
            .plant()
            .faults
            .iter()
            .filter(|f| matches!(f.template, FaultTemplate::Slow(_)))
            .map(|f| f.label.clone())
            .collect();
        assert!(!slows.is_empty(), "{}: no slow fault", g.layout().name);
        for label in slows {
            for factor in ["x1.5", "x2", "x3"] {
                let f: Factor = factor.parse().expect("a factor");
                let (_, showed) = with_factor(&g, &label, onset, end, Some(f));
                assert!(
                    showed.is_some_and(|t| t >= onset),
                    "{}: {label} {factor} never showed",
                    g.layout().name
                );
            }
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config::with_cases(24))]

    /// Any seed of any family and size gives a plant that loads, fits its
    /// size, and runs five fault-free minutes without damage.
    #[test]
    fn any_seed_gives_a_plant_that_runs(seed in proptest::prelude::any::<u64>(), size in 0usize..3, family in 0usize..4) {
        let family = Family::ALL[family];
        let g = GeneratedPlant::generate_family(seed, Size::ALL[size], family);
        proptest::prop_assert!(g.is_ok(), "{:?}", g.err());
        let g = g.expect("checked");
        fits(&g);
        let (_, report) = g.simulate_in_memory(&config(&g, seed, 300 * SECOND, Vec::new())).expect("runs");
        proptest::prop_assert!(report.damage.is_empty(), "{}: {:?}", g.layout().name, report.damage.first());
        proptest::prop_assert_eq!(family.name().parse::<Family>(), Ok(family));
    }
}
