//! The whole diagnoser automaton of a part, compiled ahead of time (seed 002,
//! Fig. 12): every state reachable from the model's states, labelled with its
//! fault labels, with transitions on observed scans (and the clock interval in
//! which they lead there) and on deadlines passing.
//!
//! The exploration runs the same [`Engine`] as a replay, on representative clock
//! readings: each clock is read at 0, at each threshold that matters to the
//! current state, or not at all (unknown, at a log's start). Readings saturate
//! past the part's largest threshold, so the exploration is finite.
//!
//! What the control may command is a choice ([`Commands`]): by default
//! ([`Compiled::explore`]) commands come as the control issued them in the
//! learned runs, in the same observed states (seed 002 does not blame the
//! control); [`Commands::Any`] knows nothing of the control, and
//! [`Commands::Filter`] keeps only the scans a safety filter lets through (seed
//! 002 §4: the filter simplifies the diagnosers; the predicate itself is built
//! in `filter-coupling`). It is for sizes, pictures and the diagnosability
//! check; a replay never needs it.

use std::collections::{HashMap, VecDeque};

use digraph::{Digraph, Edge as DrawnEdge, Node as DrawnNode, RankDirection};
use petgraph::graph::{DiGraph, NodeIndex};

use super::engine::Engine;
use super::part::PartDiagnoser;
use crate::Time;

/// An abstract state of the exploration: a diagnoser state and the clock
/// readings it was reached with.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Node {
    /// The engine's state.
    pub state: u32,
    /// Representative clock readings (nanoseconds; `None`: unknown).
    pub readings: Vec<Option<Time>>,
}

/// What a compiled transition is taken on.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Trigger {
    /// An observed scan changing these bits of the part's state vector.
    Scan(u32),
    /// Time passing until `clock` reads `at` with no event.
    Time {
        /// Index of the clock.
        clock: u8,
        /// The reading reached.
        at: Time,
    },
}

/// Which observed scans the exploration lets happen, as far as the control is
/// concerned. Scans are given as the observed state vectors before and after
/// them, bit `i` being the part's `i`-th signal ([`PartDiagnoser::names`]:
/// actuators, as written, then sensors, as read).
#[derive(Clone, Copy, Default)]
pub enum Commands<'a> {
    /// Any command change in any observed state: the diagnoser knows nothing of
    /// the control. Sensor edges are free, as under every policy.
    Any,
    /// Any command change and any sensor edges, but only the scans `(before,
    /// after)` for which the predicate holds: e.g. those after which no safety
    /// constraint is 1 (see `filter_coupling::simplify`).
    Filter(&'a dyn Fn(u32, u32) -> bool),
    /// Commands as the control issued them in the learned runs, in the same
    /// observed states (the model's transitions that include a command; seed
    /// 002 does not blame the control); sensor edges are free.
    #[default]
    Learned,
}

impl std::fmt::Debug for Commands<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Commands::Any => "Any",
            Commands::Filter(_) => "Filter(..)",
            Commands::Learned => "Learned",
        })
    }
}

impl Commands<'_> {
    /// Whether the scan that changes the bits `changed` from the observed state
    /// `obs` may happen.
    fn allow(&self, part: &PartDiagnoser, obs: u32, changed: u32) -> bool {
        match self {
            Commands::Any => true,
            Commands::Filter(allowed) => allowed(obs, obs ^ changed),
            Commands::Learned => {
                changed & part.actuator_mask() == 0
                    || part.model_state(obs).is_some_and(|s| {
                        let motion = part.motion(changed);
                        part.moves(s).iter().any(|m| m.changed == motion)
                    })
            }
        }
    }
}

/// The compiled diagnoser of one part.
#[derive(Debug, Clone)]
pub struct Compiled {
    /// Nodes and transitions.
    pub graph: DiGraph<Node, Trigger>,
    /// Whether the exploration stopped at its size limit.
    pub truncated: bool,
}

/// Size of a compiled automaton.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Size {
    /// Distinct diagnoser states (sets of hypotheses), whatever the clocks.
    pub states: usize,
    /// Distinct (state, scan or deadline, state) transitions.
    pub transitions: usize,
    /// Nodes of the exploration (states with clock regions).
    pub nodes: usize,
}

/// Stops the exploration past this many nodes.
pub const NODE_LIMIT: usize = 200_000;

impl Compiled {
    /// Explores every state reachable from the model's states (normal, clocks
    /// unknown and then at 0), with observed scans of at most `max_bits` edges
    /// or as the learned transitions take them, and commands as in the learned
    /// runs ([`Commands::Learned`]).
    pub fn explore(engine: &mut Engine, max_bits: u32) -> Compiled {
        Compiled::explore_with(engine, max_bits, Commands::Learned)
    }

    /// As [`Compiled::explore`], with the scans `commands` lets happen. The
    /// exploration starts from the model's states under every policy.
    pub fn explore_with(engine: &mut Engine, max_bits: u32, commands: Commands<'_>) -> Compiled {
        let part = engine.part.clone();
        let clocks = part.clocks.len();
        let masks = scan_masks(&part, max_bits);
        let mut graph: DiGraph<Node, Trigger> = DiGraph::new();
        let mut index: HashMap<Node, NodeIndex> = HashMap::new();
        let mut queue: VecDeque<NodeIndex> = VecDeque::new();
        // Largest threshold per clock, for saturation.
        let mut cap: Vec<Time> = vec![0; clocks];
        let mut add = |engine: &Engine,
                       graph: &mut DiGraph<Node, Trigger>,
                       queue: &mut VecDeque<NodeIndex>,
                       cap: &mut Vec<Time>,
                       node: Node| {
            if let Some(&i) = index.get(&node) {
                return i;
            }
            for (c, th) in engine.state(node.state).thresholds.iter().enumerate() {
                if let Some(&m) = th.last() {
                    cap[c] = cap[c].max(m);
                }
            }
            let i = graph.add_node(node.clone());
            index.insert(node, i);
            queue.push_back(i);
            i
        };
        for &v in part.state_vectors() {
            let unknown = vec![None; clocks];
            let s = engine.initial(v, &unknown);
            add(
                engine,
                &mut graph,
                &mut queue,
                &mut cap,
                Node {
                    state: s,
                    readings: unknown,
                },
            );
        }
        let mut truncated = false;
        while let Some(i) = queue.pop_front() {
            if graph.node_count() > NODE_LIMIT {
                truncated = true;
                break;
            }
            let node = graph[i].clone();
            // Time passing to the next threshold of any clock.
            let st = engine.state(node.state).clone();
            if let Some((d, c)) = next_threshold(&st.thresholds, &node.readings) {
                let readings: Vec<Option<Time>> = node
                    .readings
                    .iter()
                    .enumerate()
                    .map(|(k, r)| r.map(|v| (v + d).min(cap[k] + 1)))
                    .collect();
                let s = engine.advance(node.state, &readings);
                let at = readings[c as usize].unwrap_or(0);
                let j = add(
                    engine,
                    &mut graph,
                    &mut queue,
                    &mut cap,
                    Node { state: s, readings },
                );
                if j != i {
                    graph.add_edge(i, j, Trigger::Time { clock: c, at });
                }
            }
            // Observed scans.
            for &ch in &masks {
                if !commands.allow(&part, st.obs, ch) {
                    continue;
                }
                let after_obs = st.obs ^ ch;
                let after: Vec<Option<Time>> = part
                    .clocks
                    .iter()
                    .zip(&node.readings)
                    .map(|(clock, r)| {
                        if part.restarts(*clock, ch, after_obs) {
                            Some(0)
                        } else {
                            *r
                        }
                    })
                    .collect();
                let s = engine.scan(node.state, ch, &node.readings, &after);
                if engine.state(s).hyps.is_empty() {
                    continue;
                }
                let j = add(
                    engine,
                    &mut graph,
                    &mut queue,
                    &mut cap,
                    Node {
                        state: s,
                        readings: after,
                    },
                );
                graph.add_edge(i, j, Trigger::Scan(ch));
            }
        }
        Compiled { graph, truncated }
    }

    /// Its size.
    pub fn size(&self) -> Size {
        let mut states: Vec<u32> = self.graph.node_weights().map(|n| n.state).collect();
        states.sort_unstable();
        states.dedup();
        let mut edges: Vec<(u32, Trigger, u32)> = self
            .graph
            .edge_indices()
            .filter_map(|e| {
                let (a, b) = self.graph.edge_endpoints(e)?;
                let t = match &self.graph[e] {
                    Trigger::Time { clock, .. } => Trigger::Time {
                        clock: *clock,
                        at: 0,
                    },
                    other => other.clone(),
                };
                let (sa, sb) = (self.graph[a].state, self.graph[b].state);
                (sa != sb || matches!(t, Trigger::Scan(_))).then_some((sa, t, sb))
            })
            .collect();
        // Any total order puts equal edges side by side for dedup.
        let key = |t: &Trigger| match *t {
            Trigger::Scan(ch) => (0, i64::from(ch)),
            Trigger::Time { clock, at } => (1 + i64::from(clock), at),
        };
        edges.sort_unstable_by_key(|e| (e.0, key(&e.1), e.2));
        edges.dedup();
        Size {
            states: states.len(),
            transitions: edges.len(),
            nodes: self.graph.node_count(),
        }
    }

    /// The automaton as a graph to draw (its DOT text is what `gardefou check
    /// --dot` writes): one node per diagnoser state (`d0`, `d1`, …), labelled
    /// with its fault labels and observed state, white when normal, salmon with one
    /// other label, khaki with several; one edge per trigger between two states,
    /// with the command-clock intervals it is taken in.
    pub fn to_digraph(&self, engine: &Engine, unit: crate::TimeUnit) -> Digraph {
        let part = &engine.part;
        let mut states: Vec<u32> = self.graph.node_weights().map(|n| n.state).collect();
        states.sort_unstable();
        states.dedup();
        let id = |s: u32| states.binary_search(&s).unwrap_or(0);
        let nodes = states
            .iter()
            .enumerate()
            .map(|(i, &s)| {
                let st = engine.state(s);
                let labels = engine.labels(st.labels);
                let names: Vec<&str> = if labels.normal {
                    vec!["N"]
                } else if labels.modes.is_empty() {
                    vec![super::verdict::UNKNOWN_LABEL]
                } else {
                    labels
                        .modes
                        .iter()
                        .map(|&m| part.modes[m as usize].label.as_str())
                        .collect()
                };
                let colour = if labels.normal {
                    "white"
                } else if names.len() == 1 {
                    "salmon"
                } else {
                    "khaki"
                };
                DrawnNode {
                    id: format!("d{i}"),
                    label: vec![format!("{{{}}}", names.join(", ")), part.describe(st.obs)],
                    fill: Some(colour.to_string()),
                    double_border: false,
                }
            })
            .collect();
        let edges = self
            .drawn_edges(engine, unit)
            .into_iter()
            .map(|((a, b), label)| DrawnEdge {
                from: id(a),
                to: id(b),
                label: vec![label],
                bold: false,
            })
            .collect();
        Digraph {
            name: format!("diagnoser {}", part.name),
            caption: Vec::new(),
            rank_direction: RankDirection::LeftToRight,
            rounded_nodes: false,
            nodes,
            edges,
        }
    }

    /// The drawn edges, in order: between two diagnoser states, per trigger
    /// (edges between the same states on the same trigger merged), labelled
    /// with the trigger and the command-clock intervals it is taken in.
    /// Deadlines that leave the state as it was are left out.
    fn drawn_edges(&self, engine: &Engine, unit: crate::TimeUnit) -> Vec<((u32, u32), String)> {
        let part = &engine.part;
        let mut edges: HashMap<(u32, u32, String), Vec<Span>> = HashMap::new();
        for e in self.graph.edge_indices() {
            let Some((a, b)) = self.graph.edge_endpoints(e) else {
                continue;
            };
            let (na, nb) = (&self.graph[a], &self.graph[b]);
            if na.state == nb.state && matches!(self.graph[e], Trigger::Time { .. }) {
                continue;
            }
            match &self.graph[e] {
                Trigger::Scan(ch) => {
                    let label = part.edges(engine.state(na.state).obs, *ch);
                    let w = edges.entry((na.state, nb.state, label)).or_default();
                    if let Some(v) = na.readings.first().copied().flatten() {
                        let th = engine.state(na.state).thresholds.first();
                        let next = th.and_then(|th| th.iter().copied().find(|&x| x > v));
                        w.push((v, next));
                    }
                }
                Trigger::Time { clock, at } => {
                    let label = format!("{} > {}", part.clock_name(*clock), unit.format(at - 1));
                    edges.entry((na.state, nb.state, label)).or_default();
                }
            }
        }
        let mut keys: Vec<_> = edges.into_iter().collect();
        keys.sort();
        keys.into_iter()
            .map(|((a, b, label), mut spans)| {
                spans.sort_unstable();
                // Adjacent intervals merge.
                let mut merged: Vec<Span> = Vec::new();
                for (lo, hi) in spans {
                    match merged.last_mut() {
                        Some(last) if last.1.is_some_and(|h| h >= lo) => {
                            last.1 = match (last.1, hi) {
                                (Some(x), Some(y)) => Some(x.max(y)),
                                _ => None,
                            };
                        }
                        Some(last) if last.1.is_none() => {}
                        _ => merged.push((lo, hi)),
                    }
                }
                let when: Vec<String> = merged
                    .iter()
                    .map(|(lo, hi)| match hi {
                        Some(h) => format!("[{}, {}]", unit.format(*lo), unit.format(h - 1)),
                        None => format!("[{}, ∞[", unit.format(*lo)),
                    })
                    .collect();
                let text = if when.is_empty() {
                    label
                } else {
                    format!("{label} {}", when.join(" "))
                };
                ((a, b), text)
            })
            .collect()
    }
}

/// A clock interval `[from, to[` (`to`: `None` for unbounded).
type Span = (Time, Option<Time>);

/// The observed scans to explore: every one of at most `max_bits` edges, and
/// every learned transition's scan, however many edges it has. The control
/// often reacts to a sensor in the scan that shows it, and a diagnoser that
/// never took such a scan would never reach the states after it.
fn scan_masks(part: &PartDiagnoser, max_bits: u32) -> Vec<u32> {
    let nbits = part.names.len() as u32;
    let mut masks: Vec<u32> = (1u32..(1 << nbits))
        .filter(|m| m.count_ones() <= max_bits)
        .collect();
    for s in 0..part.state_vectors().len() {
        masks.extend(part.moves(s).iter().map(|m| m.changed));
    }
    masks.sort_unstable_by_key(|m| (m.count_ones(), *m));
    masks.dedup();
    masks
}

/// How long until the nearest next threshold of a clock that reads a value,
/// and that clock.
fn next_threshold(thresholds: &[Box<[Time]>], readings: &[Option<Time>]) -> Option<(Time, u8)> {
    let mut step: Option<(Time, u8)> = None;
    for (c, th) in thresholds.iter().enumerate() {
        if let Some(Some(v)) = readings.get(c) {
            let k = th.partition_point(|&x| x <= *v);
            if let Some(&x) = th.get(k) {
                let d = x - v;
                if step.is_none_or(|(best, _)| d < best) {
                    step = Some((d, c as u8));
                }
            }
        }
    }
    step
}
