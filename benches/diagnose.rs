//! Diagnosis speed: every part diagnoser of the sorting line fed with events
//! already in memory (no parsing), in normal operation and after a fault.
//!
//! The model is learned from one simulated hour (seed 3); the replayed logs are
//! 100 simulated hours with another seed: normal operation; F2 (C4 stuck at 1)
//! from minute 10, after which the turntable stops and the line soon halts, so
//! the log is short; and F7 (unexpected rises of C4) from minute 10, after which
//! the line keeps running, so nearly the whole log goes through the diagnosers
//! after detection.
//!
//! Each log is replayed by the plant diagnoser that `monitor` runs (every
//! part fed event by event, `NAME`), and by the replay by part that
//! `diagnose` runs, in batches of 65 536 events as a log is read, on one
//! thread (`NAME_partwise_1`, the one-core figure) and on two
//! (`NAME_partwise_2`).
//!
//! Run with `cargo bench --bench diagnose`. `HOURS=1000 cargo bench --bench
//! diagnose` replays 1000 simulated hours instead of 100: the logs that
//! `benches/diagnose.sh` replays end to end (seed 7), in memory.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig};
use datasets::sorting::{plant, simulate_in_memory};
use diagnoser::diagnosis::{DiagnoserOptions, PartwiseReplay, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, Time, TimeFormat};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;

/// Simulated hours of each replayed log: `HOURS`, else 100.
fn hours() -> Time {
    std::env::var("HOURS")
        .ok()
        .and_then(|h| h.parse().ok())
        .filter(|&h: &Time| h > 0)
        .unwrap_or(100)
}

/// Simulates the sorting line for `duration` with `faults` (e.g. `F2@10min`).
fn simulate(plant: &Plant, duration: Time, seed: u64, faults: &[&str]) -> MemorySink {
    let faults = faults
        .iter()
        .map(|f| {
            let spec: FaultSpec = f.parse().expect("valid fault spec");
            Injection::resolve(&spec, plant).expect("fault of the sorting plant")
        })
        .collect();
    let config = SimConfig {
        duration,
        scan_period: 10 * MS,
        seed,
        faults,
    };
    simulate_in_memory(&config).expect("in-memory simulation").0
}

/// Learns the model from one simulated hour of normal operation, in memory.
fn learn(plant: &Plant) -> Model {
    let log = simulate(plant, 3600 * SECOND, 3, &[]);
    let stream = LogStream::from_events(
        "simulated-1h-seed-3",
        TimeFormat::Numeric(plant.time_unit),
        log.start,
        log.initial,
        log.events,
    );
    let mut learner = Learner::new(plant, LearnOptions::default()).expect("learnable plant");
    learner
        .learn_log(stream, |_| {})
        .expect("in-memory log is valid");
    learner.finish()
}

/// Replays `log` from its start to its last event; returns the verdicts given.
fn replay(diagnoser: &mut PlantDiagnoser, log: &MemorySink) -> u64 {
    let mut verdicts = 0u64;
    let mut out = |v: Verdict| {
        black_box(&v);
        verdicts += 1;
    };
    diagnoser.start(log.start, &log.initial);
    for &e in &log.events {
        diagnoser.push(e, &mut out);
    }
    let end = log.events.last().map_or(log.start, |e| e.t);
    black_box(diagnoser.finish(end, &mut out));
    verdicts
}

/// Replays `log` by part, in batches as a log is read; returns the verdicts.
fn replay_by_part(replay: &mut PartwiseReplay, log: &MemorySink) -> u64 {
    let mut verdicts = 0u64;
    let mut out = |v: Verdict| {
        black_box(&v);
        verdicts += 1;
    };
    replay.start(log.start, &log.initial);
    for batch in log.events.chunks(65_536) {
        replay.push_batch(batch, &mut out);
    }
    let end = log.events.last().map_or(log.start, |e| e.t);
    black_box(replay.finish(end, &mut out));
    verdicts
}

fn diagnose(c: &mut Criterion) {
    let plant = plant();
    let model = learn(&plant);
    let options = DiagnoserOptions::default();
    let hours = hours();
    let logs = [
        ("normal", simulate(&plant, hours * 3600 * SECOND, 7, &[])),
        (
            "f2_at_10min",
            simulate(&plant, hours * 3600 * SECOND, 7, &["F2@10min"]),
        ),
        (
            "f7_at_10min",
            simulate(&plant, hours * 3600 * SECOND, 7, &["F7@10min"]),
        ),
    ];

    let mut group = c.benchmark_group(format!("diagnose_sorting_{hours}h"));
    group.sample_size(10);
    for (name, log) in &logs {
        let mut diagnoser =
            PlantDiagnoser::new(&plant, &model, &options).expect("model fits the plant");
        // The diagnoser automaton is built on the fly: one replay builds the part
        // of it this log visits, so the samples measure the steady state.
        let verdicts = replay(&mut diagnoser, log);
        eprintln!(
            "{name}: {} events over {hours} h, {verdicts} verdict change(s)",
            log.events.len()
        );
        group.throughput(Throughput::Elements(log.events.len() as u64));
        group.bench_function(*name, |b| b.iter(|| replay(&mut diagnoser, log)));
        for threads in [1, 2] {
            let diagnoser =
                PlantDiagnoser::new(&plant, &model, &options).expect("model fits the plant");
            let mut partwise = PartwiseReplay::new(diagnoser, threads);
            replay_by_part(&mut partwise, log);
            group.bench_function(format!("{name}_partwise_{threads}"), |b| {
                b.iter(|| replay_by_part(&mut partwise, log))
            });
        }
        // From a fresh diagnoser: includes building the automaton.
        group.bench_function(format!("{name}_cold"), |b| {
            b.iter(|| {
                let mut fresh =
                    PlantDiagnoser::new(&plant, &model, &options).expect("model fits the plant");
                replay(&mut fresh, log)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, diagnose);
criterion_main!(benches);
