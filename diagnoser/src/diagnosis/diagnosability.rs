//! Diagnosability of each fault of a part, on its compiled diagnoser.
//!
//! A fault `F` is *detectable* when no run with `F` can look like a normal run
//! forever, and *isolable* when no run with `F` can look like a run with another
//! fault `G` forever. Both are decided on pairs of hypotheses that follow the
//! same observations through the compiled automaton ([`Compiled`]): one in mode
//! `F`, one in mode `G` (normal or another fault). A cycle of such pairs that
//! includes at least one observed scan is an observation that can repeat for
//! ever and fits both: `F` is not diagnosable from `G`, and the cycle is the
//! counterexample. Without such a cycle, the pairs form an acyclic graph, and
//! its longest path bounds how many observed scans it takes, once the fault has
//! shown, to tell `F` apart. Like libFAUDES, that verdict assumes the plant keeps
//! running.
//!
//! # When the control waits for ever
//!
//! A sequential control program waits for the sensor it needs next, and a fault
//! may withhold that sensor for ever: the plant stops, and the observations end
//! in silence. Silence is evidence where a hypothesis has a deadline (the
//! compiled automaton then has a time transition that drops it), and none where
//! no hypothesis expects anything. `F` is *isolable when the control waits* if,
//! besides the above, no compiled node can end the observations with a
//! hypothesis of `F` and one of another fault `G` both alive once the fault has
//! shown (no normal hypothesis left), nor with a hypothesis of `F` whose
//! physical state differs from a normal one's beside it (the fault has changed
//! the plant and nothing shows it). The node must be one where the plant
//! can fall silent: no deadline of any hypothesis is pending (no time
//! transition leaves it), and the learned control waits for the part there
//! (every exit the learned runs took from that observed state includes a
//! sensor edge of the part; a command given on its own is assumed to come).
//! [`Waiting`] names the state, the first observation that would tell the two
//! apart, and what the learned control waits for instead.

use std::collections::HashMap;

use petgraph::algo::{kosaraju_scc, toposort};
use petgraph::graph::{DiGraph, EdgeIndex, NodeIndex};
use petgraph::visit::EdgeRef;

use super::compile::{Commands, Compiled, Trigger};
use super::engine::Engine;
use super::part::{Clock, Hypothesis};
use crate::{Time, TimeUnit};

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
    /// Isolable also when the control waits for ever: no silent end of the
    /// observations fits it and another fault, once it has shown. Implies
    /// `isolable`.
    pub isolable_when_waiting: bool,
    /// The modes a silent end leaves it confused with: `N` when the fault can
    /// change the plant with nothing to show for it, other faults once it has
    /// shown (empty when not `isolable`: the running verdict says it already).
    pub confused_when_waiting: Vec<String>,
    /// When isolable only while the plant runs: where the control waits, and
    /// what would tell the faults apart.
    pub waiting: Option<Waiting>,
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

/// The graph of pairs (hypothesis of fault `f`, hypothesis of another mode)
/// that follow the same observations through `compiled`.
fn pair_graph(
    engine: &Engine,
    compiled: &Compiled,
    successors: &Successors,
    f: u16,
) -> (Vec<Pair>, PairGraph) {
    let graph = &compiled.graph;
    let hyps_of = |i: NodeIndex| -> &[Hypothesis] { &engine.state(graph[i].state).hyps };
    // Every pair (F hypothesis, other hypothesis) in every node, numbered
    // node by node, F hypothesis then other: the pair of positions
    // (a, b) of node i is `base[i] + rank[a] * others[i] + rank[b]`.
    let mut nodes: Vec<Pair> = Vec::new();
    let mut base = Vec::with_capacity(graph.node_count());
    let mut others = Vec::with_capacity(graph.node_count());
    let mut rank = vec![0usize; successors.hyps];
    for i in graph.node_indices() {
        let hyps = hyps_of(i);
        let (mut in_f, mut not_f) = (0, 0);
        for (p, h) in hyps.iter().enumerate() {
            let r = &mut rank[successors.first_hyp[i.index()] + p];
            if h.mode == f {
                *r = in_f;
                in_f += 1;
            } else {
                *r = not_f;
                not_f += 1;
            }
        }
        base.push(nodes.len());
        others.push(not_f);
        for &a in hyps.iter().filter(|h| h.mode == f) {
            for &b in hyps.iter().filter(|h| h.mode != f) {
                nodes.push((i, a, b));
            }
        }
    }
    let mut adj = PairGraph::with_nodes(nodes.len());
    for i in graph.node_indices() {
        let hyps = hyps_of(i);
        let positions_f: Vec<usize> = (0..hyps.len()).filter(|&p| hyps[p].mode == f).collect();
        let positions_o: Vec<usize> = (0..hyps.len()).filter(|&p| hyps[p].mode != f).collect();
        for (ra, &pa) in positions_f.iter().enumerate() {
            for (rb, &pb) in positions_o.iter().enumerate() {
                // Pairs are numbered in the order they are visited here.
                debug_assert_eq!(adj.len(), base[i.index()] + ra * others[i.index()] + rb);
                adj.start_node();
                for e in graph.edges(i) {
                    let scan = matches!(e.weight(), Trigger::Scan(_));
                    let na = successors.of(e.id(), pa);
                    if na.is_empty() {
                        continue;
                    }
                    let nb = successors.of(e.id(), pb);
                    let t = e.target();
                    let target = hyps_of(t);
                    let first = successors.first_hyp[t.index()];
                    for &x in na {
                        if target[x as usize].mode != f {
                            continue;
                        }
                        for &y in nb {
                            if target[y as usize].mode == f {
                                continue;
                            }
                            let to = base[t.index()]
                                + rank[first + x as usize] * others[t.index()]
                                + rank[first + y as usize];
                            adj.push((to, scan, e.id()));
                        }
                    }
                }
            }
        }
    }
    (nodes, adj)
}

/// A silent end that fits the fault and another one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Waiting {
    /// The other fault.
    pub other: String,
    /// The observed state where the plant falls silent.
    pub state: String,
    /// The shortest observations from there after which only one of the two
    /// is left, if any, e.g. `FE(A4) → RE(C4)`. Searched under the learned
    /// control, then (with [`separate_under_any_order`]) under any order.
    pub until: Option<String>,
    /// Orders in `until` that the learned control does not give there.
    pub orders_outside_control: Vec<String>,
    /// The sensor events the learned control waits for in that state (the
    /// model's exits from it), e.g. `RE(C5)`.
    pub control_waits_for: Vec<String>,
    /// The silent node and pair, to search again under any order.
    #[serde(skip)]
    silent: SilentPair,
}

/// A pair of hypotheses in a compiled node, found again in another
/// exploration by its engine state and clock readings.
#[derive(Debug, Clone, PartialEq)]
struct SilentPair {
    state: u32,
    readings: Vec<Option<Time>>,
    fault: Hypothesis,
    other: Hypothesis,
}

/// Whether the learned control gives the orders of scan `ch` in observed
/// state `obs` (as [`Commands::Learned`] lets them happen).
fn learned_order(part: &super::part::PartDiagnoser, obs: u32, ch: u32) -> bool {
    part.model_state(obs).is_some_and(|s| {
        let motion = part.motion(ch);
        part.moves(s).iter().any(|m| m.changed == motion)
    })
}

/// For every verdict whose silent end no learned observation separates,
/// searches for one under any order: explores `engine`'s diagnoser once with
/// [`Commands::Any`], then, from the same node and pair, the shortest
/// observations that leave only one of the two. The result goes to
/// [`Waiting::until`] and [`Waiting::orders_outside_control`] (e.g. releasing
/// A4 brings a moving plate back to C4, and a blocked one does not).
pub fn separate_under_any_order(
    learned: &Engine,
    verdicts: &mut [FaultDiagnosability],
    unit: TimeUnit,
) {
    let wanted = |v: &FaultDiagnosability| v.waiting.as_ref().is_some_and(|w| w.until.is_none());
    if !verdicts.iter().any(wanted) {
        return;
    }
    // Orders given anywhere would turn elements in mid-stroke everywhere, and
    // the exploration would not end: the search takes each order to start a
    // whole stroke (see `PartDiagnoser::without_reversals`).
    let mut any_engine = Engine::new(learned.part.without_reversals());
    let engine = &mut any_engine;
    let any = Compiled::explore_with(engine, 2, Commands::Any);
    let successors = Successors::new(engine, &any);
    for v in verdicts.iter_mut().filter(|v| wanted(v)) {
        let Some(w) = v.waiting.as_mut() else {
            continue;
        };
        let f = w.silent.fault.mode;
        let silent = learned.state(w.silent.state);
        let Some(node) = any.graph.node_indices().find(|&i| {
            let here = engine.state(any.graph[i].state);
            any.graph[i].readings == w.silent.readings
                && here.obs == silent.obs
                && here.hyps == silent.hyps
        }) else {
            continue;
        };
        let (nodes, adj) = pair_graph(engine, &any, &successors, f);
        let Some(u) = nodes
            .iter()
            .position(|&p| p == (node, w.silent.fault, w.silent.other))
        else {
            continue;
        };
        let ctx = PairContext {
            engine,
            compiled: &any,
            successors: &successors,
            nodes: &nodes,
            adj: &adj,
            fault: f,
            unit,
        };
        if let Some(path) = ctx.separation(u) {
            let (text, orders) = ctx.path_text(&path);
            w.until = Some(text);
            w.orders_outside_control = orders;
        }
    }
}

type Pair = (NodeIndex, Hypothesis, Hypothesis);

/// Where each hypothesis of each compiled edge's source leads: positions in the
/// target's hypotheses, computed once for every fault's pair graph.
struct Successors {
    /// Per node, the index of its first hypothesis in the flat position space.
    first_hyp: Vec<usize>,
    /// Hypotheses of all nodes.
    hyps: usize,
    /// Per edge, the index of its first (edge, source hypothesis) entry.
    first_entry: Vec<usize>,
    /// Per (edge, source hypothesis), the range of its successors in `targets`.
    ranges: Vec<(u32, u32)>,
    /// Successor positions in the target node's hypotheses.
    targets: Vec<u32>,
}

impl Successors {
    fn new(engine: &Engine, compiled: &Compiled) -> Successors {
        let part = engine.part.clone();
        let graph = &compiled.graph;
        let mut first_hyp = Vec::with_capacity(graph.node_count());
        let mut total = 0;
        for i in graph.node_indices() {
            first_hyp.push(total);
            total += engine.state(graph[i].state).hyps.len();
        }
        let mut first_entry = Vec::with_capacity(graph.edge_count());
        let (mut ranges, mut targets) = (Vec::new(), Vec::new());
        for e in graph.edge_indices() {
            first_entry.push(ranges.len());
            let Some((a, b)) = graph.edge_endpoints(e) else {
                continue;
            };
            let (na, nb) = (&graph[a], &graph[b]);
            let source = engine.state(na.state).hyps.clone();
            let obs = engine.state(na.state).obs;
            let target_obs = engine.state(nb.state).obs;
            let target = engine.state(nb.state).hyps.clone();
            for &h in source.iter() {
                let mut next = match &graph[e] {
                    Trigger::Scan(ch) => part.step(obs, *ch, &[h], &na.readings),
                    Trigger::Time { .. } => vec![h],
                };
                part.close(target_obs, &mut next, &nb.readings);
                let start = targets.len() as u32;
                targets.extend(
                    next.iter()
                        .filter_map(|x| target.iter().position(|y| y == x))
                        .map(|p| p as u32),
                );
                ranges.push((start, targets.len() as u32));
            }
        }
        Successors {
            first_hyp,
            hyps: total,
            first_entry,
            ranges,
            targets,
        }
    }

    fn of(&self, e: EdgeIndex, source_position: usize) -> &[u32] {
        let (lo, hi) = self.ranges[self.first_entry[e.index()] + source_position];
        &self.targets[lo as usize..hi as usize]
    }
}

/// Decides the diagnosability of every fault of `engine`'s part on `compiled`.
pub fn check(engine: &mut Engine, compiled: &Compiled, unit: TimeUnit) -> Vec<FaultDiagnosability> {
    let part = engine.part.clone();
    let successors = Successors::new(engine, compiled);
    let silent = silent_nodes(engine, compiled);
    let mut out = Vec::new();
    for (m, mode) in part.modes.iter().enumerate().skip(1) {
        let f = m as u16;
        let (nodes, adj) = pair_graph(engine, compiled, &successors, f);
        let comp = adj.components();
        let cycle = find_cycle(&adj, &comp);
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
        // Which other modes share a scan cycle with F. Along an edge the other
        // hypothesis keeps its mode, or goes from normal to a fault that begins
        // (never back, never to another fault): every cycle keeps one mode, so
        // one pass over the components finds them all.
        let mut shares = vec![false; part.modes.len()];
        for u in 0..adj.len() {
            if adj
                .out(u)
                .iter()
                .any(|&(v, scan, _)| scan && comp[u] == comp[v])
            {
                shares[nodes[u].2.mode as usize] = true;
            }
        }
        for (g, other) in part.modes.iter().enumerate() {
            if g != m && shares[g] {
                confused.push(other.label.clone());
            }
        }
        let detectable = !confused.iter().any(|l| l == "N");
        let isolable = confused.is_empty();
        let mut confused_when_waiting: Vec<String> = Vec::new();
        let mut waiting = None;
        if isolable {
            for (u, &(i, a, b)) in nodes.iter().enumerate() {
                let Some(shown) = silent[i.index()] else {
                    continue;
                };
                // Beside a normal hypothesis, a fault that has changed the
                // plant (a physical state of its own) goes undetected; one
                // that has not is dormant. Beside another fault, once the
                // fault has shown.
                let confused = if b.mode == 0 { a.phys != b.phys } else { shown };
                if !confused {
                    continue;
                }
                let other = &part.modes[b.mode as usize].label;
                if !confused_when_waiting.contains(other) {
                    confused_when_waiting.push(other.clone());
                }
                if waiting.is_none() {
                    let ctx = PairContext {
                        engine,
                        compiled,
                        successors: &successors,
                        nodes: &nodes,
                        adj: &adj,
                        fault: f,
                        unit,
                    };
                    waiting = Some(ctx.waiting(u, other));
                }
            }
            confused_when_waiting.sort();
        }
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
            isolable_when_waiting: isolable && confused_when_waiting.is_empty(),
            confused_when_waiting,
            waiting,
            bound_scans: bound,
            counterexample,
        });
    }
    out
}

/// Per compiled node: whether the observations can end there in silence, and
/// if so whether the fault has shown there (no normal hypothesis left). Silent:
/// no time transition leaves the node and no clock with a deadline is unknown
/// (the exploration starts with unknown clocks, which a replay knows after
/// their first edge), so no hypothesis has a deadline pending; and every exit
/// the learned runs took from its observed state includes an edge of the
/// part's sensors: the control waits for the part. A command the control gives
/// on its own there (an exit made of commands only) is assumed to come, as it
/// depends on a timer or on other parts, which a fault of this part does not
/// hold up.
fn silent_nodes(engine: &Engine, compiled: &Compiled) -> Vec<Option<bool>> {
    let part = &engine.part;
    let graph = &compiled.graph;
    graph
        .node_indices()
        .map(|i| {
            let state = engine.state(graph[i].state);
            let unknown = state
                .timers
                .iter()
                .zip(&graph[i].readings)
                .any(|(timers, reading)| !timers.is_empty() && reading.is_none());
            let deadline = unknown
                || graph
                    .edges(i)
                    .any(|e| matches!(e.weight(), Trigger::Time { .. }));
            let control_acts = part.model_state(state.obs).is_some_and(|s| {
                part.moves(s)
                    .iter()
                    .any(|m| m.changed & !part.actuator_mask() == 0)
            });
            let shown = state.hyps.iter().all(|h| h.mode != 0);
            (!deadline && !control_acts).then_some(shown)
        })
        .collect()
}

/// What [`PairContext::waiting`] reads: one fault's pair graph and where it
/// came from.
struct PairContext<'a> {
    engine: &'a Engine,
    compiled: &'a Compiled,
    successors: &'a Successors,
    nodes: &'a [Pair],
    adj: &'a PairGraph,
    fault: u16,
    unit: TimeUnit,
}

/// Pairs visited when looking for the observation that separates a silent pair.
const SEPARATION_SEARCH: usize = 10_000;

impl PairContext<'_> {
    /// Describes the silent pair `u`, confused with `other`.
    fn waiting(&self, u: usize, other: &str) -> Waiting {
        let part = &self.engine.part;
        let (i, _, _) = self.nodes[u];
        let obs = self.engine.state(self.compiled.graph[i].state).obs;

        let control_waits_for = part
            .model_state(obs)
            .map(|s| {
                let mut events: Vec<String> = part
                    .moves(s)
                    .iter()
                    .filter(|m| m.changed & !part.actuator_mask() != 0)
                    .map(|m| part.edges(obs, m.changed))
                    .collect();
                events.sort();
                events.dedup();
                events
            })
            .unwrap_or_default();
        let (until, orders) = match self.separation(u) {
            Some(path) => {
                let (text, orders) = self.path_text(&path);
                (Some(text), orders)
            }
            None => (None, Vec::new()),
        };
        let (_, a, b) = self.nodes[u];
        Waiting {
            other: other.to_string(),
            state: part.describe(obs),
            until,
            orders_outside_control: orders,
            control_waits_for,
            silent: SilentPair {
                state: self.compiled.graph[i].state,
                readings: self.compiled.graph[i].readings.clone(),
                fault: a,
                other: b,
            },
        }
    }

    /// The shortest observations, breadth first from pair `u` along
    /// observations that fit both, after whose last only one of the two
    /// hypotheses is left: (node, compiled edge) steps.
    fn separation(&self, u: usize) -> Option<Vec<(NodeIndex, EdgeIndex)>> {
        let graph = &self.compiled.graph;
        let mut parent: HashMap<usize, (usize, NodeIndex, EdgeIndex)> = HashMap::new();
        let mut queue = std::collections::VecDeque::from([u]);
        let mut visited = 0;
        while let Some(w) = queue.pop_front() {
            visited += 1;
            if visited > SEPARATION_SEARCH {
                return None;
            }
            let (j, a, b) = self.nodes[w];
            let hyps = &self.engine.state(graph[j].state).hyps;
            let pa = hyps.iter().position(|h| *h == a)?;
            let pb = hyps.iter().position(|h| *h == b)?;
            let acts = self.engine.part.actuator_mask();
            let orders = |e: EdgeIndex| match graph[e] {
                Trigger::Scan(ch) => (ch & acts).count_ones(),
                Trigger::Time { .. } => 0,
            };
            let separating = graph
                .edges(j)
                .filter(|e| {
                    let target = &self.engine.state(graph[e.target()].state).hyps;
                    let alive_a = self
                        .successors
                        .of(e.id(), pa)
                        .iter()
                        .any(|&x| target[x as usize].mode == self.fault);
                    let alive_b = self
                        .successors
                        .of(e.id(), pb)
                        .iter()
                        .any(|&y| target[y as usize].mode != self.fault);
                    alive_a != alive_b
                })
                // The plainest: fewest orders, then the earliest explored.
                .min_by_key(|e| (orders(e.id()), e.id()));
            if let Some(e) = separating {
                {
                    let mut path = vec![(j, e.id())];
                    let mut x = w;
                    while let Some(&(p, node, edge)) = parent.get(&x) {
                        path.push((node, edge));
                        x = p;
                    }
                    path.reverse();
                    return Some(path);
                }
            }
            for &(v, _, e) in self.adj.out(w) {
                if v != u && !parent.contains_key(&v) {
                    parent.insert(v, (w, j, e));
                    queue.push_back(v);
                }
            }
        }
        None
    }

    /// Observations in words, joined by arrows; and the orders among them that
    /// the learned control does not give where they are given.
    fn path_text(&self, path: &[(NodeIndex, EdgeIndex)]) -> (String, Vec<String>) {
        let part = &self.engine.part;
        let mut orders = Vec::new();
        let is_time = |e: EdgeIndex| matches!(self.compiled.graph[e], Trigger::Time { .. });
        // Of consecutive stretches of silence, the last says it all.
        let kept: Vec<(NodeIndex, EdgeIndex)> = path
            .iter()
            .enumerate()
            .filter(|&(k, &(_, e))| {
                !(is_time(e) && path.get(k + 1).is_some_and(|&(_, n)| is_time(n)))
            })
            .map(|(_, &step)| step)
            .collect();
        let words: Vec<String> = kept
            .iter()
            .map(|&(node, e)| {
                let obs = self.engine.state(self.compiled.graph[node].state).obs;
                if let Trigger::Scan(ch) = self.compiled.graph[e]
                    && ch & part.actuator_mask() != 0
                    && !learned_order(part, obs, ch)
                {
                    orders.push(part.edges(obs, ch & part.actuator_mask()));
                }
                self.observation(node, e)
            })
            .collect();
        (words.join(" → "), orders)
    }

    /// An observation of the compiled graph, in words.
    fn observation(&self, node: NodeIndex, e: EdgeIndex) -> String {
        let part = &self.engine.part;
        let obs = self.engine.state(self.compiled.graph[node].state).obs;
        match &self.compiled.graph[e] {
            Trigger::Scan(ch) => part.edges(obs, *ch),
            Trigger::Time { clock, at } => format!(
                "no event until {} reads {} {}",
                part.clock_name(*clock),
                // Readings sit just past a threshold: the threshold reads best.
                self.unit.format(at / 1000 * 1000),
                self.unit.name()
            ),
        }
    }
}

type PairEdge = (usize, bool, EdgeIndex);

/// The graph of pairs, its edges stored flat: the edges of pair `u` are
/// `edges[start[u]..start[u + 1]]`, as (target pair, scan edge, compiled edge).
struct PairGraph {
    start: Vec<usize>,
    edges: Vec<PairEdge>,
    nodes: usize,
}

impl PairGraph {
    fn with_nodes(nodes: usize) -> PairGraph {
        PairGraph {
            start: Vec::with_capacity(nodes + 1),
            edges: Vec::new(),
            nodes,
        }
    }

    /// Pairs whose edges have been started.
    fn len(&self) -> usize {
        self.start.len()
    }

    /// The next pair's edges follow.
    fn start_node(&mut self) {
        self.start.push(self.edges.len());
    }

    fn push(&mut self, e: PairEdge) {
        self.edges.push(e);
    }

    fn out(&self, u: usize) -> &[PairEdge] {
        let end = self.start.get(u + 1).copied().unwrap_or(self.edges.len());
        &self.edges[self.start[u]..end]
    }

    /// The pairs as a petgraph graph, edges in the same order.
    fn digraph(&self) -> DiGraph<(), ()> {
        let mut g = DiGraph::with_capacity(self.len(), self.edges.len());
        for _ in 0..self.len() {
            g.add_node(());
        }
        for u in 0..self.len() {
            for &(v, _, _) in self.out(u) {
                g.add_edge(NodeIndex::new(u), NodeIndex::new(v), ());
            }
        }
        g
    }

    /// Strongly connected components: pairs with the same number are on a
    /// common cycle. Kosaraju's passes are iterative in petgraph (its Tarjan
    /// recurses once per pair on a path, and a long path of pairs would
    /// overflow the stack).
    fn components(&self) -> Vec<usize> {
        debug_assert_eq!(self.len(), self.nodes);
        let mut comp = vec![0; self.len()];
        for (c, members) in kosaraju_scc(&self.digraph()).into_iter().enumerate() {
            for u in members {
                comp[u.index()] = c;
            }
        }
        comp
    }
}

/// A cycle through at least one scan edge, as (pair, edge taken) steps.
fn find_cycle(adj: &PairGraph, comp: &[usize]) -> Option<Vec<(usize, EdgeIndex)>> {
    // A scan edge inside a strongly connected component closes a cycle.
    // The shortest of the first cycles found reads best as a counterexample.
    let mut best: Option<Vec<(usize, EdgeIndex)>> = None;
    let mut tried = 0;
    for u in 0..adj.len() {
        for &(v, scan, e) in adj.out(u) {
            if scan && comp[u] == comp[v] && tried < 64 {
                tried += 1;
                // Path v -> u inside the component, then u -> v.
                if let Some(mut cycle) = bfs_path(adj, comp, v, u) {
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
    adj: &PairGraph,
    comp: &[usize],
    from: usize,
    to: usize,
) -> Option<Vec<(usize, EdgeIndex)>> {
    if from == to {
        return Some(Vec::new());
    }
    let mut prev: HashMap<usize, (usize, EdgeIndex)> = HashMap::new();
    let mut queue = std::collections::VecDeque::from([from]);
    while let Some(u) = queue.pop_front() {
        for &(v, _, e) in adj.out(u) {
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

/// Longest path, counted in scan edges, of an acyclic pair graph: pairs in
/// reverse topological order, each one step longer than its best successor.
fn longest(adj: &PairGraph) -> usize {
    let Ok(order) = toposort(&adj.digraph(), None) else {
        // Only called without a cycle; with one, there is no bound.
        return usize::MAX;
    };
    let mut best = vec![0usize; adj.len()];
    for u in order.into_iter().rev().map(NodeIndex::index) {
        best[u] = adj
            .out(u)
            .iter()
            .map(|&(v, scan, _)| best[v] + usize::from(scan))
            .max()
            .unwrap_or(0);
    }
    best.into_iter().max().unwrap_or(0)
}

fn describe(
    engine: &Engine,
    compiled: &Compiled,
    nodes: &[Pair],
    cycle: &[(usize, EdgeIndex)],
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Pairs `0 -> 1 -> … -> n-1`, every edge a scan, closed into a cycle
    /// when `closed`.
    fn path(n: usize, closed: bool) -> PairGraph {
        let mut adj = PairGraph::with_nodes(n);
        for u in 0..n {
            adj.start_node();
            if u + 1 < n {
                adj.push((u + 1, true, EdgeIndex::new(0)));
            } else if closed {
                adj.push((0, true, EdgeIndex::new(0)));
            }
        }
        adj
    }

    // A path of pairs longer than any recursion a test thread's stack holds.
    const DEEP: usize = 100_000;

    #[test]
    fn a_long_cycle_of_pairs_is_one_component_and_its_counterexample_is_found() {
        let adj = path(DEEP, true);
        let comp = adj.components();
        assert!(comp.iter().all(|&c| c == comp[0]));
        let cycle = find_cycle(&adj, &comp).expect("the cycle");
        assert_eq!(cycle.len(), DEEP);
    }

    #[test]
    fn a_long_acyclic_path_of_pairs_bounds_the_scans_by_its_length() {
        let adj = path(DEEP, false);
        let comp = adj.components();
        assert_eq!(
            comp.iter().collect::<std::collections::HashSet<_>>().len(),
            DEEP
        );
        assert_eq!(find_cycle(&adj, &comp), None);
        assert_eq!(longest(&adj), DEEP - 1);
    }

    #[test]
    fn the_longest_path_counts_scan_edges_only() {
        // 0 -> 1 (scan) -> 3, and 0 -> 2 -> 3 (time edges): one scan at most.
        let mut adj = PairGraph::with_nodes(4);
        let e = EdgeIndex::new(0);
        adj.start_node();
        adj.push((1, true, e));
        adj.push((2, false, e));
        adj.start_node();
        adj.push((3, false, e));
        adj.start_node();
        adj.push((3, false, e));
        adj.start_node();
        assert_eq!(longest(&adj), 1);
    }
}
