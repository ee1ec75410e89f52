//! The flags a PLC's filter reads, as the diagnosers' verdicts set them:
//! `def_<partition>` once a part is certain of a fault there (never lowered),
//! `suspect_<partition>` while some part's labels touch it.

use diagnoser::Plant;
use diagnoser::diagnosis::Verdict;
use diagnoser::diagnosis::fusion::PLANT_VIEW;

/// The flags raised by the verdicts seen so far.
#[derive(Debug, Clone, Default)]
pub struct FlagBoard {
    /// Per part: its latest `def_` flags and suspected partitions.
    parts: Vec<(String, Vec<String>, Vec<String>)>,
    /// `def_` flags raised so far, in the order they were raised.
    raised: Vec<String>,
    /// `suspect_` flags up now.
    suspects: Vec<String>,
}

impl FlagBoard {
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
        let mut changed = false;
        for f in &v.flags {
            if !self.raised.contains(f) {
                self.raised.push(f.clone());
                changed = true;
            }
        }
        let now: Vec<String> = self
            .parts
            .iter()
            .flat_map(|(_, _, s)| s.iter().map(|p| format!("suspect_{p}")))
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
        plant.flags().iter().map(|f| self.is_up(f)).collect()
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
            .map(|(f, _)| f)
            .collect();
        assert_eq!(up, ["def_C4", "def_P"]);
    }
}
