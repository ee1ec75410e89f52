//! A part's learned model as a graph to draw ([`Digraph`]): its DOT text is what
//! `gardefou learn --dot` writes, its picture is the report's.

use std::collections::HashMap;

use digraph::{Digraph, Edge, Node, RankDirection};
use vocabulary::model::{Model, ModelClock, PartModel};

/// One part's model as a graph: states as nodes (`s0`, `s1`, … by state id,
/// with the part's signal values and visits; stable states, where the part
/// waits for a command, drawn double), transitions as edges labelled with their
/// event, guard and clock, and their count (commands bold). A transition from
/// or to a state the part does not list gets a node of its own, labelled with
/// its identifier.
pub fn part_digraph(model: &Model, part: &PartModel) -> Digraph {
    let unit = model.time_unit.name();
    let mut nodes: Vec<Node> = part
        .states
        .iter()
        .map(|s| {
            let values = part
                .signals
                .iter()
                .zip(&s.values)
                .map(|(n, &v)| format!("{n}={}", u8::from(v)))
                .collect::<Vec<_>>()
                .join(" ");
            Node {
                id: format!("s{}", s.id),
                label: vec![values, format!("({} visits)", s.visits)],
                fill: None,
                double_border: s.stable,
            }
        })
        .collect();
    let mut index: HashMap<usize, usize> = HashMap::new();
    for (i, s) in part.states.iter().enumerate() {
        index.entry(s.id).or_insert(i);
    }
    let mut node = |id: usize| {
        *index.entry(id).or_insert_with(|| {
            let name = format!("s{id}");
            nodes.push(Node {
                id: name.clone(),
                label: vec![name],
                ..Node::default()
            });
            nodes.len() - 1
        })
    };
    let edges = part
        .transitions
        .iter()
        .map(|t| {
            let mut label = vec![t.event.clone()];
            if !t.command {
                label.push(if t.timed {
                    let clock = if ModelClock::parse(&t.clock) == Some(ModelClock::Command) {
                        String::new()
                    } else {
                        format!(" after {}", t.clock)
                    };
                    format!("[{}, {}] {unit}{clock}", t.guard.lo, t.guard.hi)
                } else {
                    "(untimed)".to_string()
                });
            }
            label.push(format!("×{}", t.count));
            Edge {
                from: node(t.from),
                to: node(t.to),
                label,
                bold: t.command,
            }
        })
        .collect();
    Digraph {
        name: part.name.clone(),
        caption: vec![format!("{} — {}", model.plant, part.name)],
        rank_direction: RankDirection::LeftToRight,
        rounded_nodes: true,
        nodes,
        edges,
    }
}
