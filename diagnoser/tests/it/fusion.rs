//! The coordinator's plant view against the rules as written plainly: the
//! same views, line for line, over any parts, models and verdicts.
//!
//! [`Reference`] applies the three rules of `diagnosis::fusion` to label
//! names, one verdict at a time, as the coordinator did before it worked
//! in label ids and bit sets. Any sequence of part verdicts must give the
//! same plant views from both, and the same summary view at the end.

use std::path::Path;

use diagnoser::diagnosis::fusion::{Coordinator, PLANT_VIEW};
use diagnoser::diagnosis::{UNKNOWN_LABEL, Verdict, VerdictKind};
use diagnoser::{Flag, FlagKind, Plant};
use proptest::prelude::*;

/// The rules over label names.
struct Reference {
    models: Vec<Vec<String>>,
    partitions: Vec<(String, String)>,
    partition_order: Vec<String>,
    latest: Vec<Option<Verdict>>,
    flags: Vec<String>,
    shown: Option<(Vec<String>, Vec<String>)>,
}

impl Reference {
    fn new(plant: &Plant, models: Vec<Vec<String>>) -> Self {
        Reference {
            latest: vec![None; models.len()],
            models,
            partitions: (plant.partitions.iter())
                .flat_map(|p| p.faults.iter().map(move |f| (f.clone(), p.name.clone())))
                .collect(),
            partition_order: plant.partitions.iter().map(|p| p.name.clone()).collect(),
            flags: Vec::new(),
            shown: None,
        }
    }

    fn update(&mut self, index: usize, verdict: &Verdict) -> Option<Verdict> {
        self.latest[index] = Some(verdict.clone());
        let view = self.view();
        let key = (view.labels.clone(), view.flags.clone());
        if self.shown.as_ref() == Some(&key) {
            return None;
        }
        self.shown = Some(key);
        Some(view)
    }

    fn partition(&self, label: &str) -> Option<&str> {
        (self.partitions.iter())
            .find(|(f, _)| f == label)
            .map(|(_, p)| p.as_str())
    }

    fn view(&mut self) -> Verdict {
        let deviating: Vec<(usize, &Verdict)> = (self.latest.iter().enumerate())
            .filter_map(|(i, v)| v.as_ref().map(|v| (i, v)))
            .filter(|(_, v)| v.verdict != VerdictKind::Normal)
            .collect();
        let is_unknown = |v: &Verdict| v.labels == [UNKNOWN_LABEL];
        // A part that normal after a glitch still explains (`N` among its
        // labels) counts only when no other part deviates with faults.
        let tentative = |v: &Verdict| v.labels.iter().any(|l| l == "N");
        let confirmed: Vec<(usize, &Verdict)> = (deviating.iter().copied())
            .filter(|(_, v)| !is_unknown(v) && !tentative(v))
            .collect();
        let normal_too = confirmed.is_empty() && deviating.iter().any(|(_, v)| tentative(v));
        let faults_of = |v: &Verdict| -> Verdict {
            let mut v = v.clone();
            v.labels.retain(|l| l != "N");
            v
        };
        let owned: Vec<(usize, Verdict)> = if normal_too {
            (deviating.iter())
                .filter(|(_, v)| tentative(v))
                .map(|(i, v)| (*i, faults_of(v)))
                .collect()
        } else {
            confirmed.iter().map(|(i, v)| (*i, (*v).clone())).collect()
        };
        let known: Vec<(usize, &Verdict)> = owned.iter().map(|(i, v)| (*i, v)).collect();
        let unknown: Vec<&str> = (deviating.iter())
            .filter(|(_, v)| is_unknown(v))
            .map(|(_, v)| v.part.as_str())
            .collect();
        let mut union: Vec<String> = Vec::new();
        for (_, v) in &known {
            for l in &v.labels {
                if !union.contains(l) {
                    union.push(l.clone());
                }
            }
        }
        union.retain(|l| {
            (known.iter()).all(|(i, v)| !self.models[*i].contains(l) || v.labels.contains(l))
        });
        let common: Vec<String> = (union.iter())
            .filter(|l| known.iter().all(|(_, v)| v.labels.contains(l)))
            .cloned()
            .collect();
        let mut candidates = if common.is_empty() { union } else { common };
        if normal_too {
            candidates.insert(0, "N".to_string());
        }
        let (labels, mut reason) = if deviating.is_empty() {
            (vec!["N".to_string()], "every part is normal".to_string())
        } else if known.is_empty() {
            let reason = format!(
                "{} deviate(s) in a way no modelled fault explains",
                unknown.join(", ")
            );
            (vec![UNKNOWN_LABEL.to_string()], reason)
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
        let faults: &[String] = if normal_too { &labels[1..] } else { &labels };
        let faulty = faults
            .first()
            .is_some_and(|l| l != "N" && l != UNKNOWN_LABEL);
        let mut suspects: Vec<String> = Vec::new();
        if faulty {
            for l in faults {
                if let Some(p) = self.partition(l)
                    && !suspects.iter().any(|s| s == p)
                {
                    suspects.push(p.to_string());
                }
            }
            let all_in = |p: &str| faults.iter().all(|l| self.partition(l) == Some(p));
            if let Some(p) = suspects.first().cloned()
                && all_in(&p)
                && !normal_too
            {
                let flag = Flag::def(p.as_str()).to_string();
                if !self.flags.contains(&flag) {
                    self.flags.push(flag);
                }
            }
        }
        let order = |name: &str| {
            (self.partition_order.iter())
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
            t: 0,
            part: PLANT_VIEW.to_string(),
            verdict,
            labels,
            flags,
            suspects,
            reason,
        }
    }
}

/// Labels the parts may model: the plant's faults (in partitions) and
/// others of no partition.
fn pool(plant: &Plant) -> Vec<String> {
    let mut labels: Vec<String> = (plant.partitions.iter())
        .flat_map(|p| p.faults.iter().cloned())
        .collect();
    labels.sort();
    labels.dedup();
    labels.extend(["X".to_string(), "Y".to_string()]);
    labels
}

/// A part's verdict: normal, unknown, or labels of the pool in this order.
fn verdict(part: usize, choice: u8, labels: &[usize], pool: &[String]) -> Verdict {
    let labels: Vec<String> = match choice {
        0 => vec!["N".to_string()],
        1 => vec![UNKNOWN_LABEL.to_string()],
        _ => {
            // Choice 2: normal after a glitch beside the faults.
            let mut names: Vec<String> =
                (choice == 2).then(|| "N".to_string()).into_iter().collect();
            for &l in labels {
                let name = &pool[l % pool.len()];
                if !names.contains(name) {
                    names.push(name.clone());
                }
            }
            names
        }
    };
    Verdict {
        t: 0,
        part: format!("part{part}"),
        verdict: match labels.len() {
            _ if labels == ["N"] => VerdictKind::Normal,
            1 => VerdictKind::Certain,
            _ => VerdictKind::Ambiguous,
        },
        labels,
        flags: Vec::new(),
        suspects: Vec::new(),
        reason: String::new(),
    }
}

fn plant() -> Plant {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/plants/sorting.toml");
    Plant::from_path(&path).expect("the sorting plant")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn the_plant_view_follows_the_rules_over_any_verdicts(
        models in proptest::collection::vec(proptest::collection::btree_set(0usize..20, 0..8), 1..6),
        verdicts in proptest::collection::vec(
            (0usize..6, 0u8..5, proptest::collection::vec(0usize..20, 1..6)), 0..40),
    ) {
        let plant = plant();
        let pool = pool(&plant);
        let models: Vec<Vec<String>> = (models.iter())
            .map(|m| m.iter().map(|&l| pool[l % pool.len()].clone()).collect())
            .collect();
        let parts = (models.iter().enumerate())
            .map(|(i, m)| (format!("part{i}"), m.clone()))
            .collect();
        let mut coordinator = Coordinator::new(&plant, parts);
        let mut reference = Reference::new(&plant, models.clone());
        for (part, choice, labels) in verdicts {
            let part = part % models.len();
            let v = verdict(part, choice, &labels, &pool);
            prop_assert_eq!(coordinator.update(part, &v), reference.update(part, &v));
        }
        prop_assert_eq!(coordinator.view(0), reference.view());
    }
}
