//! Event-diagnosability of a plant given as components: several generators
//! composed as libFAUDES's `Parallel` composes them (shared events move
//! together, the others alone; the accessible part), checked without building
//! the verifier of the whole product where its structure allows.
//!
//! Why: a product's states are the product of its components' and its
//! verifier's their square, so a plant of ten small parts can be out of reach
//! as one generator. Components that share no event, directly or through
//! others, run independently; we group the components into such *clusters*
//! and compose each cluster alone. For a failure type `F` the product is then
//! not diagnosable exactly when, for some cluster `k` where a failure of `F`
//! is reachable,
//!
//! - cluster `k` alone is not diagnosable for `F` (two runs of it that look the
//!   same forever), or
//! - another cluster `j` has a run without failures of `F` that shows
//!   infinitely many events: after the failure, cluster `k` may stand still
//!   while `j` goes on, in both runs alike, so nothing tells them apart.
//!
//! (If two product runs look the same forever, one failed in some cluster `k`;
//! projected onto `k`, they either look the same forever, or stop showing
//! anything, and then the observation comes from other clusters, where the
//! normal run goes on without failures. Conversely, either case lifts to two
//! product runs, the other clusters standing still or moving alike.)
//!
//! libFAUDES's assumptions decompose the same way, over the accessible
//! product: it deadlocks where every cluster does, and has a cycle of
//! unobservable events where some cluster does. The verdicts are therefore
//! those of [`event_diagnosability`](super::event_diagnosability) on the
//! product ([`parallel`]), which the tests check. A single cluster (every
//! component linked to the others) is composed and checked as one
//! generator: its structure is not used further.
//!
//! ```
//! use std::path::Path;
//! use diagnoser::faudes::{parse_failure_types, parse_generator, product};
//!
//! // Two machines that share no event; each may fail silently.
//! let machine = |i: u32| {
//!     let text = format!(
//!         "<Generator> \"m{i}\" <Alphabet> go{i} done{i} f{i} +o+ </Alphabet>
//!          <States> idle busy broken </States>
//!          <TransRel> idle go{i} busy  busy done{i} idle  idle f{i} broken  broken go{i} broken
//!          </TransRel> <InitStates> idle </InitStates> </Generator>"
//!     );
//!     parse_generator(&text, Path::new("m.gen")).unwrap()
//! };
//! let failures = parse_failure_types(
//!     "<FailureTypes> F <FailureEvents> f0 f1 </FailureEvents> </FailureTypes>",
//!     Path::new("f.txt"),
//! )
//! .unwrap();
//! let verdict = product::event_diagnosability(&[machine(0), machine(1)], &failures, 1 << 20)
//!     .unwrap();
//! // Alone, a broken machine shows `go` and never `done`: diagnosable. Side by
//! // side, the other machine's work hides that the broken one is no longer asked.
//! assert!(!verdict.types[0].diagnosable);
//! ```

use std::collections::{HashMap, VecDeque};

use super::{
    AssumptionViolation, BREADTH_FIRST, Counterexample, EventDiagnosability, FailureTypes,
    Generator, System, TooLarge, cyclic_components, failure_event_violations, unobservable_cycle,
};

/// The most dead states of a product a [`AssumptionViolation::Deadlock`] lists.
pub const LISTED_STATES: usize = 20;

/// The accessible synchronous product of generators, with the component states
/// behind each of its states.
#[derive(Debug, Clone)]
pub struct Product {
    /// The product: events in order of first appearance, states named
    /// `x1|x2|…` after their components' states.
    pub generator: Generator,
    width: usize,
    /// Component states of product state `x`: `members[x * width..][..width]`.
    members: Vec<u32>,
}

impl Product {
    /// The state of each component in product state `x`.
    pub fn members(&self, x: usize) -> &[u32] {
        &self.members[x * self.width..][..self.width]
    }
}

/// Why a product could not be checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProductError {
    /// An event is observable in one component and unobservable in another
    /// (indices into the components).
    Observability {
        /// The event.
        event: String,
        /// A component where it is observable.
        observable_in: usize,
        /// A component where it is not.
        unobservable_in: usize,
    },
    /// A cluster's product outgrew the budget.
    ProductTooLarge {
        /// The components of the cluster.
        components: Vec<usize>,
        /// Its states and transitions when it was given up.
        reached: usize,
    },
    /// A cluster's verifier outgrew the budget.
    VerifierTooLarge {
        /// The components of the cluster.
        components: Vec<usize>,
        /// The verifier and its failure type.
        too_large: TooLarge,
    },
}

/// Each event observable in every component that has it, or unobservable in
/// every one.
pub fn check_observability(components: &[Generator]) -> Result<(), ProductError> {
    let mut seen: HashMap<&str, (bool, usize)> = HashMap::new();
    for (i, g) in components.iter().enumerate() {
        for (e, name) in g.events.iter().enumerate() {
            let observable = g.observable.get(e).copied().unwrap_or(true);
            let &mut (first, at) = seen.entry(name).or_insert((observable, i));
            if first != observable {
                let (observable_in, unobservable_in) = if first { (at, i) } else { (i, at) };
                return Err(ProductError::Observability {
                    event: name.clone(),
                    observable_in,
                    unobservable_in,
                });
            }
        }
    }
    Ok(())
}

/// The accessible part of the synchronous product of `components`, as
/// libFAUDES's `Parallel` makes it; `Err` with its size once it holds more
/// than `budget` states and transitions. An event's observability is the
/// first component's that has it ([`check_observability`]). Without
/// components, the product has no state.
pub fn parallel(components: &[&Generator], budget: usize) -> Result<Product, usize> {
    let alphabet = Alphabet::of(components);
    let width = components.len();
    let mut product = Explored::default();
    let initials: Vec<Vec<usize>> = (components.iter())
        .map(|g| (g.initial.iter().copied().filter(|&x| x < g.states.len())).collect())
        .collect();
    // Counted before they are made: a few components with many initial
    // states, or many successors on one event, are already too many.
    let mut size = count(&initials);
    if size > budget {
        return Err(size);
    }
    if width > 0 {
        for start in combinations(&initials) {
            product.state(&start);
        }
    }
    let initial = product.count;
    let mut transitions = Vec::new();
    let mut next = 0;
    while next < product.count {
        let current: Vec<usize> = (product.members[next * width..][..width].iter())
            .map(|&x| x as usize)
            .collect();
        for (event, targets) in alphabet.moves(&current) {
            size = size.saturating_add(count(&targets));
            if size > budget {
                return Err(size);
            }
            for target in combinations(&targets) {
                let to = product.state(&target);
                transitions.push((next, event, to));
            }
        }
        next += 1;
    }
    Ok(product.finish(components, alphabet, initial, transitions))
}

/// The events of the components and who takes part in each.
struct Alphabet {
    events: Vec<String>,
    observable: Vec<bool>,
    /// `shares[i][e]`: component `i` has event `e`.
    shares: Vec<Vec<bool>>,
    /// `out[i][x]`: `(event, target)` of component `i`'s transitions from
    /// state `x`, by event.
    out: Vec<Vec<Vec<(usize, usize)>>>,
}

impl Alphabet {
    fn of(components: &[&Generator]) -> Self {
        let (events, observable, global) = union(components);
        let shares = (global.iter())
            .map(|mine| {
                let mut has = vec![false; events.len()];
                mine.iter().for_each(|&e| has[e] = true);
                has
            })
            .collect();
        let out = (components.iter().zip(&global))
            .map(|(g, mine)| {
                let mut out = vec![Vec::new(); g.states.len()];
                for &(x, e, y) in &g.transitions {
                    if x < g.states.len() && y < g.states.len() && e < mine.len() {
                        out[x].push((mine[e], y));
                    }
                }
                out.iter_mut()
                    .for_each(|o: &mut Vec<(usize, usize)>| o.sort());
                out
            })
            .collect();
        Alphabet {
            events,
            observable,
            shares,
            out,
        }
    }

    /// The events enabled in product state `current` (each component either
    /// takes part or has not the event), with each component's possible
    /// next states.
    fn moves(&self, current: &[usize]) -> Vec<(usize, Vec<Vec<usize>>)> {
        let mut candidates: Vec<usize> = (current.iter().enumerate())
            .flat_map(|(i, &x)| self.out[i][x].iter().map(|&(e, _)| e))
            .collect();
        candidates.sort_unstable();
        candidates.dedup();
        let mut moves = Vec::new();
        'event: for e in candidates {
            let mut targets = Vec::with_capacity(current.len());
            for (i, &x) in current.iter().enumerate() {
                if !self.shares[i][e] {
                    targets.push(vec![x]);
                    continue;
                }
                let out = &self.out[i][x];
                let from = out.partition_point(|&(f, _)| f < e);
                let to: Vec<usize> = (out[from..].iter())
                    .take_while(|&&(f, _)| f == e)
                    .map(|&(_, y)| y)
                    .collect();
                if to.is_empty() {
                    continue 'event;
                }
                targets.push(to);
            }
            moves.push((e, targets));
        }
        moves
    }
}

/// The components' events, in order of first appearance, each observable as
/// in the first component that has it; and each component's events as
/// numbers among them.
fn union(components: &[&Generator]) -> (Vec<String>, Vec<bool>, Vec<Vec<usize>>) {
    let mut events: Vec<String> = Vec::new();
    let mut observable = Vec::new();
    let mut index: HashMap<&str, usize> = HashMap::new();
    let mut global: Vec<Vec<usize>> = Vec::new();
    for g in components {
        let mut mine = Vec::with_capacity(g.events.len());
        for (e, name) in g.events.iter().enumerate() {
            let id = *index.entry(name).or_insert_with(|| {
                events.push(name.clone());
                observable.push(g.observable.get(e).copied().unwrap_or(true));
                events.len() - 1
            });
            mine.push(id);
        }
        global.push(mine);
    }
    (events, observable, global)
}

/// The product's states found so far, numbered in order of discovery.
#[derive(Default)]
struct Explored {
    members: Vec<u32>,
    number: HashMap<Box<[u32]>, usize>,
    /// States found (also when there are no components).
    count: usize,
}

impl Explored {
    /// The number of the product state made of `members`, new or not.
    fn state(&mut self, members: &[usize]) -> usize {
        let key: Box<[u32]> = members.iter().map(|&x| x as u32).collect();
        if let Some(&x) = self.number.get(&key) {
            return x;
        }
        self.members.extend_from_slice(&key);
        self.number.insert(key, self.count);
        self.count += 1;
        self.count - 1
    }

    fn finish(
        self,
        components: &[&Generator],
        alphabet: Alphabet,
        initial: usize,
        transitions: Vec<(usize, usize, usize)>,
    ) -> Product {
        let width = components.len();
        let name_of = |x: usize| -> String {
            let members = &self.members[x * width..][..width];
            (components.iter().zip(members))
                .map(|(g, &m)| g.states[m as usize].as_str())
                .collect::<Vec<_>>()
                .join("|")
        };
        let marked_in = |x: usize| {
            let members = &self.members[x * width..][..width];
            (components.iter().zip(members)).all(|(g, &m)| g.marked.contains(&(m as usize)))
        };
        let generator = Generator {
            name: format!(
                "Parallel({})",
                components
                    .iter()
                    .map(|g| g.name.as_str())
                    .collect::<Vec<_>>()
                    .join(",")
            ),
            events: alphabet.events,
            observable: alphabet.observable,
            states: (0..self.count).map(name_of).collect(),
            initial: (0..initial).collect(),
            marked: (0..self.count).filter(|&x| marked_in(x)).collect(),
            transitions,
        };
        Product {
            generator,
            width,
            members: self.members,
        }
    }
}

/// How many [`combinations`] there are.
fn count(lists: &[Vec<usize>]) -> usize {
    (lists.iter()).fold(1usize, |n, list| n.saturating_mul(list.len()))
}

/// Every choice of one item per list, the first list's item varying slowest.
fn combinations(lists: &[Vec<usize>]) -> Vec<Vec<usize>> {
    let mut all = vec![Vec::with_capacity(lists.len())];
    for list in lists {
        all = (all.into_iter())
            .flat_map(|prefix| {
                list.iter().map(move |&item| {
                    let mut longer = prefix.clone();
                    longer.push(item);
                    longer
                })
            })
            .collect();
    }
    all
}

/// [`super::event_diagnosability_within`] for the product of `components`
/// ([`parallel`]), each cluster's product and verifier within `budget`
/// states and transitions. One component is checked as itself, with
/// libFAUDES's semantics for one generator (its unreachable states too).
pub fn event_diagnosability(
    components: &[Generator],
    f: &FailureTypes,
    budget: usize,
) -> Result<EventDiagnosability, ProductError> {
    event_diagnosability_explored(components, f, budget, BREADTH_FIRST)
}

/// [`event_diagnosability`], each cluster's verifier explored breadth-first
/// up to `breadth_first` nodes and edges
/// ([`super::event_diagnosability_explored`]).
pub fn event_diagnosability_explored(
    components: &[Generator],
    f: &FailureTypes,
    budget: usize,
    breadth_first: usize,
) -> Result<EventDiagnosability, ProductError> {
    if let [one] = components {
        return super::event_diagnosability_explored(one, f, budget, breadth_first).map_err(
            |too_large| ProductError::VerifierTooLarge {
                components: vec![0],
                too_large,
            },
        );
    }
    check_observability(components)?;
    let clusters = (clusters(components).into_iter())
        .map(|members| Cluster::compose(components, members, budget))
        .collect::<Result<Vec<_>, _>>()?;
    let refs: Vec<&Generator> = components.iter().collect();
    let (events, observable, _) = union(&refs);
    let mut assumptions = failure_event_violations(&events, &observable, f);
    let empty = (clusters.iter()).any(|c| c.product.generator.states.is_empty());
    if !empty {
        assumptions.extend(deadlock(components, &clusters));
        assumptions.extend(unobservable_cycle_in(components, &clusters));
    }
    super::verdict(f, assumptions, |name, failures| {
        if empty {
            return Ok(None);
        }
        counterexample(&clusters, name, failures, budget, breadth_first)
    })
}

/// Components that share an event, directly or through others, in one
/// cluster: each cluster's members in order, the clusters by first member.
pub fn clusters(components: &[Generator]) -> Vec<Vec<usize>> {
    let mut leader: Vec<usize> = (0..components.len()).collect();
    fn root(leader: &mut [usize], mut i: usize) -> usize {
        while leader[i] != i {
            leader[i] = leader[leader[i]];
            i = leader[i];
        }
        i
    }
    let mut first_with: HashMap<&str, usize> = HashMap::new();
    for (i, g) in components.iter().enumerate() {
        for name in &g.events {
            let other = *first_with.entry(name).or_insert(i);
            let (a, b) = (root(&mut leader, other), root(&mut leader, i));
            leader[a.max(b)] = a.min(b);
        }
    }
    let mut clusters: Vec<Vec<usize>> = Vec::new();
    let mut index: HashMap<usize, usize> = HashMap::new();
    for i in 0..components.len() {
        let r = root(&mut leader, i);
        let c = *index.entry(r).or_insert_with(|| {
            clusters.push(Vec::new());
            clusters.len() - 1
        });
        clusters[c].push(i);
    }
    clusters
}

/// A cluster of components, composed.
struct Cluster {
    members: Vec<usize>,
    product: Product,
    system: System,
}

impl Cluster {
    fn compose(
        components: &[Generator],
        members: Vec<usize>,
        budget: usize,
    ) -> Result<Cluster, ProductError> {
        let refs: Vec<&Generator> = members.iter().map(|&i| &components[i]).collect();
        match parallel(&refs, budget) {
            Ok(product) => Ok(Cluster {
                system: System::new(&product.generator),
                members,
                product,
            }),
            Err(reached) => Err(ProductError::ProductTooLarge {
                components: members,
                reached,
            }),
        }
    }

    /// Whether each event is an unobservable failure of `failures`.
    fn failure_mask(&self, failures: &[String]) -> Vec<bool> {
        let g = &self.product.generator;
        (g.events.iter().zip(&self.system.observable))
            .map(|(e, &observable)| !observable && failures.contains(e))
            .collect()
    }

    /// A shortest run without failures from an initial state to a state that
    /// `goal` accepts, as its events, and that state.
    fn run_to(
        &self,
        failure: &[bool],
        from: &[usize],
        within: impl Fn(usize) -> bool,
        mut goal: impl FnMut(usize) -> bool,
    ) -> Option<(Vec<usize>, usize)> {
        let mut how: HashMap<usize, Option<(usize, usize)>> = HashMap::new();
        let mut queue = VecDeque::new();
        for &x in from {
            if how.insert(x, None).is_none() {
                queue.push_back(x);
            }
        }
        while let Some(x) = queue.pop_front() {
            if goal(x) {
                let mut events = Vec::new();
                let mut at = x;
                while let Some(&Some((before, e))) = how.get(&at) {
                    events.push(e);
                    at = before;
                }
                events.reverse();
                return Some((events, x));
            }
            for &(e, y) in &self.system.out[x] {
                if !failure[e] && within(y) && !how.contains_key(&y) {
                    how.insert(y, Some((x, e)));
                    queue.push_back(y);
                }
            }
        }
        None
    }

    /// A shortest run to a failure, its last event.
    fn failure_run(&self, failure: &[bool]) -> Option<Vec<usize>> {
        let has_failure = |x: usize| self.system.out[x].iter().any(|&(e, _)| failure[e]);
        let (mut run, x) = self.run_to(
            failure,
            &self.product.generator.initial,
            |_| true,
            has_failure,
        )?;
        let &(e, _) = self.system.out[x].iter().find(|&&(e, _)| failure[e])?;
        run.push(e);
        Some(run)
    }

    /// A run without failures that shows infinitely many events: a stem ending
    /// with an observable event, then a loop ending with that event again.
    fn observed_lasso(&self, failure: &[bool]) -> Option<(Vec<usize>, Vec<usize>)> {
        let n = self.system.out.len();
        let mut reached = vec![false; n];
        let initial = &self.product.generator.initial;
        self.run_to(
            failure,
            initial,
            |_| true,
            |x| {
                reached[x] = true;
                false
            },
        );
        let graph: Vec<Vec<(usize, usize, usize)>> = (self.system.out.iter())
            .map(|out| {
                (out.iter().filter(|&&(e, _)| !failure[e]))
                    .map(|&(e, y)| (y, e, 0))
                    .collect()
            })
            .collect();
        let component = cyclic_components(&graph, &reached);
        let (x, e, y) = (0..n).find_map(|x| {
            let c = component[x]?;
            (graph[x].iter())
                .find(|&&(y, e, _)| self.system.observable[e] && component[y] == Some(c))
                .map(|&(y, e, _)| (x, e, y))
        })?;
        let (mut stem, _) = self.run_to(failure, initial, |_| true, |z| z == x)?;
        let (mut back, _) =
            self.run_to(failure, &[y], |z| component[z] == component[x], |z| z == x)?;
        stem.push(e);
        back.push(e);
        Some((stem, back))
    }

    fn names(&self, events: &[usize]) -> Vec<String> {
        let g = &self.product.generator;
        events.iter().map(|&e| g.events[e].clone()).collect()
    }

    fn shown(&self, events: &[usize]) -> Vec<String> {
        let observed: Vec<usize> = (events.iter().copied())
            .filter(|&e| self.system.observable[e])
            .collect();
        self.names(&observed)
    }
}

/// A counterexample to the product's diagnosability of the failure type made
/// of `failures`, if there is one (see the module's documentation).
fn counterexample(
    clusters: &[Cluster],
    failure_type: &str,
    failures: &[String],
    budget: usize,
    breadth_first: usize,
) -> Result<Option<Counterexample>, ProductError> {
    let masks: Vec<Vec<bool>> = clusters.iter().map(|c| c.failure_mask(failures)).collect();
    // A failure in one cluster, then another going on alone: cheap, and
    // it needs no verifier.
    if clusters.len() > 1 {
        let lassos: Vec<_> = (clusters.iter().zip(&masks))
            .map(|(c, mask)| c.observed_lasso(mask))
            .collect();
        for (k, (cluster, mask)) in clusters.iter().zip(&masks).enumerate() {
            let Some(failed) = cluster.failure_run(mask) else {
                continue;
            };
            let other = (lassos.iter().enumerate())
                .find_map(|(j, l)| l.as_ref().filter(|_| j != k).map(|l| (j, l)));
            if let Some((j, (stem, cycle))) = other {
                return Ok(Some(stand_still(
                    cluster,
                    &failed,
                    &clusters[j],
                    stem,
                    cycle,
                )));
            }
        }
    }
    for (cluster, mask) in clusters.iter().zip(&masks) {
        if !mask.contains(&true) {
            continue;
        }
        let found = super::verify(
            &cluster.product.generator,
            &cluster.system,
            failures,
            budget,
            breadth_first,
        )
        .map_err(|reached| ProductError::VerifierTooLarge {
            components: cluster.members.clone(),
            too_large: TooLarge {
                failure_type: failure_type.to_string(),
                reached,
            },
        })?;
        if found.is_some() {
            return Ok(found);
        }
    }
    Ok(None)
}

/// The runs where `failed`'s cluster fails, then stands still while `other`
/// goes on, and where it stops just before the failure.
fn stand_still(
    failed: &Cluster,
    run: &[usize],
    other: &Cluster,
    stem: &[usize],
    cycle: &[usize],
) -> Counterexample {
    let before = &run[..run.len() - 1];
    let tail: Vec<String> = [other.names(stem), other.names(cycle)].concat();
    let mut observed = failed.shown(before);
    observed.extend(other.shown(stem));
    let cycle_from = observed.len();
    observed.extend(other.shown(cycle));
    Counterexample {
        faulty: [failed.names(run), tail.clone()].concat(),
        normal: [failed.names(before), tail].concat(),
        observed,
        cycle_from,
    }
}

/// The product's dead states, when every cluster has some: every
/// combination of theirs.
fn deadlock(components: &[Generator], clusters: &[Cluster]) -> Option<AssumptionViolation> {
    let dead: Vec<Vec<usize>> = (clusters.iter())
        .map(|c| {
            (0..c.system.out.len())
                .filter(|&x| c.system.out[x].is_empty())
                .collect()
        })
        .collect();
    if dead.iter().any(Vec::is_empty) {
        return None;
    }
    let total = (dead.iter()).fold(1usize, |n, d| n.saturating_mul(d.len()));
    let listed = total.min(LISTED_STATES);
    let states = (0..listed)
        .map(|mut i| {
            // The i-th combination, the last cluster varying fastest.
            let mut choice = vec![0; dead.len()];
            for (c, d) in dead.iter().enumerate().rev() {
                choice[c] = d[i % d.len()];
                i /= d.len();
            }
            state_name(components, clusters, &choice)
        })
        .collect();
    Some(AssumptionViolation::Deadlock {
        states,
        more: total - listed,
    })
}

/// A cycle of unobservable events in some cluster, the others at their
/// first initial state.
fn unobservable_cycle_in(
    components: &[Generator],
    clusters: &[Cluster],
) -> Option<AssumptionViolation> {
    clusters.iter().enumerate().find_map(|(k, cluster)| {
        let (states, events) = unobservable_cycle(&cluster.system)?;
        let mut choice = vec![0; clusters.len()];
        let states = (states.into_iter())
            .map(|x| {
                choice[k] = x;
                state_name(components, clusters, &choice)
            })
            .collect();
        let g = &cluster.product.generator;
        let events = events.into_iter().map(|e| g.events[e].clone()).collect();
        Some(AssumptionViolation::UnobservableCycle { states, events })
    })
}

/// The name of the product state made of each cluster's state `choice[k]`:
/// its components' states, in component order, joined by `|`.
fn state_name(components: &[Generator], clusters: &[Cluster], choice: &[usize]) -> String {
    let mut names = vec![""; components.len()];
    for (cluster, &x) in clusters.iter().zip(choice) {
        for (&i, &m) in cluster.members.iter().zip(cluster.product.members(x)) {
            names[i] = &components[i].states[m as usize];
        }
    }
    names.join("|")
}
