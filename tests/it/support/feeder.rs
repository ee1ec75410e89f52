//! Feeds lines to a child's stdin at a chosen pace, and turns an events CSV
//! into the JSON lines `gardefou monitor --stdin` reads.
//!
//! Paced lines are flushed one by one, so the reader gets each at its time
//! and not when a buffer fills; all at once is one big write, for speed.
//! Steady pacing follows a schedule from the start, so sleeps that overrun do
//! not add up over a long feed. Jitter is drawn from a seed, so a failing run
//! can be replayed.

use super::Rng;
use std::io::{self, Write};
use std::thread;
use std::time::{Duration, Instant};

/// When each line is written.
#[derive(Clone, Debug)]
pub enum Pace {
    AllAtOnce,
    /// every line after `gap`
    Steady(Duration),
    /// pauses of `pause` after the given line numbers (0-based)
    Pauses(Vec<(usize, Duration)>),
    /// random gaps in 0..max with bursts, seeded
    Jitter {
        seed: u64,
        max: Duration,
    },
}

/// Writes `lines` (each without trailing newline) to `w` as `line\n` at the given pace; returns io errors (a closed pipe) as Err.
pub fn feed(w: &mut impl Write, lines: &[String], pace: &Pace) -> io::Result<()> {
    if let Pace::AllAtOnce = pace {
        let all: String = lines.iter().flat_map(|l| [l.as_str(), "\n"]).collect();
        w.write_all(all.as_bytes())?;
        return w.flush();
    }
    let start = Instant::now();
    let mut jitter = Jitter::new(pace);
    for (i, line) in lines.iter().enumerate() {
        match pace {
            Pace::Steady(gap) => sleep_until(start + *gap * i as u32),
            Pace::Jitter { .. } => thread::sleep(jitter.gap()),
            _ => {}
        }
        // One write per line, so a reader never sees half a line for long.
        w.write_all(format!("{line}\n").as_bytes())?;
        w.flush()?;
        if let Pace::Pauses(pauses) = pace {
            let pause: Duration = pauses
                .iter()
                .filter(|(n, _)| *n == i)
                .map(|(_, d)| *d)
                .sum();
            thread::sleep(pause);
        }
    }
    Ok(())
}

fn sleep_until(t: Instant) {
    thread::sleep(t.saturating_duration_since(Instant::now()));
}

/// Random gaps with bursts: now and then a run of 2 to 10 lines comes with
/// no gap at all, as when a PLC's scan reports several changes at once.
struct Jitter {
    rng: Rng,
    max: Duration,
    burst: u32,
}

impl Jitter {
    fn new(pace: &Pace) -> Jitter {
        let (seed, max) = match pace {
            Pace::Jitter { seed, max } => (*seed, *max),
            _ => (0, Duration::ZERO),
        };
        Jitter {
            rng: Rng::new(seed),
            max,
            burst: 0,
        }
    }

    fn gap(&mut self) -> Duration {
        if self.burst > 0 {
            self.burst -= 1;
            return Duration::ZERO;
        }
        if self.rng.chance(0.1) {
            self.burst = 1 + (self.rng.next_u64() % 9) as u32;
        }
        self.rng.between(Duration::ZERO, self.max)
    }
}

/// The events of an events CSV (`t,signal,value` header; rows `t,signal,value`; a final `t,,` end row is skipped) as JSON lines `{"t": T, "signal": "S", "value": V}` (T as written in the file, an integer).
pub fn json_lines(events_csv: &str) -> Vec<String> {
    let mut rows = events_csv.lines().filter(|l| !l.trim().is_empty());
    let header = rows.next().map(str::trim);
    assert_eq!(header, Some("t,signal,value"), "not an events CSV");
    rows.filter_map(json_line).collect()
}

/// One row as a JSON line; None for the end row (no signal).
fn json_line(row: &str) -> Option<String> {
    let fields: Vec<&str> = row.trim().split(',').map(str::trim).collect();
    let [t, signal, value] = fields[..] else {
        panic!("not a `t,signal,value` row: {row:?}")
    };
    assert!(t.parse::<u64>().is_ok(), "time is not an integer: {row:?}");
    if signal.is_empty() {
        return None;
    }
    assert!(
        value.parse::<i64>().is_ok(),
        "value is not an integer: {row:?}"
    );
    let signal = serde_json::Value::from(signal);
    Some(format!(
        r#"{{"t": {t}, "signal": {signal}, "value": {value}}}"#
    ))
}
