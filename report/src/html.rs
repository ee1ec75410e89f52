//! The report page: summary, timelines' data, explanations and pictures.
//!
//! The page is written through maud's `html!` templates, which escape every
//! value they interpolate: text from the plant file, the model, the logs or
//! the diagnosers is shown as text and never becomes markup. Only markup the
//! report builds itself goes in as it is (`PreEscaped`), each time with why it
//! is safe. maud writes no whitespace between elements; the `"\n"` literals
//! keep the page's source in readable lines.
//!
//! Timelines are drawn in the browser from the embedded data (`report.js`), so
//! that a day-long log zooms from the whole day down to single scans without
//! the file holding one picture per zoom.

use std::path::Path;

use diagnoser::diagnosis::compile::Compiled;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::model::{Model, ModelClock, PartModel};
use diagnoser::plant::{Constraint, Part};
use diagnoser::{Plant, SignalId, SignalKind, Time, TimeFormat};
use filter_coupling::filter::Coupling;
use maud::{DOCTYPE, Markup, PreEscaped, html};
use serde_json::{Value, json};

use super::collect::{Change, Detection, EXPLAINED_TRIPS, LogReplay, Rewrite, Trip, TripDetail};
use super::pictures::{self, Layout, Picture};
use super::words::{
    absolute, description, duration, edge, fault_meaning, filter_action, highlight, literal_words,
    offset,
};

const CSS: &str = include_str!("assets/report.css");
const JS: &str = include_str!("assets/report.js");

/// The two pictures of one part.
pub struct PartPictures {
    /// Part name.
    pub part: String,
    /// The learned timed model.
    pub model: Option<Picture>,
    /// The diagnoser built from it.
    pub diagnoser: Option<Picture>,
    /// Why the diagnoser is not drawn, when it is not.
    pub note: Option<String>,
}

/// Largest diagnoser drawn: beyond, no layout keeps it legible on a page, and
/// Graphviz alone would take minutes.
const DRAWN_STATES: usize = 400;
const DRAWN_TRANSITIONS: usize = 1_500;

/// Draws every part's learned model and diagnoser.
pub fn pictures(
    plant: &Plant,
    model: &Model,
    options: &DiagnoserOptions,
    layout: Layout,
) -> Result<Vec<PartPictures>, String> {
    let diagnoser = PlantDiagnoser::new(plant, model, options)?;
    let mut out = Vec::new();
    for (k, engine) in diagnoser.engines().enumerate() {
        let name = engine.part.name.clone();
        let learned = match model.parts.iter().find(|p| p.name == name) {
            Some(pm) => Some(pictures::render(
                &learning::graph::part_digraph(model, pm),
                layout,
                &format!("m{k}-"),
            )?),
            None => None,
        };
        let mut engine = engine.clone();
        let compiled = Compiled::explore(&mut engine, 2);
        let size = compiled.size();
        let (drawn, note) = if size.states <= DRAWN_STATES && size.transitions <= DRAWN_TRANSITIONS
        {
            let picture = pictures::render(
                &compiled.to_digraph(&engine, model.time_unit),
                layout,
                &format!("d{k}-"),
            )?;
            (Some(picture), None)
        } else {
            let note = format!(
                "The diagnoser of {name} has {} states and {} transitions: too many to draw legibly here. `gardefou check --dot DIR` writes it for Graphviz.",
                size.states, size.transitions
            );
            (None, Some(note))
        };
        out.push(PartPictures {
            part: name,
            model: learned,
            diagnoser: drawn,
            note,
        });
    }
    Ok(out)
}

/// Everything the page shows.
pub struct Page<'a> {
    /// The plant.
    pub plant: &'a Plant,
    /// The model.
    pub model: &'a Model,
    /// Where the plant file is.
    pub plant_path: &'a Path,
    /// Where the model is.
    pub model_path: &'a Path,
    /// Which flags the filter read.
    pub coupling: Coupling,
    /// One per log.
    pub replays: &'a [LogReplay],
    /// One per part (empty: no pictures).
    pub pictures: &'a [PartPictures],
}

/// The whole page.
pub fn page(p: &Page<'_>) -> String {
    let title = format!("Fault review: {}", p.plant.name);
    let (logs, data_logs): (Vec<Markup>, Vec<Value>) = p
        .replays
        .iter()
        .enumerate()
        .map(|(i, r)| log_section(p, i, r))
        .unzip();
    let data = json!({ "plant": p.plant.name, "logs": data_logs });
    html! {
        (DOCTYPE) "\n"
        html lang="en" {
            "\n"
            head {
                "\n"
                meta charset="utf-8"; "\n"
                meta name="viewport" content="width=device-width, initial-scale=1"; "\n"
                meta name="generator" content={ "gardefou " (env!("CARGO_PKG_VERSION")) }; "\n"
                title { (title) } "\n"
                // Safe as it is: the page's own stylesheet, from the source tree.
                style { "\n" (PreEscaped(CSS)) "\n" } "\n"
            }
            "\n"
            body {
                "\n"
                (page_header(p, &title)) "\n"
                main {
                    "\n"
                    @for log in &logs { (log) }
                    // The timelines are drawn before the browser reads the
                    // (large, folded) model pictures, so that the page is
                    // usable as soon as possible.
                    (scripts(&data))
                    (models_section(p))
                }
                "\n"
            }
            "\n"
        }
        "\n"
    }
    .into_string()
}

/// The page's heading: the plant, the model and the coupling replayed, and a
/// link to each log when there are several.
fn page_header(p: &Page<'_>, title: &str) -> Markup {
    let learned = &p.model.learned_from;
    let learned_over = (learned.duration * p.model.time_unit.nanos() as f64) as Time;
    let coupling = match p.coupling {
        Coupling::None => ": constraints read the sensors as they are",
        Coupling::Flags => ": a def_ flag switches a failed sensor to its temporal estimate",
        Coupling::FlagsAndSuspects => {
            ": def_ and suspect_ flags switch sensors to their temporal estimates"
        }
    };
    html! {
        header class="report-header" {
            h1 { (title) } "\n"
            p class="meta" {
                "Plant file " code { (p.plant_path.display()) }
                "; model " code { (p.model_path.display()) }
                " (learned from " (learned.logs.join(", ")) " over " (duration(learned_over)) ")"
                "; the safety filter replayed with coupling " code { (p.coupling.name()) }
                (coupling) "."
            }
            "\n"
            @if p.replays.len() > 1 {
                nav class="logs" {
                    ul {
                        @for (i, r) in p.replays.iter().enumerate() {
                            li { a href={ "#log-" (i) } { (r.name) } " — " (plant_line(r)) }
                        }
                    }
                }
            }
        }
    }
}

/// The timeline data, and the page's script that draws the timelines from it.
fn scripts(data: &Value) -> Markup {
    // Inside a script element, `</script>` would end it and `<!--` would make
    // the browser look for its end elsewhere: JSON may write every `<` as
    // `\u003c` (it only occurs inside strings), and then neither can occur.
    let text = data.to_string().replace('<', "\\u003c");
    html! {
        script type="application/json" id="gardefou-data" {
            // Safe as it is: no `<` in it (above); a script's text is never unescaped.
            (PreEscaped(text))
        }
        "\n"
        // Safe as it is: the page's own script, from the source tree.
        script { "\n" (PreEscaped(JS)) "\n" }
        "\n"
    }
}

fn plant_line(r: &LogReplay) -> String {
    match r.summary.last() {
        Some(s) if s.verdict != VerdictKind::Normal => {
            format!("{} {}", VerdictKind::name(s.verdict), s.labels.join(", "))
        }
        _ => "normal".to_string(),
    }
}

/// The section of one log, with its timeline data.
fn log_section(p: &Page<'_>, i: usize, r: &LogReplay) -> (Markup, Value) {
    let (detection_ids, trip_ids) = explanation_ids(r, i);
    let (parts, parts_data): (Vec<Markup>, Vec<Value>) = p
        .plant
        .parts
        .iter()
        .enumerate()
        .map(|(pi, part)| part_section(p, r, i, pi, part, &detection_ids))
        .unzip();
    let markup = html! {
        section class="log" id={ "log-" (i) } data-log=(i) {
            "\n"
            (log_header(r))
            (summary_table(p.plant, r, i))
            (timeline_toolbar(i))
            @for part in &parts { (part) }
            (filter_section(p, r, i, &trip_ids))
        }
        "\n"
    };
    (markup, log_data(r, i, parts_data, &trip_ids))
}

/// The log's heading: its name, span and events, and the whole plant's view.
fn log_header(r: &LogReplay) -> Markup {
    let at = |t: Time| absolute(r.time, t);
    html! {
        h2 { (r.name) } "\n"
        p class="meta" {
            "From " (at(r.start)) " to " (at(r.end)) " (" (duration(r.end - r.start)) "), "
            (r.events) " events."
        }
        "\n"
        @if let Some(view) = r.summary.last() {
            @let v = VerdictKind::name(view.verdict);
            p class={ "plant-view verdict-" (v) } {
                "Whole plant: " strong { (v) } " " (view.labels.join(", "))
                @if !view.flags.is_empty() {
                    "; flags raised: " code { (view.flags.join(" ")) }
                }
            }
            "\n"
        }
    }
}

/// The table of every part's final verdict, flags, first detection and
/// meaning.
fn summary_table(plant: &Plant, r: &LogReplay, i: usize) -> Markup {
    let at = |t: Time| absolute(r.time, t);
    let rel = |t: Time| offset(t - r.start);
    html! {
        table class="summary" {
            "\n"
            thead {
                tr {
                    th { "part" } th { "verdict" } th { "labels" } th { "flags" }
                    th { "first detection" } th { "meaning" }
                }
            }
            "\n"
            tbody {
                "\n"
                @for s in r.summary.iter().take(plant.parts.len()) {
                    @let v = VerdictKind::name(s.verdict);
                    tr data-part=(s.part) data-log=(i)
                        data-zoom-log=[s.detected.map(|_| i)]
                        data-zoom-t=[s.detected.map(|t| tick_of(r, t))] {
                        td class="part" { a href={ "#log-" (i) "-" (s.part) } { (s.part) } }
                        td class="verdict" { span class={ "chip verdict-" (v) } { (v) } }
                        td class="labels" { (s.labels.join(" ")) }
                        td class="flags" { (s.flags.join(" ")) }
                        td class="detected" {
                            @if let Some(t) = s.detected {
                                (at(t)) " (" (rel(t)) ")"
                            } @else {
                                "—"
                            }
                        }
                        td class="meaning" {
                            @for (k, l) in s.labels.iter().enumerate() {
                                @if k > 0 { br; }
                                @if l == "N" { "no fault seen" } @else { (fault_meaning(plant, l)) }
                            }
                        }
                    }
                    "\n"
                }
            }
        }
        "\n"
    }
}

/// The timelines' zoom and pan buttons (`report.js` wires them), and why
/// nothing shows without scripts.
fn timeline_toolbar(i: usize) -> Markup {
    html! {
        div class="timeline-toolbar" data-log=(i) {
            button type="button" data-action="fit" title="whole log" { "fit" }
            button type="button" data-action="in" title="zoom in" { "+" }
            button type="button" data-action="out" title="zoom out" { "−" }
            button type="button" data-action="left" title="earlier" { "◀" }
            button type="button" data-action="right" title="later" { "▶" }
            span class="range" {}
            span class="hint" { "wheel: zoom · drag: pan · double-click: whole log" }
        }
        "\n"
        noscript {
            p class="warning" {
                "The timelines are drawn by the page's script: allow scripts to see them."
            }
        }
        "\n"
    }
}

/// Explanation ids, for links from the timeline data: detection k is
/// `x{i}-{k}`; explained trips are numbered after them.
fn explanation_ids(r: &LogReplay, i: usize) -> (Vec<String>, Vec<Option<String>>) {
    let detection_ids: Vec<String> = (0..r.detections.len())
        .map(|k| format!("x{i}-{k}"))
        .collect();
    let mut next_id = r.detections.len();
    let trip_ids: Vec<Option<String>> = r
        .trips
        .iter()
        .map(|t| {
            t.detail.as_ref().map(|_| {
                next_id += 1;
                format!("x{i}-{}", next_id - 1)
            })
        })
        .collect();
    (detection_ids, trip_ids)
}

/// Part `pi`'s section: its verdict and meaning, timeline, verdict changes and
/// explanations, with its timeline data.
fn part_section(
    p: &Page<'_>,
    r: &LogReplay,
    i: usize,
    pi: usize,
    part: &Part,
    detection_ids: &[String],
) -> (Markup, Value) {
    let plant = p.plant;
    let s = r.summary.get(pi);
    let pm = p.model.parts.iter().find(|m| m.name == part.name);
    let v = s.map_or("normal", |s| VerdictKind::name(s.verdict));
    let (verdicts, verdicts_data) = verdicts_table(r, i, pi, &part.name, detection_ids);
    let markup = html! {
        section class="part" id={ "log-" (i) "-" (part.name) } data-part=(part.name) data-log=(i) {
            "\n"
            h3 {
                (part.name) " " span class={ "chip verdict-" (v) } { (v) } " "
                span class="part-labels" { @if let Some(s) = s { (s.labels.join(" ")) } }
                @if let Some(s) = s.filter(|s| !s.flags.is_empty()) {
                    " " span class="part-flags" { (s.flags.join(" ")) }
                }
            }
            "\n"
            @if let Some(s) = s.filter(|s| s.verdict != VerdictKind::Normal) {
                ul class="meaning" {
                    @for l in &s.labels {
                        li { strong { (l) } ": " (fault_meaning(plant, l)) }
                    }
                }
                "\n"
            }
            div class="timeline-host" data-log=(i) data-part=(part.name) {}
            "\n"
            (verdicts)
            @for (k, d) in r.detections.iter().enumerate().filter(|(_, d)| d.part == pi) {
                (detection_article(p, r, i, &detection_ids[k], d, pm))
            }
            @if !p.pictures.is_empty() {
                p class="models-link" {
                    a href={ "#models-" (part.name) } {
                        "Learned model and diagnoser of " (part.name)
                    }
                }
                "\n"
            }
        }
        "\n"
    };
    let data = json!({
        "name": part.name,
        "verdict": v,
        "labels": s.map(|s| s.labels.clone()).unwrap_or_default(),
        "flags": s.map(|s| s.flags.clone()).unwrap_or_default(),
        "detected": s.and_then(|s| s.detected).map(|t| tick_of(r, t)),
        "signals": signals_data(plant, r, part, pm),
        "windows": pm.map_or(json!({}), |pm| windows(p.model, pm, r.tick)),
        "verdicts": verdicts_data,
    });
    (markup, data)
}

/// The part's verdict changes as a table, with their timeline data.
fn verdicts_table(
    r: &LogReplay,
    i: usize,
    pi: usize,
    part: &str,
    detection_ids: &[String],
) -> (Markup, Vec<Value>) {
    let at = |t: Time| absolute(r.time, t);
    let rel = |t: Time| offset(t - r.start);
    // Each change, with the id of its explanation when it is a detection.
    let verdicts: Vec<(&Verdict, Option<&String>)> = r
        .verdicts
        .iter()
        .filter(|v| v.part == part)
        .map(|v| {
            let explanation = r
                .detections
                .iter()
                .position(|d| {
                    d.part == pi
                        && d.verdict.t == v.t
                        && d.verdict.labels == v.labels
                        && d.verdict.verdict == v.verdict
                })
                .map(|k| &detection_ids[k]);
            (v, explanation)
        })
        .collect();
    let data = verdicts
        .iter()
        .map(|(v, explanation)| {
            json!({
                "t": tick_of(r, v.t),
                "verdict": VerdictKind::name(v.verdict),
                "labels": v.labels,
                "flags": v.flags,
                "reason": v.reason,
                "explanation": explanation,
            })
        })
        .collect();
    if verdicts.is_empty() {
        let quiet = html! {
            p class="quiet" { "No verdict change: the part behaved as learned all along." } "\n"
        };
        return (quiet, data);
    }
    let table = html! {
        table class="verdicts" {
            thead {
                tr { th { "time" } th { "verdict" } th { "labels" } th { "flags" } th { "why" } }
            }
            tbody {
                "\n"
                @for (v, explanation) in &verdicts {
                    @let vk = VerdictKind::name(v.verdict);
                    tr class={ "verdict-" (vk) } data-zoom-log=(i) data-zoom-t=(tick_of(r, v.t)) {
                        td { (at(v.t)) " " span class="rel" { (rel(v.t)) } }
                        td { span class={ "chip verdict-" (vk) } { (vk) } }
                        td { (v.labels.join(" ")) }
                        td { (v.flags.join(" ")) }
                        td {
                            (v.reason)
                            @if let Some(id) = explanation {
                                " " a href={ "#" (id) } { "explanation" }
                            }
                        }
                    }
                    "\n"
                }
            }
        }
        "\n"
    };
    (table, data)
}

/// The part's signals with their edges (in ticks since the previous edge),
/// for the timeline.
fn signals_data(plant: &Plant, r: &LogReplay, part: &Part, pm: Option<&PartModel>) -> Vec<Value> {
    let tick = r.tick;
    let signals = signal_names(plant, part, pm);
    signals
        .iter()
        .filter_map(|name| {
            let id = plant.signals.id(name)?;
            let sig = plant.signals.get(id);
            let mut prev = r.start;
            let edges: Vec<i64> = r.edges[id.index()]
                .iter()
                .map(|&t| {
                    let d = (t - prev) / tick;
                    prev += d * tick;
                    d
                })
                .collect();
            Some(json!({
                "name": name,
                "kind": if sig.kind == SignalKind::Actuator { "actuator" } else { "sensor" },
                "description": sig.description,
                "init": u8::from(r.initial.get(id.index()).copied().unwrap_or(false)),
                "edges": edges,
            }))
        })
        .collect()
}

/// The log's timeline data: its time form, parts, trips and rewrites.
fn log_data(r: &LogReplay, i: usize, parts_data: Vec<Value>, trip_ids: &[Option<String>]) -> Value {
    let tick = r.tick;
    let time = match r.time {
        TimeFormat::Numeric(unit) => json!({
            "kind": "numeric",
            "unit": unit.name(),
            "unit_ns": unit.nanos(),
            "start": r.start as f64 / unit.nanos() as f64,
        }),
        TimeFormat::Rfc3339 => json!({
            "kind": "rfc3339",
            "start_epoch_ms": r.start as f64 / 1e6,
        }),
    };
    json!({
        "index": i,
        "name": r.name,
        "tick_ns": tick,
        "duration": (r.end - r.start) / tick,
        "time": time,
        "parts": parts_data,
        "filter": {
            "trips": r.trips.iter().zip(trip_ids).map(|(t, id)| json!({
                "t": tick_of(r, t.t),
                "constraint": t.constraint,
                "literals": t.literals,
                "parts": t.parts,
                "explanation": id,
            })).collect::<Vec<_>>(),
            "rewrites": r.rewrites.iter().map(|w| json!({
                "t": tick_of(r, w.t),
                "flag": w.flag,
                "sensor": w.sensors.join(" "),
                "constraints": w.constraints.iter().map(|c| c.0.clone()).collect::<Vec<_>>(),
                "parts": w.parts,
            })).collect::<Vec<_>>(),
        },
    })
}

fn tick_of(r: &LogReplay, t: Time) -> i64 {
    ((t - r.start) as f64 / r.tick as f64).round() as i64
}

/// Per state of the part (its signals' values as `0`/`1` text), the sensor
/// events expected next and their windows on the command clock, in ticks.
fn windows(model: &Model, pm: &PartModel, tick: Time) -> Value {
    let scale = model.time_unit.nanos() as f64 / tick as f64;
    let mut out = serde_json::Map::new();
    for s in &pm.states {
        let key: String = s
            .values
            .iter()
            .map(|&v| if v { '1' } else { '0' })
            .collect();
        let mut list = Vec::new();
        let command = ModelClock::Command.to_string();
        for e in s.expected.iter().filter(|e| e.clock == command) {
            let Some(tr) = pm.transitions.get(e.transition).filter(|t| t.timed) else {
                continue;
            };
            let signal = e
                .event
                .split_whitespace()
                .next()
                .and_then(|first| first.split_once('('))
                .map(|(_, rest)| rest.trim_end_matches(')').to_string())
                .unwrap_or_default();
            list.push(json!({
                "signal": signal,
                "event": e.event,
                "lo": (tr.guard.lo * scale).floor() as i64,
                "hi": (tr.guard.hi * scale).ceil() as i64,
            }));
        }
        if !list.is_empty() {
            out.insert(key, Value::Array(list));
        }
    }
    Value::Object(out)
}

/// A part's signals in its model's order (actuators first), or the plant
/// file's when the model lacks the part.
fn signal_names(
    plant: &Plant,
    part: &diagnoser::plant::Part,
    pm: Option<&PartModel>,
) -> Vec<String> {
    match pm {
        Some(pm) => pm.signals.clone(),
        None => part
            .actuators
            .iter()
            .chain(&part.sensors)
            .map(|&s| plant.signals.name(s).to_string())
            .collect(),
    }
}

/// A table of signals: name, value, meaning; `marked` ones highlighted,
/// `changed` ones flagged.
fn state_table(
    plant: &Plant,
    names: &[String],
    values: &[bool],
    marked: &[String],
    before: Option<&[bool]>,
) -> Markup {
    html! {
        table class="state" {
            thead { tr { th { "signal" } th { "value" } th { "meaning" } } }
            tbody {
                @for (n, id) in names.iter().filter_map(|n| Some((n, plant.signals.id(n)?))) {
                    @let v = values.get(id.index()).copied().unwrap_or(false);
                    @let changed =
                        before.is_some_and(|b| b.get(id.index()).copied().unwrap_or(false) != v);
                    @let mark = marked.iter().any(|m| m == n);
                    tr class={
                        (if mark { "in-constraint" } else { "" })
                        (if changed { " changed" } else { "" })
                    } {
                        td { code { (n) } }
                        td class={ "value v" (u8::from(v)) } {
                            (u8::from(v))
                            @if changed { " " span class="was" { "(was " (u8::from(!v)) ")" } }
                        }
                        td { (description(plant, n)) }
                    }
                }
            }
        }
    }
}

/// The name of signal number `index`.
fn signal_name(plant: &Plant, index: usize) -> &str {
    plant.signals.name(SignalId(index as u32))
}

/// The last changes before `reference`, their edges `marked` or not.
fn changes_table(plant: &Plant, changes: &[Change], reference: Time, marked: &[String]) -> Markup {
    if changes.is_empty() {
        return html! { p class="quiet" { "No change of these signals since the log started." } };
    }
    html! {
        table class="changes" {
            thead { tr { th { "when" } th { "edges" } th { "meaning" } } }
            tbody {
                @for c in changes {
                    @let d = c.t - reference;
                    tr {
                        td { @if d == 0 { "at that scan" } @else { (duration(-d)) " before" } }
                        td {
                            @for (k, &(s, v)) in c.edges.iter().enumerate() {
                                @let name = signal_name(plant, s);
                                @if k > 0 { " " }
                                @if marked.iter().any(|m| m == name) {
                                    mark class="literal" { (edge(name, v)) }
                                } @else {
                                    code { (edge(name, v)) }
                                }
                            }
                        }
                        td {
                            @for (k, &(s, v)) in c.edges.iter().enumerate() {
                                @if k > 0 { "; " }
                                (description(plant, signal_name(plant, s)))
                                (if v { " (on)" } else { " (off)" })
                            }
                        }
                    }
                }
            }
        }
    }
}

fn vector_text(plant: &Plant, names: &[String], values: &[bool]) -> String {
    names
        .iter()
        .filter_map(|n| {
            let id = plant.signals.id(n)?;
            Some(format!(
                "{n}={}",
                u8::from(values.get(id.index()).copied().unwrap_or(false))
            ))
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The explanation of a detection, at seed 002's levels.
fn detection_article(
    p: &Page<'_>,
    r: &LogReplay,
    i: usize,
    id: &str,
    d: &Detection,
    pm: Option<&PartModel>,
) -> Markup {
    let plant = p.plant;
    let part = &plant.parts[d.part];
    let v = &d.verdict;
    let vk = VerdictKind::name(v.verdict);
    let names = signal_names(plant, part, pm);
    let before = vector_text(plant, &names, &d.before);
    let waited = duration(v.t - d.since);
    html! {
        article class={ "explanation detection verdict-" (vk) } id=(id) {
            "\n"
            h4 data-zoom-log=(i) data-zoom-t=(tick_of(r, v.t)) {
                (part.name) ": " (vk) " " (v.labels.join(", ")) " at " (absolute(r.time, v.t)) " "
                span class="rel" { (offset(v.t - r.start)) }
            }
            "\n"
            p class="reason" { (v.reason) }
            "\n"
            section class="level" data-level="0" {
                h5 { "Current state" }
                (state_table(plant, &names, &d.now, &[], Some(&d.before)))
                @if !v.flags.is_empty() {
                    p {
                        "Flags raised: " code { (v.flags.join(" ")) } ". The filter now reads the "
                        "flagged sensors' temporal estimates instead of their readings."
                    }
                }
            }
            "\n"
            section class="level" data-level="1" {
                h5 { "State before stop" }
                p {
                    @if d.by_scan {
                        "Before the scan that changed the verdict, the part was in "
                        code { (before) } ", entered " (waited) " earlier."
                    } @else {
                        "The part had been waiting in " code { (before) } " for " (waited)
                        " when the deadline passed."
                    }
                }
                (state_table(plant, &names, &d.before, &[], None))
            }
            "\n"
            section class="level" data-level="2" {
                h5 { "Advanced state: the last changes" }
                (changes_table(plant, &d.changes, v.t, &[]))
            }
            "\n"
            (detection_hypothesis(p, d, &names, pm))
            "\n"
        }
        "\n"
    }
}

/// A detection's last level: what the diagnoser saw, what the model expected
/// and the candidate faults.
fn detection_hypothesis(
    p: &Page<'_>,
    d: &Detection,
    names: &[String],
    pm: Option<&PartModel>,
) -> Markup {
    let plant = p.plant;
    let v = &d.verdict;
    html! {
        section class="level" data-level="3" {
            h5 { "Hypothesis" }
            ul {
                li { "What the diagnoser saw: " (v.reason) "." }
                @if let Some(pm) = pm { (expected_next(p, pm, names, &d.before)) }
                @for l in &v.labels {
                    li { "Candidate " strong { (l) } ": " (fault_meaning(plant, l)) "." }
                }
                @if v.verdict == VerdictKind::Ambiguous {
                    li {
                        "The candidates explain the observations equally well so far: later "
                        "events will tell them apart, or a check on the machine will."
                    }
                }
            }
        }
    }
}

/// What the learned model expects next in the state the part was in
/// (`before`), or that it never saw that state.
fn expected_next(p: &Page<'_>, pm: &PartModel, names: &[String], before: &[bool]) -> Markup {
    let key: Vec<bool> = names
        .iter()
        .map(|n| {
            p.plant
                .signals
                .id(n)
                .and_then(|id| before.get(id.index()).copied())
                .unwrap_or(false)
        })
        .collect();
    let Some(state) = pm.states.iter().find(|s| s.values == key) else {
        return html! { li { "That state was never seen while learning." } };
    };
    let expected: Vec<_> = state
        .expected
        .iter()
        .filter_map(|e| Some((e, pm.transitions.get(e.transition)?)))
        .collect();
    html! {
        @if !expected.is_empty() {
            li {
                "In that state, the learned model expects "
                @for (k, (e, tr)) in expected.iter().enumerate() {
                    @if k > 0 { ", or " }
                    code { (e.event) } " within [" (tr.guard.lo) ", " (tr.guard.hi) "] "
                    (p.model.time_unit.name()) " after "
                    (ModelClock::parse(&e.clock).map_or_else(|| e.clock.clone(), |c| c.since()))
                }
                "."
            }
        }
    }
}

/// The safety filter's part of a log: the flags that rewrote constraints, the
/// constraints that held, and the explanations of their first trips.
fn filter_section(p: &Page<'_>, r: &LogReplay, i: usize, ids: &[Option<String>]) -> Markup {
    let total: u64 = r.trip_counts.iter().map(|c| c.1).sum();
    html! {
        section class="filter" data-log=(i) {
            h3 { "Safety filter" }
            "\n"
            @if r.rewrites.is_empty() {
                p class="quiet" {
                    "No flag was raised: the constraints read the sensors as they are."
                }
                "\n"
            }
            @for w in &r.rewrites { (rewrite_article(p.coupling, r, i, w)) }
            @if total == 0 {
                p class="quiet" { "No safety constraint held in this log." }
                "\n"
            } @else {
                (trips_table(r, i, ids, total))
            }
            @for (t, id) in r.trips.iter().zip(ids) {
                @if let (Some(id), Some(detail)) = (id, &t.detail) {
                    (trip_article(p.plant, r, i, id, t, detail))
                }
            }
        }
        "\n"
    }
}

/// A flag raised, and the constraints it rewrote.
fn rewrite_article(coupling: Coupling, r: &LogReplay, i: usize, w: &Rewrite) -> Markup {
    html! {
        article class="rewrite" {
            h4 data-zoom-log=(i) data-zoom-t=(tick_of(r, w.t)) {
                code { (w.flag) } " raised at " (absolute(r.time, w.t)) " "
                span class="rel" { (offset(w.t - r.start)) }
            }
            @if w.constraints.is_empty() {
                p {
                    @if coupling == Coupling::None {
                        "The filter was replayed without coupling: the constraints still read "
                        "the sensors."
                    } @else if w.sensors.is_empty() {
                        "No constraint reads a sensor of this partition; the parts of "
                        (w.parts.join(", "))
                        " go to the fallback (their outputs forced to their safe values)."
                    } @else {
                        "No constraint reads the switched sensors."
                    }
                }
            } @else {
                p {
                    "From the next scan, " (w.sensors.join(", ")) " read"
                    @if w.sensors.len() == 1 { "s" }
                    " the temporal estimate instead of the sensor. The constraints so rewritten:"
                }
                table class="rewrites" {
                    thead {
                        tr { th { "constraint" } th { "as written" } th { "as evaluated now" } }
                    }
                    tbody {
                        @for (name, written, now) in &w.constraints {
                            tr {
                                td { code { (name) } }
                                td { code { (written) } }
                                td { code { (now) } }
                            }
                        }
                    }
                }
            }
        }
        "\n"
    }
}

/// How often each constraint started to hold, with a link to its first trip.
fn trips_table(r: &LogReplay, i: usize, ids: &[Option<String>], total: u64) -> Markup {
    html! {
        table class="trips" {
            thead {
                tr { th { "constraint" } th { "times it started to hold" } th { "first" } }
            }
            tbody {
                @for (name, n) in r.trip_counts.iter().filter(|c| c.1 > 0) {
                    tr {
                        td { code { (name) } }
                        td { (n) }
                        td {
                            @if let Some((t, id)) =
                                r.trips.iter().zip(ids).find(|(t, _)| &t.constraint == name)
                            {
                                a href={ "#" (id.as_deref().unwrap_or_default()) }
                                    data-zoom-log=(i) data-zoom-t=(tick_of(r, t.t)) {
                                    (absolute(r.time, t.t))
                                }
                            }
                        }
                    }
                }
            }
        }
        "\n"
        @if r.trips.len() > ids.iter().flatten().count() {
            p class="quiet" {
                "The first " (EXPLAINED_TRIPS) " trips of each constraint are explained below; all "
                (r.trips.len()) " are on the timelines"
                @if total > r.trips.len() as u64 { " (of " (total) ", the rest only counted)" }
                "."
            }
            "\n"
        }
    }
}

/// The explanation of a trip, at seed 002's levels.
fn trip_article(
    plant: &Plant,
    r: &LogReplay,
    i: usize,
    id: &str,
    t: &Trip,
    detail: &TripDetail,
) -> Markup {
    let written = plant.constraints.iter().find(|c| c.name == t.constraint);
    let signals = constraint_signals(plant, written);
    let literal_names = literal_names(&t.literals);
    let actions: Vec<String> = t
        .literals
        .iter()
        .filter_map(|l| filter_action(plant, l))
        .collect();
    let after = after_filter(plant, &detail.now, &t.literals);
    html! {
        article class="explanation trip" id=(id) {
            "\n"
            h4 data-zoom-log=(i) data-zoom-t=(tick_of(r, t.t)) {
                (t.constraint) " held at " (absolute(r.time, t.t)) " "
                span class="rel" { (offset(t.t - r.start)) }
            }
            "\n"
            p class="constraint" { code { (highlight(&t.evaluated, &t.literals)) } }
            "\n"
            @if let Some(c) = written.filter(|c| c.expr.to_string() != t.evaluated) {
                p class="quiet" {
                    "As written in the plant file: " code { (c.expr) } "; the flags raised ("
                    code { (detail.flags.join(" ")) } ") rewrote it."
                }
            }
            section class="level" data-level="0" {
                h5 { "Current state" }
                p {
                    "The filter "
                    @if actions.is_empty() { "sends the plant to the fallback" }
                    @else { (actions.join("; ")) }
                    "."
                }
                (state_table(plant, &signals, &after, &[], Some(&detail.now)))
            }
            "\n"
            section class="level" data-level="1" {
                h5 { "Projection" }
                p {
                    "Without the filter, the orders would have gone out in the forbidden situation "
                    (t.constraint) ": " (situation(plant, t).join(", ")) "."
                }
            }
            "\n"
            section class="level" data-level="2" {
                h5 { "State before stop" }
                p {
                    "The scan in which the constraint held; its elements are marked, and changes "
                    "from the scan before are shown."
                }
                (state_table(plant, &signals, &detail.now, &literal_names, Some(&detail.before)))
            }
            "\n"
            section class="level" data-level="3" {
                h5 { "Advanced state: the last changes" }
                (changes_table(plant, &detail.changes, t.t, &literal_names))
            }
            "\n"
            (trip_hypothesis(plant, t, detail, &signals, &actions))
            "\n"
        }
        "\n"
    }
}

/// The signals constraint `written` reads, sorted, once each.
fn constraint_signals(plant: &Plant, written: Option<&Constraint>) -> Vec<String> {
    let mut read: Vec<String> = written
        .map(|c| c.expr.names().into_iter().map(str::to_string).collect())
        .unwrap_or_default();
    read.sort();
    read.dedup();
    read.iter()
        .filter(|n| plant.signals.id(n).is_some())
        .cloned()
        .collect()
}

/// The names the literals are about (`!RE(x)` is about `x`).
fn literal_names(literals: &[String]) -> Vec<String> {
    literals
        .iter()
        .map(|l| {
            let l = l.trim_start_matches('!');
            l.split_once('(')
                .map_or(l, |(_, rest)| rest.trim_end_matches(')'))
                .to_string()
        })
        .collect()
}

/// The current state once the filter acted: each order the constraint
/// forbids (its `literals`) put back to its safe value.
fn after_filter(plant: &Plant, now: &[bool], literals: &[String]) -> Vec<bool> {
    let mut after = now.to_vec();
    for l in literals {
        let (negated, body) = l
            .strip_prefix('!')
            .map_or((false, l.as_str()), |b| (true, b));
        let (name, safe) =
            if let Some(a) = body.strip_prefix("RE(").and_then(|b| b.strip_suffix(')')) {
                (a, false)
            } else if let Some(a) = body.strip_prefix("FE(").and_then(|b| b.strip_suffix(')')) {
                (a, true)
            } else {
                (body, negated)
            };
        if let Some(id) = plant.signals.id(name)
            && plant.signals.get(id).kind == SignalKind::Actuator
            && let Some(v) = after.get_mut(id.index())
        {
            *v = safe;
        }
    }
    after
}

/// The literals of trip `t` in words, estimated ones saying so.
fn situation(plant: &Plant, t: &Trip) -> Vec<String> {
    t.literals
        .iter()
        .zip(&t.estimated)
        .map(|(l, est)| match est {
            Some(sensor) => format!(
                "{l} ({} by the temporal estimate of {sensor}, {})",
                if l.starts_with('!') { "off" } else { "on" },
                description(plant, sensor)
            ),
            None => literal_words(plant, l),
        })
        .collect()
}

/// A trip's last level, after seed 002: which sensor changes may have led the
/// control program to the forbidden orders.
fn trip_hypothesis(
    plant: &Plant,
    t: &Trip,
    detail: &TripDetail,
    signals: &[String],
    actions: &[String],
) -> Markup {
    let last: Option<&Change> = detail.changes.last().filter(|c| c.t == t.t);
    let recent: Vec<&Change> = detail.changes.iter().rev().take(3).collect();
    let mut inside = Vec::new();
    let mut outside = Vec::new();
    for c in &recent {
        for &(s, v) in &c.edges {
            let name = signal_name(plant, s);
            if plant.signals.get(SignalId(s as u32)).kind != SignalKind::Sensor {
                continue;
            }
            let text = edge(name, v);
            if signals.iter().any(|n| n == name) {
                inside.push(text);
            } else {
                outside.push(text);
            }
        }
    }
    html! {
        section class="level" data-level="4" {
            h5 { "Hypothesis" }
            ul {
                @if !inside.is_empty() {
                    li {
                        "Sensors of the constraint changed just before: "
                        code { (inside.join(" ")) }
                        ". The control program may not have taken them into account to change "
                        "its outputs."
                    }
                }
                @if !outside.is_empty() {
                    li {
                        "Sensors outside the constraint changed just before: "
                        code { (outside.join(" ")) } ". One of them may have made the program "
                        "change an output the constraint reads (a wrong receptivity)."
                    }
                }
                @if inside.is_empty() && outside.is_empty() {
                    li {
                        "No sensor changed just before: the orders may come from inside the PLC "
                        "(a timer, a memory)."
                    }
                }
                @if last.is_none() {
                    li {
                        "Nothing changed in this very scan: the constraint started to hold as "
                        "time passed (an estimate's interval or a flag)."
                    }
                }
                @if !actions.is_empty() {
                    li {
                        "Expected of the control program: what the filter did, "
                        (actions.join("; ")) "."
                    }
                }
            }
        }
    }
}

/// The pictures of every part's learned model and diagnoser, if drawn.
fn models_section(p: &Page<'_>) -> Markup {
    if p.pictures.is_empty() {
        return html! {};
    }
    html! {
        section class="models" id="models" {
            h2 { "Models" }
            "\n"
            p class="meta" {
                "Learned models: states are the observed vectors of a part's signals (double "
                "border: the part waits there for a command); transitions carry the learned "
                "window on their clock. Diagnosers: each state holds the candidate fault labels "
                "(red: one fault certain, amber: ambiguous)."
            }
            "\n"
            @for pics in p.pictures {
                // Closed by default: a large diagnoser is laid out only when opened.
                details class="part-models" id={ "models-" (pics.part) } {
                    summary { h3 { (pics.part) } }
                    "\n"
                    @let drawn = [("learned model", &pics.model), ("diagnoser", &pics.diagnoser)];
                    @for (what, pic) in drawn {
                        @if let Some(pic) = pic {
                            figure class="model-picture" {
                                // Safe as it is: SVG whose text `pictures` or Graphviz escaped.
                                (PreEscaped(&pic.svg))
                                figcaption { (what) " of " (pics.part) " (" (pic.by) ")" }
                            }
                            "\n"
                        }
                    }
                    @if let Some(note) = &pics.note { p class="quiet" { (note) } "\n" }
                }
                "\n"
            }
        }
        "\n"
    }
}

#[cfg(test)]
mod tests {
    use diagnoser::Plant;

    use super::*;
    use crate::fixtures::{learned, replay, sorting};

    /// Markup, quotes and ampersands where the plant file, the log and the
    /// diagnosers put free text.
    const PLANT: &str = "<script>alert('plant')</script>";
    const PART: &str = "turn<script>alert('part')</script>\"table\" & 'co'";
    const DESCRIPTION: &str = "<script>alert(1)</script> \"at\" 'unloading' & position";
    const REASON: &str = "<!--<script>alert(1)</script> \"stuck\" & 'late'";
    const PATH: &str = "<script>alert('path')</script>/plant.toml";

    /// `text` as it must reach the page: every character that could start or
    /// end markup, or an attribute value, as a character reference.
    fn escaped(text: &str) -> String {
        text.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
            .replace('"', "&quot;")
    }

    /// `text` as a TOML basic string's content.
    fn toml(text: &str) -> String {
        text.replace('\\', "\\\\").replace('"', "\\\"")
    }

    /// The sorting line with markup in its name, its turntable's name and
    /// C5's description.
    fn hostile_plant() -> Plant {
        let path = sorting("normal").join("plant.toml");
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{e}"));
        let text = text
            .replacen(
                "name = \"sorting\"",
                &format!("name = \"{}\"", toml(PLANT)),
                1,
            )
            .replacen(
                "name = \"turntable\"",
                &format!("name = \"{}\"", toml(PART)),
                1,
            )
            .replacen(
                "description = \"turntable at unloading position\"",
                &format!("description = \"{}\"", toml(DESCRIPTION)),
                1,
            );
        let plant = Plant::parse(&text, &path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(plant.name, PLANT);
        assert!(plant.parts.iter().any(|p| p.name == PART));
        plant
    }

    #[test]
    fn markup_in_the_inputs_stays_text() {
        let plant = hostile_plant();
        let model = learned(&plant);
        // F4 (C5 stuck at 1): the turntable's detection prints C5's description
        // and the verdict's reason in its explanation.
        let mut r = replay(&plant, &model, "F4");
        let turntable = plant.parts.iter().position(|p| p.name == PART);
        assert!(r.detections.iter().any(|d| Some(d.part) == turntable));
        for v in r
            .verdicts
            .iter_mut()
            .chain(r.detections.iter_mut().map(|d| &mut d.verdict))
        {
            v.reason = REASON.to_string();
        }
        let options = DiagnoserOptions::default();
        let pictures =
            pictures(&plant, &model, &options, Layout::BuiltIn).unwrap_or_else(|e| panic!("{e}"));
        let html = page(&Page {
            plant: &plant,
            model: &model,
            plant_path: Path::new(PATH),
            model_path: Path::new("model.json"),
            coupling: Coupling::Flags,
            replays: &[r],
            pictures: &pictures,
        });

        // No script from the inputs anywhere: not in the markup, the data or
        // the pictures.
        assert!(!html.contains("<script>alert"), "a script from the inputs");
        // The markup is printed as text wherever the page shows it.
        let (markup, rest) = html
            .split_once("<script type=\"application/json\" id=\"gardefou-data\">")
            .expect("the timeline data");
        for text in [PLANT, PART, DESCRIPTION, REASON, PATH] {
            assert!(markup.contains(&escaped(text)), "{text} not shown");
        }
        assert!(!markup.contains("<script"), "a script tag from the inputs");
        // The timeline data ends where the page ends it, whole: no text in it
        // closes the element.
        let (data, rest) = rest.split_once("</script>").expect("the data's end");
        // No `<` at all: neither `</script>` nor `<!--` (which would make a
        // browser look past the element's end) can occur in the data.
        assert!(!data.contains('<'), "markup in the timeline data");
        let data: Value = serde_json::from_str(data).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(data["plant"], PLANT);
        let part = data["logs"][0]["parts"]
            .as_array()
            .and_then(|parts| parts.iter().find(|p| p["name"] == PART))
            .expect("the turntable's data");
        assert!(
            part["signals"]
                .as_array()
                .is_some_and(|s| s.iter().any(|s| s["description"] == DESCRIPTION))
        );
        assert!(
            part["verdicts"]
                .as_array()
                .is_some_and(|v| !v.is_empty() && v.iter().all(|v| v["reason"] == REASON))
        );
        // Then only the page's own script, and the pictures, which name the part.
        let models = rest
            .strip_prefix(&format!("\n<script>\n{JS}\n</script>"))
            .expect("the page's script");
        assert!(models.contains(&escaped(PART)));
        assert!(!models.contains("<script"), "a script tag from the inputs");
    }

    /// Every element the page opens is closed as often, outside the inline
    /// script and data, which hold no markup of the page's own.
    #[test]
    fn every_element_opened_is_closed() {
        let plant =
            Plant::from_path(&sorting("F4").join("plant.toml")).unwrap_or_else(|e| panic!("{e}"));
        let model = learned(&plant);
        let r = replay(&plant, &model, "F4");
        let options = DiagnoserOptions::default();
        let pictures =
            pictures(&plant, &model, &options, Layout::BuiltIn).unwrap_or_else(|e| panic!("{e}"));
        let html = page(&Page {
            plant: &plant,
            model: &model,
            plant_path: Path::new("plant.toml"),
            model_path: Path::new("model.json"),
            coupling: Coupling::Flags,
            replays: &[r],
            pictures: &pictures,
        });
        let markup = html.split("<script").next().unwrap_or_default();
        for tag in [
            "table", "tbody", "tr", "section", "article", "ul", "svg", "g", "p",
        ] {
            let opened = markup.matches(&format!("<{tag}>")).count()
                + markup.matches(&format!("<{tag} ")).count();
            let closed = markup.matches(&format!("</{tag}>")).count();
            assert_eq!(opened, closed, "<{tag}>: {opened} opened, {closed} closed");
        }
    }
}
