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
        if now != self.suspects {
            changed |=
                now.len() != self.suspects.len() || now.iter().any(|s| !self.suspects.contains(s));
            self.suspects = now;
        }
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
