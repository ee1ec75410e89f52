//! Progress of a replay or of learning over logs, drawn on a terminal
//! (standard error) and hidden in a pipe.
//!
//! One log gets a spinner with the events read and their rate. Several get a
//! bar over the logs, with the events read so far, their rate and the time
//! left, so that an archive of a thousand logs says how far it is.

use std::io::IsTerminal;
use std::time::Instant;

use indicatif::{HumanCount, ProgressBar, ProgressStyle};

/// The progress of `verb` (`diagnosing`, `learning`) over some logs.
pub struct LogsProgress {
    bar: ProgressBar,
    several: bool,
    /// Events of the logs finished.
    done: u64,
    /// Events read of the log under way.
    current: u64,
    since: Instant,
}

impl LogsProgress {
    /// Progress over `logs` logs; hidden unless standard error is a terminal.
    pub fn new(verb: &str, logs: usize) -> Self {
        let several = logs > 1;
        let bar = if !std::io::stderr().is_terminal() {
            ProgressBar::hidden()
        } else if several {
            let bar = ProgressBar::new(logs as u64);
            let template = format!(
                "{{spinner}} {verb} {{pos}}/{{len}} logs [{{wide_bar}}] {{msg}}, {{eta}} left"
            );
            bar.set_style(
                ProgressStyle::with_template(&template)
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            bar
        } else {
            let bar = ProgressBar::new_spinner();
            let template = format!("{{spinner}} {verb}: {{human_pos}} events ({{per_sec}})");
            bar.set_style(
                ProgressStyle::with_template(&template)
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            bar
        };
        LogsProgress {
            bar,
            several,
            done: 0,
            current: 0,
            since: Instant::now(),
        }
    }

    /// `events` events read so far of the log under way.
    pub fn read(&mut self, events: u64) {
        self.current = events;
        let total = self.done + events;
        if !self.several {
            self.bar.set_position(total);
        } else if !self.bar.is_hidden() {
            let rate = total as f64 / self.since.elapsed().as_secs_f64().max(1e-3);
            self.bar.set_message(format!(
                "{} events, {:.1} M/s",
                HumanCount(total),
                rate / 1e6
            ));
        }
    }

    /// The log under way is finished.
    pub fn log_done(&mut self) {
        self.done += self.current;
        self.current = 0;
        if self.several {
            self.bar.inc(1);
        }
    }

    /// Clears the bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Drop for LogsProgress {
    /// A run that stops on an error leaves no bar above its message.
    fn drop(&mut self) {
        self.finish();
    }
}
