//! Learning speed: the sorting line's part models learned from events already in
//! memory, so that the learner's own work is measured apart from reading logs.
//!
//! The log is 100 simulated hours of normal operation (seed 7), learned once per
//! sample with the default options.
//!
//! Run with `cargo bench -p learning --bench learn`.

use std::hint::black_box;

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use datasets::sim::{MemorySink, SimConfig};
use datasets::sorting::{plant, simulate_in_memory};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;
use vocabulary::model::Model;
use vocabulary::{Event, MS, Plant, SECOND, Time, TimeFormat};

/// Simulated hours of the learned log.
const HOURS: Time = 100;

/// Simulates `HOURS` of the sorting line's normal operation.
fn simulate() -> MemorySink {
    let config = SimConfig {
        duration: HOURS * 3600 * SECOND,
        scan_period: 10 * MS,
        seed: 7,
        faults: Vec::new(),
    };
    simulate_in_memory(&config).expect("in-memory simulation").0
}

/// Learns the model of `plant` from `events` of `log`.
fn learn(plant: &Plant, log: &MemorySink, events: Vec<Event>) -> Model {
    let stream = LogStream::from_events(
        "simulated-sorting",
        TimeFormat::Numeric(plant.time_unit),
        log.start,
        log.initial.clone(),
        events,
    );
    let mut learner = Learner::new(plant, LearnOptions::default()).expect("learnable plant");
    learner
        .learn_log(stream, |_| {})
        .expect("in-memory log is valid");
    learner.finish()
}

fn learn_sorting(c: &mut Criterion) {
    let plant = plant();
    let log = simulate();
    eprintln!("sorting: {} events over {HOURS} h", log.events.len());
    let mut group = c.benchmark_group(format!("learn_sorting_{HOURS}h"));
    group.sample_size(10);
    group.throughput(Throughput::Elements(log.events.len() as u64));
    // The copy of the events that the learner consumes is made outside the
    // measured time.
    group.bench_function("normal", |b| {
        b.iter_batched(
            || log.events.clone(),
            |events| black_box(learn(&plant, &log, events)),
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

criterion_group!(benches, learn_sorting);
criterion_main!(benches);
