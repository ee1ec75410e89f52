//! The generality benchmark: learn, replay and check on many generated plants.
//!
//! ```sh
//! cargo bench -p evaluation --bench generality -- [--quick] [--plants 50] [--first-seed 1]
//!     [--sizes small,medium,large] [--families assembly,process,axes,mixed]
//!     [--jobs N] [--json FILE] [--markdown FILE]
//! ```
//!
//! Plants are evaluated in parallel, one per core. The table goes to stdout
//! (and to `--markdown`), one JSON line per plant to `--json`, progress to
//! stderr on a terminal.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use clap::Parser;
use datasets::generated::{Family, Size};
use evaluation::summary::{describe, disagreement_table, disagreements, table, template_table};
use evaluation::{PlantOutcome, Settings, evaluate_family};
use indicatif::{ProgressBar, ProgressStyle};

/// Learn, replay and check on generated plants; print the rates.
#[derive(Debug, Parser)]
struct Args {
    /// A short run that fits in continuous integration (6 plants, fewer faults).
    #[arg(long)]
    quick: bool,
    /// Number of plants [default: 50; 6 with --quick].
    #[arg(long)]
    plants: Option<usize>,
    /// Seed of the first plant; plant k has seed first + k.
    #[arg(long, default_value_t = 1)]
    first_seed: u64,
    /// Sizes, taken in turn.
    #[arg(long, value_delimiter = ',', default_value = "small,medium,large")]
    sizes: Vec<Size>,
    /// Plant families, taken in turn (each with every size in turn).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "assembly,process,axes,mixed"
    )]
    families: Vec<Family>,
    /// Plants evaluated at once [default: the cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Write every plant's outcome as a JSON line to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write the report (Markdown) to this file.
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Passed by `cargo bench`; ignored.
    #[arg(long, hide = true)]
    bench: bool,
}

fn main() {
    let args = Args::parse();
    if args.sizes.is_empty() {
        eprintln!("error: --sizes needs at least one size");
        std::process::exit(2);
    }
    let settings = if args.quick {
        Settings::quick()
    } else {
        Settings::full()
    };
    let count = args.plants.unwrap_or(if args.quick { 6 } else { 50 });
    if args.families.is_empty() {
        eprintln!("error: --families needs at least one family");
        std::process::exit(2);
    }
    let (sizes, families) = (args.sizes.len(), args.families.len());
    let plants: Vec<(u64, Size, Family)> = (0..count)
        .map(|k| {
            (
                args.first_seed + k as u64,
                args.sizes[k % sizes],
                args.families[k / sizes % families],
            )
        })
        .collect();
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(2, |n| n.get()))
        .max(1);
    let clock = Instant::now();
    let outcomes = run_all(&plants, &settings, jobs);
    let wall = clock.elapsed().as_secs_f64();

    let report = render(&outcomes, &settings, jobs, wall);
    print!("{report}");
    if let Some(path) = &args.markdown {
        write(path, report.as_bytes());
    }
    if let Some(path) = &args.json {
        let mut text = String::new();
        for o in &outcomes {
            text.push_str(&serde_json::to_string(o).unwrap_or_default());
            text.push('\n');
        }
        write(path, text.as_bytes());
    }
    if outcomes.iter().any(|o| o.error.is_some()) {
        std::process::exit(1);
    }
}

fn write(path: &PathBuf, bytes: &[u8]) {
    if let Err(e) = std::fs::write(path, bytes) {
        eprintln!("error: cannot write {}: {e}", path.display());
        std::process::exit(1);
    }
}

/// Evaluates every plant on `jobs` threads, largest first (the longest jobs
/// start first, so the threads finish together); outcomes in plant order.
fn run_all(plants: &[(u64, Size, Family)], settings: &Settings, jobs: usize) -> Vec<PlantOutcome> {
    let mut order: Vec<usize> = (0..plants.len()).collect();
    order.sort_by_key(|&k| std::cmp::Reverse(plants[k].1));
    let bar = if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new(plants.len() as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} plants [{bar:30}] {pos}/{len} ({elapsed}, {eta} left) {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<PlantOutcome>>> = Mutex::new(vec![None; plants.len()]);
    std::thread::scope(|s| {
        for _ in 0..jobs.min(plants.len()) {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&k) = order.get(i) else { break };
                    let (seed, size, family) = plants[k];
                    let outcome = evaluate_family(seed, size, family, settings);
                    bar.set_message(format!("{} done", outcome.name));
                    bar.inc(1);
                    if let Ok(mut r) = results.lock() {
                        r[k] = Some(outcome);
                    }
                }
            });
        }
    });
    bar.finish_and_clear();
    results
        .into_inner()
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .collect()
}

fn render(outcomes: &[PlantOutcome], settings: &Settings, jobs: usize, wall: f64) -> String {
    let mut out = String::new();
    let cpu: f64 = outcomes
        .iter()
        .map(|o| o.seconds.learn + o.seconds.normal + o.seconds.check + o.seconds.faults)
        .sum();
    let sum = |f: fn(&PlantOutcome) -> f64| outcomes.iter().map(f).sum::<f64>();
    out.push_str(&format!(
        "# Generality benchmark: {} generated plants (seeds {}–{})\n\n{}.\n\n",
        outcomes.len(),
        outcomes.iter().map(|o| o.seed).min().unwrap_or(0),
        outcomes.iter().map(|o| o.seed).max().unwrap_or(0),
        describe(settings),
    ));
    out.push_str(&table(outcomes));
    out.push_str("\nBy fault template (`slow` by factor):\n\n");
    out.push_str(&template_table(outcomes));
    out.push_str(&format!(
        "\n{wall:.0} s wall on {jobs} thread(s), {cpu:.0} s of work: learning {:.0} s, fault-free replay {:.0} s, check {:.0} s, faulty runs {:.0} s.\n",
        sum(|o| o.seconds.learn),
        sum(|o| o.seconds.normal),
        sum(|o| o.seconds.check),
        sum(|o| o.seconds.faults),
    ));
    for o in outcomes.iter().filter(|o| o.error.is_some()) {
        out.push_str(&format!(
            "\nplant {} ({}) failed: {}\n",
            o.seed,
            o.size,
            o.error.as_deref().unwrap_or("")
        ));
    }
    let found = disagreements(outcomes);
    out.push_str(&format!(
        "\n## `check` against the replays: {} disagreement(s)\n\nAmong the faulty runs where the fault showed and its part was still normal at the onset.\n\n{}\n",
        found.len(),
        disagreement_table(&found)
    ));
    for d in &found {
        out.push_str(&format!(
            "- plant {} {}, {} at {} ms: {}. Rerun: `{}`\n",
            d.seed,
            d.size,
            d.label,
            d.onset_ms,
            d.what,
            d.rerun(settings)
        ));
    }
    let _ = std::io::stderr().flush();
    out
}
