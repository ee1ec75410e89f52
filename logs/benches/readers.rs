//! The log readers on given files, as `logs::open` streams them.
//!
//! ```text
//! cargo bench -p logs --features parquet --bench readers -- PLANT FILE...
//! ```
//!
//! Each FILE (events, intervals or scans, CSV or Parquet, detected) is read to
//! the end three times, each time in a process of its own so that the peak
//! resident size is the reader's alone. Prints one markdown row per file:
//! events read, median wall time, events and megabytes per second, and the
//! largest peak resident size of the three runs.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use logs::{IngestOptions, detect_format, open};
use vocabulary::Plant;

const RUNS: usize = 3;

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    if let [mode, plant, file] = &args[..]
        && mode == "--child"
    {
        child(Path::new(plant), Path::new(file));
        return;
    }
    let [plant, files @ ..] = &args[..] else {
        eprintln!("usage: cargo bench -p logs --features parquet --bench readers -- PLANT FILE...");
        std::process::exit(2);
    };
    println!("| file | MB | form | events | median s | M events/s | MB/s | peak MB |");
    println!("|---|---:|---|---:|---:|---:|---:|---:|");
    for file in files {
        let mb = std::fs::metadata(file).map_or(0, |m| m.len()) >> 20;
        let name = detect_format(Path::new(file)).map_or("?".into(), |f| format!("{f:?}"));
        {
            let runs: Vec<(u64, f64, u64)> =
                (0..RUNS).map(|_| run("--child", plant, file)).collect();
            let mut secs: Vec<f64> = runs.iter().map(|r| r.1).collect();
            secs.sort_by(f64::total_cmp);
            let median = secs[RUNS / 2];
            let events = runs[0].0;
            let peak = runs.iter().map(|r| r.2).max().unwrap_or(0);
            println!(
                "| {} | {mb} | {name} | {events} | {median:.2} | {:.1} | {:.0} | {} |",
                PathBuf::from(file).display(),
                events as f64 / median / 1e6,
                mb as f64 / median,
                peak >> 10
            );
        }
    }
}

/// One read of `file` in a child process: (events, seconds, peak resident KB).
fn run(flag: &str, plant: &str, file: &str) -> (u64, f64, u64) {
    let exe = std::env::current_exe().expect("the bench's own path");
    let out = Command::new(exe)
        .args([flag, plant, file])
        .output()
        .expect("the bench runs itself");
    assert!(
        out.status.success(),
        "{flag} {file}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let fields: Vec<&str> = text.split_whitespace().collect();
    (
        fields[0].parse().expect("events"),
        fields[1].parse().expect("seconds"),
        fields[2].parse().expect("peak KB"),
    )
}

/// Reads `file` to its end and prints events, seconds and the process's peak
/// resident size in KB.
fn child(plant: &Path, file: &Path) {
    let plant = Plant::from_path(plant).expect("plant file");
    let started = Instant::now();
    let options = IngestOptions {
        time_unit: plant.time_unit,
        ..IngestOptions::default()
    };
    let stream = open(file, &plant, &options).expect("log");
    let events: u64 = stream.batches.map(|b| b.expect("batch").len() as u64).sum();
    let secs = started.elapsed().as_secs_f64();
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let peak = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
        .unwrap_or(0);
    println!("{events} {secs} {peak}");
}
