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
//!
//! The rules run over label ids and bit sets, built once from the plant and
//! the parts' modes: a plant with many parts and faults gives many verdicts,
//! and each one's view costs a few word operations per part, not string
//! comparisons.

use std::collections::HashMap;

use super::verdict::{UNKNOWN_LABEL, Verdict, VerdictKind};
use crate::{Flag, FlagKind, Plant, Time};

/// The part name of plant-view verdict lines.
pub const PLANT_VIEW: &str = "plant";

/// A set of label ids.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct LabelSet(Vec<u64>);

impl LabelSet {
    fn insert(&mut self, id: u32) {
        let word = id as usize / 64;
        if self.0.len() <= word {
            self.0.resize(word + 1, 0);
        }
        self.0[word] |= 1 << (id % 64);
    }

    #[inline]
    fn contains(&self, id: u32) -> bool {
        self.0
            .get(id as usize / 64)
            .is_some_and(|w| w >> (id % 64) & 1 == 1)
    }
}

/// A part's latest verdict when it is not normal, as the rules read it.
#[derive(Debug, Clone)]
struct Deviation {
    /// No modelled fault explains it.
    unknown: bool,
    /// Normal after a glitch still explains it too (`N` among its labels,
    /// left out of `labels`): it neither rules labels out nor needs
    /// explaining.
    tentative: bool,
    /// Its labels, in the verdict's order.
    labels: Vec<u32>,
    set: LabelSet,
}

/// Combines the parts' latest verdicts.
#[derive(Debug, Clone)]
pub struct Coordinator {
    /// Every label met, by id.
    names: Vec<String>,
    ids: HashMap<String, u32>,
    /// Per fault label, its partition, as the plant lists them.
    partitions: Vec<(String, String)>,
    /// Partition order of the plant file.
    partition_order: Vec<String>,
    /// Per label id, its partition (the first listing it) as the index of
    /// the first partition of that name.
    partition_of: Vec<Option<usize>>,
    /// Per partition index, where its name sorts among suspects.
    suspect_rank: Vec<usize>,
    /// Per part: the labels its diagnoser models.
    models: Vec<LabelSet>,
    latest: Vec<Option<Verdict>>,
    deviations: Vec<Option<Deviation>>,
    /// Flags raised, in the order raised; and sorted as the view gives them.
    flags: Vec<String>,
    sorted_flags: Vec<String>,
    shown: Option<(Vec<String>, Vec<String>)>,
    /// The candidates and the count of flags of the view last judged:
    /// flags are never lowered, so the count tells whether they changed.
    shown_ids: Option<(Option<Vec<u32>>, usize)>,
}

impl Coordinator {
    /// A coordinator for `parts` (name, labels modelled), in plant order.
    pub fn new(plant: &Plant, parts: Vec<(String, Vec<String>)>) -> Self {
        let partitions = plant
            .partitions
            .iter()
            .flat_map(|p| p.faults.iter().map(move |f| (f.clone(), p.name.clone())))
            .collect();
        let partition_order: Vec<String> =
            plant.partitions.iter().map(|p| p.name.clone()).collect();
        let mut c = Coordinator {
            names: Vec::new(),
            ids: HashMap::new(),
            partitions,
            suspect_rank: Vec::new(),
            partition_order,
            partition_of: Vec::new(),
            models: Vec::new(),
            latest: vec![None; parts.len()],
            deviations: vec![None; parts.len()],
            flags: Vec::new(),
            sorted_flags: Vec::new(),
            shown: None,
            shown_ids: None,
        };
        c.suspect_rank = (c.partition_order.iter()).map(|p| c.rank(p)).collect();
        c.models = parts
            .iter()
            .map(|(_, labels)| {
                let mut set = LabelSet::default();
                for l in labels {
                    set.insert(c.id(l));
                }
                set
            })
            .collect();
        c
    }

    /// Where a partition's name or flag sorts: the place of the first
    /// partition it names.
    fn rank(&self, name: &str) -> usize {
        self.partition_order
            .iter()
            .position(|p| Flag::names(FlagKind::Def, p, name) || name == p)
            .unwrap_or(usize::MAX)
    }

    /// The id of `label`, given one if new.
    fn id(&mut self, label: &str) -> u32 {
        if let Some(&id) = self.ids.get(label) {
            return id;
        }
        let id = self.names.len() as u32;
        let partition = self
            .partitions
            .iter()
            .find(|(f, _)| f == label)
            .and_then(|(_, p)| self.partition_order.iter().position(|q| q == p));
        self.names.push(label.to_string());
        self.ids.insert(label.to_string(), id);
        self.partition_of.push(partition);
        id
    }

    /// What the rules read of `verdict`: `None` when normal.
    fn deviation(&mut self, verdict: &Verdict) -> Option<Deviation> {
        if verdict.verdict == VerdictKind::Normal {
            return None;
        }
        let tentative = verdict.labels.iter().any(|l| l == "N");
        let labels: Vec<u32> = (verdict.labels.iter())
            .filter(|l| *l != "N")
            .map(|l| self.id(l))
            .collect();
        let mut set = LabelSet::default();
        labels.iter().for_each(|&l| set.insert(l));
        Some(Deviation {
            unknown: is_unknown(verdict),
            tentative,
            labels,
            set,
        })
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
        self.deviations = latest
            .iter()
            .map(|v| v.as_ref().and_then(|v| self.deviation(v)))
            .collect();
        self.latest = latest;
        self.flags = flags;
        self.sort_flags();
        self.shown = shown;
        self.shown_ids = None;
    }

    /// Forgets every verdict (a new log).
    pub fn reset(&mut self) {
        self.latest.iter_mut().for_each(|v| *v = None);
        self.deviations.iter_mut().for_each(|v| *v = None);
        self.flags.clear();
        self.sorted_flags.clear();
        self.shown = None;
        self.shown_ids = None;
    }

    /// Takes part `index`'s new verdict; returns the plant view if it changed.
    pub fn update(&mut self, index: usize, verdict: &Verdict) -> Option<Verdict> {
        if index < self.latest.len() {
            self.deviations[index] = self.deviation(verdict);
            self.latest[index] = Some(verdict.clone());
        }
        let judged = self.judge();
        // Most updates leave the view as it was: that is told in ids, and
        // the view is written out only when it changed.
        let key = (judged.labels.clone(), self.flags.len());
        if self.shown_ids.as_ref() == Some(&key) {
            return None;
        }
        self.shown_ids = Some(key);
        let view = self.render(judged, verdict.t);
        let key = (view.labels.clone(), view.flags.clone());
        if self.shown.as_ref() == Some(&key) {
            return None;
        }
        self.shown = Some(key);
        Some(view)
    }

    fn sort_flags(&mut self) {
        let mut sorted = self.flags.clone();
        sorted.sort_by_cached_key(|f| self.rank(f));
        self.sorted_flags = sorted;
    }

    /// The plant view now.
    pub fn view(&mut self, t: Time) -> Verdict {
        let judged = self.judge();
        self.render(judged, t)
    }

    /// The view by rules 1 to 3, in ids; raises `def_` when the candidates
    /// all lie in one partition.
    fn judge(&mut self) -> Judged {
        let mut known = Vec::new();
        let mut unknown = Vec::new();
        let mut tentative = Vec::new();
        for (i, d) in self.deviations.iter().enumerate() {
            match d {
                Some(d) if d.unknown => unknown.push(i),
                Some(d) if d.tentative => tentative.push(i),
                Some(_) => known.push(i),
                None => {}
            }
        }
        let labels = if !known.is_empty() {
            Some(self.candidates(&known))
        } else if !tentative.is_empty() {
            // Every deviation may be a glitch: normal stays a candidate.
            let mut ids = vec![self.id("N")];
            ids.extend(self.candidates(&tentative));
            known = tentative;
            Some(ids)
        } else if !unknown.is_empty() {
            Some(vec![self.id(UNKNOWN_LABEL)])
        } else {
            None
        };
        let suspects = match &labels {
            Some(ids) if !known.is_empty() => self.suspects(ids),
            _ => Vec::new(),
        };
        Judged {
            labels,
            known,
            unknown,
            suspects,
        }
    }

    /// The candidates of the parts `known` to deviate with modelled faults.
    fn candidates(&self, known: &[usize]) -> Vec<u32> {
        let known: Vec<(usize, &Deviation)> = (known.iter())
            .filter_map(|&i| self.deviations[i].as_ref().map(|d| (i, d)))
            .collect();
        // Rule 1: exclusion by the parts that model a label.
        let mut seen = LabelSet::default();
        let mut union: Vec<u32> = Vec::new();
        for (_, d) in &known {
            for &l in &d.labels {
                if !seen.contains(l) {
                    seen.insert(l);
                    union.push(l);
                }
            }
        }
        let models = &self.models;
        let modelled = |i: usize, l: u32| models.get(i).is_some_and(|m| m.contains(l));
        union.retain(|&l| {
            known
                .iter()
                .all(|(i, d)| !modelled(*i, l) || d.set.contains(l))
        });
        // Rule 2: a single fault explaining every deviation.
        let common: Vec<u32> = (union.iter().copied())
            .filter(|&l| known.iter().all(|(_, d)| d.set.contains(l)))
            .collect();
        if common.is_empty() { union } else { common }
    }

    /// The partitions of the candidates `ids` when they are faults, in the
    /// plant's order, as indices; raises `def_` when they all lie in one.
    fn suspects(&mut self, ids: &[u32]) -> Vec<usize> {
        let (normal, ids) = match ids.split_first() {
            Some((&l, rest)) if self.names[l as usize] == "N" => (true, rest),
            _ => (false, ids),
        };
        let faulty = ids
            .first()
            .is_some_and(|&l| !matches!(self.names[l as usize].as_str(), "N" | UNKNOWN_LABEL));
        if !faulty {
            return Vec::new();
        }
        let of = |l: u32| self.partition_of.get(l as usize).copied().flatten();
        let mut suspects: Vec<usize> = Vec::new();
        for &l in ids {
            if let Some(p) = of(l)
                && !suspects.contains(&p)
            {
                suspects.push(p);
            }
        }
        // Normal after a glitch among the candidates: no fault is certain.
        if let Some(&p) = suspects.first()
            && !normal
            && ids.iter().all(|&l| of(l) == Some(p))
        {
            let flag = Flag::def(self.partition_order[p].as_str()).to_string();
            if !self.flags.contains(&flag) {
                self.flags.push(flag);
                self.sort_flags();
            }
        }
        suspects.sort_by_key(|&p| self.suspect_rank[p]);
        suspects
    }

    /// The view `judged` at `t` as a verdict line.
    fn render(&self, judged: Judged, t: Time) -> Verdict {
        let part = |i: &usize| self.latest[*i].as_ref().map_or("", |v| v.part.as_str());
        let names = |parts: &[usize]| parts.iter().map(part).collect::<Vec<_>>().join(", ");
        let (labels, reason) = match &judged.labels {
            None => (vec!["N".to_string()], "every part is normal".to_string()),
            Some(ids) => {
                let labels = ids
                    .iter()
                    .map(|&l| self.names[l as usize].clone())
                    .collect();
                let reason = if judged.known.is_empty() {
                    format!(
                        "{} deviate(s) in a way no modelled fault explains",
                        names(&judged.unknown)
                    )
                } else if judged.unknown.is_empty() {
                    format!("from {}", names(&judged.known))
                } else {
                    // Rule 3: the unknown parts as consequences.
                    format!(
                        "from {}; {} deviate(s) too, probably as a consequence",
                        names(&judged.known),
                        names(&judged.unknown)
                    )
                };
                (labels, reason)
            }
        };
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
            flags: self.sorted_flags.clone(),
            suspects: (judged.suspects.iter())
                .map(|&p| self.partition_order[p].clone())
                .collect(),
            reason,
        }
    }
}

/// A plant view in ids, before it is written out.
struct Judged {
    /// The candidates; `None` when every part is normal.
    labels: Option<Vec<u32>>,
    /// The parts deviating with modelled faults, and without.
    known: Vec<usize>,
    unknown: Vec<usize>,
    /// The candidates' partitions, as indices in the plant's order.
    suspects: Vec<usize>,
}

fn is_unknown(v: &Verdict) -> bool {
    v.labels.len() == 1 && v.labels[0] == UNKNOWN_LABEL
}
