//! Diagnosability of each fault of a part, on its compiled diagnoser.
//!
//! A fault `F` is *detectable* when no run with `F` can look like a normal run
//! forever, and *isolable* when no run with `F` can look like a run with another
//! fault `G` forever. Both are decided on pairs of hypotheses that follow the
//! same observations through the compiled automaton ([`Compiled`]): one in mode
//! `F`, one in mode `G` (normal or another fault). A cycle of such pairs that
//! includes at least one observed scan is an observation that can repeat for
//! ever and fits both: `F` is not diagnosable from `G`, and the cycle is the
//! counterexample. (Runs that stop forever, with no event at all, are left out:
//! like libFAUDES, the check assumes the plant keeps running.) Without such a
//! cycle, the pairs form an acyclic graph, and its longest path bounds how many
//! observed scans it takes, once the fault has shown, to tell `F` apart.

use std::collections::HashMap;

use petgraph::graph::NodeIndex;
use petgraph::visit::EdgeRef;

use super::compile::{Compiled, Trigger};
use super::engine::Engine;
use super::part::{Clock, Hypothesis};
use crate::TimeUnit;

/// The verdict on one fault of a part.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FaultDiagnosability {
    /// The fault's label.
    pub label: String,
    /// Its template, as written.
    pub template: String,
    /// No faulty run looks normal forever.
    pub detectable: bool,
    /// No faulty run looks like another fault's forever.
    pub isolable: bool,
    /// The faults it cannot be told apart from (with `N` when not detectable).
    pub confused_with: Vec<String>,
    /// When diagnosable: at most this many observed scans after the fault shows.
    pub bound_scans: Option<usize>,
    /// When not: two runs with the same observations, one with the fault.
    pub counterexample: Option<Counterexample>,
}

/// Two runs that look the same: the same repeating observations, with the
/// physical states each explains them by.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Counterexample {
    /// The other mode: `N` or a fault label.
    pub other: String,
    /// The repeating observations, e.g. `RE(A4) at command clock 0`.
    pub observed: Vec<String>,
    /// The physical states of the faulty run along the cycle.
    pub faulty: Vec<String>,
    /// The physical states of the other run.
    pub other_run: Vec<String>,
}

type Pair = (NodeIndex, Hypothesis, Hypothesis);

/// Decides the diagnosability of every fault of `engine`'s part on `compiled`.
pub fn check(engine: &mut Engine, compiled: &Compiled, unit: TimeUnit) -> Vec<FaultDiagnosability> {
    let part = engine.part.clone();
    let graph = &compiled.graph;
    // Per edge, which hypothesis of the source leads to which of the target.
    let mut derive: HashMap<(usize, Hypothesis), Vec<Hypothesis>> = HashMap::new();
    let mut successors = |engine: &mut Engine, e: petgraph::graph::EdgeIndex, h: Hypothesis| {
        if let Some(v) = derive.get(&(e.index(), h)) {
            return v.clone();
        }
        let Some((a, b)) = graph.edge_endpoints(e) else {
            return Vec::new();
        };
        let (na, nb) = (&graph[a], &graph[b]);
        let obs = engine.state(na.state).obs;
        let mut next = match &graph[e] {
            Trigger::Scan(ch) => part.step(obs, *ch, &[h], &na.readings),
            Trigger::Time { .. } => vec![h],
        };
        let target = engine.state(nb.state).obs;
        part.close(target, &mut next, &nb.readings);
        let hyps = &engine.state(nb.state).hyps;
        next.retain(|x| hyps.contains(x));
        derive.insert((e.index(), h), next.clone());
        next
    };

    let mut out = Vec::new();
    for (m, mode) in part.modes.iter().enumerate().skip(1) {
        let f = m as u16;
        // Every pair (F hypothesis, other hypothesis) in every node; hypotheses
        // are distinct within a node, so the pairs are too.
        let mut nodes: Vec<Pair> = Vec::new();
        for i in graph.node_indices() {
            let hyps = &engine.state(graph[i].state).hyps;
            for &a in hyps.iter().filter(|h| h.mode == f) {
                for &b in hyps.iter().filter(|h| h.mode != f) {
                    nodes.push((i, a, b));
                }
            }
        }
        let index: HashMap<Pair, usize> = nodes.iter().enumerate().map(|(k, &p)| (p, k)).collect();
        let mut adj: Vec<Vec<(usize, bool, petgraph::graph::EdgeIndex)>> =
            vec![Vec::new(); nodes.len()];
        // Edges between pairs (new pairs cannot appear: every node's pairs are in).
        for (k, &(i, a, b)) in nodes.iter().enumerate() {
            for e in graph.edges(i) {
                let scan = matches!(e.weight(), Trigger::Scan(_));
                let na = successors(engine, e.id(), a);
                if na.is_empty() {
                    continue;
                }
                let nb = successors(engine, e.id(), b);
                for &x in &na {
                    for &y in &nb {
                        if let Some(&t) = index.get(&(e.target(), x, y)) {
                            adj[k].push((t, scan, e.id()));
                        }
                    }
                }
            }
        }
        let cycle = find_cycle(&adj);
        let mut confused: Vec<String> = Vec::new();
        let mut counterexample = None;
        if let Some(cycle) = &cycle {
            let (_, _, other) = nodes[cycle[0].0];
            let other_label = part.modes[other.mode as usize].label.clone();
            counterexample = Some(describe(
                engine,
                compiled,
                &nodes,
                cycle,
                &other_label,
                unit,
            ));
        }
        // Which other modes share a scan cycle with F.
        for (g, other) in part.modes.iter().enumerate() {
            if g == m {
                continue;
            }
            let keep: Vec<bool> = nodes.iter().map(|p| p.2.mode == g as u16).collect();
            let sub: Vec<Vec<(usize, bool, petgraph::graph::EdgeIndex)>> = adj
                .iter()
                .enumerate()
                .map(|(k, es)| {
                    if keep[k] {
                        es.iter().copied().filter(|e| keep[e.0]).collect()
                    } else {
                        Vec::new()
                    }
                })
                .collect();
            if find_cycle(&sub).is_some() {
                confused.push(other.label.clone());
            }
        }
        let detectable = !confused.iter().any(|l| l == "N");
        let isolable = confused.is_empty();
        let bound = if cycle.is_none() {
            Some(longest(&adj))
        } else {
            None
        };
        out.push(FaultDiagnosability {
            label: mode.label.clone(),
            template: mode
                .template
                .as_ref()
                .map(|t| t.to_string())
                .unwrap_or_default(),
            detectable,
            isolable,
            confused_with: confused,
            bound_scans: bound,
            counterexample,
        });
    }
    out
}

/// A cycle through at least one scan edge, as (pair, edge taken) steps.
fn find_cycle(
    adj: &[Vec<(usize, bool, petgraph::graph::EdgeIndex)>],
) -> Option<Vec<(usize, petgraph::graph::EdgeIndex)>> {
    // Strongly connected components (Tarjan, iterative), then a scan edge
    // inside one of them closes a cycle.
    let comp = scc(adj);
    // The shortest of the first cycles found reads best as a counterexample.
    let mut best: Option<Vec<(usize, petgraph::graph::EdgeIndex)>> = None;
    let mut tried = 0;
    for (u, es) in adj.iter().enumerate() {
        for &(v, scan, e) in es {
            if scan && comp[u] == comp[v] && tried < 64 {
                tried += 1;
                // Path v -> u inside the component, then u -> v.
                if let Some(mut cycle) = bfs_path(adj, &comp, v, u) {
                    cycle.push((u, e));
                    if best.as_ref().is_none_or(|b| cycle.len() < b.len()) {
                        best = Some(cycle);
                    }
                }
            }
        }
    }
    best
}

fn bfs_path(
    adj: &[Vec<(usize, bool, petgraph::graph::EdgeIndex)>],
    comp: &[usize],
    from: usize,
    to: usize,
) -> Option<Vec<(usize, petgraph::graph::EdgeIndex)>> {
    if from == to {
        return Some(Vec::new());
    }
    let mut prev: HashMap<usize, (usize, petgraph::graph::EdgeIndex)> = HashMap::new();
    let mut queue = std::collections::VecDeque::from([from]);
    while let Some(u) = queue.pop_front() {
        for &(v, _, e) in &adj[u] {
            if comp[v] != comp[from] || v == from || prev.contains_key(&v) {
                continue;
            }
            prev.insert(v, (u, e));
            if v == to {
                let mut path = Vec::new();
                let mut x = to;
                while x != from {
                    let (p, e) = prev[&x];
                    path.push((p, e));
                    x = p;
                }
                path.reverse();
                return Some(path);
            }
            queue.push_back(v);
        }
    }
    None
}

fn scc(adj: &[Vec<(usize, bool, petgraph::graph::EdgeIndex)>]) -> Vec<usize> {
    let mut g: petgraph::graph::DiGraph<(), ()> = petgraph::graph::DiGraph::new();
    let idx: Vec<NodeIndex> = (0..adj.len()).map(|_| g.add_node(())).collect();
    for (u, es) in adj.iter().enumerate() {
        for &(v, _, _) in es {
            g.add_edge(idx[u], idx[v], ());
        }
    }
    let mut comp = vec![0; adj.len()];
    for (c, members) in petgraph::algo::kosaraju_scc(&g).into_iter().enumerate() {
        for m in members {
            comp[m.index()] = c;
        }
    }
    comp
}

/// Longest path, counted in scan edges, of an acyclic pair graph.
fn longest(adj: &[Vec<(usize, bool, petgraph::graph::EdgeIndex)>]) -> usize {
    let n = adj.len();
    let mut memo: Vec<Option<usize>> = vec![None; n];
    // Iterative post-order DFS.
    for s in 0..n {
        if memo[s].is_some() {
            continue;
        }
        let mut stack = vec![(s, 0usize)];
        while let Some((u, k)) = stack.pop() {
            if k < adj[u].len() {
                stack.push((u, k + 1));
                let v = adj[u][k].0;
                if memo[v].is_none() && !stack.iter().any(|&(w, _)| w == v) {
                    stack.push((v, 0));
                }
            } else {
                let best = adj[u]
                    .iter()
                    .map(|&(v, scan, _)| memo[v].unwrap_or(0) + usize::from(scan))
                    .max()
                    .unwrap_or(0);
                memo[u] = Some(best);
            }
        }
    }
    memo.into_iter().flatten().max().unwrap_or(0)
}

fn describe(
    engine: &Engine,
    compiled: &Compiled,
    nodes: &[Pair],
    cycle: &[(usize, petgraph::graph::EdgeIndex)],
    other: &str,
    unit: TimeUnit,
) -> Counterexample {
    let part = &engine.part;
    let graph = &compiled.graph;
    let mut observed = Vec::new();
    let mut faulty = Vec::new();
    let mut other_run = Vec::new();
    for &(k, e) in cycle {
        let (node, a, b) = nodes[k];
        faulty.push(part.describe(a.phys));
        other_run.push(part.describe(b.phys));
        let n = &graph[node];
        let obs = engine.state(n.state).obs;
        let clock_text = |c: usize| -> String {
            match (part.clocks.get(c), n.readings.get(c).copied().flatten()) {
                (Some(Clock::Command), Some(v)) => {
                    format!("{} {} after the last command", unit.format(v), unit.name())
                }
                (Some(_), Some(v)) => format!(
                    "{} {} after {}",
                    unit.format(v),
                    unit.name(),
                    part.clock_name(c as u8)
                ),
                _ => "at any time".to_string(),
            }
        };
        observed.push(match &graph[e] {
            Trigger::Scan(ch) => format!("{} ({})", part.edges(obs, *ch), clock_text(0)),
            Trigger::Time { clock, at } => format!(
                "no event until {} reads {} {}",
                part.clock_name(*clock),
                unit.format(*at),
                unit.name()
            ),
        });
    }
    Counterexample {
        other: other.to_string(),
        observed,
        faulty,
        other_run,
    }
}
