//! The replay by part on one thread, over a log already in memory: the
//! inner loop's speed, with nothing else in the process.
//!
//! `cargo run --release -p diagnoser --example replay_speed -- PLANT MODEL LOG [ROUNDS]`
//! reads LOG (any form `logs::open` reads) into memory, replays it ROUNDS
//! times (default 10) by part on one thread, and prints each round's events
//! per second and their median. The automaton is built by a first round,
//! not counted.

use std::path::PathBuf;
use std::time::Instant;

use diagnoser::diagnosis::{DiagnoserOptions, PartwiseReplay, PlantDiagnoser};
use diagnoser::model::Model;
use diagnoser::{Event, Plant};
use logs::{IngestOptions, open};

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [plant, model, log, rest @ ..] = args.as_slice() else {
        return Err("usage: replay_speed PLANT MODEL LOG [ROUNDS]".into());
    };
    let rounds: usize = rest
        .first()
        .map_or(Ok(10), |r| r.parse())
        .map_err(|e| format!("{e}"))?;
    let plant = Plant::from_path(&PathBuf::from(plant)).map_err(|e| e.to_string())?;
    let model = Model::from_path(&PathBuf::from(model)).map_err(|e| e.to_string())?;
    let options = IngestOptions {
        time_unit: plant.time_unit,
        ..IngestOptions::default()
    };
    let stream = open(&PathBuf::from(log), &plant, &options).map_err(|e| e.to_string())?;
    let (start, initial) = (stream.start, stream.initial.clone());
    let mut events: Vec<Event> = Vec::new();
    for batch in stream.batches {
        events.extend(batch.map_err(|e| e.to_string())?);
    }
    let diagnoser = PlantDiagnoser::new(&plant, &model, &DiagnoserOptions::default())?;
    let mut replay = PartwiseReplay::new(diagnoser, 1);
    let mut once = || {
        let mut verdicts = 0u64;
        replay.start(start, &initial);
        for batch in events.chunks(65_536) {
            replay.push_batch(batch, &mut |_| verdicts += 1);
        }
        let end = events.last().map_or(start, |e| e.t);
        replay.finish(end, &mut |_| verdicts += 1);
        verdicts
    };
    let verdicts = once();
    let mut rates = Vec::new();
    for _ in 0..rounds {
        let clock = Instant::now();
        std::hint::black_box(once());
        let rate = events.len() as f64 / clock.elapsed().as_secs_f64() / 1e6;
        eprintln!("{rate:.1} M events/s");
        rates.push(rate);
    }
    rates.sort_by(f64::total_cmp);
    let median = rates.get(rates.len() / 2).copied().unwrap_or(0.0);
    println!(
        "{} events, {verdicts} verdicts, median {median:.1} M events/s",
        events.len()
    );
    Ok(())
}
