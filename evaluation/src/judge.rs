//! A replay's verdicts judged against the ground truth: false alarms on
//! fault-free logs, and, for a faulty log, when the fault's part left normal,
//! whether its labels kept the true fault, and how it ended.

use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::diagnosis::{PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::{FaultTemplate, Plant, Time};
use serde::Serialize;

use crate::runs::Log;

/// Replays `log` through every part's diagnoser (the coordinator's plant view
/// left out), up to the log's last scan.
pub fn replay(diagnoser: &mut PlantDiagnoser, log: &Log) -> Vec<Verdict> {
    let mut out = Vec::new();
    let mut keep = |v: Verdict| {
        if v.part != PLANT_VIEW {
            out.push(v);
        }
    };
    diagnoser.start(log.start, &log.initial);
    for &e in &log.events {
        diagnoser.push(e, &mut keep);
    }
    diagnoser.finish(log.end, &mut keep);
    out
}

/// A part leaving normal: an alarm, false on a fault-free log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Alarm {
    /// When, in ms from the start.
    pub t_ms: f64,
    /// Which part.
    pub part: String,
    /// Its verdict and labels then.
    pub verdict: String,
    /// Its labels.
    pub labels: Vec<String>,
    /// Why, in the diagnoser's words.
    pub reason: String,
}

/// Every time a part leaves normal.
pub fn alarms(verdicts: &[Verdict]) -> Vec<Alarm> {
    let mut out = Vec::new();
    let mut was_normal = std::collections::HashMap::new();
    for v in verdicts {
        let before = was_normal.insert(v.part.as_str(), v.verdict == VerdictKind::Normal);
        if v.verdict != VerdictKind::Normal && before.unwrap_or(true) {
            out.push(alarm(v));
        }
    }
    out
}

fn alarm(v: &Verdict) -> Alarm {
    Alarm {
        t_ms: ms(v.t),
        part: v.part.clone(),
        verdict: v.verdict.name().to_string(),
        labels: v.labels.clone(),
        reason: v.reason.clone(),
    }
}

/// Nanoseconds as milliseconds.
pub fn ms(t: Time) -> f64 {
    t as f64 / diagnoser::MS as f64
}

/// The part a fault belongs to: the part of its signal, or of its element.
pub fn part_of(plant: &Plant, template: &FaultTemplate) -> Option<String> {
    let part = match template.signal() {
        Some(s) => {
            let id = plant.signals.id(s)?;
            plant
                .parts
                .iter()
                .find(|p| p.sensors.contains(&id) || p.actuators.contains(&id))
        }
        None => {
            // An element's fault, or a slow motion of an element or of what
            // an actuator drives.
            let x = template.arguments()[0];
            let actuator = plant.signals.id(x);
            plant.parts.iter().find(|p| {
                p.element.as_deref() == Some(x)
                    || actuator.is_some_and(|a| p.actuators.contains(&a))
            })
        }
    };
    part.map(|p| p.name.clone())
}

/// How the diagnosers did on one faulty run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Judgement {
    /// The fault's part had already left normal (a false alarm) when the fault
    /// began: the run says nothing of how the fault itself is diagnosed.
    pub preempted: bool,
    /// When the fault's part first left normal at or after the onset, in ms.
    pub detected_ms: Option<f64>,
    /// Whether every verdict of the fault's part that was not normal, from
    /// the onset on, had the true label among its labels (`None`: the part
    /// never left normal).
    pub sound: Option<bool>,
    /// The part's last verdict.
    pub final_verdict: String,
    /// Its labels.
    pub final_labels: Vec<String>,
    /// The last verdict is certain, with the true label alone.
    pub isolated: bool,
    /// Other parts that left normal from the onset on.
    pub other_parts: Vec<String>,
    /// The first verdict of the part, from the onset on, that lost the true
    /// label (why the run is unsound).
    pub lost: Option<Alarm>,
}

/// Judges the verdicts of a run with fault `label` of part `part` from `onset`.
pub fn judge(verdicts: &[Verdict], part: &str, label: &str, onset: Time) -> Judgement {
    let preempted = verdicts
        .iter()
        .rev()
        .find(|v| v.part == part && v.t < onset)
        .is_some_and(|v| v.verdict != VerdictKind::Normal);
    let own: Vec<&Verdict> = verdicts
        .iter()
        .filter(|v| v.part == part && v.t >= onset)
        .collect();
    let faulty: Vec<&&Verdict> = own
        .iter()
        .filter(|v| v.verdict != VerdictKind::Normal)
        .collect();
    let last = verdicts.iter().rev().find(|v| v.part == part);
    let mut other_parts: Vec<String> = verdicts
        .iter()
        .filter(|v| v.part != part && v.t >= onset && v.verdict != VerdictKind::Normal)
        .map(|v| v.part.clone())
        .collect();
    other_parts.sort();
    other_parts.dedup();
    let lost = faulty
        .iter()
        .find(|v| !v.labels.iter().any(|l| l == label))
        .map(|v| alarm(v));
    Judgement {
        preempted,
        detected_ms: faulty.first().map(|v| ms(v.t)),
        sound: (!faulty.is_empty()).then_some(lost.is_none()),
        final_verdict: last.map_or("normal", |v| v.verdict.name()).to_string(),
        final_labels: last.map_or_else(|| vec!["N".to_string()], |v| v.labels.clone()),
        isolated: last.is_some_and(|v| v.verdict == VerdictKind::Certain && v.labels == [label]),
        other_parts,
        lost,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(t: i64, part: &str, kind: VerdictKind, labels: &[&str]) -> Verdict {
        Verdict {
            t: t * diagnoser::MS,
            part: part.to_string(),
            verdict: kind,
            labels: labels.iter().map(|l| l.to_string()).collect(),
            flags: Vec::new(),
            suspects: Vec::new(),
            reason: String::new(),
        }
    }

    #[test]
    fn a_run_that_narrows_to_the_true_fault_is_sound_and_isolated() {
        let vs = [
            v(100, "arm", VerdictKind::Ambiguous, &["F1", "F2"]),
            v(150, "arm", VerdictKind::Certain, &["F1"]),
        ];
        let j = judge(&vs, "arm", "F1", 50 * diagnoser::MS);
        assert_eq!(j.detected_ms, Some(100.0));
        assert_eq!(j.sound, Some(true));
        assert!(j.isolated && !j.preempted);
        assert!(j.other_parts.is_empty());
    }

    #[test]
    fn a_verdict_without_the_true_label_is_unsound_and_an_early_one_preempts() {
        let vs = [
            v(10, "table", VerdictKind::Ambiguous, &["unknown"]),
            v(100, "arm", VerdictKind::Certain, &["F2"]),
            v(120, "arm", VerdictKind::Ambiguous, &["F1", "F2"]),
        ];
        let j = judge(&vs, "arm", "F1", 50 * diagnoser::MS);
        // Another part's alarm before the onset does not preempt; the own
        // part's does.
        assert!(!j.preempted);
        assert!(judge(&vs, "table", "F3", 50 * diagnoser::MS).preempted);
        assert_eq!(j.sound, Some(false));
        assert_eq!(j.lost.as_ref().map(|a| a.t_ms), Some(100.0));
        assert!(!j.isolated);
        assert_eq!(j.final_verdict, "ambiguous");
        // The table's verdict came before the onset: not counted after it.
        assert!(j.other_parts.is_empty());
        let quiet = judge(&vs[..1], "arm", "F1", 50 * diagnoser::MS);
        assert_eq!((quiet.sound, quiet.detected_ms), (None, None));
        assert_eq!(quiet.final_labels, ["N"]);
    }

    #[test]
    fn alarms_count_each_departure_from_normal_once() {
        let vs = [
            v(10, "arm", VerdictKind::Ambiguous, &["F1", "F2"]),
            v(20, "arm", VerdictKind::Certain, &["F1"]),
            v(30, "table", VerdictKind::Certain, &["F3"]),
        ];
        let a = alarms(&vs);
        assert_eq!(a.len(), 2);
        assert_eq!((a[0].part.as_str(), a[1].part.as_str()), ("arm", "table"));
    }
}
