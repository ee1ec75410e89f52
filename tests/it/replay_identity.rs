//! The verdict lines of `gardefou diagnose` are the same whatever the number
//! of threads that run the parts, and the same as before the parts ran side
//! by side: on every shipped log of both reference plants (events and
//! intervals forms), and on 1000 simulated hours of the sorting line with F7.
//!
//! The expected lines in `tests/fixtures/replay/` were written by the plant
//! diagnoser that fed every part in turn, event by event (the path the
//! monitor keeps), before the replay by part existed. They are not rewritten
//! by any switch: a change to them is a change of the diagnosis, to be made
//! by hand and explained.

use std::fs;
use std::path::{Path, PathBuf};

use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, ScanSink, SimConfig};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl};
use diagnoser::diagnosis::{DiagnoserOptions, PartwiseReplay, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{Event, MS, Plant, SECOND, SignalId, Time, TimeFormat};
use learning::learn::{LearnOptions, Learner};
use logs::LogStream;

use crate::support::{gardefou, repo};

fn expected(name: &str) -> String {
    let path = repo(&format!("tests/fixtures/replay/{name}.jsonl"));
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// With `UPDATE_EXPECT=1`, records `lines` as the expected lines of `name`
/// (after a change of what the diagnosers say, never of how they run).
fn update(name: &str, lines: &str) {
    if std::env::var_os("UPDATE_EXPECT").is_some() {
        let path = repo(&format!("tests/fixtures/replay/{name}.jsonl"));
        fs::write(&path, lines).unwrap_or_else(|e| panic!("{path}: {e}"));
    }
}

/// Every shipped run of `plant`, with the model learned from its normal run.
fn shipped(plant: &str, dir: &Path) -> (PathBuf, Vec<PathBuf>) {
    let root = PathBuf::from(repo(&format!("datasets/data/{plant}")));
    let model = dir.join(format!("{plant}.json"));
    let normal = root.join("normal");
    let o = gardefou(&[
        "learn",
        "-q",
        "--plant",
        &normal.join("plant.toml").display().to_string(),
        &normal.join("events.csv").display().to_string(),
        "-o",
        &model.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut runs: Vec<PathBuf> = fs::read_dir(&root)
        .expect("the plant's runs")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join("events.csv").is_file())
        .collect();
    runs.sort();
    (model, runs)
}

#[test]
fn every_shipped_log_gives_the_same_verdict_lines_on_any_number_of_threads() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut checked = 0;
    for plant in ["sorting", "cylinders"] {
        let (model, runs) = shipped(plant, dir.path());
        for run in runs {
            let name = format!("{plant}-{}", run.file_name().unwrap().to_string_lossy());
            for form in ["events", "intervals"] {
                let log = run.join(format!("{form}.csv"));
                let mut want = None;
                for threads in ["1", "2"] {
                    let o = gardefou(&[
                        "diagnose",
                        "--threads",
                        threads,
                        "--plant",
                        &run.join("plant.toml").display().to_string(),
                        "--model",
                        &model.display().to_string(),
                        &log.display().to_string(),
                    ]);
                    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
                    let got = String::from_utf8_lossy(&o.stdout);
                    let want = want.get_or_insert_with(|| {
                        update(&format!("{name}.{form}"), &got);
                        expected(&format!("{name}.{form}"))
                    });
                    assert!(
                        got == *want,
                        "{name}/{form} on {threads} thread(s): verdict lines differ\n--- got\n{got}--- expected\n{want}"
                    );
                    checked += 1;
                }
            }
        }
    }
    // 13 sorting runs and 3 of the rig, two forms, two thread counts.
    assert_eq!(checked, 16 * 2 * 2);
}

/// Feeds a simulation's changes to a sequential plant diagnoser and to a
/// replay by part, in batches as a log is read.
struct Both {
    reference: PlantDiagnoser,
    partwise: PartwiseReplay,
    batch: Vec<Event>,
    last: Vec<bool>,
    lines: [Vec<String>; 2],
    events: u64,
}

impl Both {
    const BATCH: usize = 65_536;

    fn lines(lines: &mut Vec<String>) -> impl FnMut(Verdict) + '_ {
        |v| lines.push(v.json_line(TimeFormat::Numeric(diagnoser::TimeUnit::Ms), None))
    }

    fn feed(&mut self) {
        let [sequential, by_part] = &mut self.lines;
        let mut out = Self::lines(sequential);
        for &e in &self.batch {
            self.reference.push(e, &mut out);
        }
        self.partwise
            .push_batch(&self.batch, &mut Self::lines(by_part));
        self.events += self.batch.len() as u64;
        self.batch.clear();
    }
}

impl ScanSink for Both {
    fn scan(&mut self, t: Time, values: &[bool]) -> std::io::Result<()> {
        if self.last.is_empty() {
            self.reference.start(t, values);
            self.partwise.start(t, values);
            self.last = values.to_vec();
            return Ok(());
        }
        // Most scans change nothing: one comparison of the slices (this
        // crate's own loops are not optimised in tests).
        if self.last == values {
            return Ok(());
        }
        if self.batch.len() >= Self::BATCH {
            self.feed();
        }
        for (i, (old, &new)) in self.last.iter_mut().zip(values).enumerate() {
            if *old != new {
                self.batch.push(Event {
                    t,
                    signal: SignalId(i as u32),
                    value: new,
                });
                *old = new;
            }
        }
        Ok(())
    }
}

fn config(hours: Time, seed: u64, faults: &[&str], plant: &Plant) -> SimConfig {
    SimConfig {
        duration: hours * 3600 * SECOND,
        scan_period: 10 * MS,
        seed,
        faults: faults
            .iter()
            .map(|f| {
                let spec: FaultSpec = f.parse().expect("a fault spec");
                Injection::resolve(&spec, plant).expect("a fault of the sorting line")
            })
            .collect(),
    }
}

/// The model `gardefou learn` gives on one simulated hour with seed 3.
fn learned(plant: &Plant) -> Model {
    let (log, _) =
        datasets::sorting::simulate_in_memory(&config(1, 3, &[], plant)).expect("a simulation");
    let MemorySink {
        start,
        initial,
        events,
        ..
    } = log;
    let stream = LogStream::from_events(
        "1h-seed-3",
        TimeFormat::Numeric(plant.time_unit),
        start,
        initial,
        events,
    );
    let mut learner = Learner::new(plant, LearnOptions::default()).expect("a learnable plant");
    learner.learn_log(stream, |_| {}).expect("a valid log");
    learner.finish()
}

#[test]
fn a_thousand_hours_with_f7_give_the_verdict_lines_of_the_sequential_diagnoser() {
    let plant = datasets::sorting::plant();
    let model = learned(&plant);
    let options = DiagnoserOptions::default();
    let diagnoser = || PlantDiagnoser::new(&plant, &model, &options).expect("the model fits");
    let mut both = Both {
        reference: diagnoser(),
        partwise: PartwiseReplay::new(diagnoser(), 2),
        batch: Vec::new(),
        last: Vec::new(),
        lines: [Vec::new(), Vec::new()],
        events: 0,
    };
    let mut line = SortingLine::new(SortingConfig::default());
    let mut control = SynthesisedControl::new(line.ids());
    let config = config(1000, 7, &["F7@10min"], &plant);
    datasets::sim::run(&mut line, &mut control, &config, &mut both, |_| {}).expect("a simulation");
    both.feed();
    let end = config.duration;
    let [sequential, by_part] = &mut both.lines;
    both.reference.finish(end, &mut Both::lines(sequential));
    both.partwise.finish(end, &mut Both::lines(by_part));
    assert!(both.events > 8_000_000, "{} events", both.events);
    update(
        "sorting-F7-1000h",
        &sequential
            .iter()
            .map(|l| format!("{l}\n"))
            .collect::<String>(),
    );
    let want = expected("sorting-F7-1000h");
    let want: Vec<&str> = want.lines().collect();
    assert_eq!(sequential.len(), want.len(), "{sequential:#?}");
    for (got, want) in sequential.iter().zip(&want) {
        assert_eq!(got, want);
    }
    assert_eq!(by_part, sequential);
}

#[test]
fn a_directory_stands_for_the_logs_in_it_by_name() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (model, _) = shipped("sorting", dir.path());
    let logs = dir.path().join("archive");
    fs::create_dir(&logs).expect("a directory");
    let data = PathBuf::from(repo("datasets/data/sorting"));
    fs::copy(data.join("F5/intervals.csv"), logs.join("b-f5.csv")).expect("copy");
    fs::copy(data.join("F2/events.csv"), logs.join("a-f2.csv")).expect("copy");
    // Not logs: skipped.
    fs::copy(data.join("F2/plant.toml"), logs.join("plant.toml")).expect("copy");
    fs::copy(data.join("F2/truth.json"), logs.join("truth.json")).expect("copy");
    let plant = data.join("F2/plant.toml").display().to_string();
    let model = model.display().to_string();
    let run = |logs: &[&Path]| {
        let mut args = vec!["diagnose", "--plant", &plant, "--model", &model];
        let logs: Vec<String> = logs.iter().map(|p| p.display().to_string()).collect();
        args.extend(logs.iter().map(String::as_str));
        gardefou(&args)
    };
    let by_files = run(&[&logs.join("a-f2.csv"), &logs.join("b-f5.csv")]);
    let by_dir = run(&[&logs]);
    assert!(
        by_dir.status.success(),
        "{}",
        String::from_utf8_lossy(&by_dir.stderr)
    );
    let lines = String::from_utf8_lossy(&by_dir.stdout);
    assert!(lines.lines().count() >= 10, "{lines}");
    assert!(
        lines.lines().next().is_some_and(|l| l.contains("a-f2.csv")),
        "{lines}"
    );
    assert_eq!(by_dir.stdout, by_files.stdout);

    let empty = dir.path().join("empty");
    fs::create_dir(&empty).expect("a directory");
    let o = run(&[&empty]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("a directory with no log"), "{err}");
}
