//! The benchmark's figures: rates over many plants, per size and in all, and
//! the faults on which `check` and the replays disagree.

use std::fmt::Write;

use serde::Serialize;

use crate::evaluate::{FAULT_SEED, FaultOutcome, PlantOutcome, Settings};

/// Counts over a set of plants.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    /// Plants evaluated (without error).
    pub plants: usize,
    /// Plants that could not be evaluated.
    pub errors: usize,
    /// Their parts.
    pub parts: usize,
    /// Faulty runs.
    pub runs: usize,
    /// Hours of fresh fault-free logs.
    pub normal_hours: f64,
    /// Parts leaving normal on them.
    pub false_alarms: usize,
    /// `def_` flags raised on them.
    pub false_flags: usize,
    /// Judged runs whose last verdict is `certain` on labels without the
    /// true fault (`unknown` apart).
    pub certain_wrong: usize,
    /// Faulty runs whose part had left normal before the onset (left out of
    /// every rate below).
    pub preempted: usize,
    /// Faulty runs where the fault showed in the log.
    pub showed: usize,
    /// ...and its part left normal after the onset.
    pub detected: usize,
    /// Faulty runs where the fault changed its part's edges, not only their
    /// times.
    pub edges_changed: usize,
    /// ...and its part left normal after the onset.
    pub edges_changed_detected: usize,
    /// Runs where the fault's part left normal after the onset.
    pub judged: usize,
    /// ...and every such verdict kept the true label.
    pub sound: usize,
    /// Runs where the fault showed and `check` says it is isolable, also if the
    /// control waits for ever.
    pub isolable: usize,
    /// ...and the last verdict is the true fault alone.
    pub isolable_isolated: usize,
    /// Runs where the fault showed and `check` says it is isolable while the
    /// plant keeps running.
    pub isolable_running: usize,
    /// ...and the last verdict is the true fault alone.
    pub isolable_running_isolated: usize,
    /// Runs where the fault showed and the last verdict is the true fault alone.
    pub isolated: usize,
    /// Detection delays (s) from the onset, of detected runs that showed.
    pub delays: Vec<f64>,
}

impl Totals {
    /// Adds a plant.
    pub fn add(&mut self, p: &PlantOutcome) {
        if p.error.is_some() {
            self.errors += 1;
            return;
        }
        self.plants += 1;
        self.parts += p.parts;
        self.normal_hours += p.normal_hours;
        self.false_alarms += p.false_alarms.len();
        self.false_flags += p.false_flags.len();
        for r in &p.runs {
            self.add_run(r);
        }
    }

    fn add_run(&mut self, r: &FaultOutcome) {
        let j = &r.judgement;
        self.runs += 1;
        if j.preempted {
            self.preempted += 1;
            return;
        }
        if let Some(sound) = j.sound {
            self.judged += 1;
            self.sound += usize::from(sound);
            self.certain_wrong += usize::from(
                j.final_verdict == "certain"
                    && j.final_labels != ["unknown"]
                    && !j.final_labels.contains(&r.label),
            );
        }
        if r.showed_ms.is_none() {
            return;
        }
        self.showed += 1;
        if let Some(t) = j.detected_ms {
            self.detected += 1;
            self.delays.push((t - r.onset_ms as f64) / 1000.0);
        }
        if !r.timing_only {
            self.edges_changed += 1;
            self.edges_changed_detected += usize::from(j.detected_ms.is_some());
        }
        self.isolated += usize::from(j.isolated);
        if r.check_isolable == Some(true) {
            self.isolable += 1;
            self.isolable_isolated += usize::from(j.isolated);
        }
        if r.check_isolable_running == Some(true) {
            self.isolable_running += 1;
            self.isolable_running_isolated += usize::from(j.isolated);
        }
    }
}

fn percent(n: usize, of: usize) -> String {
    if of == 0 {
        "–".to_string()
    } else {
        format!("{:.1} % ({n}/{of})", 100.0 * n as f64 / of as f64)
    }
}

/// The `q` quantile (0 to 1) of `values`, by the nearest rank.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    Some(v[rank - 1])
}

fn seconds(v: Option<f64>) -> String {
    v.map_or("–".to_string(), |s| format!("{s:.2} s"))
}

/// The figures as a Markdown table: one row per size, then all plants.
pub fn table(outcomes: &[PlantOutcome]) -> String {
    let mut rows: Vec<(String, Totals)> = Vec::new();
    for size in ["small", "medium", "large"] {
        let mut t = Totals::default();
        for p in outcomes.iter().filter(|p| p.size == size) {
            t.add(p);
        }
        if t.plants + t.errors > 0 {
            rows.push((size.to_string(), t));
        }
    }
    for family in ["assembly", "process", "axes", "mixed"] {
        let mut t = Totals::default();
        for p in outcomes.iter().filter(|p| p.family == family) {
            t.add(p);
        }
        if t.plants + t.errors > 0 && t.plants + t.errors < outcomes.len() {
            rows.push((family.to_string(), t));
        }
    }
    let mut all = Totals::default();
    for p in outcomes {
        all.add(p);
    }
    rows.push(("all".to_string(), all));
    let mut out = String::from(
        "| plants | parts | faulty runs | false alarms / 100 h (fault-free h) | `def_` flags on fault-free logs | preempted (part alarmed before onset) | sound | ending `certain` on a wrong label | detected (of showed) | detected (of edges changed) | isolated (of `check` isolable) | isolated (of isolable while running) | isolated (of showed) | delay median | delay p95 |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (name, t) in rows {
        let rate = if t.normal_hours > 0.0 {
            format!(
                "{:.1} ({} in {:.0} h)",
                100.0 * t.false_alarms as f64 / t.normal_hours,
                t.false_alarms,
                t.normal_hours
            )
        } else {
            "–".to_string()
        };
        let errors = if t.errors > 0 {
            format!(" ({} failed)", t.errors)
        } else {
            String::new()
        };
        let _ = writeln!(
            out,
            "| {name}: {}{errors} | {} | {} | {rate} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            t.plants,
            t.parts,
            t.runs,
            t.false_flags,
            percent(t.preempted, t.runs),
            percent(t.sound, t.judged),
            t.certain_wrong,
            percent(t.detected, t.showed),
            percent(t.edges_changed_detected, t.edges_changed),
            percent(t.isolable_isolated, t.isolable),
            percent(t.isolable_running_isolated, t.isolable_running),
            percent(t.isolated, t.showed),
            seconds(quantile(&t.delays, 0.5)),
            seconds(quantile(&t.delays, 0.95)),
        );
    }
    out
}

/// The rates by fault template (`slow` by factor), over every plant: how
/// each kind of fault is detected, kept and isolated.
pub fn template_table(outcomes: &[PlantOutcome]) -> String {
    let mut rows: Vec<(String, Totals)> = Vec::new();
    for p in outcomes.iter().filter(|p| p.error.is_none()) {
        for r in &p.runs {
            let name = r.template.split('(').next().unwrap_or("").to_string();
            let name = match r.factor {
                Some(f) => format!("{name} ×{f}"),
                None => name,
            };
            let at = match rows.iter().position(|(n, _)| *n == name) {
                Some(at) => at,
                None => {
                    rows.push((name, Totals::default()));
                    rows.len() - 1
                }
            };
            rows[at].1.add_run(r);
        }
    }
    rows.sort_by(|a, b| a.0.cmp(&b.0));
    let mut out = String::from(
        "| template | faulty runs | preempted | sound | detected (of showed) | detected (of edges changed) | isolated (of showed) | ending `certain` on a wrong label |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (name, t) in rows {
        let _ = writeln!(
            out,
            "| {name} | {} | {} | {} | {} | {} | {} | {} |",
            t.runs,
            percent(t.preempted, t.runs),
            percent(t.sound, t.judged),
            percent(t.detected, t.showed),
            percent(t.edges_changed_detected, t.edges_changed),
            percent(t.isolated, t.showed),
            t.certain_wrong,
        );
    }
    out
}

/// A fault on which `check` and the replay disagree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Disagreement {
    /// Plant seed.
    pub seed: u64,
    /// Plant size.
    pub size: &'static str,
    /// Plant family.
    pub family: &'static str,
    /// The fault.
    pub label: String,
    /// A `slow` fault's factor.
    pub factor: Option<f64>,
    /// Its onset, ms.
    pub onset_ms: i64,
    /// The run's last scan, ms.
    pub end_ms: i64,
    /// The fault's template name, e.g. `stuck1`.
    pub template: String,
    /// Which way they disagree, e.g. "check: isolable; replay: not isolated".
    pub kind: &'static str,
    /// What `check` said and what the replay did.
    pub what: String,
}

impl Disagreement {
    /// The command that replays this one fault alone.
    pub fn rerun(&self, settings: &Settings) -> String {
        let mut env = String::new();
        if self.family != "assembly" {
            env.push_str(&format!("FAMILY={} ", self.family));
        }
        if let Some(f) = self.factor {
            env.push_str(&format!("FACTOR={f} "));
        }
        format!(
            "{env}bash benches/generality-rerun.sh {} {} {} {} {} {} {}",
            self.seed,
            self.size,
            self.label,
            self.onset_ms,
            self.end_ms,
            settings.learn_runs,
            settings.learn_duration / diagnoser::MS,
        )
    }
}

/// `check` says isolable, also if the control waits; the replay did not end on
/// the fault alone.
pub const ISOLABLE: &str = "check: isolable; replay: not isolated";
/// `check` says detectable; the fault's part never left normal.
pub const DETECTABLE: &str = "check: detectable; replay: not detected";
/// `check` says not detectable; the replay detected it, soundly.
pub const NOT_DETECTABLE: &str = "check: not detectable; replay: detected";
/// `check` says not isolable, even while the plant runs; the replay isolated it.
pub const NOT_ISOLABLE: &str = "check: not isolable; replay: isolated";

/// The disagreements counted per kind and, within a kind, per template.
pub fn disagreement_table(found: &[Disagreement]) -> String {
    let templates = [
        "stuck0",
        "stuck1",
        "unexpected_rise",
        "unexpected_fall",
        "actuator_stuck0",
        "actuator_stuck1",
        "blocked_at",
        "blocked_between",
    ];
    let mut out = format!(
        "| disagreement | all | {} |\n|---|---:|",
        templates.join(" | ")
    );
    out.push_str(&"---:|".repeat(templates.len()));
    out.push('\n');
    for kind in [ISOLABLE, DETECTABLE, NOT_DETECTABLE, NOT_ISOLABLE] {
        let of: Vec<&Disagreement> = found.iter().filter(|d| d.kind == kind).collect();
        let cells: Vec<String> = templates
            .iter()
            .map(|t| of.iter().filter(|d| d.template == *t).count().to_string())
            .collect();
        let _ = writeln!(out, "| {kind} | {} | {} |", of.len(), cells.join(" | "));
    }
    out
}

/// Faults that showed, where `check` and the replay disagree: `check` said
/// isolable and the replay did not isolate it, `check` said detectable and the
/// replay never left normal, or `check` said not detectable (or not isolable)
/// and the replay detected (or isolated) it.
pub fn disagreements(outcomes: &[PlantOutcome]) -> Vec<Disagreement> {
    let mut out = Vec::new();
    for p in outcomes {
        for r in p
            .runs
            .iter()
            .filter(|r| r.showed_ms.is_some() && !r.judgement.preempted)
        {
            let j = &r.judgement;
            let (Some(detectable), Some(isolable), Some(running)) = (
                r.check_detectable,
                r.check_isolable,
                r.check_isolable_running,
            ) else {
                continue;
            };
            let ended = format!("ended {} [{}]", j.final_verdict, j.final_labels.join(", "));
            let (kind, what) = if isolable && !j.isolated {
                (ISOLABLE, format!("check: isolable; replay {ended}"))
            } else if detectable && j.detected_ms.is_none() {
                (
                    DETECTABLE,
                    "check: detectable; replay never left normal".to_string(),
                )
            } else if !detectable && j.detected_ms.is_some() && j.sound == Some(true) {
                (
                    NOT_DETECTABLE,
                    format!("check: not detectable; replay detected it and {ended}"),
                )
            } else if !running && j.isolated {
                (
                    NOT_ISOLABLE,
                    "check: not isolable; replay isolated it".to_string(),
                )
            } else {
                continue;
            };
            out.push(Disagreement {
                seed: p.seed,
                size: p.size,
                family: p.family,
                label: r.label.clone(),
                factor: r.factor,
                onset_ms: r.onset_ms,
                end_ms: r.end_ms,
                template: r.template.split('(').next().unwrap_or("").to_string(),
                kind,
                what,
            });
        }
    }
    out
}

/// How the runs were made, for the report's header.
pub fn describe(settings: &Settings) -> String {
    let h = |t: diagnoser::Time| t as f64 / (3600 * diagnoser::SECOND) as f64;
    let s = |t: diagnoser::Time| t / diagnoser::SECOND;
    format!(
        "learned from {} fault-free log(s) of {:.1} h (run seeds 1…); false alarms on a fresh {:.1} h \
         log (run seed {}); each fault once, from an onset drawn in [{} s, {} s), for {} s, branching \
         off one fault-free run (run seed {FAULT_SEED}){}",
        settings.learn_runs,
        h(settings.learn_duration),
        h(settings.normal_duration),
        crate::evaluate::NORMAL_SEED,
        s(settings.first_onset),
        s(settings.first_onset + settings.onset_window),
        s(settings.horizon),
        settings
            .max_faults
            .map_or(String::new(), |k| format!("; at most {k} faults per plant")),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_by_nearest_rank() {
        let v = [3.0, 1.0, 2.0, 4.0];
        assert_eq!(quantile(&v, 0.5), Some(2.0));
        assert_eq!(quantile(&v, 0.95), Some(4.0));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&[], 0.5), None);
    }
}
