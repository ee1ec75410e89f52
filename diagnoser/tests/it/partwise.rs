//! The replay by part gives the plant diagnoser's verdict lines, in its order,
//! whatever the threads, the batches (a scan may straddle two) and the events:
//! shipped runs of the sorting line damaged at random (events dropped, values
//! flipped, times moved, events added), so that parts leave normal, go
//! unknown, start again and fire their deadlines in every order.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use diagnoser::diagnosis::{DiagnoserOptions, PartwiseReplay, PlantDiagnoser, Verdict};
use diagnoser::model::Model;
use diagnoser::{Event, MS, Plant, SignalId, Time, TimeFormat, TimeUnit};
use logs::{EventLog, read_events};
use proptest::prelude::*;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

/// The sorting line, its model, and three of its shipped runs.
fn setup() -> &'static (Plant, Model, Vec<EventLog>) {
    static SETUP: OnceLock<(Plant, Model, Vec<EventLog>)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let plant = Plant::from_path(&repo("datasets/plants/sorting.toml")).expect("plant");
        let model = Model::from_path(&repo(
            "diagnoser/tests/fixtures/diagnosis/sorting-model.json",
        ))
        .expect("model");
        let logs = ["normal", "F2", "F7"]
            .iter()
            .map(|run| {
                let path = repo(&format!("datasets/data/sorting/{run}/events.csv"));
                read_events(&path, &plant.signals, TimeUnit::Ms).expect("shipped log")
            })
            .collect();
        (plant, model, logs)
    })
}

/// One change to a log.
#[derive(Debug, Clone)]
enum Damage {
    Drop(usize),
    Flip(usize),
    Move(usize, Time),
    Add(Time, u32, bool),
    /// Edges of several signals (a mask) in the scan of an event.
    Join(usize, u64),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (0usize..100_000).prop_map(Damage::Drop),
        (0usize..100_000).prop_map(Damage::Flip),
        (0usize..100_000, -3000i64..3000).prop_map(|(i, d)| Damage::Move(i, d * MS / 10)),
        (0i64..3_600_000, 0u32..64, any::<bool>()).prop_map(|(t, s, v)| Damage::Add(t * MS, s, v)),
        (0usize..100_000, any::<u64>()).prop_map(|(i, mask)| Damage::Join(i, mask)),
    ]
}

/// The first `minutes` of `log`, damaged, sorted by time then signal as a
/// log reader gives them.
fn damaged(log: &EventLog, minutes: Time, damages: &[Damage], signals: u32) -> Vec<Event> {
    let end = log.start + minutes * 60_000 * MS;
    let mut events: Vec<Event> = log.events.iter().copied().filter(|e| e.t <= end).collect();
    for d in damages {
        let n = events.len().max(1);
        match *d {
            Damage::Drop(i) if !events.is_empty() => {
                events.remove(i % n);
            }
            Damage::Flip(i) if !events.is_empty() => events[i % n].value ^= true,
            Damage::Move(i, dt) if !events.is_empty() => {
                let e = &mut events[i % n];
                e.t = (e.t + dt).clamp(log.start + MS, end);
            }
            Damage::Add(t, s, value) => events.push(Event {
                t: log.start + MS + t % (end - log.start).max(MS),
                signal: SignalId(s % signals),
                value,
            }),
            Damage::Join(i, mask) if !events.is_empty() => {
                let t = events[i % n].t;
                for s in (0..signals.min(64)).filter(|s| mask >> s & 1 == 1) {
                    events.push(Event {
                        t,
                        signal: SignalId(s),
                        value: (mask >> ((s + 7) % 64)) & 1 == 1,
                    });
                }
            }
            _ => {}
        }
    }
    events.sort_by_key(|e| (e.t, e.signal.index()));
    events.dedup_by_key(|e| (e.t, e.signal.index()));
    events
}

/// Adds edges at the time of deadlines that gave verdicts: for each pick,
/// the `k`-th such deadline (as the plant diagnoser gives them), edges of the
/// signals in `mask`. The replay by part must then order the deadline's
/// verdict and the scan's as the plant diagnoser does.
fn at_deadlines(log: &EventLog, events: &mut Vec<Event>, picks: &[(usize, u64)], signals: u32) {
    let (plant, model, _) = setup();
    let mut d = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default()).expect("diagnoser");
    let mut deadlines = Vec::new();
    d.start(log.start, &log.initial);
    let mut record = |v: Verdict| deadlines.push(v.t + 1);
    for &e in events.iter() {
        d.push(e, &mut record);
    }
    // A deadline's verdict comes 1 ns before it; a scan's at its own time,
    // which no deadline shares.
    let scans: std::collections::HashSet<Time> = events.iter().map(|e| e.t).collect();
    deadlines.retain(|t| !scans.contains(&(t - 1)));
    if deadlines.is_empty() {
        return;
    }
    for &(k, mask) in picks {
        let t = deadlines[k % deadlines.len()];
        for s in (0..signals.min(64)).filter(|s| mask >> s & 1 == 1) {
            // The value does not matter much: half of them are edges.
            events.push(Event {
                t,
                signal: SignalId(s),
                value: mask >> (63 - s) & 1 == 1,
            });
        }
    }
    events.sort_by_key(|e| (e.t, e.signal.index()));
    events.dedup_by_key(|e| (e.t, e.signal.index()));
}

fn line(v: &Verdict) -> String {
    v.json_line(TimeFormat::Numeric(TimeUnit::Ms), None)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn replay_by_part_gives_the_plant_diagnosers_lines(
        run in 0usize..3,
        minutes in 1i64..40,
        damages in proptest::collection::vec(damage(), 0..40),
        threads in 1usize..4,
        cuts in proptest::collection::vec(0usize..100_000, 0..12),
        picks in proptest::collection::vec((0usize..1000, any::<u64>()), 0..6),
        polled in any::<bool>(),
        held_reactions in any::<bool>(),
    ) {
        let (plant, model, logs) = setup();
        let log = &logs[run];
        let mut events = damaged(log, minutes, &damages, plant.signals.len() as u32);
        at_deadlines(log, &mut events, &picks, plant.signals.len() as u32);
        let options = DiagnoserOptions { polled, held_reactions, ..DiagnoserOptions::default() };
        let end = events.last().map_or(log.start, |e| e.t) + 5_000 * MS;

        let mut reference = PlantDiagnoser::new(plant, model, &options).expect("diagnoser");
        let mut want = Vec::new();
        reference.start(log.start, &log.initial);
        for &e in &events {
            reference.push(e, &mut |v| want.push(line(&v)));
        }
        let want_summary = reference.finish(end, &mut |v| want.push(line(&v)));

        let diagnoser = PlantDiagnoser::new(plant, model, &options).expect("diagnoser");
        let mut partwise = PartwiseReplay::new(diagnoser, threads);
        let mut got = Vec::new();
        partwise.start(log.start, &log.initial);
        // Batches cut anywhere, within a scan too.
        let mut cuts: Vec<usize> = cuts.iter().map(|c| c % (events.len() + 1)).collect();
        cuts.push(events.len());
        cuts.sort_unstable();
        let mut from = 0;
        for to in cuts {
            partwise.push_batch(&events[from..to], &mut |v| got.push(line(&v)));
            from = to;
        }
        let got_summary = partwise.finish(end, &mut |v| got.push(line(&v)));
        prop_assert_eq!(&got, &want);
        prop_assert_eq!(got_summary, want_summary);
    }
}

/// The damage above does reach the verdicts: without it the property would
/// hold on logs that never leave normal.
#[test]
fn damaged_runs_give_many_verdict_lines() {
    let (plant, model, logs) = setup();
    let damages: Vec<Damage> = (0..30)
        .map(|i| Damage::Flip(i * 997))
        .chain((0..30).map(|i| Damage::Add(i * 61_000 * MS, i as u32 * 7, i % 2 == 0)))
        .collect();
    let events = damaged(&logs[0], 30, &damages, plant.signals.len() as u32);
    let mut d = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default()).expect("diagnoser");
    let mut lines = 0;
    d.start(logs[0].start, &logs[0].initial);
    for &e in &events {
        d.push(e, &mut |_| lines += 1);
    }
    assert!(lines >= 20, "{lines} verdict lines");
}
