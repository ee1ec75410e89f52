//! Writing a simulated run to a directory: `events.csv`, `intervals.csv`,
//! optionally `scans.csv`, `truth.json`, `damage.json` and `plant.toml`.
//!
//! Files are written into a hidden staging directory inside the target and moved
//! into place only once the run has finished, so a failed or interrupted run never
//! leaves half-written files, nor replaces those of an earlier run. Once they
//! are in place, the files of an earlier run that this one did not write are
//! removed: a directory holds one run. Staging directories of killed runs are
//! removed by the next run in the same directory.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use logs::{EventWriter, IntervalWriter, ScanWriter};
use vocabulary::{Event, Plant, SignalId, Time, TimeFormat};

use crate::inject::{time_value, truth_json};
use crate::sim::{Controller, Physics, ScanSink, SimConfig, SimReport, run_with_showing};

/// Where and what to write.
#[derive(Debug, Clone)]
pub struct RunFiles {
    /// Output directory (created if needed).
    pub dir: PathBuf,
    /// Also write the wide `scans.csv`.
    pub scans: bool,
    /// Also write `intervals.parquet`, with this writer (which gets the
    /// staging directory, holding the run's `events.csv`, the plant and the
    /// run's end): the Parquet writer lives with the log layer's `parquet`
    /// feature, which this crate does not build.
    pub archive: Option<ArchiveWriter>,
}

/// Writes `intervals.parquet` into a directory holding a run's `events.csv`.
pub type ArchiveWriter = fn(&Path, &Plant, Time) -> io::Result<()>;

/// Every file a run may write: those the run at hand does not write are
/// removed once it is in place, so that a directory never mixes two runs.
pub const RUN_FILES: [&str; 7] = [
    "events.csv",
    "intervals.csv",
    "scans.csv",
    "intervals.parquet",
    "truth.json",
    "damage.json",
    "plant.toml",
];

/// The prefix of the hidden directory a run is staged in, before its process id.
const STAGING: &str = ".gardefou-staging-";

type Out = BufWriter<File>;

/// Records each scan into the log forms, writing only changes to the long forms.
pub struct LogRecorder {
    events: EventWriter<Out>,
    intervals: IntervalWriter<Out>,
    scans: Option<ScanWriter<Out>>,
    last: Vec<bool>,
    /// Time of the last scan recorded: where the recording ends.
    last_t: Option<Time>,
}

impl LogRecorder {
    /// Opens the log files of `plant` in `dir`.
    pub fn create(dir: &Path, plant: &Plant, with_scans: bool) -> io::Result<LogRecorder> {
        let format = TimeFormat::Numeric(plant.time_unit);
        let open = |name: &str| -> io::Result<Out> {
            Ok(BufWriter::with_capacity(
                1 << 16,
                File::create(dir.join(name))?,
            ))
        };
        Ok(LogRecorder {
            events: EventWriter::new(open("events.csv")?, &plant.signals, format)?,
            intervals: IntervalWriter::new(open("intervals.csv")?, &plant.signals, format)?,
            scans: if with_scans {
                Some(ScanWriter::new(open("scans.csv")?, &plant.signals, format)?)
            } else {
                None
            },
            last: Vec::new(),
            last_t: None,
        })
    }

    /// Ends the events log at the last scan (its end row), then flushes and
    /// closes every file.
    pub fn finish(mut self) -> io::Result<()> {
        if let Some(t) = self.last_t {
            self.events.write_end(t)?;
        }
        self.events
            .finish()?
            .into_inner()
            .map_err(|e| e.into_error())?
            .sync_all()?;
        self.intervals
            .finish()?
            .into_inner()
            .map_err(|e| e.into_error())?
            .sync_all()?;
        if let Some(scans) = self.scans {
            scans
                .finish()?
                .into_inner()
                .map_err(|e| e.into_error())?
                .sync_all()?;
        }
        Ok(())
    }
}

impl ScanSink for LogRecorder {
    fn scan(&mut self, t: Time, values: &[bool]) -> io::Result<()> {
        self.last_t = Some(t);
        if let Some(scans) = &mut self.scans {
            scans.write(t, values)?;
        }
        if self.last.is_empty() {
            self.events.write_initial(t, values)?;
            self.intervals.write_initial(t, values)?;
        } else {
            for (i, (old, &new)) in self.last.iter_mut().zip(values).enumerate() {
                if *old != new {
                    *old = new;
                    let e = Event {
                        t,
                        signal: SignalId(i as u32),
                        value: new,
                    };
                    self.events.write(&e)?;
                    self.intervals.write(&e)?;
                }
            }
            return Ok(());
        }
        self.last = values.to_vec();
        Ok(())
    }
}

/// Runs a simulation and writes all its files into `files.dir`; `truth.json`
/// says when each fault first showed (see [`run_with_showing`]).
pub fn write_run<P: Physics + Clone, C: Controller + Clone>(
    files: &RunFiles,
    physics: &mut P,
    controller: &mut C,
    config: &SimConfig,
    progress: impl FnMut(Time),
) -> io::Result<SimReport> {
    fs::create_dir_all(&files.dir)?;
    remove_abandoned_staging(&files.dir);
    let staging = staging_dir(&files.dir);
    let result = (|| {
        fs::create_dir_all(&staging)?;
        let plant = physics.plant().clone();
        let mut recorder = LogRecorder::create(&staging, &plant, files.scans)?;
        let (report, showed) =
            run_with_showing(physics, controller, config, &mut recorder, progress)?;
        recorder.finish()?;

        let unit = plant.time_unit;
        write_json(
            &staging.join("truth.json"),
            &truth_json(&config.faults, &showed, unit),
        )?;
        let damage: Vec<serde_json::Value> = report
            .damage
            .iter()
            .map(|d| serde_json::json!({ "t": time_value(d.t, unit), "cause": d.cause, "detail": d.detail }))
            .collect();
        let counters: serde_json::Map<String, serde_json::Value> = report
            .counters
            .iter()
            .map(|(k, v)| (k.clone(), (*v).into()))
            .collect();
        let summary = serde_json::json!({
            "plant": plant.name,
            "seed": config.seed,
            "duration": time_value(config.duration, unit),
            "scan_period": time_value(config.scan_period, unit),
            "time_unit": unit.name(),
            "scans": report.scans,
            "damage": damage,
            "counters": counters,
        });
        write_json(&staging.join("damage.json"), &summary)?;
        let plant_toml = with_scan_period(physics.plant_toml(), config.scan_period);
        fs::write(staging.join("plant.toml"), plant_toml)?;

        let mut names = vec![
            "events.csv",
            "intervals.csv",
            "truth.json",
            "damage.json",
            "plant.toml",
        ];
        if files.scans {
            names.push("scans.csv");
        }
        if let Some(archive) = files.archive {
            archive(&staging, &plant, config.duration)?;
            names.push("intervals.parquet");
        }
        for name in &names {
            fs::rename(staging.join(name), files.dir.join(name))?;
        }
        for stale in RUN_FILES.iter().filter(|f| !names.contains(f)) {
            match fs::remove_file(files.dir.join(stale)) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
                _ => {}
            }
        }
        Ok(report)
    })();
    // Best effort: the staging directory is empty on success.
    let _ = fs::remove_dir_all(&staging);
    result
}

/// The directory this process stages a run in, inside `dir`.
pub fn staging_dir(dir: &Path) -> PathBuf {
    dir.join(format!("{STAGING}{}", std::process::id()))
}

/// Removes the staging directories in `dir` of runs whose process is gone
/// (killed before it could clean up). Best effort: what cannot be removed
/// stays, and only on Linux is a process known to be gone.
fn remove_abandoned_staging(dir: &Path) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(|n| n.strip_prefix(STAGING)) else {
            continue;
        };
        let gone = pid.parse::<u32>().is_ok_and(|pid| {
            pid != std::process::id()
                && Path::new("/proc/self").exists()
                && !Path::new("/proc").join(pid.to_string()).exists()
        });
        if gone {
            let _ = fs::remove_dir_all(entry.path());
        }
    }
}

fn write_json(path: &Path, value: &serde_json::Value) -> io::Result<()> {
    let mut f = BufWriter::new(File::create(path)?);
    serde_json::to_writer_pretty(&mut f, value).map_err(io::Error::other)?;
    f.write_all(b"\n")?;
    f.into_inner().map_err(|e| e.into_error())?.sync_all()
}

/// A plant file's text with the run's scan period.
fn with_scan_period(source: &str, scan_period: Time) -> String {
    let ms = vocabulary::TimeUnit::Ms.format(scan_period);
    source
        .lines()
        .map(|l| {
            if l.starts_with("scan_period_ms") {
                format!("scan_period_ms = {ms}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}
