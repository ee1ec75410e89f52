//! Generated plants: their plant files load and fit their size, each runs ten
//! fault-free hours with no damage, no deadlock and no violated constraint, a
//! reckless program does damage, and faults act on the physics as their
//! templates say, showing in the log when `truth.json` says they do.

use std::collections::BTreeSet;

use datasets::generated::{GeneratedPlant, Size};
use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{Controller, MemorySink, ScanSink, SimConfig, Stepper, run_with_showing};
use diagnoser::diagnosis::part::MAX_PART_SIGNALS;
use filter_coupling::filter::{Coupling, Filter};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use vocabulary::{FaultTemplate, SECOND, Time};

const HOUR: Time = 3600 * SECOND;

fn generate(seed: u64, size: Size) -> GeneratedPlant {
    match GeneratedPlant::generate(seed, size) {
        Ok(p) => p,
        Err(e) => panic!("plant {seed} ({}): {e}", size.name()),
    }
}

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
        let (least, most) = size.parts();
        for seed in 0..60 {
            let g = generate(seed, size);
            let plant = g.plant();
            let n = plant.parts.len();
            assert!((least..=most).contains(&n), "{}: {n} parts", plant.name);
            assert!(
                plant.signals.len() <= 150,
                "{}: {} signals",
                plant.name,
                plant.signals.len()
            );
            largest = largest.max((n, plant.signals.len()));
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
            assert_eq!(
                g.plant_toml(),
                generate(seed, size).plant_toml(),
                "not deterministic"
            );
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

/// Ten fault-free hours of one plant: no damage, no timeout, every station
/// delivers in every hour, and (over the first `checked` hours) no safety
/// constraint is ever violated.
fn ten_hours(seed: u64, size: Size, checked: Time) -> Result<(), String> {
    let g = generate(seed, size);
    let name = &g.layout().name;
    let config = config(&g, seed + 1000, 10 * HOUR, Vec::new());
    let (mut physics, mut program) = (g.physics(), g.program());
    let mut stepper = Stepper::new(g.plant(), &config);
    let filter =
        Filter::new(g.plant(), None, Coupling::None).map_err(|e| format!("{name}: {e}"))?;
    let mut sink = Checked {
        filter,
        violations: Vec::new(),
    };
    let mut hour_start = physics.cycles().to_vec();
    let mut next_hour = HOUR;
    while let Some((t, values)) = stepper
        .step(&mut physics, &mut program)
        .map_err(|e| e.to_string())?
    {
        if t < checked {
            sink.scan(t, values).map_err(|e| e.to_string())?;
        }
        if t >= next_hour {
            let now = physics.cycles();
            if let Some(k) = (0..now.len()).find(|&k| now[k] == hour_start[k]) {
                return Err(format!(
                    "{name}: station {} delivered nothing in hour {} (active steps: {:?})",
                    k + 1,
                    t / HOUR,
                    program.active_steps()
                ));
            }
            hour_start = now.to_vec();
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
    // 102 plants: 34 of each size, over every core.
    let jobs: Vec<(u64, Size)> = Size::ALL
        .into_iter()
        .flat_map(|size| (0..34).map(move |seed| (seed, size)))
        .collect();
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let failures = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&(seed, size)) = jobs.get(i) else {
                        break;
                    };
                    // The constraints are checked over the first two hours.
                    if let Err(e) = ten_hours(seed, size, 2 * HOUR) {
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

#[test]
fn a_reckless_program_does_damage_of_every_kind() {
    let mut causes = BTreeSet::new();
    for seed in 0..12 {
        let g = generate(seed, Size::Medium);
        let actuators: Vec<usize> = g
            .plant()
            .signals
            .iter()
            .filter(|(_, s)| s.kind == vocabulary::SignalKind::Actuator)
            .map(|(id, _)| id.index())
            .collect();
        let mut control = Reckless(ChaCha8Rng::seed_from_u64(seed), actuators);
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
    }
    let all: BTreeSet<&str> = ["collision", "workpiece_dropped", "workpiece_jam"].into();
    assert_eq!(causes, all);
}

/// Runs one fault; returns the log and when it showed.
fn with_fault(
    g: &GeneratedPlant,
    label: &str,
    onset: Time,
    duration: Time,
) -> (MemorySink, Option<Time>) {
    let spec = FaultSpec {
        what: label.to_string(),
        onset,
        factor: None,
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
    let g = generate(3, Size::Medium);
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
            FaultTemplate::BlockedBetween { to, .. } => {
                let reached = value_after(&log, id(to), onset);
                assert!(
                    reached.len() <= 2,
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
