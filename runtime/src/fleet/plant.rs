//! One plant as a fleet worker diagnoses it: its stream's records fed to its
//! diagnosers in event time, and the checkpoint that another worker takes
//! over from.
//!
//! The records are what the publishing monitor's source showed, and they
//! are fed by the monitor's rules: deadlines fire only up to a watermark
//! (a scan's time is one); nothing fires while the plant is lost; a start
//! starts the diagnosers again from the values read, every clock unknown.
//! So a worker prints the monitor's verdict lines.
//!
//! A [`Checkpoint`] is the plant between two records: the stream sequence
//! consumed, the verdict lines given, the model version, the event-time
//! state, the signals' values, and the diagnosers
//! ([`diagnoser::diagnosis::Snapshot`]). Restored with the same model, the
//! lines that follow are those of an uninterrupted run. With another model
//! version (a new one published), the diagnosers start again from the
//! values at the checkpoint, as after a reconnection: the safe point where a
//! new model takes over.

use diagnoser::diagnosis::{PlantDiagnoser, Snapshot, Verdict};
use diagnoser::{Event, Time};
use serde::{Deserialize, Serialize};

use crate::jetstream::record::Record;

/// A plant's diagnosers fed with its stream's records.
#[derive(Debug, Clone)]
pub struct PlantRun {
    diagnoser: PlantDiagnoser,
    at: EventTime,
    /// Every signal's value now (empty before the first start).
    values: Vec<bool>,
    /// The stream sequence of the last record taken in (0: none).
    pub seq: u64,
    /// Verdict lines given so far.
    pub lines: u64,
    /// The plant's signals.
    signals: usize,
}

/// Where the plant stands in event time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EventTime {
    /// A start has been read.
    pub started: bool,
    /// The publishing monitor lost the plant: nothing fires until a start.
    pub blind: bool,
    /// The source's view was complete up to this time.
    pub watermark: Option<Time>,
    /// The publishing monitor stopped.
    pub ended: bool,
}

/// A plant between two records, as the key-value bucket keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The stream sequence of the last record taken in.
    pub seq: u64,
    /// Verdict lines given.
    pub lines: u64,
    /// The model version the diagnosers ran.
    pub model: String,
    /// How times are printed (from the start record), by name.
    pub time: Option<String>,
    /// Event time.
    pub at: EventTime,
    /// Every signal's value, by signal index (`0`/`1` text: compact).
    pub values: String,
    /// The diagnosers, once started.
    pub diagnosers: Option<Snapshot>,
}

impl PlantRun {
    /// `diagnoser`, of a plant of `signals` signals, before the plant's
    /// first record.
    pub fn new(diagnoser: PlantDiagnoser, signals: usize) -> PlantRun {
        PlantRun {
            diagnoser,
            at: EventTime::default(),
            values: Vec::new(),
            seq: 0,
            lines: 0,
            signals,
        }
    }

    /// Where the plant stands in event time.
    pub fn event_time(&self) -> EventTime {
        self.at
    }

    /// Takes in the record at stream sequence `seq`; its verdicts go to
    /// `out`. A scan at or behind the watermark, or while the plant is not
    /// seen, is ignored (the monitor warned of it): `false`.
    pub fn take(&mut self, seq: u64, record: Record, out: &mut impl FnMut(Verdict)) -> bool {
        self.seq = seq;
        let mut counted = |v: Verdict| {
            self.lines += 1;
            out(v)
        };
        match record {
            Record::Start(t, values, _) => {
                self.diagnoser.start(t, &values);
                self.values = values;
                self.at = EventTime {
                    started: true,
                    blind: false,
                    watermark: Some(t),
                    ended: false,
                };
                true
            }
            Record::Scan(events) => Self::scan(
                &mut self.diagnoser,
                &mut self.at,
                &mut self.values,
                &events,
                &mut counted,
            ),
            Record::Watermark(w) => {
                Self::watermark(&mut self.diagnoser, &mut self.at, w, &mut counted)
            }
            Record::End(t) => {
                Self::watermark(&mut self.diagnoser, &mut self.at, t, &mut counted);
                self.at.ended = true;
                true
            }
            Record::Lost(..) => {
                self.at.blind = true;
                true
            }
        }
    }

    fn scan(
        d: &mut PlantDiagnoser,
        at: &mut EventTime,
        values: &mut [bool],
        events: &[Event],
        out: &mut impl FnMut(Verdict),
    ) -> bool {
        let Some(t) = events.first().map(|e| e.t) else {
            return true;
        };
        if !at.started || at.blind || at.watermark.is_some_and(|w| t <= w) {
            return false;
        }
        d.advance_to(t - 1, out);
        for &e in events {
            if let Some(v) = values.get_mut(e.signal.index()) {
                *v = e.value;
            }
            d.push(e, out);
        }
        d.advance_to(t, out);
        at.watermark = Some(t);
        true
    }

    fn watermark(
        d: &mut PlantDiagnoser,
        at: &mut EventTime,
        w: Time,
        out: &mut impl FnMut(Verdict),
    ) -> bool {
        if !at.started || at.blind || at.watermark.is_some_and(|old| w <= old) {
            return false;
        }
        d.advance_to(w, out);
        at.watermark = Some(w);
        true
    }

    /// The plant now, for a checkpoint (between two records, always).
    pub fn checkpoint(&self, model: &str, time: Option<String>) -> Checkpoint {
        Checkpoint {
            seq: self.seq,
            lines: self.lines,
            model: model.to_string(),
            time,
            at: self.at,
            values: self
                .values
                .iter()
                .map(|&v| if v { '1' } else { '0' })
                .collect(),
            diagnosers: self.at.started.then(|| self.diagnoser.snapshot()).flatten(),
        }
    }

    /// Puts the plant where `c` says. With the model version `model` of the
    /// checkpoint, the diagnosers go on from theirs; with another, they start
    /// again at the checkpoint's watermark from its values (a new model's
    /// safe point), and the answer says so. An error when the checkpoint
    /// does not fit the plant.
    pub fn restore(&mut self, c: &Checkpoint, model: &str) -> Result<Resumed, String> {
        let values: Vec<bool> = c.values.chars().map(|v| v == '1').collect();
        if c.at.started && values.len() != self.signals {
            return Err(format!(
                "{} signal values where the plant has {}",
                values.len(),
                self.signals
            ));
        }
        let resumed = match (&c.diagnosers, c.model == model, c.at.watermark) {
            (Some(s), true, _) => {
                self.diagnoser.restore(s)?;
                Resumed::Diagnosers
            }
            (_, _, Some(w)) if c.at.started => {
                self.diagnoser.start(w, &values);
                Resumed::Restarted
            }
            _ => Resumed::NotStarted,
        };
        self.at = c.at;
        self.values = values;
        self.seq = c.seq;
        self.lines = c.lines;
        Ok(resumed)
    }
}

/// How a plant was put back from a checkpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resumed {
    /// The diagnosers went on from their snapshot.
    Diagnosers,
    /// The model version changed: the diagnosers started again from the
    /// values at the checkpoint.
    Restarted,
    /// The plant had not started.
    NotStarted,
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use diagnoser::diagnosis::DiagnoserOptions;
    use diagnoser::model::Model;
    use diagnoser::{Plant, TimeFormat};
    use logs::{IngestOptions, open};
    use proptest::prelude::*;

    use super::*;

    /// The shipped F2 run as the records of its stream: a start, then each
    /// scan followed by a watermark 50 ms later (deadlines between scans).
    fn f2() -> (Plant, PlantDiagnoser, Vec<Record>) {
        let at = |rel: &str| Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel);
        let plant = Plant::from_path(&at("datasets/data/sorting/F2/plant.toml")).expect("plant");
        let model = Model::from_path(&at("diagnoser/tests/fixtures/diagnosis/sorting-model.json"))
            .expect("model");
        let diagnoser =
            PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default()).expect("diagnoser");
        let log = open(
            &at("datasets/data/sorting/F2/events.csv"),
            &plant,
            &IngestOptions::default(),
        )
        .expect("log");
        let mut records = vec![Record::Start(log.start, log.initial.clone(), None)];
        let mut scan: Vec<Event> = Vec::new();
        let flush = |scan: &mut Vec<Event>, records: &mut Vec<Record>| {
            if let Some(t) = scan.first().map(|e| e.t) {
                records.push(Record::Scan(std::mem::take(scan)));
                records.push(Record::Watermark(t + 50_000_000));
            }
        };
        for e in log.batches.flat_map(|b| b.expect("batch")) {
            if scan.first().is_some_and(|s| s.t != e.t) {
                flush(&mut scan, &mut records);
            }
            scan.push(e);
        }
        flush(&mut scan, &mut records);
        records.push(Record::End(1_200_000_000_000));
        (plant, diagnoser, records)
    }

    fn lines(run: &mut PlantRun, records: &[Record], from: usize) -> Vec<String> {
        let mut out = Vec::new();
        for (i, r) in records.iter().enumerate().skip(from) {
            run.take(i as u64 + 1, r.clone(), &mut |v| {
                out.push(v.json_line(TimeFormat::Numeric(diagnoser::TimeUnit::Ms), None))
            });
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

        /// A run checkpointed anywhere, through JSON, and restored into a
        /// fresh one, goes on with the lines of the uninterrupted run.
        #[test]
        fn a_restored_checkpoint_goes_on_with_the_lines_of_one_run(cut in 0.0..1.0f64) {
            let (plant, d, records) = f2();
            let whole = lines(&mut PlantRun::new(d.clone(), plant.signals.len()), &records, 0);
            prop_assert!(whole.iter().any(|l| l.contains("def_C4")));
            let cut = (cut * records.len() as f64) as usize;
            let mut first = PlantRun::new(d.clone(), plant.signals.len());
            let mut got = lines(&mut first, &records[..cut], 0);
            let saved = serde_json::to_string(&first.checkpoint("v1", None)).expect("JSON");
            let c: Checkpoint = serde_json::from_str(&saved).expect("reads back");
            let mut second = PlantRun::new(d, plant.signals.len());
            let resumed = second.restore(&c, "v1").expect("fits");
            prop_assert_eq!(resumed == Resumed::NotStarted, cut == 0);
            prop_assert_eq!(second.seq, cut as u64);
            got.extend(lines(&mut second, &records, cut));
            prop_assert_eq!(got, whole);
        }
    }

    #[test]
    fn another_model_version_starts_the_diagnosers_again_from_the_values_there() {
        let (plant, d, records) = f2();
        let cut = records.len() / 2;
        let mut first = PlantRun::new(d.clone(), plant.signals.len());
        lines(&mut first, &records[..cut], 0);
        let c = first.checkpoint("v1", None);
        let mut second = PlantRun::new(d.clone(), plant.signals.len());
        assert_eq!(second.restore(&c, "v2"), Ok(Resumed::Restarted));
        // As a monitor's reconnection: a start at the watermark with the values.
        let mut fresh = PlantRun::new(d, plant.signals.len());
        let values: Vec<bool> = c.values.chars().map(|v| v == '1').collect();
        let w = c.at.watermark.expect("a watermark");
        fresh.take(1, Record::Start(w, values, None), &mut |_| {});
        assert_eq!(
            lines(&mut second, &records, cut),
            lines(&mut fresh, &records, cut)
        );
    }

    #[test]
    fn a_checkpoint_of_another_plant_is_refused() {
        let (plant, d, records) = f2();
        let mut run = PlantRun::new(d.clone(), plant.signals.len());
        lines(&mut run, &records[..10], 0);
        let mut c = run.checkpoint("v1", None);
        c.values.push('1');
        let err = PlantRun::new(d, plant.signals.len())
            .restore(&c, "v1")
            .expect_err("refused");
        assert!(err.contains("signal values"), "{err}");
    }
}
