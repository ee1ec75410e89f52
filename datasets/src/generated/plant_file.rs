//! A generated plant's `plant.toml`: what a user would write for it, with a
//! description of the stations, every signal described, the parts, every fault
//! the templates allow with one partition per component, and a safety
//! constraint for each hazard.

use std::fmt::Write;

use super::layout::{
    Element, Family, Hazard, Layout, Middle, PartSpec, PlaceKind, Stage, Template,
};

/// The plant file of `layout`.
pub fn plant_toml(layout: &Layout) -> String {
    let mut out = String::new();
    header(layout, &mut out);
    signals(layout, &mut out);
    parts(layout, &mut out);
    faults(layout, &mut out);
    constraints(layout, &mut out);
    out
}

/// A TOML basic string.
fn quoted(text: &str) -> String {
    let mut s = String::with_capacity(text.len() + 2);
    s.push('"');
    for c in text.chars() {
        match c {
            '"' => s.push_str("\\\""),
            '\\' => s.push_str("\\\\"),
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

fn list(layout: &Layout, signals: &[usize]) -> String {
    let names: Vec<String> = signals
        .iter()
        .map(|&s| quoted(&layout.signals[s].name))
        .collect();
    format!("[{}]", names.join(", "))
}

/// Wraps `text` as comment lines of at most 88 characters.
fn comment(text: &str, out: &mut String) {
    let mut line = String::from("#");
    for word in text.split_whitespace() {
        if line.len() + 1 + word.len() > 88 && line.len() > 1 {
            out.push_str(&line);
            out.push('\n');
            line = String::from("#  ");
        }
        line.push(' ');
        line.push_str(word);
    }
    out.push_str(&line);
    out.push('\n');
}

fn header(layout: &Layout, out: &mut String) {
    let program = if layout.timeouts {
        "each step of the control program has a timeout that sends its station to a safe stop"
    } else {
        "the control program waits for ever for each sensor, with no timeout"
    };
    if layout.family != Family::Assembly {
        return family_header(layout, program, out);
    }
    comment(
        &format!(
            "Generated plant {} ({}): {} station(s) in a line, {} parts, {} signals; \
             PLC scan {} ms; {program}. Written by `gardefou simulate --plant generated \
             --plant-seed {} --size {}`.",
            layout.seed,
            layout.size.name(),
            layout.stations.len(),
            layout.parts.len(),
            layout.signals.len(),
            layout.scan_period / vocabulary::MS,
            layout.seed,
            layout.size.name(),
        ),
        out,
    );
    for station in &layout.stations {
        out.push_str("#\n");
        comment(&station_words(layout, station), out);
    }
    let ms = layout.scan_period as f64 / vocabulary::MS as f64;
    let _ = write!(
        out,
        "name = {}\nscan_period_ms = {ms}\ntime_unit = \"ms\"\n",
        quoted(&layout.name)
    );
}

/// The header of a plant of another family than the assembly lines: the same
/// facts, and each tank and cell in words.
fn family_header(layout: &Layout, program: &str, out: &mut String) {
    comment(
        &format!(
            "Generated plant {} ({}, {} family): {} station(s) in a line, {} tank(s), {} \
             positioning cell(s), {} parts, {} signals; PLC scan {} ms; {program}. Written by \
             `gardefou simulate --plant generated --plant-seed {} --size {} --family {}`.",
            layout.seed,
            layout.size.name(),
            layout.family.name(),
            layout.stations.len(),
            layout.tanks.len(),
            layout.cells.len(),
            layout.parts.len(),
            layout.signals.len(),
            layout.scan_period / vocabulary::MS,
            layout.seed,
            layout.size.name(),
            layout.family.name(),
        ),
        out,
    );
    for station in &layout.stations {
        out.push_str("#\n");
        comment(&station_words(layout, station), out);
    }
    for tank in &layout.tanks {
        out.push_str("#\n");
        comment(&super::process::words(layout, tank), out);
    }
    for cell in &layout.cells {
        out.push_str("#\n");
        comment(&super::positioning::words(layout, cell), out);
    }
    let ms = layout.scan_period as f64 / vocabulary::MS as f64;
    let _ = write!(
        out,
        "name = {}\nscan_period_ms = {ms}\ntime_unit = \"ms\"\n",
        quoted(&layout.name)
    );
}

/// A part's moving element: its name, the sensors it drives and the orders
/// that drive it.
fn element(layout: &Layout, part: &PartSpec) -> Option<(String, Vec<usize>, Vec<usize>)> {
    match part.element? {
        Element::Axis(e) => {
            let a = &layout.axes[e];
            Some((
                a.tag.clone(),
                a.at0.into_iter().chain(a.at1).collect(),
                std::iter::once(a.out).chain(a.back).collect(),
            ))
        }
        Element::Carriage(c) => {
            let c = &layout.cells[c];
            Some((
                c.tag.clone(),
                c.positions.iter().map(|p| p.cam).chain([c.zone]).collect(),
                c.orders().to_vec(),
            ))
        }
    }
}

fn station_words(layout: &Layout, station: &super::layout::Station) -> String {
    let sig = |s: usize| layout.signals[s].name.as_str();
    let mut text = format!("Station {}, {}:", station.number, station.name);
    let mut clauses = Vec::new();
    for stage in &station.stages {
        clauses.push(match *stage {
            Stage::Push { axis, from, to } => {
                let a = &layout.axes[axis];
                let from = match layout.places[from].kind {
                    PlaceKind::Outlet(m) => format!(
                        "out of a gravity magazine that an operator refills ({} empty)",
                        sig(layout.magazines[m].empty)
                    ),
                    _ => format!("from {}", layout.places[from].name),
                };
                format!(
                    "{} {} pushes the workpiece {from} to {}",
                    a.role.noun(),
                    a.tag,
                    layout.places[to].name
                )
            }
            Stage::Carry { conveyor, .. } => {
                let c = &layout.conveyors[conveyor];
                let middle = match c.middle {
                    Some(Middle::Metal(s)) => format!(", past an inductive sensor ({})", sig(s)),
                    Some(Middle::Presence(s)) => format!(", past a sensor half-way ({})", sig(s)),
                    None => String::new(),
                };
                format!(
                    "conveyor {} carries it from its entry ({}) to its end stop ({}){middle}",
                    c.tag,
                    sig(c.entry),
                    sig(c.exit)
                )
            }
            Stage::PickPlace {
                arm, gripper, to, ..
            } => {
                let g = &layout.grippers[gripper];
                let kind = if g.vacuum { "suction" } else { "mechanical" };
                format!(
                    "swivel arm {} with {kind} gripper {} picks it up and places it on {}",
                    layout.axes[arm].tag, g.tag, layout.places[to].name
                )
            }
            Stage::Rotate { table, .. } => format!(
                "rotary table {} turns it from the loading to the work position",
                layout.axes[table].tag
            ),
            Stage::Process { tool, .. } => {
                let a = &layout.axes[tool];
                format!("{} {} works on it", a.role.noun(), a.tag)
            }
        });
    }
    text.push(' ');
    text.push_str(&clauses.join("; "));
    if layout.places[station.output].kind == PlaceKind::Downstream {
        text.push_str(", which takes a workpiece when it is ready and is then busy for a while");
    }
    if station.template == Template::Distribution && station.number > 1 {
        text.push_str(" (the separator takes the workpiece from the previous station)");
    }
    text.push('.');
    text
}

fn signals(layout: &Layout, out: &mut String) {
    out.push_str("\n[signals]\n");
    for s in &layout.signals {
        let kind = if s.sensor { "sensor" } else { "actuator" };
        let _ = writeln!(
            out,
            "{} = {{ kind = \"{kind}\", description = {} }}",
            s.name,
            quoted(&s.description)
        );
    }
}

fn parts(layout: &Layout, out: &mut String) {
    out.push('\n');
    comment(
        "One part per component: its orders, its switches, and the sensors of the \
         places it takes workpieces from. The moving element of a cylinder, arm or \
         table is named after it, and drives its end switches only.",
        out,
    );
    for p in &layout.parts {
        let _ = write!(
            out,
            "\n[[parts]]\nname = {}\nactuators = {}\nsensors = {}\n",
            quoted(&p.name),
            list(layout, &p.actuators),
            list(layout, &p.sensors)
        );
        if let Some((tag, drives, _)) = element(layout, p) {
            let _ = writeln!(out, "element = {}", quoted(&tag));
            let _ = writeln!(out, "drives = {}", list(layout, &drives));
        }
        if !p.inputs.is_empty() {
            let _ = writeln!(out, "inputs = {}", list(layout, &p.inputs));
        }
    }
}

/// Every fault of a part: four per sensor, two per actuator, and the element
/// blocked at either end switch or between them, each way.
pub fn part_faults(layout: &Layout, part: &PartSpec) -> Vec<(String, String)> {
    let name = |s: usize| layout.signals[s].name.clone();
    let mut out = Vec::new();
    for &s in &part.sensors {
        let n = name(s);
        for t in ["stuck0", "stuck1", "unexpected_rise", "unexpected_fall"] {
            out.push((format!("{n}.{t}"), format!("{t}({n})")));
        }
    }
    for &a in &part.actuators {
        let n = name(a);
        for t in ["actuator_stuck0", "actuator_stuck1"] {
            out.push((format!("{n}.{t}"), format!("{t}({n})")));
        }
    }
    if let Some(Element::Carriage(c)) = part.element {
        // A carriage is blocked at each position, or between two neighbours.
        let c = &layout.cells[c];
        let cams: Vec<String> = c.positions.iter().map(|p| name(p.cam)).collect();
        for s in &cams {
            out.push((
                format!("{}.blocked_at.{s}", c.tag),
                format!("blocked_at({}, {s})", c.tag),
            ));
        }
        for pair in cams.windows(2) {
            for (from, to) in [(&pair[0], &pair[1]), (&pair[1], &pair[0])] {
                out.push((
                    format!("{}.blocked_between.{from}.{to}", c.tag),
                    format!("blocked_between({}, {from}, {to})", c.tag),
                ));
            }
        }
    }
    if layout.family != Family::Assembly {
        // Slower motions: of the element, or of each order of a part without one.
        match element(layout, part) {
            Some((tag, _, _)) => out.push((format!("{tag}.slow"), format!("slow({tag})"))),
            None => {
                for &a in &part.actuators {
                    let n = name(a);
                    out.push((format!("{n}.slow"), format!("slow({n})")));
                }
            }
        }
    }
    if let Some(Element::Axis(e)) = part.element {
        let a = &layout.axes[e];
        let ends: Vec<String> = a.at0.into_iter().chain(a.at1).map(name).collect();
        for s in &ends {
            out.push((
                format!("{}.blocked_at.{s}", a.tag),
                format!("blocked_at({}, {s})", a.tag),
            ));
        }
        if let [s0, s1] = ends.as_slice() {
            for (from, to) in [(s0, s1), (s1, s0)] {
                out.push((
                    format!("{}.blocked_between.{from}.{to}", a.tag),
                    format!("blocked_between({}, {from}, {to})", a.tag),
                ));
            }
        }
    }
    out
}

fn faults(layout: &Layout, out: &mut String) {
    out.push('\n');
    comment(
        "Every fault the templates allow on each part. Partitions: one per sensor, one \
         per moving element (its blocking faults and the faults of the orders that \
         drive it), and one per other order (a gripper, a belt motor).",
        out,
    );
    out.push_str("[faults]\n");
    let mut partitions: Vec<(String, Vec<String>)> = Vec::new();
    for part in &layout.parts {
        let _ = writeln!(out, "# {}", part.name);
        let element = element(layout, part);
        let element_orders: Vec<usize> = element.as_ref().map(|e| e.2.clone()).unwrap_or_default();
        for (label, template) in part_faults(layout, part) {
            let _ = writeln!(out, "{} = {}", quoted(&label), quoted(&template));
            let target = label.split('.').next().unwrap_or(&label).to_string();
            let owner = match &element {
                Some((tag, _, _))
                    if element_orders
                        .iter()
                        .any(|&o| layout.signals[o].name == target) =>
                {
                    tag.clone()
                }
                _ => target,
            };
            match partitions.iter_mut().find(|(n, _)| *n == owner) {
                Some((_, labels)) => labels.push(label),
                None => partitions.push((owner, vec![label])),
            }
        }
    }
    out.push_str("\n[partitions]\n");
    for (name, labels) in partitions {
        let labels: Vec<String> = labels.iter().map(|l| quoted(l)).collect();
        let _ = writeln!(out, "{name} = [{}]", labels.join(", "));
    }
}

/// The safety constraints of every hazard, each with a comment saying why.
pub fn hazard_constraints(layout: &Layout) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for h in &layout.hazards {
        match *h {
            Hazard::RodVsArm { rod, arm, end } => rod_vs_arm(layout, rod, arm, end, &mut out),
            Hazard::RodInNest { rod, table, end } => rod_in_nest(layout, rod, table, end, &mut out),
            Hazard::ReleaseInTransit { gripper, arm } => {
                release_in_transit(layout, gripper, arm, &mut out)
            }
            Hazard::Delivery {
                station,
                stage,
                place,
            } => delivery(layout, station, stage, place, &mut out),
        }
    }
    for tank in &layout.tanks {
        super::process::constraints(layout, tank, &mut out);
    }
    for cell in &layout.cells {
        super::positioning::constraints(layout, cell, &mut out);
    }
    out
}

/// A signal's name.
fn sig(layout: &Layout, s: usize) -> String {
    layout.signals[s].name.clone()
}

/// The name of an axis's switch at `end`, if it has one.
fn switch(layout: &Layout, axis: usize, end: bool) -> Option<String> {
    layout.axes[axis].switch(end).map(|s| sig(layout, s))
}

/// A rod and the swivel arm whose sweep it reaches: neither moves into the other.
fn rod_vs_arm(layout: &Layout, rod: usize, arm: usize, end: bool, out: &mut Vec<(String, String)>) {
    let (r, a) = (&layout.axes[rod], &layout.axes[arm]);
    let (Some(clear), Some(rod_back)) = (switch(layout, arm, !end), switch(layout, rod, false))
    else {
        return;
    };
    out.push((
        format!(
            "{} {} must not extend unless swivel arm {} is clear",
            r.role.noun(),
            r.tag,
            a.tag
        ),
        format!("{} & !{clear}", sig(layout, r.out)),
    ));
    let toward = if end { Some(a.out) } else { a.back };
    if let Some(toward) = toward {
        out.push((
            format!(
                "swivel arm {} must not swivel over {} unless it is retracted",
                a.tag, r.tag
            ),
            format!("{} & !{rod_back}", sig(layout, toward)),
        ));
    }
}

/// A rod reaching into a rotary table's nest: the table must be there, and
/// must not turn with the rod in it.
fn rod_in_nest(
    layout: &Layout,
    rod: usize,
    table: usize,
    end: bool,
    out: &mut Vec<(String, String)>,
) {
    let (r, t) = (&layout.axes[rod], &layout.axes[table]);
    let (Some(there), Some(rod_back)) = (switch(layout, table, end), switch(layout, rod, false))
    else {
        return;
    };
    out.push((
        format!(
            "{} {} must not extend into the nest of table {} unless the table is there",
            r.role.noun(),
            r.tag,
            t.tag
        ),
        format!("{} & !{there}", sig(layout, r.out)),
    ));
    for order in std::iter::once(t.out).chain(t.back) {
        out.push((
            format!(
                "rotary table {} must not turn unless {} {} is retracted",
                t.tag,
                r.role.noun(),
                r.tag
            ),
            format!("{} & !{rod_back}", sig(layout, order)),
        ));
    }
}

/// A gripper on a swivel arm must not let go between the arm's positions.
fn release_in_transit(
    layout: &Layout,
    gripper: usize,
    arm: usize,
    out: &mut Vec<(String, String)>,
) {
    let (g, a) = (&layout.grippers[gripper], &layout.axes[arm]);
    let (Some(s0), Some(s1)) = (a.at0, a.at1) else {
        return;
    };
    out.push((
        format!(
            "gripper {} must not let go while arm {} is between positions",
            g.tag, a.tag
        ),
        format!(
            "FE({}) & !{} & !{}",
            sig(layout, g.order),
            sig(layout, s0),
            sig(layout, s1)
        ),
    ));
}

/// A stage delivering onto a place: not while the place is occupied (or,
/// for the next machine, not ready).
fn delivery(
    layout: &Layout,
    station: usize,
    stage: usize,
    place: usize,
    out: &mut Vec<(String, String)>,
) {
    let p = &layout.places[place];
    let Some(sensor) = p.sensor else { return };
    let occupied = if p.kind == PlaceKind::Downstream {
        format!("!{}", sig(layout, sensor))
    } else {
        sig(layout, sensor)
    };
    let why = format!("nothing is delivered onto {} while it is occupied", p.name);
    match layout.stations[station].stages[stage] {
        Stage::Push { axis, .. } => {
            let order = sig(layout, layout.axes[axis].out);
            out.push((why, format!("RE({order}) & {occupied}")));
        }
        Stage::PickPlace { arm, gripper, .. } => {
            let Some(at) = layout.axes[arm].at1 else {
                return;
            };
            let release = sig(layout, layout.grippers[gripper].order);
            out.push((
                why,
                format!("FE({release}) & {} & {occupied}", sig(layout, at)),
            ));
        }
        _ => {}
    }
}

fn constraints(layout: &Layout, out: &mut String) {
    out.push('\n');
    comment(
        "Safety constraints (each must stay 0): one for each obvious hazard of the \
         layout. RE(x) is a rising edge of x in this scan, FE(x) a falling one.",
        out,
    );
    for (k, (why, expr)) in hazard_constraints(layout).into_iter().enumerate() {
        let _ = write!(
            out,
            "\n# {why}\n[[constraints]]\nname = \"CSs{}\"\nexpr = {}\n",
            k + 1,
            quoted(&expr)
        );
    }
}
