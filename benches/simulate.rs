//! Simulation speed: one simulated hour of the sorting line, in memory and
//! written to disk (events, intervals, truth, damage, plant file).
//!
//! Run with `cargo bench --bench simulate`.

use criterion::{Criterion, criterion_group, criterion_main};
use datasets::output::{RunFiles, write_run};
use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl};
use diagnoser::{MS, SECOND};

fn config() -> SimConfig {
    SimConfig {
        duration: 3600 * SECOND,
        scan_period: 10 * MS,
        seed: 7,
        faults: Vec::new(),
    }
}

fn one_hour(c: &mut Criterion) {
    let mut group = c.benchmark_group("sorting_one_simulated_hour");
    group.sample_size(10);
    group.bench_function("in_memory", |b| {
        b.iter(|| {
            let mut line = SortingLine::new(SortingConfig::default());
            let mut ctl = SynthesisedControl::new(line.ids());
            let mut sink = MemorySink::default();
            run(&mut line, &mut ctl, &config(), &mut sink, |_| {}).map(|r| r.scans)
        })
    });
    let dir = std::env::temp_dir().join(format!("gardefou-bench-{}", std::process::id()));
    group.bench_function("to_files", |b| {
        b.iter(|| {
            let mut line = SortingLine::new(SortingConfig::default());
            let mut ctl = SynthesisedControl::new(line.ids());
            let files = RunFiles {
                dir: dir.clone(),
                scans: false,
                archive: None,
            };
            write_run(&files, &mut line, &mut ctl, &config(), |_| {}).map(|r| r.scans)
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, one_hour);
criterion_main!(benches);
