//! The report page: summary, timelines' data, explanations and pictures.
//!
//! The page is written as one string. Timelines are drawn in the browser from
//! the embedded data (`report.js`), so that a day-long log zooms from the whole
//! day down to single scans without the file holding one picture per zoom.

use std::fmt::Write;
use std::path::Path;

use diagnoser::diagnosis::compile::Compiled;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict, VerdictKind};
use diagnoser::model::{Model, ModelClock, PartModel};
use diagnoser::plant::{Constraint, Part};
use diagnoser::{Plant, SignalKind, Time, TimeFormat};
use filter_coupling::filter::Coupling;
use serde_json::{Value, json};

use super::collect::{Change, Detection, LogReplay, Trip, TripDetail};
use super::pictures::{self, Layout, Picture};
use super::words::{
    absolute, description, duration, edge, escape, fault_meaning, filter_action, highlight,
    literal_words, offset,
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
    for (k, engine) in diagnoser.engines().iter().enumerate() {
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
    let mut h = String::with_capacity(1 << 20);
    let title = format!("Fault review: {}", p.plant.name);
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <meta name=\"generator\" content=\"gardefou {}\">\n<title>{}</title>\n<style>\n{CSS}\n</style>\n</head>\n<body>\n",
        env!("CARGO_PKG_VERSION"),
        escape(&title)
    );
    let _ = writeln!(
        h,
        "<header class=\"report-header\"><h1>{}</h1>\n<p class=\"meta\">Plant file <code>{}</code>; model <code>{}</code> (learned from {} over {}); the safety filter replayed with coupling <code>{}</code>{}.</p>",
        escape(&title),
        escape(&p.plant_path.display().to_string()),
        escape(&p.model_path.display().to_string()),
        escape(&p.model.learned_from.logs.join(", ")),
        duration((p.model.learned_from.duration * p.model.time_unit.nanos() as f64) as Time),
        p.coupling.name(),
        match p.coupling {
            Coupling::None => ": constraints read the sensors as they are",
            Coupling::Flags => ": a def_ flag switches a failed sensor to its temporal estimate",
            Coupling::FlagsAndSuspects =>
                ": def_ and suspect_ flags switch sensors to their temporal estimates",
        }
    );
    if p.replays.len() > 1 {
        h.push_str("<nav class=\"logs\"><ul>");
        for (i, r) in p.replays.iter().enumerate() {
            let _ = write!(
                h,
                "<li><a href=\"#log-{i}\">{}</a> — {}</li>",
                escape(&r.name),
                escape(&plant_line(r))
            );
        }
        h.push_str("</ul></nav>");
    }
    h.push_str("</header>\n<main>\n");
    let mut data_logs = Vec::new();
    for (i, r) in p.replays.iter().enumerate() {
        data_logs.push(log_section(&mut h, p, i, r));
    }
    // The timelines are drawn before the browser reads the (large, folded)
    // model pictures, so that the page is usable as soon as possible.
    let data = json!({ "plant": p.plant.name, "logs": data_logs });
    // Inside a script element, `</script>` would end it and `<!--` would make
    // the browser look for its end elsewhere: JSON may write every `<` as
    // `\u003c` (it only occurs inside strings), and then neither can occur.
    let text = data.to_string().replace('<', "\\u003c");
    let _ = writeln!(
        h,
        "<script type=\"application/json\" id=\"gardefou-data\">{text}</script>\n<script>\n{JS}\n</script>"
    );
    models_section(&mut h, p);
    h.push_str("</main>\n</body>\n</html>\n");
    h
}

fn plant_line(r: &LogReplay) -> String {
    match r.summary.last() {
        Some(s) if s.verdict != VerdictKind::Normal => {
            format!("{} {}", VerdictKind::name(s.verdict), s.labels.join(", "))
        }
        _ => "normal".to_string(),
    }
}

/// The section of one log; returns its timeline data.
fn log_section(h: &mut String, p: &Page<'_>, i: usize, r: &LogReplay) -> Value {
    log_header(h, r, i);
    summary_table(h, p.plant, r, i);
    let _ = writeln!(
        h,
        "<div class=\"timeline-toolbar\" data-log=\"{i}\"><button type=\"button\" data-action=\"fit\" title=\"whole log\">fit</button><button type=\"button\" data-action=\"in\" title=\"zoom in\">+</button><button type=\"button\" data-action=\"out\" title=\"zoom out\">−</button><button type=\"button\" data-action=\"left\" title=\"earlier\">◀</button><button type=\"button\" data-action=\"right\" title=\"later\">▶</button><span class=\"range\"></span><span class=\"hint\">wheel: zoom · drag: pan · double-click: whole log</span></div>\n<noscript><p class=\"warning\">The timelines are drawn by the page's script: allow scripts to see them.</p></noscript>"
    );
    let (detection_ids, trip_ids) = explanation_ids(r, i);
    let parts_data: Vec<Value> = p
        .plant
        .parts
        .iter()
        .enumerate()
        .map(|(pi, part)| part_section(h, p, r, i, pi, part, &detection_ids))
        .collect();
    // The safety filter.
    filter_section(h, p, r, i, &trip_ids);
    h.push_str("</section>\n");
    log_data(r, i, parts_data, &trip_ids)
}

/// The log's heading: its name, span and events, and the whole plant's view.
fn log_header(h: &mut String, r: &LogReplay, i: usize) {
    let at = |t: Time| absolute(r.time, t);
    let _ = writeln!(
        h,
        "<section class=\"log\" id=\"log-{i}\" data-log=\"{i}\">\n<h2>{}</h2>\n<p class=\"meta\">From {} to {} ({}), {} events.</p>",
        escape(&r.name),
        escape(&at(r.start)),
        escape(&at(r.end)),
        duration(r.end - r.start),
        r.events
    );
    if let Some(view) = r.summary.last() {
        let _ = writeln!(
            h,
            "<p class=\"plant-view verdict-{v}\">Whole plant: <strong>{v}</strong> {}{}</p>",
            escape(&view.labels.join(", ")),
            if view.flags.is_empty() {
                String::new()
            } else {
                format!(
                    "; flags raised: <code>{}</code>",
                    escape(&view.flags.join(" "))
                )
            },
            v = VerdictKind::name(view.verdict),
        );
    }
}

/// The table of every part's final verdict, flags, first detection and
/// meaning.
fn summary_table(h: &mut String, plant: &Plant, r: &LogReplay, i: usize) {
    let at = |t: Time| absolute(r.time, t);
    let rel = |t: Time| offset(t - r.start);
    h.push_str(
        "<table class=\"summary\">\n<thead><tr><th>part</th><th>verdict</th><th>labels</th><th>flags</th><th>first detection</th><th>meaning</th></tr></thead>\n<tbody>\n",
    );
    for s in r.summary.iter().take(plant.parts.len()) {
        let meaning: Vec<String> = s
            .labels
            .iter()
            .map(|l| {
                if l == "N" {
                    "no fault seen".to_string()
                } else {
                    fault_meaning(plant, l)
                }
            })
            .collect();
        let _ = writeln!(
            h,
            "<tr data-part=\"{part}\" data-log=\"{i}\"{zoom}><td class=\"part\"><a href=\"#log-{i}-{part}\">{part}</a></td><td class=\"verdict\"><span class=\"chip verdict-{v}\">{v}</span></td><td class=\"labels\">{}</td><td class=\"flags\">{}</td><td class=\"detected\">{}</td><td class=\"meaning\">{}</td></tr>",
            escape(&s.labels.join(" ")),
            escape(&s.flags.join(" ")),
            s.detected.map_or("—".to_string(), |t| format!(
                "{} ({})",
                escape(&at(t)),
                rel(t)
            )),
            meaning
                .iter()
                .map(|m| escape(m))
                .collect::<Vec<_>>()
                .join("<br>"),
            part = escape(&s.part),
            v = VerdictKind::name(s.verdict),
            zoom = s.detected.map_or(String::new(), |t| format!(
                " data-zoom-log=\"{i}\" data-zoom-t=\"{}\"",
                tick_of(r, t)
            )),
        );
    }
    h.push_str("</tbody></table>\n");
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
/// explanations. Returns its timeline data.
fn part_section(
    h: &mut String,
    p: &Page<'_>,
    r: &LogReplay,
    i: usize,
    pi: usize,
    part: &Part,
    detection_ids: &[String],
) -> Value {
    let plant = p.plant;
    let tick = r.tick;
    let s = r.summary.get(pi);
    let pm = p.model.parts.iter().find(|m| m.name == part.name);
    let _ = writeln!(
        h,
        "<section class=\"part\" id=\"log-{i}-{name}\" data-part=\"{name}\" data-log=\"{i}\">\n<h3>{name} <span class=\"chip verdict-{v}\">{v}</span> <span class=\"part-labels\">{labels}</span>{flags}</h3>",
        name = escape(&part.name),
        v = s.map_or("normal", |s| VerdictKind::name(s.verdict)),
        labels = escape(&s.map_or(String::new(), |s| s.labels.join(" "))),
        flags = s
            .filter(|s| !s.flags.is_empty())
            .map_or(String::new(), |s| format!(
                " <span class=\"part-flags\">{}</span>",
                escape(&s.flags.join(" "))
            )),
    );
    if let Some(s) = s.filter(|s| s.verdict != VerdictKind::Normal) {
        h.push_str("<ul class=\"meaning\">");
        for l in &s.labels {
            let _ = write!(
                h,
                "<li><strong>{}</strong>: {}</li>",
                escape(l),
                escape(&fault_meaning(plant, l))
            );
        }
        h.push_str("</ul>\n");
    }
    let _ = writeln!(
        h,
        "<div class=\"timeline-host\" data-log=\"{i}\" data-part=\"{}\"></div>",
        escape(&part.name)
    );
    let verdicts_data = verdicts_table(h, r, i, pi, &part.name, detection_ids);
    // Explanations of its detections.
    for (k, d) in r
        .detections
        .iter()
        .enumerate()
        .filter(|(_, d)| d.part == pi)
    {
        detection_article(h, p, r, i, &detection_ids[k], d, pm);
    }
    let signals_data = signals_data(plant, r, part, pm);
    let data = json!({
        "name": part.name,
        "verdict": s.map_or("normal", |s| VerdictKind::name(s.verdict)),
        "labels": s.map(|s| s.labels.clone()).unwrap_or_default(),
        "flags": s.map(|s| s.flags.clone()).unwrap_or_default(),
        "detected": s.and_then(|s| s.detected).map(|t| tick_of(r, t)),
        "signals": signals_data,
        "windows": pm.map_or(json!({}), |pm| windows(p.model, pm, tick)),
        "verdicts": verdicts_data,
    });
    if !p.pictures.is_empty() {
        let _ = writeln!(
            h,
            "<p class=\"models-link\"><a href=\"#models-{}\">Learned model and diagnoser of {}</a></p>",
            escape(&part.name),
            escape(&part.name)
        );
    }
    h.push_str("</section>\n");
    data
}

/// The part's verdict changes as a table; returns them as timeline data.
fn verdicts_table(
    h: &mut String,
    r: &LogReplay,
    i: usize,
    pi: usize,
    part: &str,
    detection_ids: &[String],
) -> Vec<Value> {
    let at = |t: Time| absolute(r.time, t);
    let rel = |t: Time| offset(t - r.start);
    // Verdict changes.
    let verdicts: Vec<&Verdict> = r.verdicts.iter().filter(|v| v.part == part).collect();
    let mut verdicts_data = Vec::new();
    if verdicts.is_empty() {
        h.push_str(
            "<p class=\"quiet\">No verdict change: the part behaved as learned all along.</p>\n",
        );
    } else {
        h.push_str("<table class=\"verdicts\"><thead><tr><th>time</th><th>verdict</th><th>labels</th><th>flags</th><th>why</th></tr></thead><tbody>\n");
        for v in &verdicts {
            let explanation = r
                .detections
                .iter()
                .position(|d| {
                    d.part == pi
                        && d.verdict.t == v.t
                        && d.verdict.labels == v.labels
                        && d.verdict.verdict == v.verdict
                })
                .map(|k| detection_ids[k].clone());
            let _ = writeln!(
                h,
                "<tr class=\"verdict-{vk}\" data-zoom-log=\"{i}\" data-zoom-t=\"{tk}\"><td>{} <span class=\"rel\">{}</span></td><td><span class=\"chip verdict-{vk}\">{vk}</span></td><td>{}</td><td>{}</td><td>{}{}</td></tr>",
                escape(&at(v.t)),
                rel(v.t),
                escape(&v.labels.join(" ")),
                escape(&v.flags.join(" ")),
                escape(&v.reason),
                explanation.as_ref().map_or(String::new(), |id| format!(
                    " <a href=\"#{id}\">explanation</a>"
                )),
                vk = VerdictKind::name(v.verdict),
                tk = tick_of(r, v.t),
            );
            verdicts_data.push(json!({
                "t": tick_of(r, v.t),
                "verdict": VerdictKind::name(v.verdict),
                "labels": v.labels,
                "flags": v.flags,
                "reason": v.reason,
                "explanation": explanation,
            }));
        }
        h.push_str("</tbody></table>\n");
    }
    verdicts_data
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
) -> String {
    let mut t = String::from(
        "<table class=\"state\"><thead><tr><th>signal</th><th>value</th><th>meaning</th></tr></thead><tbody>",
    );
    for n in names {
        let Some(id) = plant.signals.id(n) else {
            continue;
        };
        let v = values.get(id.index()).copied().unwrap_or(false);
        let changed = before.is_some_and(|b| b.get(id.index()).copied().unwrap_or(false) != v);
        let mark = marked.iter().any(|m| m == n);
        let _ = write!(
            t,
            "<tr class=\"{}{}\"><td><code>{}</code></td><td class=\"value v{}\">{}{}</td><td>{}</td></tr>",
            if mark { "in-constraint" } else { "" },
            if changed { " changed" } else { "" },
            escape(n),
            u8::from(v),
            u8::from(v),
            if changed {
                " <span class=\"was\">(was ".to_string() + if v { "0" } else { "1" } + ")</span>"
            } else {
                String::new()
            },
            escape(description(plant, n))
        );
    }
    t.push_str("</tbody></table>");
    t
}

fn changes_table(plant: &Plant, changes: &[Change], reference: Time, marked: &[String]) -> String {
    if changes.is_empty() {
        return "<p class=\"quiet\">No change of these signals since the log started.</p>"
            .to_string();
    }
    let mut t = String::from(
        "<table class=\"changes\"><thead><tr><th>when</th><th>edges</th><th>meaning</th></tr></thead><tbody>",
    );
    for c in changes {
        let edges: Vec<String> = c
            .edges
            .iter()
            .map(|&(i, v)| {
                let name = plant.signals.name(diagnoser::SignalId(i as u32));
                let text = edge(name, v);
                if marked.iter().any(|m| m == name) {
                    format!("<mark class=\"literal\">{}</mark>", escape(&text))
                } else {
                    format!("<code>{}</code>", escape(&text))
                }
            })
            .collect();
        let meaning: Vec<String> = c
            .edges
            .iter()
            .map(|&(i, v)| {
                let name = plant.signals.name(diagnoser::SignalId(i as u32));
                format!(
                    "{} {}",
                    escape(description(plant, name)),
                    if v { "(on)" } else { "(off)" }
                )
            })
            .collect();
        let d = c.t - reference;
        let _ = write!(
            t,
            "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
            if d == 0 {
                "at that scan".to_string()
            } else {
                format!("{} before", duration(-d))
            },
            edges.join(" "),
            meaning.join("; ")
        );
    }
    t.push_str("</tbody></table>");
    t
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

fn detection_article(
    h: &mut String,
    p: &Page<'_>,
    r: &LogReplay,
    i: usize,
    id: &str,
    d: &Detection,
    pm: Option<&PartModel>,
) {
    let plant = p.plant;
    let part = &plant.parts[d.part];
    let v = &d.verdict;
    let names = signal_names(plant, part, pm);
    let _ = writeln!(
        h,
        "<article class=\"explanation detection verdict-{vk}\" id=\"{id}\">\n<h4 data-zoom-log=\"{i}\" data-zoom-t=\"{tk}\">{part}: {vk} {labels} at {when} <span class=\"rel\">{rel}</span></h4>\n<p class=\"reason\">{reason}</p>",
        vk = VerdictKind::name(v.verdict),
        tk = tick_of(r, v.t),
        part = escape(&part.name),
        labels = escape(&v.labels.join(", ")),
        when = escape(&absolute(r.time, v.t)),
        rel = offset(v.t - r.start),
        reason = escape(&v.reason),
    );
    // Level 0: current state.
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"0\"><h5>Current state</h5>{}{}</section>",
        state_table(plant, &names, &d.now, &[], Some(&d.before)),
        if v.flags.is_empty() {
            String::new()
        } else {
            format!(
                "<p>Flags raised: <code>{}</code>. The filter now reads the flagged sensors' temporal estimates instead of their readings.</p>",
                escape(&v.flags.join(" "))
            )
        }
    );
    // Level 1: the state before stop.
    let before_text = vector_text(plant, &names, &d.before);
    let waited = if d.by_scan {
        format!(
            "Before the scan that changed the verdict, the part was in <code>{}</code>, entered {} earlier.",
            escape(&before_text),
            duration(v.t - d.since)
        )
    } else {
        format!(
            "The part had been waiting in <code>{}</code> for {} when the deadline passed.",
            escape(&before_text),
            duration(v.t - d.since)
        )
    };
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"1\"><h5>State before stop</h5><p>{waited}</p>{}</section>",
        state_table(plant, &names, &d.before, &[], None)
    );
    // Level 2: advanced state, the last changes.
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"2\"><h5>Advanced state: the last changes</h5>{}</section>",
        changes_table(plant, &d.changes, v.t, &[])
    );
    // Level 3: hypothesis.
    h.push_str("<section class=\"level\" data-level=\"3\"><h5>Hypothesis</h5><ul>");
    let _ = write!(h, "<li>What the diagnoser saw: {}.</li>", escape(&v.reason));
    if let Some(pm) = pm {
        let key: Vec<bool> = names
            .iter()
            .map(|n| {
                plant
                    .signals
                    .id(n)
                    .and_then(|id| d.before.get(id.index()).copied())
                    .unwrap_or(false)
            })
            .collect();
        if let Some(state) = pm.states.iter().find(|s| s.values == key) {
            let expected: Vec<String> = state
                .expected
                .iter()
                .filter_map(|e| {
                    let tr = pm.transitions.get(e.transition)?;
                    Some(format!(
                        "<code>{}</code> within [{}, {}] {} after {}",
                        escape(&e.event),
                        tr.guard.lo,
                        tr.guard.hi,
                        p.model.time_unit.name(),
                        ModelClock::parse(&e.clock)
                            .map_or(escape(&e.clock), |c| escape(&c.since()))
                    ))
                })
                .collect();
            if !expected.is_empty() {
                let _ = write!(
                    h,
                    "<li>In that state, the learned model expects {}.</li>",
                    expected.join(", or ")
                );
            }
        } else {
            h.push_str("<li>That state was never seen while learning.</li>");
        }
    }
    for l in &v.labels {
        let _ = write!(
            h,
            "<li>Candidate <strong>{}</strong>: {}.</li>",
            escape(l),
            escape(&fault_meaning(plant, l))
        );
    }
    if v.verdict == VerdictKind::Ambiguous {
        h.push_str("<li>The candidates explain the observations equally well so far: later events will tell them apart, or a check on the machine will.</li>");
    }
    h.push_str("</ul></section>\n</article>\n");
}

fn filter_section(h: &mut String, p: &Page<'_>, r: &LogReplay, i: usize, ids: &[Option<String>]) {
    let plant = p.plant;
    let total: u64 = r.trip_counts.iter().map(|c| c.1).sum();
    let _ = writeln!(
        h,
        "<section class=\"filter\" data-log=\"{i}\"><h3>Safety filter</h3>"
    );
    if r.rewrites.is_empty() {
        h.push_str("<p class=\"quiet\">No flag was raised: the constraints read the sensors as they are.</p>\n");
    }
    for w in &r.rewrites {
        let _ = write!(
            h,
            "<article class=\"rewrite\"><h4 data-zoom-log=\"{i}\" data-zoom-t=\"{}\"><code>{}</code> raised at {} <span class=\"rel\">{}</span></h4>",
            tick_of(r, w.t),
            escape(&w.flag),
            escape(&absolute(r.time, w.t)),
            offset(w.t - r.start)
        );
        if w.constraints.is_empty() {
            let _ = write!(
                h,
                "<p>{}</p>",
                if p.coupling == Coupling::None {
                    "The filter was replayed without coupling: the constraints still read the sensors.".to_string()
                } else if w.sensors.is_empty() {
                    format!(
                        "No constraint reads a sensor of this partition; the parts of {} go to the fallback (their outputs forced to their safe values).",
                        escape(&w.parts.join(", "))
                    )
                } else {
                    "No constraint reads the switched sensors.".to_string()
                }
            );
        } else {
            let _ = write!(
                h,
                "<p>From the next scan, {} read{} the temporal estimate instead of the sensor. The constraints so rewritten:</p><table class=\"rewrites\"><thead><tr><th>constraint</th><th>as written</th><th>as evaluated now</th></tr></thead><tbody>",
                escape(&w.sensors.join(", ")),
                if w.sensors.len() == 1 { "s" } else { "" },
            );
            for (name, written, now) in &w.constraints {
                let _ = write!(
                    h,
                    "<tr><td><code>{}</code></td><td><code>{}</code></td><td><code>{}</code></td></tr>",
                    escape(name),
                    escape(written),
                    escape(now)
                );
            }
            h.push_str("</tbody></table>");
        }
        h.push_str("</article>\n");
    }
    if total == 0 {
        h.push_str("<p class=\"quiet\">No safety constraint held in this log.</p>\n");
    } else {
        h.push_str("<table class=\"trips\"><thead><tr><th>constraint</th><th>times it started to hold</th><th>first</th></tr></thead><tbody>");
        for (name, n) in r.trip_counts.iter().filter(|c| c.1 > 0) {
            let first = r.trips.iter().zip(ids).find(|(t, _)| &t.constraint == name);
            let _ = write!(
                h,
                "<tr><td><code>{}</code></td><td>{n}</td><td>{}</td></tr>",
                escape(name),
                first.map_or(String::new(), |(t, id)| format!(
                    "<a href=\"#{}\" data-zoom-log=\"{i}\" data-zoom-t=\"{}\">{}</a>",
                    id.as_deref().unwrap_or_default(),
                    tick_of(r, t.t),
                    escape(&absolute(r.time, t.t))
                ))
            );
        }
        h.push_str("</tbody></table>\n");
        if r.trips.len() as u64 > ids.iter().flatten().count() as u64 {
            let _ = writeln!(
                h,
                "<p class=\"quiet\">The first {} trips of each constraint are explained below; all {} are on the timelines{}.</p>",
                super::collect::EXPLAINED_TRIPS,
                r.trips.len(),
                if total > r.trips.len() as u64 {
                    format!(" (of {total}, the rest only counted)")
                } else {
                    String::new()
                }
            );
        }
    }
    for (t, id) in r.trips.iter().zip(ids) {
        if let (Some(id), Some(_)) = (id, &t.detail) {
            trip_article(h, plant, r, i, id, t);
        }
    }
    h.push_str("</section>\n");
}

fn trip_article(h: &mut String, plant: &Plant, r: &LogReplay, i: usize, id: &str, t: &Trip) {
    let Some(detail) = &t.detail else {
        return;
    };
    let written = plant.constraints.iter().find(|c| c.name == t.constraint);
    let signals = constraint_signals(plant, written);
    let literal_names = literal_names(&t.literals);
    let _ = writeln!(
        h,
        "<article class=\"explanation trip\" id=\"{id}\">\n<h4 data-zoom-log=\"{i}\" data-zoom-t=\"{}\">{} held at {} <span class=\"rel\">{}</span></h4>\n<p class=\"constraint\"><code>{}</code></p>",
        tick_of(r, t.t),
        escape(&t.constraint),
        escape(&absolute(r.time, t.t)),
        offset(t.t - r.start),
        highlight(&t.evaluated, &t.literals)
    );
    if let Some(c) = written
        && c.expr.to_string() != t.evaluated
    {
        let _ = write!(
            h,
            "<p class=\"quiet\">As written in the plant file: <code>{}</code>; the flags raised (<code>{}</code>) rewrote it.</p>",
            escape(&c.expr.to_string()),
            escape(&detail.flags.join(" "))
        );
    }
    let actions: Vec<String> = t
        .literals
        .iter()
        .filter_map(|l| filter_action(plant, l))
        .collect();
    let after = after_filter(plant, &detail.now, &t.literals);
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"0\"><h5>Current state</h5><p>The filter {}.</p>{}</section>",
        if actions.is_empty() {
            "sends the plant to the fallback".to_string()
        } else {
            escape(&actions.join("; "))
        },
        state_table(plant, &signals, &after, &[], Some(&detail.now)),
    );
    let situation = situation(plant, t);
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"1\"><h5>Projection</h5><p>Without the filter, the orders would have gone out in the forbidden situation {}: {}.</p></section>",
        escape(&t.constraint),
        escape(&situation.join(", "))
    );
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"2\"><h5>State before stop</h5><p>The scan in which the constraint held; its elements are marked, and changes from the scan before are shown.</p>{}</section>",
        state_table(
            plant,
            &signals,
            &detail.now,
            &literal_names,
            Some(&detail.before)
        )
    );
    let _ = writeln!(
        h,
        "<section class=\"level\" data-level=\"3\"><h5>Advanced state: the last changes</h5>{}</section>",
        changes_table(plant, &detail.changes, t.t, &literal_names)
    );
    hypothesis_level(h, plant, t, detail, &signals, &actions);
    h.push_str("</article>\n");
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

/// The explanation's last level, after seed 002: which sensor changes may
/// have led the control program to the forbidden orders.
fn hypothesis_level(
    h: &mut String,
    plant: &Plant,
    t: &Trip,
    detail: &TripDetail,
    signals: &[String],
    actions: &[String],
) {
    let last: Option<&Change> = detail.changes.last().filter(|c| c.t == t.t);
    let recent: Vec<&Change> = detail.changes.iter().rev().take(3).collect();
    let mut inside = Vec::new();
    let mut outside = Vec::new();
    for c in &recent {
        for &(s, v) in &c.edges {
            let name = plant.signals.name(diagnoser::SignalId(s as u32));
            let id = diagnoser::SignalId(s as u32);
            if plant.signals.get(id).kind != SignalKind::Sensor {
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
    h.push_str("<section class=\"level\" data-level=\"4\"><h5>Hypothesis</h5><ul>");
    if !inside.is_empty() {
        let _ = write!(
            h,
            "<li>Sensors of the constraint changed just before: <code>{}</code>. The control program may not have taken them into account to change its outputs.</li>",
            escape(&inside.join(" "))
        );
    }
    if !outside.is_empty() {
        let _ = write!(
            h,
            "<li>Sensors outside the constraint changed just before: <code>{}</code>. One of them may have made the program change an output the constraint reads (a wrong receptivity).</li>",
            escape(&outside.join(" "))
        );
    }
    if inside.is_empty() && outside.is_empty() {
        h.push_str("<li>No sensor changed just before: the orders may come from inside the PLC (a timer, a memory).</li>");
    }
    if last.is_none() {
        h.push_str("<li>Nothing changed in this very scan: the constraint started to hold as time passed (an estimate's interval or a flag).</li>");
    }
    if !actions.is_empty() {
        let _ = write!(
            h,
            "<li>Expected of the control program: what the filter did, {}.</li>",
            escape(&actions.join("; "))
        );
    }
    h.push_str("</ul></section>\n");
}

fn models_section(h: &mut String, p: &Page<'_>) {
    if p.pictures.is_empty() {
        return;
    }
    h.push_str("<section class=\"models\" id=\"models\"><h2>Models</h2>\n<p class=\"meta\">Learned models: states are the observed vectors of a part's signals (double border: the part waits there for a command); transitions carry the learned window on their clock. Diagnosers: each state holds the candidate fault labels (red: one fault certain, amber: ambiguous).</p>\n");
    for pics in p.pictures {
        // Closed by default: a large diagnoser is laid out only when opened.
        let _ = writeln!(
            h,
            "<details class=\"part-models\" id=\"models-{}\"><summary><h3>{}</h3></summary>",
            escape(&pics.part),
            escape(&pics.part)
        );
        for (what, pic) in [
            ("learned model", &pics.model),
            ("diagnoser", &pics.diagnoser),
        ] {
            if let Some(pic) = pic {
                let _ = writeln!(
                    h,
                    "<figure class=\"model-picture\">{}<figcaption>{} of {} ({})</figcaption></figure>",
                    pic.svg,
                    what,
                    escape(&pics.part),
                    pic.by
                );
            }
        }
        if let Some(note) = &pics.note {
            let _ = writeln!(h, "<p class=\"quiet\">{}</p>", escape(note));
        }
        h.push_str("</details>\n");
    }
    h.push_str("</section>\n");
}

#[cfg(test)]
mod tests {
    use diagnoser::Plant;

    use super::*;
    use crate::fixtures::{learned, replay, sorting};

    /// Markup where the plant file, the log and the diagnosers put free text.
    const PLANT: &str = "<script>alert('plant')</script>";
    const PART: &str = "turn<script>alert('part')</script>table";
    const DESCRIPTION: &str = "<script>alert('C5')</script> at unloading position";
    const REASON: &str = "<!--<script>alert('reason')</script>";
    const PATH: &str = "<script>alert('path')</script>/plant.toml";

    /// The sorting line with markup in its name, its turntable's name and
    /// C5's description.
    fn hostile_plant() -> Plant {
        let path = sorting("normal").join("plant.toml");
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{e}"));
        let text = text
            .replacen("name = \"sorting\"", &format!("name = \"{PLANT}\""), 1)
            .replacen("name = \"turntable\"", &format!("name = \"{PART}\""), 1)
            .replacen(
                "description = \"turntable at unloading position\"",
                &format!("description = \"{DESCRIPTION}\""),
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

        // The markup is printed as text wherever the page shows it.
        let (markup, rest) = html
            .split_once("<script type=\"application/json\" id=\"gardefou-data\">")
            .expect("the timeline data");
        for text in [PLANT, PART, DESCRIPTION, REASON, PATH] {
            assert!(markup.contains(&escape(text)), "{text} not shown");
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
        assert!(models.contains(&escape(PART)));
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
