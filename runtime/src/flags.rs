//! The flags a PLC's filter reads, as the diagnosers' verdicts set them:
//! `def_<partition>` once a part is certain of a fault there (never lowered),
//! `suspect_<partition>` while some part's labels touch it.
//!
//! A `def_` flag switches a sensor to its estimate for good, so a board may
//! ask for a confirmation time: the flag goes up only once the verdict that
//! raised it has held that long in event time ([`FlagBoard::confirm`]).

use diagnoser::diagnosis::Verdict;
use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::{Flag, Plant, Time};

/// The flags raised by the verdicts seen so far.
#[derive(Debug, Clone, Default)]
pub struct FlagBoard {
    /// Per part: its latest `def_` flags and suspected partitions.
    parts: Vec<(String, Vec<String>, Vec<String>)>,
    /// `def_` flags raised so far, in the order they were raised.
    raised: Vec<String>,
    /// `suspect_` flags up now.
    suspects: Vec<String>,
    /// How long a `def_` flag's verdict must hold before the flag goes up.
    confirmation: Time,
    /// `def_` flags waiting for their confirmation.
    waiting: Vec<Candidate>,
}

/// A `def_` flag a verdict raised, not yet confirmed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Candidate {
    /// The flag.
    pub flag: String,
    /// The part whose verdict raised it.
    pub part: String,
    /// When that verdict came.
    pub since: Time,
    /// The verdict's labels and reason, for the log of the write.
    pub evidence: String,
}

impl FlagBoard {
    /// A board whose `def_` flags go up only once their verdict has held for
    /// `confirmation` (see [`FlagBoard::confirm`]); a zero confirmation raises
    /// them with the verdict, like [`FlagBoard::default`].
    pub fn with_confirmation(confirmation: Time) -> FlagBoard {
        FlagBoard {
            confirmation: confirmation.max(0),
            ..FlagBoard::default()
        }
    }

    /// Takes in one verdict. The plant view repeats the parts' verdicts and is
    /// skipped. Returns whether a flag went up or down.
    pub fn update(&mut self, v: &Verdict) -> bool {
        if v.part == PLANT_VIEW {
            return false;
        }
        match self.parts.iter_mut().find(|p| p.0 == v.part) {
            Some(p) => {
                p.1.clone_from(&v.flags);
                p.2.clone_from(&v.suspects);
            }
            None => self
                .parts
                .push((v.part.clone(), v.flags.clone(), v.suspects.clone())),
        }
        // A verdict that no longer holds a waiting flag withdraws it.
        self.waiting
            .retain(|c| c.part != v.part || v.flags.contains(&c.flag));
        let mut changed = false;
        for f in &v.flags {
            if self.raised.contains(f) || self.waiting.iter().any(|c| &c.flag == f) {
                continue;
            }
            if self.confirmation > 0 {
                self.waiting.push(Candidate {
                    flag: f.clone(),
                    part: v.part.clone(),
                    since: v.t,
                    evidence: format!("{} {}: {}", v.part, v.labels.join(" "), v.reason),
                });
            } else {
                self.raised.push(f.clone());
                changed = true;
            }
        }
        let now: Vec<String> = self
            .parts
            .iter()
            .flat_map(|(_, _, s)| s.iter().map(|p| Flag::suspect(p.as_str()).to_string()))
            .fold(Vec::new(), |mut acc, s| {
                if !acc.contains(&s) {
                    acc.push(s);
                }
                acc
            });
        // The same suspects in another order change no flag.
        changed |=
            now.len() != self.suspects.len() || now.iter().any(|s| !self.suspects.contains(s));
        self.suspects = now;
        changed
    }

    /// Raises the waiting `def_` flags whose verdict has held for the
    /// confirmation time by `upto` (the event time up to which the source has
    /// shown everything), and returns them.
    pub fn confirm(&mut self, upto: Time) -> Vec<Candidate> {
        // Called on every scan and watermark: nothing to do is the rule.
        if self.waiting.is_empty() {
            return Vec::new();
        }
        let due = |c: &Candidate| c.since.saturating_add(self.confirmation) <= upto;
        let (now, later): (Vec<Candidate>, Vec<Candidate>) =
            self.waiting.drain(..).partition(|c| due(c));
        self.waiting = later;
        for c in &now {
            if !self.raised.contains(&c.flag) {
                self.raised.push(c.flag.clone());
            }
        }
        now
    }

    /// Counts `flag` (a `def_` flag found up on the PLC) as raised.
    pub fn adopt(&mut self, flag: &str) {
        if !self.raised.iter().any(|f| f == flag) {
            self.raised.push(flag.to_string());
        }
    }

    /// `def_` flags raised so far (never lowered), in the order raised.
    pub fn raised(&self) -> &[String] {
        &self.raised
    }

    /// `suspect_` flags up now.
    pub fn suspects(&self) -> &[String] {
        &self.suspects
    }

    /// Whether `flag` is up.
    pub fn is_up(&self, flag: &str) -> bool {
        self.raised.iter().any(|f| f == flag) || self.suspects.iter().any(|f| f == flag)
    }

    /// Every flag of `plant` ([`Plant::flags`] order) as up or down.
    pub fn image(&self, plant: &Plant) -> Vec<bool> {
        plant
            .flags()
            .iter()
            .map(|f| self.is_up(&f.to_string()))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use diagnoser::diagnosis::VerdictKind;

    use super::*;

    fn verdict(part: &str, flags: &[&str], suspects: &[&str]) -> Verdict {
        Verdict {
            t: 0,
            part: part.into(),
            verdict: VerdictKind::Ambiguous,
            labels: Vec::new(),
            flags: flags.iter().map(|f| f.to_string()).collect(),
            suspects: suspects.iter().map(|s| s.to_string()).collect(),
            reason: String::new(),
        }
    }

    #[test]
    fn def_flags_stay_raised_and_suspects_follow_the_parts() {
        let plant = datasets::sorting::plant();
        let mut board = FlagBoard::default();
        assert!(board.update(&verdict("turntable", &[], &["C4", "P"])));
        assert_eq!(board.suspects(), ["suspect_C4", "suspect_P"]);
        // The plant view repeats the parts: it changes nothing.
        assert!(!board.update(&verdict(PLANT_VIEW, &["def_C5"], &["C5"])));
        assert!(board.update(&verdict("turntable", &["def_C4"], &["C4"])));
        assert_eq!(board.raised(), ["def_C4"]);
        assert_eq!(board.suspects(), ["suspect_C4"]);
        // A later verdict without the flag does not lower it.
        assert!(board.update(&verdict("turntable", &[], &[])));
        assert_eq!(board.raised(), ["def_C4"]);
        assert!(board.suspects().is_empty());
        assert!(!board.update(&verdict("turntable", &[], &[])));
        board.adopt("def_P");
        let image = board.image(&plant);
        let up: Vec<String> = plant
            .flags()
            .into_iter()
            .zip(image)
            .filter(|(_, up)| *up)
            .map(|(f, _)| f.to_string())
            .collect();
        assert_eq!(up, ["def_C4", "def_P"]);
    }

    fn at(t: Time, part: &str, flags: &[&str]) -> Verdict {
        Verdict {
            t,
            ..verdict(part, flags, &[])
        }
    }

    #[test]
    fn a_def_flag_waits_until_its_verdict_has_held_for_the_confirmation() {
        let mut board = FlagBoard::with_confirmation(10);
        assert!(!board.update(&at(100, "turntable", &["def_C4"])));
        assert!(board.raised().is_empty());
        assert!(board.confirm(109).is_empty());
        // Withdrawn before it held: never raised.
        board.update(&at(105, "turntable", &[]));
        assert!(board.confirm(1000).is_empty());
        // Another part's verdict does not withdraw it.
        board.update(&at(200, "turntable", &["def_C4"]));
        board.update(&at(205, "rollers", &[]));
        let up = board.confirm(210);
        assert_eq!(up.len(), 1);
        assert_eq!((up[0].flag.as_str(), up[0].since), ("def_C4", 200));
        assert_eq!(board.raised(), ["def_C4"]);
        // Raised for good: a later verdict without it does not lower it.
        board.update(&at(300, "turntable", &[]));
        assert_eq!(board.raised(), ["def_C4"]);
        // Without a confirmation time, the flag goes up with its verdict.
        let mut now = FlagBoard::default();
        assert!(now.update(&at(1, "turntable", &["def_C4"])));
        assert_eq!(now.raised(), ["def_C4"]);
    }
}
