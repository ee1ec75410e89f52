//! The coordinator: the parts' local verdicts combined into one plant view.
//!
//! Each part's diagnoser is sound for its own observations: if one of the faults
//! it models is present, that label is among its labels. The coordinator uses
//! this, with seed 002's assumption of a single permanent fault per component,
//! and three rules:
//!
//! 1. **Exclusion.** A label modelled by several parts (a fault of a sensor two
//!    parts read) stays a candidate only if every part that models it and has
//!    left normal still lists it: a part that left normal without it has shown
//!    the fault absent.
//! 2. **Parsimony.** If some candidates appear in the labels of every part that
//!    left normal, one fault explains every deviation: the plant view keeps only
//!    those. This is how one part resolves another's ambiguity: the turntable's
//!    `{F2, F5}` with a neighbour's certain `{F2}` gives `F2`. Otherwise several
//!    faults are present and the view is the union of the parts' labels.
//! 3. **Consequences.** A part whose deviation no fault of its model explains
//!    (`unknown`), while another part has a modelled fault, is reported as a
//!    probable consequence of that fault (a faulty reading makes the control do
//!    what it never did in normal operation), not as a fault of its own. Only
//!    when no part has a modelled fault is the plant view `unknown`.
//!
//! Flags of the plant view follow SPEC §3 on its candidates: `def_<partition>`
//! when they all lie in one partition (and, like every flag, never lowered).

use super::verdict::{UNKNOWN_LABEL, Verdict, VerdictKind};
use crate::{Flag, FlagKind, Plant, Time};

/// The part name of plant-view verdict lines.
pub const PLANT_VIEW: &str = "plant";

/// Combines the parts' latest verdicts.
#[derive(Debug, Clone)]
pub struct Coordinator {
    /// Per part: the fault labels its diagnoser models.
    models: Vec<(String, Vec<String>)>,
    /// Per fault label, its partition.
    partitions: Vec<(String, String)>,
    /// Partition order of the plant file.
    partition_order: Vec<String>,
    latest: Vec<Option<Verdict>>,
    flags: Vec<String>,
    shown: Option<(Vec<String>, Vec<String>)>,
}

impl Coordinator {
    /// A coordinator for `parts` (name, labels modelled), in plant order.
    pub fn new(plant: &Plant, parts: Vec<(String, Vec<String>)>) -> Self {
        let partitions = plant
            .partitions
            .iter()
            .flat_map(|p| p.faults.iter().map(move |f| (f.clone(), p.name.clone())))
            .collect();
        Coordinator {
            latest: vec![None; parts.len()],
            models: parts,
            partitions,
            partition_order: plant.partitions.iter().map(|p| p.name.clone()).collect(),
            flags: Vec::new(),
            shown: None,
        }
    }

    /// The latest verdicts, the flags raised and the view last shown: what
    /// [`Coordinator::set_state`] takes back.
    #[allow(clippy::type_complexity)]
    pub(crate) fn state(
        &self,
    ) -> (
        &[Option<Verdict>],
        &[String],
        &Option<(Vec<String>, Vec<String>)>,
    ) {
        (&self.latest, &self.flags, &self.shown)
    }

    /// Puts back a [`Coordinator::state`].
    pub(crate) fn set_state(
        &mut self,
        latest: Vec<Option<Verdict>>,
        flags: Vec<String>,
        shown: Option<(Vec<String>, Vec<String>)>,
    ) {
        self.latest = latest;
        self.flags = flags;
        self.shown = shown;
    }

    /// Forgets every verdict (a new log).
    pub fn reset(&mut self) {
        self.latest.iter_mut().for_each(|v| *v = None);
        self.flags.clear();
        self.shown = None;
    }

    /// Takes part `index`'s new verdict; returns the plant view if it changed.
    pub fn update(&mut self, index: usize, verdict: &Verdict) -> Option<Verdict> {
        if let Some(slot) = self.latest.get_mut(index) {
            *slot = Some(verdict.clone());
        }
        let view = self.view(verdict.t);
        let key = (view.labels.clone(), view.flags.clone());
        if self.shown.as_ref() == Some(&key) {
            return None;
        }
        self.shown = Some(key);
        Some(view)
    }

    fn partition(&self, label: &str) -> Option<&str> {
        self.partitions
            .iter()
            .find(|(f, _)| f == label)
            .map(|(_, p)| p.as_str())
    }

    /// The plant view now.
    pub fn view(&mut self, t: Time) -> Verdict {
        let deviating: Vec<(usize, &Verdict)> = self
            .latest
            .iter()
            .enumerate()
            .filter_map(|(i, v)| v.as_ref().map(|v| (i, v)))
            .filter(|(_, v)| v.verdict != VerdictKind::Normal)
            .collect();
        let known: Vec<(usize, &Verdict)> = deviating
            .iter()
            .copied()
            .filter(|(_, v)| !is_unknown(v))
            .collect();
        let unknown: Vec<&str> = deviating
            .iter()
            .filter(|(_, v)| is_unknown(v))
            .map(|(_, v)| v.part.as_str())
            .collect();

        // Rule 1: exclusion by the parts that model a label.
        let mut union: Vec<String> = Vec::new();
        for (_, v) in &known {
            for l in &v.labels {
                if !union.contains(l) {
                    union.push(l.clone());
                }
            }
        }
        union.retain(|l| {
            known
                .iter()
                .all(|(i, v)| !self.models[*i].1.contains(l) || v.labels.contains(l))
        });
        // Rule 2: a single fault explaining every deviation.
        let common: Vec<String> = union
            .iter()
            .filter(|l| known.iter().all(|(_, v)| v.labels.contains(l)))
            .cloned()
            .collect();
        let candidates = if common.is_empty() { union } else { common };

        let (labels, mut reason) = if deviating.is_empty() {
            (vec!["N".to_string()], "every part is normal".to_string())
        } else if known.is_empty() {
            (
                vec![UNKNOWN_LABEL.to_string()],
                format!(
                    "{} deviate(s) in a way no modelled fault explains",
                    unknown.join(", ")
                ),
            )
        } else {
            let parts: Vec<&str> = known.iter().map(|(_, v)| v.part.as_str()).collect();
            (candidates, format!("from {}", parts.join(", ")))
        };
        if !known.is_empty() && !unknown.is_empty() {
            reason.push_str(&format!(
                "; {} deviate(s) too, probably as a consequence",
                unknown.join(", ")
            ));
        }
        let faulty = labels
            .first()
            .is_some_and(|l| l != "N" && l != UNKNOWN_LABEL);
        let mut suspects: Vec<String> = Vec::new();
        if faulty {
            for l in &labels {
                if let Some(p) = self.partition(l)
                    && !suspects.iter().any(|s| s == p)
                {
                    suspects.push(p.to_string());
                }
            }
            let all_in = |p: &str| labels.iter().all(|l| self.partition(l) == Some(p));
            if let Some(p) = suspects.first().cloned()
                && all_in(&p)
            {
                let flag = Flag::def(p.as_str()).to_string();
                if !self.flags.contains(&flag) {
                    self.flags.push(flag);
                }
            }
        }
        let order = |name: &str| {
            self.partition_order
                .iter()
                .position(|p| Flag::names(FlagKind::Def, p, name) || name == p)
                .unwrap_or(usize::MAX)
        };
        suspects.sort_by_key(|s| order(s));
        let mut flags = self.flags.clone();
        flags.sort_by_key(|f| order(f));
        let verdict = if labels == ["N"] {
            VerdictKind::Normal
        } else if labels.len() == 1 {
            VerdictKind::Certain
        } else {
            VerdictKind::Ambiguous
        };
        Verdict {
            t,
            part: PLANT_VIEW.to_string(),
            verdict,
            labels,
            flags,
            suspects,
            reason,
        }
    }
}

fn is_unknown(v: &Verdict) -> bool {
    v.labels.len() == 1 && v.labels[0] == UNKNOWN_LABEL
}
