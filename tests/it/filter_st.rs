//! The Structured Text of `gardefou filter st` against the Rust filter.
//!
//! The generated function block is parsed and run by a small interpreter
//! (`tests/it/st.rs`, IEC 61131-3 TON semantics included) beside the Rust
//! [`Filter`], on the simulated sorting line: each scan, the synthesised
//! control law proposes orders (with a few deliberately wrong ones), both
//! filters get the same sensors, proposals and flags, and every order, every
//! violation bit, FALLBACK, the parts' fallbacks, the observers and the
//! estimate intervals must agree. The plant follows the Rust filter's orders.
//! Each run is one simulated hour at 10 ms scans.
//!
//! When matiec's `iec2c` is on PATH the generated texts are also compiled by it.

use crate::st;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::sync::OnceLock;

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{Controller, ScanSink, SimConfig};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, SignalKind, Time};
use filter_coupling::filter::{Coupling, Filter, Mode, Request};
use filter_coupling::st::{StOptions, generate};
use learning::learn::{LearnOptions, Learner};
use logs::{IngestOptions, open};

use crate::support::{assert_bad_input, gardefou, repo as path};
use st::Fb;

const MINUTE: Time = 60 * SECOND;
const SCAN: Time = 10 * MS;

/// The model learned from the shipped normal run, once for all tests.
fn model() -> &'static Model {
    static MODEL: OnceLock<Model> = OnceLock::new();
    MODEL.get_or_init(|| {
        let plant = plant();
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/data/sorting/normal/events.csv");
        let log = open(&path, &plant, &IngestOptions::default()).expect("opens the normal log");
        let mut learner = Learner::new(&plant, LearnOptions::default()).expect("learner");
        learner.learn_log(log, |_| {}).expect("learns");
        learner.finish()
    })
}

/// A plant name as the generator spells it.
fn ident(name: &str) -> String {
    if name.starts_with(|c: char| c.is_ascii_digit()) {
        format!("_{name}")
    } else {
        name.to_string()
    }
}

/// What a run went through, to show the comparison was not vacuous.
#[derive(Debug, Default)]
struct Stats {
    scans: u64,
    compared: u64,
    violated_scans: u64,
    fallback_scans: u64,
    part_fallback_scans: u64,
    /// Scans where some order differs from the control program's proposal.
    overridden_scans: u64,
    /// Scans where a flagged C4's estimate differs from what C4 reads.
    estimate_differs: u64,
    violations: BTreeMap<String, u64>,
    intervals: BTreeMap<String, u64>,
}

/// The PLC: the synthesised control proposes, both filters decide.
struct Twin {
    control: SynthesisedControl,
    filter: Filter,
    fb: Fb,
    mode: Mode,
    sensors: Vec<(usize, String)>,
    actuators: Vec<(usize, String)>,
    constraints: Vec<String>,
    parts: Vec<String>,
    /// Observers and intervals, compared too.
    internals: Vec<String>,
    /// `(when, flag, value)`, in time order.
    flags: Vec<(Time, &'static str, bool)>,
    next_flag: usize,
    rng: u64,
    stats: Stats,
    mismatches: Vec<String>,
    mismatch_count: u64,
}

impl Twin {
    fn new(
        plant: &Plant,
        filter: Filter,
        fb: Fb,
        mode: Mode,
        flags: Vec<(Time, &'static str, bool)>,
        seed: u64,
    ) -> Twin {
        let ids = |kind| {
            plant
                .signals
                .of_kind(kind)
                .map(|id| (id.index(), plant.signals.name(id).to_string()))
                .collect::<Vec<_>>()
        };
        let mut internals: Vec<String> = plant.observers.iter().map(|o| o.name.clone()).collect();
        for part in filter.intervals() {
            for (_, iv) in part.states {
                internals.extend(iv.into_iter().map(|i| i.name));
            }
        }
        Twin {
            control: SynthesisedControl::new(
                datasets::sorting::SortingIds::resolve(plant).expect("ids"),
            ),
            sensors: ids(SignalKind::Sensor),
            actuators: ids(SignalKind::Actuator),
            constraints: plant.constraints.iter().map(|c| c.name.clone()).collect(),
            parts: plant.parts.iter().map(|p| p.name.clone()).collect(),
            internals,
            filter,
            fb,
            mode,
            flags,
            next_flag: 0,
            rng: seed | 1,
            stats: Stats::default(),
            mismatches: Vec::new(),
            mismatch_count: 0,
        }
    }

    fn random(&mut self) -> u64 {
        // xorshift64
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        self.rng
    }

    fn compare(&mut self, t: Time, what: &str, rust: bool, st: Option<bool>) {
        self.stats.compared += 1;
        if st != Some(rust) {
            self.mismatch_count += 1;
            if self.mismatches.len() < 20 {
                self.mismatches
                    .push(format!("t = {} ms: {what}: Rust {rust}, ST {st:?}", t / MS));
            }
        }
    }
}

impl Controller for Twin {
    fn scan(&mut self, t: Time, io: &mut [bool]) {
        while let Some(&(at, flag, value)) = self.flags.get(self.next_flag) {
            if at > t {
                break;
            }
            assert!(
                self.filter.set(flag, value),
                "the filter has no flag {flag}"
            );
            if self.fb.has_input(flag) {
                self.fb.set(flag, value);
            }
            self.next_flag += 1;
        }
        self.control.scan(t, io);
        // Now and then a wrong order, so that the check and the fallback work.
        if self.random().is_multiple_of(300) {
            let k = (self.random() % self.actuators.len() as u64) as usize;
            let a = self.actuators[k].0;
            io[a] = !io[a];
        }
        for (i, name) in &self.sensors {
            self.fb.set(name, io[*i]);
        }
        let proposed: Vec<bool> = self.actuators.iter().map(|(i, _)| io[*i]).collect();
        for ((_, name), &p) in self.actuators.iter().zip(&proposed) {
            let req = format!("{name}_REQ");
            if self.fb.has_input(&req) {
                self.fb.set(&req, p);
            }
        }
        let outcome = self.filter.scan(t, io, self.mode);
        self.fb.call(t);

        self.stats.scans += 1;
        for k in 0..self.actuators.len() {
            let (i, name) = self.actuators[k].clone();
            let st = self.fb.get(&name);
            self.compare(t, &name, io[i], st);
        }
        for c in 0..self.constraints.len() {
            let name = self.constraints[c].clone();
            let rust = outcome.violated.iter().any(|v| v.constraint == name);
            let st = self.fb.get(&format!("{name}_VIOLATED"));
            self.compare(t, &format!("{name}_VIOLATED"), rust, st);
            if rust {
                *self.stats.violations.entry(name).or_default() += 1;
            }
        }
        let st = self.fb.get("FALLBACK");
        self.compare(t, "FALLBACK", outcome.fallback, st);
        for p in 0..self.parts.len() {
            let bit = format!("FALLBACK_{}", self.parts[p]);
            let rust = outcome.parts_in_fallback.contains(&p);
            let st = if self.fb.has_output(&bit) {
                self.fb.get(&bit)
            } else {
                Some(false)
            };
            self.compare(t, &bit, rust, st);
        }
        for n in 0..self.internals.len() {
            let name = self.internals[n].clone();
            let rust = self.filter.value(&name).unwrap_or(false);
            let st = self.fb.get(&ident(&name));
            self.compare(t, &name, rust, st);
            if rust && name.starts_with('I') {
                *self.stats.intervals.entry(name).or_default() += 1;
            }
        }
        if !outcome.violated.is_empty() {
            self.stats.violated_scans += 1;
        }
        if outcome.fallback {
            self.stats.fallback_scans += 1;
        }
        if !outcome.parts_in_fallback.is_empty() {
            self.stats.part_fallback_scans += 1;
        }
        if self
            .actuators
            .iter()
            .zip(&proposed)
            .any(|((i, _), p)| io[*i] != *p)
        {
            self.stats.overridden_scans += 1;
        }
        let value = |n: &str| self.filter.value(n).unwrap_or(false);
        if value("def_C4") && value("C4") != ["I1", "I2", "I9", "I10"].iter().any(|i| value(i)) {
            self.stats.estimate_differs += 1;
        }
    }
}

struct NoSink;

impl ScanSink for NoSink {
    fn scan(&mut self, _t: Time, _values: &[bool]) -> std::io::Result<()> {
        Ok(())
    }
}

/// The flags: some that no fault asked for, to exercise every path (a
/// suspected C5, the turntable's element flagged for two minutes), then those a
/// monitor would raise on the C4 stuck at 1 from 20 min.
fn flag_schedule() -> Vec<(Time, &'static str, bool)> {
    vec![
        (5 * MINUTE, "suspect_C5", true),
        (8 * MINUTE, "suspect_C5", false),
        (10 * MINUTE, "def_P", true),
        (12 * MINUTE, "def_P", false),
        (20 * MINUTE + 30 * SECOND, "suspect_C4", true),
        (21 * MINUTE, "def_C4", true),
        (21 * MINUTE, "suspect_C4", false),
    ]
}

/// Generates the filter's text, checks it with iec2c if there is one, runs it
/// beside the Rust filter for one simulated hour and returns what happened.
fn run(coupling: Coupling, mode: Mode, seed: u64) -> (Stats, Filter) {
    let plant = plant();
    let filter = Filter::new(&plant, Some(model()), coupling).expect("filter");
    let options = StOptions {
        mode,
        ..StOptions::default()
    };
    let text = generate(&plant, &filter, &options).expect("generates");
    iec2c(&text, &format!("{}-{mode:?}", coupling.name()));
    let fb = Fb::parse(&text)
        .unwrap_or_else(|e| panic!("the generated text does not parse: {e}\n{text}"));
    let mut twin = Twin::new(&plant, filter.clone(), fb, mode, flag_schedule(), seed);
    let fault = Injection::resolve(
        &FaultSpec {
            what: "stuck1(C4)".into(),
            onset: 20 * MINUTE,
            factor: None,
        },
        &plant,
    )
    .expect("fault");
    let config = SimConfig {
        duration: 60 * MINUTE,
        scan_period: SCAN,
        seed,
        faults: vec![fault],
    };
    let mut line = SortingLine::new(SortingConfig::default());
    datasets::sim::run(&mut line, &mut twin, &config, &mut NoSink, |_| {}).expect("runs");
    eprintln!(
        "coupling {}, {mode:?}: {} scans, {} values compared, {} mismatches; {:?}",
        coupling.name(),
        twin.stats.scans,
        twin.stats.compared,
        twin.mismatch_count,
        twin.stats
    );
    assert!(
        twin.mismatches.is_empty(),
        "{} mismatches between the Rust filter and its Structured Text, first ones:\n{}",
        twin.mismatch_count,
        twin.mismatches.join("\n")
    );
    assert_eq!(twin.stats.scans, 360_001);
    (twin.stats, filter)
}

/// Every interval that can hold at this scan period held at some scan.
fn every_interval_held(stats: &Stats, filter: &Filter) {
    let mut names = Vec::new();
    for part in filter.intervals() {
        for (_, iv) in part.states {
            for i in iv {
                // `[from, to[` with `to <= one scan` never holds: the first scan
                // after an order already reads one scan period.
                if i.to.is_none_or(|to| to > SCAN) {
                    names.push(i.name);
                }
            }
        }
    }
    assert!(names.len() >= 9, "{names:?}");
    for n in names {
        assert!(
            stats.intervals.get(&n).copied().unwrap_or(0) > 0,
            "{n} never held: {stats:?}"
        );
    }
}

#[test]
fn filter_without_coupling_matches_scan_by_scan() {
    let (stats, _) = run(Coupling::None, Mode::Filter, 3);
    assert!(stats.violated_scans > 100, "{stats:?}");
    assert!(stats.fallback_scans > 100, "{stats:?}");
    assert!(stats.violations.len() >= 8, "{stats:?}");
    assert_eq!(stats.part_fallback_scans, 0, "{stats:?}");
}

#[test]
fn filter_coupled_with_flags_and_suspects_matches_scan_by_scan() {
    let (stats, filter) = run(Coupling::FlagsAndSuspects, Mode::Filter, 5);
    every_interval_held(&stats, &filter);
    assert!(stats.violated_scans > 100, "{stats:?}");
    assert!(stats.part_fallback_scans > 1000, "{stats:?}");
    assert!(stats.estimate_differs > 1000, "{stats:?}");
}

#[test]
fn safe_control_by_constraints_matches_scan_by_scan() {
    let (stats, filter) = run(Coupling::Flags, Mode::Control, 9);
    every_interval_held(&stats, &filter);
    assert!(stats.overridden_scans > 1000, "{stats:?}");
    assert!(stats.part_fallback_scans > 1000, "{stats:?}");
    assert!(stats.estimate_differs > 1000, "{stats:?}");
}

/// Compiles `text` with matiec's `iec2c` when it is on PATH.
fn iec2c(text: &str, label: &str) {
    let Some(iec2c) = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|p| p.join("iec2c"))
            .find(|p| p.is_file())
    }) else {
        static NOTED: std::sync::Once = std::sync::Once::new();
        NOTED.call_once(|| {
            eprintln!(
                "note: iec2c (matiec) is not on PATH: the generated texts ({label}...) are checked by the interpreter only"
            );
        });
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("filter.st");
    std::fs::write(&file, text).expect("writes");
    // matiec's standard library (TON...) sits in its `lib` folder.
    let lib = std::env::var_os("MATIEC_LIB")
        .map(std::path::PathBuf::from)
        .or_else(|| {
            let bin = iec2c.parent()?;
            [
                bin.join("lib"),
                bin.join("../lib/matiec"),
                bin.join("../share/matiec/lib"),
                bin.join("../lib/matiec/lib"),
                bin.join("../matiec/lib"),
            ]
            .into_iter()
            .find(|p| p.join("ieclib.txt").is_file())
        });
    let mut cmd = std::process::Command::new(&iec2c);
    if let Some(lib) = &lib {
        cmd.arg("-I").arg(lib);
    }
    cmd.arg("-T").arg(dir.path()).arg(&file);
    let out = cmd.output().expect("runs iec2c");
    assert!(
        out.status.success(),
        "iec2c rejects the generated text ({label}):\n{}{}\n{text}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A small plant that uses what the sorting line does not: a part with two
/// actuators, interval names shared by two parts, bounds off the millisecond,
/// an observer reading an order and its edge, a name starting with a digit, an
/// internal variable, `prev` of a sensor, chained combined constraints and a
/// constraint on two outputs without priority.
const BENCH_PLANT: &str = r#"
name = "bench"
scan_period_ms = 10
time_unit = "ms"
variables = ["X1"]

[signals]
S1 = { kind = "sensor", description = "press down" }
S2 = { kind = "sensor", description = "part present" }
S3 = { kind = "sensor", description = "belt end" }
Y1 = { kind = "actuator", description = "press" }
Y2 = { kind = "actuator", description = "clamp" }
Y3 = { kind = "actuator", description = "belt" }

[[parts]]
name = "press"
actuators = ["Y1", "Y2"]
sensors = ["S1", "S2"]
element = "E"

[[parts]]
name = "belt"
actuators = ["Y3"]
sensors = ["S3"]

[faults]
F1 = "stuck1(S1)"
F2 = "stuck0(S3)"
F3 = "actuator_stuck0(Y3)"
F4 = "blocked_at(E, S1)"

[partitions]
S1 = ["F1"]
S3 = ["F2"]
Y3 = ["F3"]
E = ["F4"]

[observers]
2M = { set = "RE(S2) & Y1", reset = "FE(Y2) | S3" }
T = { toggle = "RE(S3) | FE(S1)", init = true }

[[constraints]]
name = "CA"
expr = "S1 & !S2 & Y1"
[[constraints]]
name = "CB"
expr = "!S1 & RE(Y2)"
[[constraints]]
name = "CC"
expr = "2M & !Y3"
[[constraints]]
name = "CD"
expr = "prev(S1) & FE(Y1)"
[[constraints]]
name = "CE"
expr = "S3 & !X1 & Y3"
[[constraints]]
name = "CF"
expr = "S2 & Y1 & !Y2"
priority = "Y2"
[[constraints]]
name = "CG"
expr = "T & Y2 & !Y3"
priority = "Y3"
[[constraints]]
name = "CH"
expr = "S3 & Y1 & Y3"
[[constraints]]
name = "CI"
expr = "RE(X1) & Y2"

[[functional]]
name = "G1"
expr = "S2 & !Y1"
[[functional]]
name = "G2"
expr = "!S1 & Y2"
[[functional]]
name = "G3"
expr = "T & !S3 & !Y3"
"#;

const BENCH_MODEL: &str = r#"{
  "version": 1, "plant": "bench", "time_unit": "ms", "scan_period": 10.0,
  "learned_from": {"logs": [], "events": 0, "duration": 0.0},
  "settings": {"margin": 10.0, "margin_relative": 0.0, "trim": 0.0},
  "parts": [
    {"name": "press", "signals": ["Y1", "Y2", "S1", "S2"], "actuators": 2,
     "states": [], "transitions": [], "untimed": [],
     "estimates": [
       {"actuators": "Y1=1 Y2=0", "sensors": [], "intervals": [
         {"name": "I1", "from": 0.0, "to": 25.5}, {"name": "I2", "from": 25.5, "to": 60.0},
         {"name": "I3", "from": 60.0, "to": null}]},
       {"actuators": "Y1=0 Y2=0", "sensors": [], "intervals": [
         {"name": "I4", "from": 0.0, "to": 5.0}, {"name": "I5", "from": 5.0, "to": 40.25},
         {"name": "I6", "from": 40.25, "to": null}]},
       {"actuators": "Y1=1 Y2=1", "sensors": [], "intervals": [
         {"name": "I7", "from": 0.0, "to": null}]}],
     "sensor_estimates": [{"sensor": "S1", "expr": "I2 | I3 | I4 | I5", "uncertain": ["I2", "I5"]}]},
    {"name": "belt", "signals": ["Y3", "S3"], "actuators": 1,
     "states": [], "transitions": [], "untimed": [],
     "estimates": [
       {"actuators": "Y3=1", "sensors": [], "intervals": [
         {"name": "I1", "from": 0.0, "to": 30.0}, {"name": "I2", "from": 30.0, "to": null}]},
       {"actuators": "Y3=0", "sensors": [], "intervals": [
         {"name": "I3", "from": 0.0, "to": 20.0}, {"name": "I4", "from": 20.0, "to": null}]}],
     "sensor_estimates": [{"sensor": "S3", "expr": "I2 | I3", "uncertain": ["I3"]}]}
  ]
}"#;

/// What random runs went through.
#[derive(Debug, Default)]
struct RandomStats {
    fallbacks: u64,
    part_fallbacks: u64,
    /// Scans with a probing move applied, or refused, per output.
    probes_applied: u64,
    probes_refused: u64,
    /// Scans where each interval held.
    intervals: BTreeMap<String, u64>,
}

/// `plant` under random sensors, proposals, flags and internal variables: the
/// Rust filter and its Structured Text, for each coupling in both modes,
/// `scans` scans each, compared on every variable they share.
#[allow(clippy::too_many_lines)] // one scenario: both filters side by side, scan by scan
fn random_runs(
    label: &str,
    plant: &Plant,
    model: Option<&Model>,
    couplings: &[Coupling],
    scans: i64,
) -> RandomStats {
    let mut stats = RandomStats::default();
    let sensors: Vec<(usize, String)> = plant
        .signals
        .of_kind(SignalKind::Sensor)
        .map(|id| (id.index(), plant.signals.name(id).to_string()))
        .collect();
    let actuators: Vec<(usize, String)> = plant
        .signals
        .of_kind(SignalKind::Actuator)
        .map(|id| (id.index(), plant.signals.name(id).to_string()))
        .collect();
    for &coupling in couplings {
        for mode in [Mode::Filter, Mode::Control] {
            let mut filter = Filter::new(plant, model, coupling).expect("filter");
            let text = generate(
                plant,
                &filter,
                &StOptions {
                    mode,
                    ..StOptions::default()
                },
            )
            .expect("generates");
            iec2c(&text, &format!("{label} {}-{mode:?}", coupling.name()));
            let mut fb = Fb::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
            let intervals: Vec<String> = filter
                .intervals()
                .into_iter()
                .flat_map(|p| p.states)
                .flat_map(|(_, iv)| iv.into_iter().map(|i| i.name))
                .collect();
            // Flags and internal variables: what the caller writes.
            let flags: Vec<String> = filter
                .names()
                .iter()
                .skip(plant.signals.len())
                .filter(|n| {
                    !intervals.contains(n) && !plant.observers.iter().any(|o| o.name == **n)
                })
                .cloned()
                .collect();
            let mut rng: u64 = 0x9E37_79B9_7F4A_7C15;
            let mut next = move || {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng
            };
            let mut io = vec![false; plant.signals.len()];
            // Orders proposed from the first scan on: they stand for those of
            // the scan before, so the first scan has no edge.
            let mut proposed: Vec<bool> = actuators.iter().map(|_| next() % 2 == 0).collect();
            let mut raised = vec![false; flags.len()];
            // Probing moves, on a coupled filter: requested, changed and
            // given back at random.
            let probing = coupling != Coupling::None;
            let mut mismatches = Vec::new();
            for scan in 0..scans {
                let t = scan * SCAN;
                for (i, name) in &sensors {
                    if next() % 12 == 0 {
                        io[*i] = !io[*i];
                    }
                    fb.set(name, io[*i]);
                }
                for p in proposed.iter_mut() {
                    if next() % 8 == 0 {
                        *p = !*p;
                    }
                }
                for (k, f) in flags.iter().enumerate() {
                    if next() % 400 == 0 {
                        raised[k] = !raised[k];
                        assert!(filter.set(f, raised[k]), "{f}");
                        if fb.has_input(f) {
                            fb.set(f, raised[k]);
                        }
                    }
                }
                for ((i, name), &p) in actuators.iter().zip(&proposed) {
                    io[*i] = p;
                    let req = format!("{name}_REQ");
                    if fb.has_input(&req) {
                        fb.set(&req, p);
                    }
                }
                if probing {
                    for (_, name) in &actuators {
                        if next() % 50 == 0 {
                            let value = match next() % 3 {
                                0 => None,
                                v => Some(v == 2),
                            };
                            assert!(filter.request(name, value), "{name}");
                            fb.set(&format!("{name}_PROBE"), value.is_some());
                            fb.set(&format!("{name}_PROBE_VALUE"), value.unwrap_or(false));
                        }
                    }
                }
                let outcome = filter.scan(t, &mut io, mode);
                fb.call(t);
                let mut check = |what: &str, rust: bool, st: Option<bool>| {
                    if st != Some(rust) && mismatches.len() < 20 {
                        mismatches.push(format!("scan {scan}: {what}: Rust {rust}, ST {st:?}"));
                    }
                };
                for (i, name) in &actuators {
                    check(name, io[*i], fb.get(name));
                }
                for c in &plant.constraints {
                    let rust = outcome.violated.iter().any(|v| v.constraint == c.name);
                    check(&c.name, rust, fb.get(&format!("{}_VIOLATED", c.name)));
                }
                check("FALLBACK", outcome.fallback, fb.get("FALLBACK"));
                for (_, name) in actuators.iter().filter(|_| probing) {
                    let rust = outcome
                        .requests
                        .iter()
                        .any(|(a, r)| a == name && matches!(r, Request::Refused(_)));
                    stats.probes_refused += u64::from(rust);
                    let bit = format!("{name}_PROBE_REFUSED");
                    check(&bit, rust, fb.get(&bit));
                }
                stats.probes_applied += outcome
                    .requests
                    .iter()
                    .filter(|(_, r)| *r == Request::Applied)
                    .count() as u64;
                for (p, part) in plant.parts.iter().enumerate() {
                    let bit = format!("FALLBACK_{}", part.name);
                    let st = if fb.has_output(&bit) {
                        fb.get(&bit)
                    } else {
                        Some(false)
                    };
                    check(&bit, outcome.parts_in_fallback.contains(&p), st);
                }
                for o in &plant.observers {
                    check(
                        &o.name,
                        filter.value(&o.name).unwrap_or(false),
                        fb.get(&ident(&o.name)),
                    );
                }
                for name in &intervals {
                    let rust = filter.value(name).unwrap_or(false);
                    check(name, rust, fb.get(name));
                    if rust {
                        *stats.intervals.entry(name.clone()).or_default() += 1;
                    }
                }
                stats.fallbacks += u64::from(outcome.fallback);
                stats.part_fallbacks += u64::from(!outcome.parts_in_fallback.is_empty());
            }
            assert!(
                mismatches.is_empty(),
                "{label}, coupling {}, {mode:?}:\n{}\n{text}",
                coupling.name(),
                mismatches.join("\n")
            );
        }
    }
    eprintln!("{label}: {stats:?}");
    stats
}

#[test]
fn bench_plant_under_random_inputs_matches_scan_by_scan() {
    let plant = Plant::parse(BENCH_PLANT, Path::new("bench.toml")).expect("plant");
    let model = Model::parse(BENCH_MODEL, Path::new("bench.json")).expect("model");
    let couplings = [Coupling::None, Coupling::Flags, Coupling::FlagsAndSuspects];
    let stats = random_runs("bench", &plant, Some(&model), &couplings, 20_000);
    assert!(
        stats.fallbacks > 1000 && stats.part_fallbacks > 1000,
        "{stats:?}"
    );
    assert!(
        stats.probes_applied > 1000 && stats.probes_refused > 1000,
        "{stats:?}"
    );
    // Every interval that can hold did, under both parts' qualified names
    // (press_I4 = [0, 5[ ms cannot: the first scan after an order reads 10 ms).
    assert!(!stats.intervals.contains_key("press_I4"));
    for name in [
        "press_I1", "press_I2", "press_I3", "I5", "I6", "I7", "belt_I1", "belt_I2", "belt_I3",
        "belt_I4",
    ] {
        assert!(stats.intervals.contains_key(name), "{name}: {stats:?}");
    }
}

/// The four-cylinder rig's filter (GRAFCET steps as internal variables, four
/// combined constraints in a cycle), uncoupled, under random inputs.
#[test]
fn cylinders_plant_under_random_inputs_matches_scan_by_scan() {
    let plant =
        Plant::from_path(Path::new(&path("datasets/plants/cylinders.toml"))).expect("plant");
    let stats = random_runs("cylinders", &plant, None, &[Coupling::None], 20_000);
    assert!(stats.fallbacks > 1000, "{stats:?}");
}

#[test]
fn command_line_prints_the_function_block_and_rejects_bad_input() {
    let plant = path("datasets/plants/sorting.toml");
    let model = path("diagnoser/tests/fixtures/diagnosis/sorting-model.json");
    let o = gardefou(&[
        "filter",
        "st",
        "--plant",
        &plant,
        "--model",
        &model,
        "--suspects",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let fb = Fb::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(fb.name, "GARDEFOU_FILTER");
    assert!(
        fb.has_input("suspect_C4") && fb.has_input("A4_REQ"),
        "{text}"
    );
    assert!(text.contains("while def_C4 OR suspect_C4"), "{text}");

    let o = gardefou(&[
        "filter",
        "st",
        "--plant",
        &plant,
        "--coupling",
        "none",
        "--control",
        "--name",
        "SORTING_SAFE",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let fb = Fb::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(fb.name, "SORTING_SAFE");
    assert!(!fb.has_input("def_C4"), "{text}");
    assert!(
        text.contains(
            "A4_REQ : BOOL; (* proposed by the control program (read at the first scan only)"
        ),
        "{text}"
    );
    assert!(
        fb.has_input("A5_REQ") || text.contains("A5 := TRUE;"),
        "{text}"
    );

    let other = path("datasets/plants/cylinders.toml");
    for (args, needle) in [
        (
            vec!["--model", model.as_str(), "--coupling", "def", "--suspects"],
            "--suspects",
        ),
        (vec![], "--model"),
        (vec!["--model", "/nonexistent/model.json"], "model.json"),
        (
            vec!["--model", model.as_str(), "--name", "9LIVES"],
            "--name",
        ),
        (
            vec!["--model", model.as_str(), "--coupling", "both"],
            "both",
        ),
    ] {
        let mut all = vec!["filter", "st", "--plant", plant.as_str()];
        all.extend(args);
        assert_bad_input(&gardefou(&all), needle);
    }
    let o = gardefou(&["filter", "st", "--plant", &other, "--model", &model]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("learned for plant 'sorting'"), "{err}");
}

/// An independent IEC 61131-3 parser (blark, TwinCAT's dialect) reads every
/// variant the command line writes: both plants, both modes, every coupling.
#[test]
fn every_function_block_variant_parses_with_an_independent_parser() {
    let python = std::env::var("GARDEFOU_PYTHON").unwrap_or_else(|_| "python3".into());
    let dir = tempfile::tempdir().expect("temp dir");
    let cylinders_plant = path("datasets/data/cylinders/normal/plant.toml");
    let cylinders_model = dir.path().join("cylinders.json");
    let learned = gardefou(&[
        "learn",
        "--quiet",
        "--plant",
        &cylinders_plant,
        "-o",
        cylinders_model.to_str().expect("path"),
        &path("datasets/data/cylinders/normal/events.csv"),
    ]);
    assert!(
        learned.status.success(),
        "{}",
        String::from_utf8_lossy(&learned.stderr)
    );
    let plants = [
        (
            path("datasets/plants/sorting.toml"),
            path("diagnoser/tests/fixtures/diagnosis/sorting-model.json"),
        ),
        (
            cylinders_plant.clone(),
            cylinders_model.display().to_string(),
        ),
    ];
    let mut parsed = 0;
    for (plant, model) in &plants {
        for mode in [None, Some("--control")] {
            for coupling in ["none", "def", "def+suspect"] {
                let mut args = vec!["filter", "st", "--plant", plant, "--model", model];
                args.extend(["--coupling", coupling]);
                args.extend(mode);
                let o = gardefou(&args);
                assert!(
                    o.status.success(),
                    "{args:?}: {}",
                    String::from_utf8_lossy(&o.stderr)
                );
                let file = dir.path().join(format!("fb{parsed}.st"));
                std::fs::write(&file, &o.stdout).expect("writes");
                let blark = Command::new(&python)
                    .args(["-m", "blark", "parse"])
                    .arg(&file)
                    .output()
                    .expect("runs python");
                assert!(
                    blark.status.success(),
                    "{args:?}: blark: {}{}",
                    String::from_utf8_lossy(&blark.stdout),
                    String::from_utf8_lossy(&blark.stderr)
                );
                parsed += 1;
            }
        }
    }
    assert_eq!(parsed, 12);
}
