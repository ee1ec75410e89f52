//! Model pictures for the report: the graphs this project draws
//! ([`Digraph`]s: `learning::graph::part_digraph`, `Compiled::to_digraph`)
//! turned into inline SVG.
//!
//! Graphviz's `dot` draws the best pictures, from the graph's DOT text
//! ([`Digraph::to_dot`]), but it is an optional install and takes long on a
//! large diagnoser, so a built-in layered layout draws the graph itself when
//! `dot` is missing, fails or runs too long. No DOT text is read back.

use std::fmt::Write as _;
use std::io::{ErrorKind, Read, Write as _};
use std::process::{Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use digraph::{Digraph, Edge, Node, RankDirection};

/// How the pictures are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// Graphviz when its `dot` program runs (in time), else the built-in layout.
    Auto,
    /// Graphviz only: an error when `dot` cannot run.
    Graphviz,
    /// The built-in layout only: `dot` is never run.
    BuiltIn,
}

/// One picture, ready to inline in HTML.
#[derive(Debug, Clone)]
pub struct Picture {
    /// One `<svg>` element (no XML prolog) that shrinks to fit its container.
    pub svg: String,
    /// What laid it out: "Graphviz dot" or "built-in layout".
    pub by: &'static str,
}

const BY_GRAPHVIZ: &str = "Graphviz dot";
const BY_BUILT_IN: &str = "built-in layout";

/// Renders a graph. `id_prefix` makes every `id="..."` in the SVG unique in a
/// page holding several pictures.
///
/// Auto: Graphviz `dot -Tsvg` when the program runs, else the built-in layout.
/// Graphviz: an error if `dot` cannot run. BuiltIn: never runs `dot`. An edge
/// to or from a node the graph does not have is an error.
pub fn render(graph: &Digraph, layout: Layout, id_prefix: &str) -> Result<Picture, String> {
    let n = graph.nodes.len();
    if let Some(e) = graph.edges.iter().find(|e| e.from >= n || e.to >= n) {
        return Err(format!(
            "graph {:?}: an edge from node {} to node {}, of {n} nodes",
            graph.name, e.from, e.to
        ));
    }
    match layout {
        Layout::BuiltIn => built_in(graph, id_prefix),
        Layout::Graphviz => graphviz(graph, id_prefix),
        Layout::Auto => graphviz(graph, id_prefix).or_else(|_| built_in(graph, id_prefix)),
    }
}

fn built_in(graph: &Digraph, id_prefix: &str) -> Result<Picture, String> {
    let drawing = lay_out(graph)?;
    Ok(Picture {
        svg: drawing.to_svg(id_prefix),
        by: BY_BUILT_IN,
    })
}

// ---------------------------------------------------------------------------
// Graphviz

/// Longest wait for `dot`: a picture is not worth holding the report up.
const DOT_TIMEOUT: Duration = Duration::from_secs(20);

/// Above this many edges, `dot`'s network simplex passes are bounded: unbounded,
/// they take half a minute on the turntable's diagnoser (282 states, 766 edges),
/// bounded a few seconds, for a picture hardly worse.
const DOT_BIG_GRAPH_EDGES: usize = 300;

fn graphviz(graph: &Digraph, id_prefix: &str) -> Result<Picture, String> {
    let args: &[&str] = if graph.edges.len() > DOT_BIG_GRAPH_EDGES {
        &["-Gnslimit=2", "-Gnslimit1=2"]
    } else {
        &[]
    };
    let raw = run_dot("dot", args, &graph.to_dot(), DOT_TIMEOUT)?;
    Ok(Picture {
        svg: tidy_graphviz_svg(&raw, id_prefix)?,
        by: BY_GRAPHVIZ,
    })
}

/// Runs `program -Tsvg args` (Graphviz's `dot`) on `input`, killing it after
/// `timeout`.
fn run_dot(program: &str, args: &[&str], input: &str, timeout: Duration) -> Result<String, String> {
    let mut child = Command::new(program)
        .arg("-Tsvg")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            if e.kind() == ErrorKind::NotFound {
                format!(
                    "Graphviz `{program}` not found: install Graphviz or use the built-in layout"
                )
            } else {
                format!("cannot run Graphviz `{program}`: {e}")
            }
        })?;
    // Feed and drain the pipes from threads, so that neither side blocks the
    // other and the timeout below stays in force.
    let stdin = child.stdin.take();
    let text = input.to_owned();
    let writer = thread::spawn(move || {
        if let Some(mut stdin) = stdin {
            let _ = stdin.write_all(text.as_bytes());
        }
    });
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());

    let deadline = Instant::now() + timeout;
    let mut pause = Duration::from_millis(1);
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if Instant::now() < deadline => {
                thread::sleep(pause);
                pause = (pause * 2).min(Duration::from_millis(25));
            }
            waited => {
                let _ = child.kill();
                let _ = child.wait();
                // The pipe threads end when the pipes close; not waited for, in
                // case something the program started still holds them.
                return Err(match waited {
                    Err(e) => format!("cannot wait for Graphviz `{program}`: {e}"),
                    _ => format!(
                        "Graphviz `{program}` took more than {} s: stopped",
                        timeout.as_secs_f64()
                    ),
                });
            }
        }
    };
    let _ = writer.join();
    let out = stdout.join().unwrap_or_default();
    let err = stderr.join().unwrap_or_default();
    if !status.success() {
        let err = String::from_utf8_lossy(&err);
        let first = err.lines().take(3).collect::<Vec<_>>().join(" / ");
        return Err(format!("Graphviz `{program}` failed ({status}): {first}"));
    }
    String::from_utf8(out).map_err(|_| format!("Graphviz `{program}` wrote invalid UTF-8"))
}

/// Reads a pipe to its end in a thread.
fn drain<R: Read + Send + 'static>(pipe: Option<R>) -> thread::JoinHandle<Vec<u8>> {
    thread::spawn(move || {
        let mut bytes = Vec::new();
        if let Some(mut pipe) = pipe {
            let _ = pipe.read_to_end(&mut bytes);
        }
        bytes
    })
}

/// Keeps Graphviz's `<svg>` element only (no prolog, doctype or comments),
/// prefixes its ids and makes it shrink to fit the page.
fn tidy_graphviz_svg(raw: &str, id_prefix: &str) -> Result<String, String> {
    let start = raw
        .find("<svg")
        .ok_or_else(|| "Graphviz `dot` wrote no <svg> element".to_string())?;
    let prefix = esc(id_prefix);
    let mut out = String::with_capacity(raw.len() - start + 64);
    let mut rest = &raw[start..];
    let mut root = true;
    while let Some(i) = rest.find('<') {
        out.push_str(&rest[..i]);
        rest = &rest[i..];
        if rest.starts_with("<!--") {
            rest = rest.find("-->").map_or("", |j| &rest[j + 3..]);
            continue;
        }
        let end = rest.find('>').map_or(rest.len(), |j| j + 1);
        let tag = &rest[..end];
        rest = &rest[end..];
        if root {
            root = false;
            out.push_str(&prefix_refs(&fit_root(tag), &prefix));
        } else {
            out.push_str(&prefix_refs(tag, &prefix));
        }
    }
    out.push_str(rest);
    // Comments leave blank lines behind.
    let mut tidy = String::with_capacity(out.len());
    for line in out.lines().filter(|l| !l.trim().is_empty()) {
        tidy.push_str(line);
        tidy.push('\n');
    }
    Ok(tidy)
}

/// The root `<svg>` tag sized in pixels from its viewBox (1 pt of Graphviz = 1
/// px: its 14 pt text stays legible) and free to shrink to the page's width.
fn fit_root(tag: &str) -> String {
    let inner = tag
        .trim_start_matches("<svg")
        .trim_end_matches('>')
        .trim_end_matches('/');
    let attrs = tag_attributes(inner);
    let get = |k: &str| attrs.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
    let number = |v: &str| {
        v.trim()
            .trim_end_matches(|c: char| c.is_ascii_alphabetic())
            .parse::<f64>()
            .ok()
    };
    let view_box = get("viewBox").map(str::to_string).or_else(|| {
        let w = number(get("width")?)?;
        let h = number(get("height")?)?;
        Some(format!("0 0 {} {}", N(w), N(h)))
    });
    let size = view_box.as_deref().and_then(|vb| {
        let v: Vec<f64> = vb
            .split([' ', ','])
            .filter(|s| !s.is_empty())
            .filter_map(|s| s.parse().ok())
            .collect();
        (v.len() == 4).then(|| (v[2], v[3]))
    });
    let mut out = String::from("<svg");
    if let Some((w, h)) = size {
        let _ = write!(out, r#" width="{}" height="{}""#, N(w), N(h));
    }
    if let Some(vb) = &view_box {
        let _ = write!(out, r#" viewBox="{vb}""#);
    }
    out.push_str(r#" style="max-width:100%;height:auto""#);
    for (k, v) in &attrs {
        if !matches!(k.as_str(), "width" | "height" | "viewBox" | "style") {
            let _ = write!(out, r#" {k}="{v}""#);
        }
    }
    out.push('>');
    out
}

/// `name="value"` pairs of a tag (values kept escaped as they are).
fn tag_attributes(s: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut rest = s;
    while let Some(eq) = rest.find('=') {
        let name = rest[..eq].trim().to_string();
        let after = rest[eq + 1..].trim_start();
        let Some(quote) = after.chars().next().filter(|c| *c == '"' || *c == '\'') else {
            break;
        };
        let Some(close) = after[1..].find(quote) else {
            break;
        };
        out.push((name, after[1..1 + close].to_string()));
        rest = &after[close + 2..];
    }
    out
}

/// Prefixes the ids a tag defines and the ids it refers to.
fn prefix_refs(tag: &str, prefix: &str) -> String {
    if prefix.is_empty() {
        return tag.to_string();
    }
    let mut out = String::with_capacity(tag.len() + 16);
    let mut i = 0;
    while i < tag.len() {
        let rest = &tag[i..];
        let preceded_by_space = tag[..i].ends_with(char::is_whitespace);
        let pattern = if preceded_by_space && rest.starts_with("id=\"") {
            Some("id=\"")
        } else if rest.starts_with("href=\"#") {
            Some("href=\"#")
        } else if rest.starts_with("url(#") {
            Some("url(#")
        } else {
            None
        };
        match pattern {
            Some(p) => {
                out.push_str(p);
                out.push_str(prefix);
                i += p.len();
            }
            None => {
                let c = rest.chars().next().unwrap_or(' ');
                out.push(c);
                i += c.len_utf8();
            }
        }
    }
    out
}

// ---------------------------------------------------------------------------
// Labels

/// The lines a label is drawn in: its lines, each broken again at a line break
/// it holds, as Graphviz reads DOT text (a final break ends the last line
/// rather than opening an empty one), carriage returns dropped; none when
/// every line is empty.
fn drawn_lines(label: &[String]) -> Vec<String> {
    let text = label.join("\n");
    let body = text.strip_suffix('\n').unwrap_or(&text);
    let mut lines: Vec<String> = body.split('\n').map(|l| l.replace('\r', "")).collect();
    if lines.iter().all(String::is_empty) {
        lines.clear();
    }
    lines
}

// ---------------------------------------------------------------------------
// Built-in layout: layered (Sugiyama) drawing along the graph's rank direction.

/// Text metrics: 12 px Helvetica, about 7 px a character.
const FONT_SIZE: f64 = 12.0;
const CHAR_W: f64 = 7.0;
const LINE_H: f64 = 15.0;
const CAPTION_SIZE: f64 = 14.0;
const CAPTION_CHAR_W: f64 = 8.0;
const CAPTION_LINE_H: f64 = 17.0;
/// Space around the drawing.
const MARGIN: f64 = 8.0;
/// Space between a rank's column and the next (where the edges bend).
const RANK_GAP: f64 = 28.0;
/// Space between neighbours in a rank: boxes, edge lines, a box and a line.
const NODE_GAP: f64 = 18.0;
const LINE_GAP: f64 = 8.0;
const MIXED_GAP: f64 = 12.0;
const ARROW: f64 = 8.0;
const ARROW_HALF_WIDTH: f64 = 3.5;
/// Space between a node's border and its second periphery.
const PERIPHERY_GAP: f64 = 4.0;
/// Padding around label text on its white background.
const LABEL_PAD: f64 = 2.0;
/// Bound on the layout's vertices (nodes plus edge bends).
const MAX_VERTICES: usize = 400_000;
/// Bounds on the ordering and placement sweeps, scaled down on big graphs so
/// the layout stays well under a second.
const MAX_SWEEPS: usize = 24;
const SWEEP_BUDGET: usize = 1_500_000;

/// A point on the page.
#[derive(Debug, Clone, Copy, PartialEq)]
struct P {
    x: f64,
    y: f64,
}

/// An axis-aligned box on the page (top-left corner and size).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rect {
    x: f64,
    y: f64,
    w: f64,
    h: f64,
}

impl Rect {
    fn centred(c: P, w: f64, h: f64) -> Rect {
        Rect {
            x: c.x - w / 2.0,
            y: c.y - h / 2.0,
            w,
            h,
        }
    }

    #[cfg(test)]
    fn overlaps(&self, o: &Rect) -> bool {
        self.x < o.x + o.w && o.x < self.x + self.w && self.y < o.y + o.h && o.y < self.y + self.h
    }
}

/// The rank direction: layout works in (rank, order) coordinates, `r` along
/// the ranks and `o` across them, turned into page coordinates at the end.
#[derive(Debug, Clone, Copy)]
enum Flow {
    Right,
    Left,
    Down,
    Up,
}

impl Flow {
    fn of(direction: RankDirection) -> Flow {
        match direction {
            RankDirection::LeftToRight => Flow::Right,
            RankDirection::RightToLeft => Flow::Left,
            RankDirection::BottomToTop => Flow::Up,
            RankDirection::TopToBottom => Flow::Down,
        }
    }

    fn point(self, r: f64, o: f64) -> P {
        match self {
            Flow::Right => P { x: r, y: o },
            Flow::Left => P { x: -r, y: o },
            Flow::Down => P { x: o, y: r },
            Flow::Up => P { x: o, y: -r },
        }
    }

    /// A page size `(w, h)` as (extent along the ranks, extent across them).
    fn along(self, (w, h): (f64, f64)) -> (f64, f64) {
        match self {
            Flow::Right | Flow::Left => (w, h),
            Flow::Down | Flow::Up => (h, w),
        }
    }
}

/// How a node looks.
#[derive(Debug)]
struct NodeLook {
    name: String,
    lines: Vec<String>,
    fill: Option<String>,
    double: bool,
    rounded: bool,
}

impl NodeLook {
    fn new(g: &Digraph, n: &Node) -> NodeLook {
        NodeLook {
            name: n.id.clone(),
            lines: drawn_lines(&n.label),
            fill: n
                .fill
                .as_deref()
                .map(|c| colour(c).unwrap_or("lightgrey").to_string()),
            double: n.double_border,
            rounded: g.rounded_nodes,
        }
    }

    /// Page size: the text plus padding (and the second periphery).
    fn size(&self) -> (f64, f64) {
        let (tw, th) = text_size(&self.lines, CHAR_W, LINE_H);
        let extra = if self.double {
            2.0 * PERIPHERY_GAP
        } else {
            0.0
        };
        ((tw + 16.0).max(30.0) + extra, (th + 10.0).max(24.0) + extra)
    }
}

/// How an edge looks.
#[derive(Debug)]
struct EdgeLook {
    title: String,
    lines: Vec<String>,
    bold: bool,
}

impl EdgeLook {
    fn new(g: &Digraph, e: &Edge) -> EdgeLook {
        EdgeLook {
            title: format!("{}->{}", g.nodes[e.from].id, g.nodes[e.to].id),
            lines: drawn_lines(&e.label),
            bold: e.bold,
        }
    }

    /// Page size of the label on its background, if any.
    fn label_size(&self) -> Option<(f64, f64)> {
        (!self.lines.is_empty()).then(|| {
            let (w, h) = text_size(&self.lines, CHAR_W, LINE_H);
            (w + 2.0 * LABEL_PAD, h + 2.0 * LABEL_PAD)
        })
    }
}

/// A colour safe to write into an attribute (a name or `#rrggbb`).
fn colour(c: &str) -> Option<&str> {
    let c = c.trim();
    (!c.is_empty() && c.len() <= 40 && c.chars().all(|ch| ch.is_ascii_alphanumeric() || ch == '#'))
        .then_some(c)
}

fn text_size(lines: &[String], char_w: f64, line_h: f64) -> (f64, f64) {
    let chars = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    (chars as f64 * char_w, lines.len() as f64 * line_h)
}

/// A drawn node.
#[derive(Debug)]
struct NodeShape {
    look: NodeLook,
    rect: Rect,
}

/// A drawn edge.
#[derive(Debug)]
struct EdgeShape {
    look: EdgeLook,
    route: Route,
}

/// Where an edge goes: a chain of cubic Bézier segments, its arrowhead and label.
#[derive(Debug)]
struct Route {
    start: P,
    segments: Vec<[P; 3]>,
    /// Base and tip of the arrowhead.
    arrow: (P, P),
    label: Option<Rect>,
}

/// A laid-out graph, in page coordinates.
#[derive(Debug)]
struct Drawing {
    title: String,
    width: f64,
    height: f64,
    nodes: Vec<NodeShape>,
    edges: Vec<EdgeShape>,
    caption: Vec<String>,
}

/// One vertex of the layered graph: a node, or where an edge crosses a rank.
#[derive(Debug, Clone, Copy)]
struct Vertex {
    rank: usize,
    /// Extent along the ranks and across them.
    size_r: f64,
    size_o: f64,
    dummy: bool,
}

/// An edge's vertices from its lower rank to its higher.
#[derive(Debug)]
struct Chain {
    edge: usize,
    vertices: Vec<usize>,
    /// Drawn from the last vertex to the first (an edge reversed to break a cycle).
    reversed: bool,
    label: Option<usize>,
}

/// How far the `i`th self-loop of a node reaches out from its side.
fn loop_bulge(i: usize) -> f64 {
    16.0 + 10.0 * i as f64
}

/// How far the ends of the `i`th self-loop of a node are from the side's middle.
fn loop_end(i: usize) -> f64 {
    6.0 + 5.0 * i as f64
}

/// Lays a graph out in layers along its rank direction: cycles broken, ranks
/// by longest path, each rank ordered against crossings, positions across the
/// ranks by least squares, edges drawn as Bézier curves through their bends.
fn lay_out(g: &Digraph) -> Result<Drawing, String> {
    let flow = Flow::of(g.rank_direction);
    let looks: Vec<NodeLook> = g.nodes.iter().map(|n| NodeLook::new(g, n)).collect();
    let edge_looks: Vec<EdgeLook> = g.edges.iter().map(|e| EdgeLook::new(g, e)).collect();
    let n = looks.len();
    let labels: Vec<Option<(f64, f64)>> = edge_looks.iter().map(EdgeLook::label_size).collect();
    let loops = self_loops(g, n);
    let boxes = node_boxes(&looks, &loops, flow);
    let pairs: Vec<(usize, usize)> = g.edges.iter().map(|e| (e.from, e.to)).collect();
    let back = back_edges(n, &pairs);
    let dag: Vec<(usize, usize)> = pairs
        .iter()
        .zip(&back)
        .filter(|((a, b), _)| a != b)
        .map(|(&(a, b), &rev)| if rev { (b, a) } else { (a, b) })
        .collect();
    let rank = rank_nodes(n, &dag);
    let mut vertices = node_vertices(&boxes, &loops, &labels, &rank, flow);
    let chains = edge_chains(&pairs, &back, &labels, &mut vertices, flow)?;
    let (up, down, links) = chain_neighbours(&chains, &vertices);
    let sweeps = (SWEEP_BUDGET / (vertices.len() + links).max(1)).clamp(2, MAX_SWEEPS);
    let layers = order_layers(&vertices, &up, &down, sweeps);
    let o = place_across(&layers, &vertices, &up, &down, sweeps);
    let (extent, rank_at) = rank_positions(layers.len(), &vertices);
    let placed = Placed {
        flow,
        boxes,
        vertices,
        o,
        extent,
        rank_at,
        labels,
    };
    let ports = placed.ports(&chains, n);
    let nodes: Vec<NodeShape> = looks
        .into_iter()
        .enumerate()
        .map(|(v, look)| placed.node(v, look))
        .collect();
    let mut routes: Vec<Option<Route>> = (0..g.edges.len()).map(|_| None).collect();
    for (c, &port) in chains.iter().zip(&ports) {
        routes[c.edge] = Some(placed.chain_route(c, port));
    }
    for (v, list) in loops.iter().enumerate() {
        for (e, route) in placed.loop_routes(v, list) {
            routes[e] = Some(route);
        }
    }
    // Every edge is either a chain or a loop.
    let edges = routes
        .into_iter()
        .zip(edge_looks)
        .filter_map(|(route, look)| route.map(|route| EdgeShape { look, route }))
        .collect();
    let caption = drawn_lines(&g.caption);
    let title = drawn_lines(std::slice::from_ref(&g.name)).join(" ");
    let mut drawing = Drawing {
        title,
        width: 0.0,
        height: 0.0,
        nodes,
        edges,
        caption,
    };
    drawing.fit();
    Ok(drawing)
}

/// Per node, its self-loops (edge numbers).
fn self_loops(g: &Digraph, n: usize) -> Vec<Vec<usize>> {
    let mut loops: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (i, e) in g.edges.iter().enumerate() {
        if e.from == e.to {
            loops[e.from].push(i);
        }
    }
    loops
}

/// Each node's box as (extent along the ranks, across them). Self-loops hang
/// on one side of their node, nested, their labels past them: the node is
/// widened to hold their ends apart.
fn node_boxes(looks: &[NodeLook], loops: &[Vec<usize>], flow: Flow) -> Vec<(f64, f64)> {
    looks
        .iter()
        .zip(loops)
        .map(|(look, list)| {
            let (r, o) = flow.along(look.size());
            let ends = list
                .len()
                .checked_sub(1)
                .map_or(0.0, |i| 2.0 * loop_end(i) + 8.0);
            (r.max(ends), o)
        })
        .collect()
}

/// The nodes as vertices on even ranks, each slot across its rank making room
/// for the node's self-loops and their labels.
fn node_vertices(
    boxes: &[(f64, f64)],
    loops: &[Vec<usize>],
    labels: &[Option<(f64, f64)>],
    rank: &[usize],
    flow: Flow,
) -> Vec<Vertex> {
    (0..boxes.len())
        .map(|v| {
            let (br, bo) = boxes[v];
            let (mut size_r, mut size_o) = (br, bo);
            if let Some(last) = loops[v].len().checked_sub(1) {
                size_o += loop_bulge(last) + 4.0;
                for &e in &loops[v] {
                    if let Some(size) = labels[e] {
                        let (lr, lo) = flow.along(size);
                        size_r = size_r.max(lr);
                        size_o += lo + 2.0;
                    }
                }
            }
            Vertex {
                rank: 2 * rank[v],
                size_r,
                size_o,
                dummy: false,
            }
        })
        .collect()
}

/// Each edge between two nodes as a chain of vertices, one per rank it
/// crosses (`vertices` gains them). Ranks are doubled: nodes sit on even
/// ranks, edge labels on odd ones, so labels get room of their own and never
/// cover a node.
fn edge_chains(
    pairs: &[(usize, usize)],
    back: &[bool],
    labels: &[Option<(f64, f64)>],
    vertices: &mut Vec<Vertex>,
    flow: Flow,
) -> Result<Vec<Chain>, String> {
    let n = vertices.len();
    let mut chains = Vec::new();
    for (i, &(tail, head)) in pairs.iter().enumerate() {
        if tail == head {
            continue;
        }
        let (a, b) = if back[i] { (head, tail) } else { (tail, head) };
        let (ra, rb) = (vertices[a].rank, vertices[b].rank);
        let label_rank = ((ra + rb) / 2) | 1;
        let mut chain = vec![a];
        let mut label = None;
        for r in ra + 1..rb {
            if vertices.len() >= MAX_VERTICES {
                return Err(format!(
                    "graph too large for the built-in layout ({n} nodes, {} edges)",
                    pairs.len()
                ));
            }
            let (size_r, size_o) = match labels[i] {
                Some(size) if r == label_rank => {
                    label = Some(vertices.len());
                    flow.along(size)
                }
                _ => (0.0, 0.0),
            };
            chain.push(vertices.len());
            vertices.push(Vertex {
                rank: r,
                size_r,
                size_o,
                dummy: true,
            });
        }
        chain.push(b);
        chains.push(Chain {
            edge: i,
            vertices: chain,
            reversed: back[i],
            label,
        });
    }
    Ok(chains)
}

/// Per vertex, its neighbours in one direction, each with its link's weight.
type Neighbours = Vec<Vec<(usize, f64)>>;

/// Each vertex's neighbours in the rank above and below, weighted so that
/// long edges (chains of bends) pull hardest towards straight lines, and how
/// many links there are.
fn chain_neighbours(chains: &[Chain], vertices: &[Vertex]) -> (Neighbours, Neighbours, usize) {
    let count = vertices.len();
    let mut up: Neighbours = vec![Vec::new(); count];
    let mut down: Neighbours = vec![Vec::new(); count];
    let mut links = 0;
    for c in chains {
        for w in c.vertices.windows(2) {
            let weight = match (vertices[w[0]].dummy, vertices[w[1]].dummy) {
                (false, false) => 1.0,
                (true, true) => 8.0,
                _ => 2.0,
            };
            down[w[0]].push((w[1], weight));
            up[w[1]].push((w[0], weight));
            links += 1;
        }
    }
    (up, down, links)
}

/// Each rank's extent along the flow, and its position.
fn rank_positions(ranks: usize, vertices: &[Vertex]) -> (Vec<f64>, Vec<f64>) {
    let mut extent = vec![0.0f64; ranks];
    for v in vertices {
        extent[v.rank] = extent[v.rank].max(v.size_r);
    }
    let mut rank_at = vec![0.0f64; ranks];
    for r in 1..ranks {
        rank_at[r] = rank_at[r - 1] + extent[r - 1] / 2.0 + RANK_GAP + extent[r] / 2.0;
    }
    (extent, rank_at)
}

/// Vertices placed in (rank, order) coordinates: what routes are drawn from.
struct Placed {
    flow: Flow,
    /// Each node's box (along, across).
    boxes: Vec<(f64, f64)>,
    vertices: Vec<Vertex>,
    /// Each vertex's position across the ranks.
    o: Vec<f64>,
    /// Each rank's extent along the flow.
    extent: Vec<f64>,
    /// Each rank's position along the flow.
    rank_at: Vec<f64>,
    /// Each edge's label size, if it has a label.
    labels: Vec<Option<(f64, f64)>>,
}

impl Placed {
    /// Where node `v`'s box is centred across its rank: at the start of its
    /// slot, its self-loops after it.
    fn centre_o(&self, v: usize) -> f64 {
        self.o[v] - self.vertices[v].size_o / 2.0 + self.boxes[v].1 / 2.0
    }

    /// Node `v`'s shape on the page.
    fn node(&self, v: usize, look: NodeLook) -> NodeShape {
        let (w, h) = self.flow.along(self.boxes[v]);
        let c = self
            .flow
            .point(self.rank_at[self.vertices[v].rank], self.centre_o(v));
        NodeShape {
            look,
            rect: Rect::centred(c, w, h),
        }
    }

    /// Per chain, where it leaves its first node and enters its last: the
    /// edges leaving one side of a node spread along it in the order of
    /// where they go, so parallel edges fan out instead of stacking.
    fn ports(&self, chains: &[Chain], n: usize) -> Vec<(f64, f64)> {
        let mut sides: Vec<[Vec<(f64, usize)>; 2]> = vec![[Vec::new(), Vec::new()]; n];
        for (ci, c) in chains.iter().enumerate() {
            let k = c.vertices.len();
            sides[c.vertices[0]][1].push((self.o[c.vertices[1]], ci));
            sides[c.vertices[k - 1]][0].push((self.o[c.vertices[k - 2]], ci));
        }
        let mut ports = vec![(0.0, 0.0); chains.len()];
        for (v, [before, after]) in sides.iter_mut().enumerate() {
            let (lo, span) = (self.centre_o(v) - self.boxes[v].1 / 2.0, self.boxes[v].1);
            for (side, list) in [(0, before), (1, after)] {
                list.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                let k = list.len() as f64;
                for (i, &(_, ci)) in list.iter().enumerate() {
                    let at = lo + span * (i as f64 + 1.0) / (k + 1.0);
                    if side == 1 {
                        ports[ci].0 = at;
                    } else {
                        ports[ci].1 = at;
                    }
                }
            }
        }
        ports
    }

    /// Chain `c`'s route from port `start_o` to port `end_o`, straight
    /// across each rank it crosses, with its arrowhead and label.
    fn chain_route(&self, c: &Chain, (start_o, end_o): (f64, f64)) -> Route {
        let (flow, vertices, rank_at) = (self.flow, &self.vertices, &self.rank_at);
        let k = c.vertices.len();
        let (a, b) = (c.vertices[0], c.vertices[k - 1]);
        let mut points = Vec::with_capacity(2 * k);
        push_point(
            &mut points,
            (rank_at[vertices[a].rank] + self.boxes[a].0 / 2.0, start_o),
        );
        for &d in &c.vertices[1..k - 1] {
            let r = vertices[d].rank;
            let half = self.extent[r] / 2.0;
            // Straight across the rank's column, clear of its boxes.
            push_point(&mut points, (rank_at[r] - half, self.o[d]));
            if half > 0.0 {
                push_point(&mut points, (rank_at[r] + half, self.o[d]));
            }
        }
        push_point(
            &mut points,
            (rank_at[vertices[b].rank] - self.boxes[b].0 / 2.0, end_o),
        );
        if c.reversed {
            points.reverse();
        }
        let tip = points[points.len() - 1];
        let before = points[points.len() - 2];
        let back = if before.0 < tip.0 { -ARROW } else { ARROW };
        let base = (tip.0 + back, tip.1);
        let last = points.len() - 1;
        points[last] = base;
        let arrow = (flow.point(base.0, base.1), flow.point(tip.0, tip.1));
        let segments = points
            .windows(2)
            .map(|w| {
                let ((r0, o0), (r1, o1)) = (w[0], w[1]);
                let mid = (r0 + r1) / 2.0;
                [flow.point(mid, o0), flow.point(mid, o1), flow.point(r1, o1)]
            })
            .collect();
        let label = c.label.zip(self.labels[c.edge]).map(|(d, (w, h))| {
            Rect::centred(flow.point(rank_at[vertices[d].rank], self.o[d]), w, h)
        });
        Route {
            start: flow.point(points[0].0, points[0].1),
            segments,
            arrow,
            label,
        }
    }

    /// The routes of node `v`'s self-loops `list`, nested on one side of it,
    /// their labels past them.
    fn loop_routes(&self, v: usize, list: &[usize]) -> Vec<(usize, Route)> {
        let flow = self.flow;
        let bo = self.boxes[v].1;
        let cr = self.rank_at[self.vertices[v].rank];
        let side = self.centre_o(v) + bo / 2.0;
        let mut next_label = side + list.len().checked_sub(1).map_or(0.0, loop_bulge) + 4.0;
        let mut routes = Vec::with_capacity(list.len());
        for (i, &e) in list.iter().enumerate() {
            let a = loop_end(i);
            let reach = side + loop_bulge(i) * 4.0 / 3.0;
            let tip = (cr + a, side);
            let end = (cr + a, side + ARROW);
            let label = self.labels[e].map(|(w, h)| {
                let (_, lo) = flow.along((w, h));
                let r = Rect::centred(flow.point(cr, next_label + lo / 2.0), w, h);
                next_label += lo + 2.0;
                r
            });
            let route = Route {
                start: flow.point(cr - a, side),
                segments: vec![[
                    flow.point(cr - 2.0 * a, reach),
                    flow.point(cr + 2.0 * a, reach),
                    flow.point(end.0, end.1),
                ]],
                arrow: (flow.point(end.0, end.1), flow.point(tip.0, tip.1)),
                label,
            };
            routes.push((e, route));
        }
        routes
    }
}

/// Appends a point to an edge's route; a straight run along the ranks needs
/// no points in between.
fn push_point(points: &mut Vec<(f64, f64)>, p: (f64, f64)) {
    let n = points.len();
    if n >= 2 && (points[n - 2].1 - p.1).abs() < 0.5 && (points[n - 1].1 - p.1).abs() < 0.5 {
        points[n - 1] = p;
    } else {
        points.push(p);
    }
}

/// Edges to reverse so the graph has no cycle: the back edges of a depth-first
/// search started from the sources, then from the nodes in their order.
fn back_edges(n: usize, edges: &[(usize, usize)]) -> Vec<bool> {
    let mut out: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    let mut indegree = vec![0usize; n];
    for (i, &(a, b)) in edges.iter().enumerate() {
        if a != b {
            out[a].push((i, b));
            indegree[b] += 1;
        }
    }
    let roots = (0..n)
        .filter(|&v| indegree[v] == 0)
        .chain((0..n).filter(|&v| indegree[v] > 0));
    // 0: unseen, 1: on the search path, 2: done.
    let mut state = vec![0u8; n];
    let mut back = vec![false; edges.len()];
    let mut stack: Vec<(usize, usize)> = Vec::new();
    for root in roots {
        if state[root] != 0 {
            continue;
        }
        state[root] = 1;
        stack.push((root, 0));
        while let Some(top) = stack.last_mut() {
            let (v, k) = *top;
            match out[v].get(k) {
                Some(&(e, w)) => {
                    top.1 += 1;
                    match state[w] {
                        0 => {
                            state[w] = 1;
                            stack.push((w, 0));
                        }
                        1 => back[e] = true,
                        _ => {}
                    }
                }
                None => {
                    state[v] = 2;
                    stack.pop();
                }
            }
        }
    }
    back
}

/// Longest-path ranks of an acyclic graph, then nodes with more edges out than
/// in pulled towards their successors, which shortens edges.
fn rank_nodes(n: usize, dag: &[(usize, usize)]) -> Vec<usize> {
    let mut out: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut indegree = vec![0usize; n];
    for &(a, b) in dag {
        out[a].push(b);
        indegree[b] += 1;
    }
    let mut waiting = indegree.clone();
    let mut topo: Vec<usize> = (0..n).filter(|&v| waiting[v] == 0).collect();
    let mut i = 0;
    while i < topo.len() {
        let v = topo[i];
        i += 1;
        for &w in &out[v] {
            waiting[w] -= 1;
            if waiting[w] == 0 {
                topo.push(w);
            }
        }
    }
    let mut rank = vec![0usize; n];
    for &v in &topo {
        for &w in &out[v] {
            rank[w] = rank[w].max(rank[v] + 1);
        }
    }
    for &v in topo.iter().rev() {
        if out[v].len() > indegree[v]
            && let Some(closest) = out[v].iter().map(|&w| rank[w]).min()
        {
            rank[v] = rank[v].max(closest - 1);
        }
    }
    let low = rank.iter().copied().min().unwrap_or(0);
    rank.iter().map(|r| r - low).collect()
}

/// Orders each rank to reduce edge crossings: depth-first initial order, then
/// barycentre sweeps down and up, keeping the best order seen.
fn order_layers(
    vertices: &[Vertex],
    up: &[Vec<(usize, f64)>],
    down: &[Vec<(usize, f64)>],
    sweeps: usize,
) -> Vec<Vec<usize>> {
    let count = vertices.len();
    let ranks = vertices.iter().map(|v| v.rank + 1).max().unwrap_or(0);
    let mut seen = vec![false; count];
    let mut layers: Vec<Vec<usize>> = vec![Vec::new(); ranks];
    let mut stack = Vec::new();
    for start in 0..count {
        stack.push(start);
        while let Some(v) = stack.pop() {
            if seen[v] {
                continue;
            }
            seen[v] = true;
            layers[vertices[v].rank].push(v);
            stack.extend(down[v].iter().rev().map(|&(w, _)| w).filter(|&w| !seen[w]));
        }
    }
    let mut pos = vec![0usize; count];
    for layer in &layers {
        for (i, &v) in layer.iter().enumerate() {
            pos[v] = i;
        }
    }
    let mut best = layers.clone();
    let mut fewest = crossings(&layers, &pos, down);
    for sweep in 0..sweeps {
        if fewest == 0 {
            break;
        }
        if sweep % 2 == 0 {
            for layer in layers.iter_mut().skip(1) {
                barycentre_sort(layer, up, &mut pos);
            }
        } else {
            for layer in layers.iter_mut().rev().skip(1) {
                barycentre_sort(layer, down, &mut pos);
            }
        }
        let now = crossings(&layers, &pos, down);
        if now < fewest {
            fewest = now;
            best.clone_from(&layers);
        }
    }
    best
}

fn barycentre_sort(layer: &mut [usize], neighbours: &[Vec<(usize, f64)>], pos: &mut [usize]) {
    let mut keyed: Vec<(f64, usize)> = layer
        .iter()
        .map(|&v| {
            let (sum, weight) = neighbours[v].iter().fold((0.0, 0.0), |(s, w), &(u, wt)| {
                (s + pos[u] as f64 * wt, w + wt)
            });
            let key = if weight > 0.0 {
                sum / weight
            } else {
                pos[v] as f64
            };
            (key, v)
        })
        .collect();
    keyed.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (i, &(_, v)) in keyed.iter().enumerate() {
        layer[i] = v;
        pos[v] = i;
    }
}

/// Edge crossings between consecutive ranks (inversions, by a Fenwick tree).
fn crossings(layers: &[Vec<usize>], pos: &[usize], down: &[Vec<(usize, f64)>]) -> u64 {
    let mut total = 0u64;
    let mut ends: Vec<(usize, usize)> = Vec::new();
    let mut tree: Vec<u64> = Vec::new();
    for pair in layers.windows(2) {
        ends.clear();
        for &u in &pair[0] {
            ends.extend(down[u].iter().map(|&(w, _)| (pos[u], pos[w])));
        }
        ends.sort_unstable();
        tree.clear();
        tree.resize(pair[1].len() + 1, 0);
        for (seen, &(_, lower)) in ends.iter().enumerate() {
            let mut at_most = 0;
            let mut i = lower + 1;
            while i > 0 {
                at_most += tree[i];
                i &= i - 1;
            }
            total += seen as u64 - at_most;
            let mut i = lower + 1;
            while i < tree.len() {
                tree[i] += 1;
                i += i & i.wrapping_neg();
            }
        }
    }
    total
}

/// Positions across the ranks: each vertex pulled towards its neighbours'
/// weighted mean, each rank kept in order with its gaps by an exact
/// least-squares fit (pool-adjacent-violators).
fn place_across(
    layers: &[Vec<usize>],
    vertices: &[Vertex],
    up: &[Vec<(usize, f64)>],
    down: &[Vec<(usize, f64)>],
    sweeps: usize,
) -> Vec<f64> {
    let gap = |a: usize, b: usize| {
        let (va, vb) = (&vertices[a], &vertices[b]);
        (va.size_o + vb.size_o) / 2.0
            + match (va.dummy, vb.dummy) {
                (false, false) => NODE_GAP,
                (true, true) => LINE_GAP,
                _ => MIXED_GAP,
            }
    };
    let mut o = vec![0.0f64; vertices.len()];
    for layer in layers {
        for w in layer.windows(2) {
            o[w[1]] = o[w[0]] + gap(w[0], w[1]);
        }
    }
    let mut target = Vec::new();
    let mut weight = Vec::new();
    let mut gaps = Vec::new();
    for sweep in 0..sweeps {
        let order: Box<dyn Iterator<Item = &Vec<usize>>> = if sweep % 2 == 0 {
            Box::new(layers.iter())
        } else {
            Box::new(layers.iter().rev())
        };
        for layer in order {
            target.clear();
            weight.clear();
            gaps.clear();
            for &v in layer {
                let (sum, w) = up[v]
                    .iter()
                    .chain(&down[v])
                    .fold((0.0, 0.0), |(s, w), &(u, wt)| (s + o[u] * wt, w + wt));
                if w > 0.0 {
                    target.push(sum / w);
                    weight.push(w);
                } else {
                    target.push(o[v]);
                    weight.push(1e-3);
                }
            }
            gaps.extend(layer.windows(2).map(|w| gap(w[0], w[1])));
            for (&v, x) in layer.iter().zip(fit_in_order(&target, &weight, &gaps)) {
                o[v] = x;
            }
        }
    }
    o
}

/// The positions closest to `target` (weighted least squares) that keep their
/// order with `gaps[i]` between positions `i` and `i + 1`.
fn fit_in_order(target: &[f64], weight: &[f64], gaps: &[f64]) -> Vec<f64> {
    let mut offset = Vec::with_capacity(target.len());
    let mut acc = 0.0;
    for i in 0..target.len() {
        if i > 0 {
            acc += gaps[i - 1];
        }
        offset.push(acc);
    }
    // Blocks of (total weight, weighted sum, length), means increasing.
    let mut blocks: Vec<(f64, f64, usize)> = Vec::new();
    for ((&t, &w), &c) in target.iter().zip(weight).zip(&offset) {
        blocks.push((w, w * (t - c), 1));
        while blocks.len() > 1 {
            let (w2, s2, n2) = blocks[blocks.len() - 1];
            let (w1, s1, n1) = blocks[blocks.len() - 2];
            if s1 / w1 < s2 / w2 {
                break;
            }
            blocks.pop();
            let last = blocks.len() - 1;
            blocks[last] = (w1 + w2, s1 + s2, n1 + n2);
        }
    }
    let mut out = Vec::with_capacity(target.len());
    for (w, s, len) in blocks {
        for _ in 0..len {
            out.push(s / w + offset[out.len()]);
        }
    }
    out
}

impl Rect {
    fn shift(&mut self, dx: f64, dy: f64) {
        self.x += dx;
        self.y += dy;
    }

    fn corners(&self) -> [P; 2] {
        [
            P {
                x: self.x,
                y: self.y,
            },
            P {
                x: self.x + self.w,
                y: self.y + self.h,
            },
        ]
    }
}

impl Route {
    fn points(&self) -> impl Iterator<Item = P> + '_ {
        let (base, tip) = self.arrow;
        let label = self.label.iter().flat_map(Rect::corners);
        std::iter::once(self.start)
            .chain(self.segments.iter().flatten().copied())
            .chain([base, tip])
            .chain(label)
    }

    fn shift(&mut self, dx: f64, dy: f64) {
        let points = std::iter::once(&mut self.start)
            .chain(self.segments.iter_mut().flatten())
            .chain([&mut self.arrow.0, &mut self.arrow.1]);
        for p in points {
            p.x += dx;
            p.y += dy;
        }
        if let Some(r) = &mut self.label {
            r.shift(dx, dy);
        }
    }
}

impl Drawing {
    /// Moves everything inside the margin, leaves room for the caption below,
    /// and sets the size.
    fn fit(&mut self) {
        let points = self
            .nodes
            .iter()
            .flat_map(|n| n.rect.corners())
            .chain(self.edges.iter().flat_map(|e| e.route.points()));
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in points {
            x0 = x0.min(p.x);
            y0 = y0.min(p.y);
            x1 = x1.max(p.x);
            y1 = y1.max(p.y);
        }
        if x0 > x1 {
            (x0, y0, x1, y1) = (0.0, 0.0, 0.0, 0.0);
        }
        let (cw, ch) = text_size(&self.caption, CAPTION_CHAR_W, CAPTION_LINE_H);
        // A caption wider than the graph: the graph goes under its middle.
        let dx = MARGIN - x0 + ((cw - (x1 - x0)) / 2.0).max(0.0);
        let dy = MARGIN - y0;
        for node in &mut self.nodes {
            node.rect.shift(dx, dy);
        }
        for e in &mut self.edges {
            e.route.shift(dx, dy);
        }
        self.width = (x1 - x0).max(cw) + 2.0 * MARGIN;
        self.height = y1 - y0 + 2.0 * MARGIN + if ch > 0.0 { ch + MARGIN } else { 0.0 };
    }

    fn to_svg(&self, id_prefix: &str) -> String {
        let p = esc(id_prefix);
        let (w, h) = (N(self.width), N(self.height));
        let mut s = String::with_capacity(512 + 400 * (self.nodes.len() + self.edges.len()));
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" style="max-width:100%;height:auto">"#
        );
        let _ = writeln!(
            s,
            r#"<g class="graph" id="{p}graph0" font-family="Helvetica,Arial,sans-serif" font-size="{}">"#,
            N(FONT_SIZE)
        );
        let _ = writeln!(s, "<title>{}</title>", esc(&self.title));
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        // Edges first, so that nodes cover their ends.
        for (i, e) in self.edges.iter().enumerate() {
            edge_svg(&mut s, &p, i, e);
        }
        for (i, node) in self.nodes.iter().enumerate() {
            node_svg(&mut s, &p, i, node);
        }
        if !self.caption.is_empty() {
            self.caption_svg(&mut s);
        }
        s.push_str("</g>\n</svg>\n");
        s
    }

    /// The caption under the graph, one centred `<text>` per line.
    fn caption_svg(&self, s: &mut String) {
        let (_, ch) = text_size(&self.caption, CAPTION_CHAR_W, CAPTION_LINE_H);
        let top = self.height - MARGIN - ch;
        for (i, line) in self.caption.iter().enumerate() {
            let _ = writeln!(
                s,
                r#"<text class="caption" x="{}" y="{}" text-anchor="middle" font-size="{}">{}</text>"#,
                N(self.width / 2.0),
                N(top + i as f64 * CAPTION_LINE_H + CAPTION_LINE_H * 0.8),
                N(CAPTION_SIZE),
                esc(line)
            );
        }
    }
}

/// Edge number `i` as an SVG group: its path, arrowhead and label.
fn edge_svg(s: &mut String, p: &str, i: usize, e: &EdgeShape) {
    let look = &e.look;
    let _ = writeln!(
        s,
        r#"<g class="edge" id="{p}edge{}"><title>{}</title>"#,
        i + 1,
        esc(&look.title)
    );
    let route = &e.route;
    let d = path_data(route);
    let width = line_width(look.bold);
    let _ = writeln!(
        s,
        r#"<path{}{width} d="{d}"/>"#,
        paint(("none", None), "black")
    );
    let (base, tip) = route.arrow;
    let (dx, dy) = (tip.x - base.x, tip.y - base.y);
    let len = dx.hypot(dy).max(1e-9);
    let (nx, ny) = (-dy / len * ARROW_HALF_WIDTH, dx / len * ARROW_HALF_WIDTH);
    let _ = writeln!(
        s,
        r#"<polygon{}{width} points="{},{} {},{} {},{}"/>"#,
        paint(("black", None), "black"),
        N(tip.x),
        N(tip.y),
        N(base.x + nx),
        N(base.y + ny),
        N(base.x - nx),
        N(base.y - ny)
    );
    if let Some(r) = &route.label {
        let _ = writeln!(
            s,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="white"/>"#,
            N(r.x),
            N(r.y),
            N(r.w),
            N(r.h)
        );
        let centre = P {
            x: r.x + r.w / 2.0,
            y: r.y + r.h / 2.0,
        };
        text_lines(s, centre, &look.lines);
    }
    s.push_str("</g>\n");
}

/// An edge's route as SVG path data: straight lines where a segment is
/// straight, cubic Béziers elsewhere.
fn path_data(route: &Route) -> String {
    let mut d = format!("M{},{}", N(route.start.x), N(route.start.y));
    let mut from = route.start;
    for &[c1, c2, to] in &route.segments {
        let straight = [c1, c2, to].iter().all(|p| p.x == from.x)
            || [c1, c2, to].iter().all(|p| p.y == from.y);
        if straight {
            let _ = write!(d, "L{},{}", N(to.x), N(to.y));
        } else {
            let _ = write!(
                d,
                "C{},{} {},{} {},{}",
                N(c1.x),
                N(c1.y),
                N(c2.x),
                N(c2.y),
                N(to.x),
                N(to.y)
            );
        }
        from = to;
    }
    d
}

/// The SVG attribute of a bold line (empty when not).
fn line_width(bold: bool) -> &'static str {
    if bold { r#" stroke-width="2""# } else { "" }
}

/// Node number `i` as an SVG group: its box (two for a double periphery) and
/// its text.
fn node_svg(s: &mut String, p: &str, i: usize, node: &NodeShape) {
    let look = &node.look;
    let _ = writeln!(
        s,
        r#"<g class="node" id="{p}node{}"><title>{}</title>"#,
        i + 1,
        esc(&look.name)
    );
    let r = node.rect;
    let round = if look.rounded { r#" rx="5""# } else { "" };
    let mut rects = vec![(r, ("white", None))];
    if look.double {
        let g = PERIPHERY_GAP;
        rects.push((
            Rect {
                x: r.x + g,
                y: r.y + g,
                w: r.w - 2.0 * g,
                h: r.h - 2.0 * g,
            },
            ("white", look.fill.as_deref()),
        ));
    } else {
        rects[0].1 = ("white", look.fill.as_deref());
    }
    for (b, fill) in rects {
        let _ = writeln!(
            s,
            r#"<rect x="{}" y="{}" width="{}" height="{}"{round}{}/>"#,
            N(b.x),
            N(b.y),
            N(b.w),
            N(b.h),
            paint(fill, "black")
        );
    }
    let centre = P {
        x: r.x + r.w / 2.0,
        y: r.y + r.h / 2.0,
    };
    text_lines(s, centre, &look.lines);
    s.push_str("</g>\n");
}

/// Text lines centred on `centre`, one `<text>` each.
fn text_lines(s: &mut String, centre: P, lines: &[String]) {
    let top = centre.y - lines.len() as f64 * LINE_H / 2.0;
    for (i, line) in lines.iter().enumerate() {
        if line.is_empty() {
            continue;
        }
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            N(centre.x),
            N(top + i as f64 * LINE_H + (LINE_H + FONT_SIZE * 0.7) / 2.0),
            esc(line)
        );
    }
}

/// Fill and stroke attributes: the fill a fallback and maybe a node's fill
/// colour. The colour goes in `style`, which browsers ignore when they do not
/// know it (Graphviz knows more colour names than CSS), leaving the fallback.
fn paint((fill, colour): (&str, Option<&str>), stroke: &str) -> String {
    let mut out = format!(r#" fill="{fill}" stroke="{stroke}""#);
    if let Some(c) = colour {
        let _ = write!(out, r#" style="{}""#, esc(&format!("fill:{c}")));
    }
    out
}

/// A number for SVG: one decimal at most.
struct N(f64);

impl std::fmt::Display for N {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let tenths = (self.0 * 10.0).round();
        if !tenths.is_finite() {
            f.write_str("0")
        } else if tenths % 10.0 == 0.0 {
            write!(f, "{}", (tenths / 10.0) as i64)
        } else {
            write!(f, "{:.1}", tenths / 10.0)
        }
    }
}

/// Text escaped for XML content and attribute values; characters XML forbids
/// are dropped.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            '\t' | '\n' => out.push(c),
            _ if c.is_control() || c == '\u{fffe}' || c == '\u{ffff}' => {}
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use diagnoser::Plant;
    use diagnoser::diagnosis::compile::Compiled;
    use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
    use diagnoser::model::Model;
    use learning::graph::part_digraph;
    use proptest::prelude::*;

    use super::*;
    use crate::fixtures::{learned, plant};

    fn turntable_graph(model: &Model) -> Digraph {
        let part = model
            .parts
            .iter()
            .find(|p| p.name == "turntable")
            .expect("the sorting model has a turntable");
        part_digraph(model, part)
    }

    /// The turntable's diagnoser as `gardefou check --dot` draws it, with its
    /// number of states.
    fn diagnoser_graph(plant: &Plant, model: &Model, part: &str) -> (Digraph, usize) {
        let diagnoser = PlantDiagnoser::new(plant, model, &DiagnoserOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        let mut engine = diagnoser
            .engines()
            .find(|e| e.part.name == part)
            .expect("the part has a diagnoser")
            .clone();
        let compiled = Compiled::explore(&mut engine, 2);
        (
            compiled.to_digraph(&engine, model.time_unit),
            compiled.size().states,
        )
    }

    fn lines(l: &[&str]) -> Vec<String> {
        l.iter().map(|s| (*s).to_string()).collect()
    }

    /// A node `id` labelled with `label`'s lines.
    fn node(id: &str, label: &[&str]) -> Node {
        Node {
            id: id.to_string(),
            label: lines(label),
            ..Node::default()
        }
    }

    /// An edge from node `from` to node `to` labelled with `label`'s lines.
    fn edge(from: usize, to: usize, label: &[&str]) -> Edge {
        Edge {
            from,
            to,
            label: lines(label),
            bold: false,
        }
    }

    /// The `x`, `y`, `width`, `height` of the first `<rect` of every node group.
    fn node_rects(svg: &str) -> Vec<Rect> {
        svg.split(r#"<g class="node""#)
            .skip(1)
            .map(|group| {
                let tag = &group[group.find("<rect").expect("a node has a rect")..];
                let tag = &tag[..tag.find("/>").expect("closed rect")];
                let attrs = tag_attributes(&tag[5..]);
                let get = |k: &str| -> f64 {
                    attrs
                        .iter()
                        .find(|(n, _)| n == k)
                        .and_then(|(_, v)| v.parse().ok())
                        .unwrap_or_else(|| panic!("rect without {k}: {tag}"))
                };
                Rect {
                    x: get("x"),
                    y: get("y"),
                    w: get("width"),
                    h: get("height"),
                }
            })
            .collect()
    }

    fn assert_disjoint(what: &str, rects: &[Rect]) {
        for (i, a) in rects.iter().enumerate() {
            for b in &rects[i + 1..] {
                assert!(!a.overlaps(b), "{what}: {a:?} overlaps {b:?}");
            }
        }
    }

    /// Node boxes and edge labels of a drawing, none overlapping another, all
    /// inside the picture.
    fn assert_tidy(drawing: &Drawing) {
        let mut boxes: Vec<Rect> = drawing.nodes.iter().map(|n| n.rect).collect();
        boxes.extend(drawing.edges.iter().filter_map(|e| e.route.label));
        assert_disjoint("boxes and labels", &boxes);
        for r in &boxes {
            assert!(
                r.x >= 0.0
                    && r.y >= 0.0
                    && r.x + r.w <= drawing.width
                    && r.y + r.h <= drawing.height,
                "{r:?} outside the {}×{} picture",
                drawing.width,
                drawing.height
            );
        }
    }

    fn count(svg: &str, what: &str) -> usize {
        svg.matches(what).count()
    }

    #[test]
    fn learned_model_drawn_by_the_built_in_layout() {
        let plant = plant();
        let model = learned(&plant);
        let graph = turntable_graph(&model);
        let part = model.parts.iter().find(|p| p.name == "turntable").unwrap();
        let picture = render(&graph, Layout::BuiltIn, "m0-").unwrap_or_else(|e| panic!("{e}"));
        let svg = &picture.svg;
        assert_eq!(picture.by, "built-in layout");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        for s in &part.states {
            let values = part
                .signals
                .iter()
                .zip(&s.values)
                .map(|(n, &v)| format!("{n}={}", u8::from(v)))
                .collect::<Vec<_>>()
                .join(" ");
            for line in [values, format!("({} visits)", s.visits)] {
                assert!(svg.contains(&format!(">{}<", esc(&line))), "{line} missing");
            }
        }
        for t in &part.transitions {
            assert!(
                svg.contains(&format!(">{}<", esc(&t.event))),
                "{} missing",
                t.event
            );
            assert!(svg.contains(&format!(">×{}<", t.count)));
        }
        assert_eq!(count(svg, r#"<g class="node""#), part.states.len());
        assert_eq!(count(svg, r#"<g class="edge""#), part.transitions.len());
        // Stable states are drawn double, commands bold.
        let stable = part.states.iter().filter(|s| s.stable).count();
        assert!(stable > 0);
        assert_eq!(
            count(svg, "<rect") - 1,
            part.states.len() + stable + part.transitions.len()
        );
        let commands = part.transitions.iter().filter(|t| t.command).count();
        assert_eq!(
            count(svg, r#"<path fill="none" stroke="black" stroke-width="2""#),
            commands
        );
        assert!(svg.contains(&format!(">{}<", esc("sorting — turntable"))));
        assert_disjoint("node boxes", &node_rects(svg));
        assert_tidy(&lay_out(&graph).unwrap());
        for id in svg.split(" id=\"").skip(1) {
            assert!(id.starts_with("m0-"), "unprefixed id {id}");
        }
    }

    #[test]
    fn diagnoser_drawn_by_the_built_in_layout() {
        let plant = plant();
        let model = learned(&plant);
        let (graph, states) = diagnoser_graph(&plant, &model, "turntable");
        assert!(states > 100, "a big diagnoser to draw: {states} states");
        assert_eq!(graph.nodes.len(), states);
        let started = Instant::now();
        let picture = render(&graph, Layout::BuiltIn, "d0-").unwrap_or_else(|e| panic!("{e}"));
        let took = started.elapsed();
        let svg = &picture.svg;
        assert_eq!(count(svg, r#"<g class="node""#), states);
        let edges = graph.edges.len();
        assert_eq!(count(svg, r#"<g class="edge""#), edges);
        assert!(svg.contains(r#"style="fill:salmon""#) && svg.contains(r#"style="fill:khaki""#));
        assert!(svg.contains(&format!(">{}<", esc("{F2, F7}"))));
        assert_disjoint("node boxes", &node_rects(svg));
        assert_tidy(&lay_out(&graph).unwrap());
        eprintln!("built-in layout of {states} states, {edges} edges: {took:?}");
    }

    #[test]
    fn graphviz_pictures_are_inline_svg_with_prefixed_ids() {
        let plant = plant();
        let model = learned(&plant);
        let graph = turntable_graph(&model);
        let picture = render(&graph, Layout::Graphviz, "g1-").unwrap_or_else(|e| {
            panic!("this test needs Graphviz's `dot` on the PATH (CI installs graphviz): {e}")
        });
        let svg = &picture.svg;
        assert_eq!(picture.by, "Graphviz dot");
        assert!(svg.starts_with("<svg"), "{}", &svg[..svg.len().min(200)]);
        for junk in ["<?xml", "<!DOCTYPE", "<!--"] {
            assert!(!svg.contains(junk), "{junk} left in");
        }
        let root = &svg[..svg.find('>').unwrap()];
        assert!(
            root.contains("viewBox=") && root.contains(r#"style="max-width:100%;height:auto""#)
        );
        assert!(!root.contains("pt\""), "sized in points: {root}");
        let ids = count(svg, " id=\"");
        assert!(ids >= 12, "{ids} ids");
        assert_eq!(count(svg, " id=\"g1-"), ids);
        for line in ["A4=0 C4=1 C5=0", "RE(A4)", "FE(C4)"] {
            assert!(svg.contains(&format!(">{line}<")), "{line} missing");
        }
        assert_eq!(count(svg, r#"class="node""#), 6);
        // Auto takes Graphviz when it runs.
        assert_eq!(
            render(&graph, Layout::Auto, "a-").unwrap().by,
            "Graphviz dot"
        );
        // Graphviz's verdict on text it rejects is an error, not a picture.
        assert!(run_dot("dot", &[], "digraph { a -> }", DOT_TIMEOUT).is_err());
    }

    #[test]
    fn a_missing_or_stuck_dot_is_an_error() {
        let missing = run_dot(
            "/nonexistent/dot",
            &[],
            "digraph {}",
            Duration::from_secs(5),
        );
        assert!(missing.unwrap_err().contains("not found"));
        let dir = tempfile::tempdir().unwrap();
        let stuck = dir.path().join("dot");
        std::fs::write(&stuck, "#!/bin/sh\nexec sleep 30\n").unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&stuck, std::fs::Permissions::from_mode(0o755)).unwrap();
            let started = Instant::now();
            let e = run_dot(
                stuck.to_str().unwrap(),
                &[],
                "digraph {}",
                Duration::from_millis(300),
            )
            .unwrap_err();
            assert!(e.contains("took more than 0.3 s"), "{e}");
            assert!(started.elapsed() < Duration::from_secs(10));
        }
    }

    #[test]
    fn ids_and_references_get_the_prefix() {
        let raw = concat!(
            "<?xml version=\"1.0\"?>\n<!DOCTYPE svg>\n<!-- made -->\n",
            "<svg width=\"100pt\" height=\"50pt\" viewBox=\"0.00 0.00 100.00 50.00\" xmlns=\"http://www.w3.org/2000/svg\">\n",
            "<defs><linearGradient id=\"l_0\"/></defs>\n<!-- a -->\n",
            "<g id=\"node1\" class=\"node\"><rect fill=\"url(#l_0)\"/><a xlink:href=\"#node1\"><text>id=\"x\"</text></a></g>\n</svg>\n"
        );
        let svg = tidy_graphviz_svg(raw, "p-").unwrap();
        assert!(svg.starts_with(
            r#"<svg width="100" height="50" viewBox="0.00 0.00 100.00 50.00" style="max-width:100%;height:auto" xmlns="#
        ));
        assert!(svg.contains(r#"<linearGradient id="p-l_0"/>"#));
        assert!(svg.contains(
            r##"<g id="p-node1" class="node"><rect fill="url(#p-l_0)"/><a xlink:href="#p-node1">"##
        ));
        // Text is not markup.
        assert!(svg.contains(r#"<text>id="x"</text>"#));
        assert!(!svg.contains("<!--") && !svg.contains("<?xml"));
    }

    #[test]
    fn labels_are_drawn_as_plain_text() {
        let graph = Digraph {
            name: "g".into(),
            rank_direction: RankDirection::LeftToRight,
            nodes: vec![
                node("a", &["x; ] -> {y}", r#""q" \ <&> \n"#]),
                node("b", &["b"]),
            ],
            edges: vec![edge(0, 1, &["e]1;"])],
            ..Digraph::default()
        };
        let svg = render(&graph, Layout::BuiltIn, "q").unwrap().svg;
        assert!(svg.contains(">x; ] -&gt; {y}<"), "{svg}");
        assert!(svg.contains(r">&quot;q&quot; \ &lt;&amp;&gt; \n<"), "{svg}");
        assert!(svg.contains(">e]1;<"));
        assert!(svg.contains("<title>b</title>") && svg.contains(">b<"));
        assert!(svg.contains("<title>a-&gt;b</title>"));
        let mut stray = graph.clone();
        stray.edges.push(edge(1, 2, &[]));
        let e = render(&stray, Layout::BuiltIn, "q").unwrap_err();
        assert_eq!(e, r#"graph "g": an edge from node 1 to node 2, of 2 nodes"#);
        // A line break inside a line breaks it, as Graphviz reads the DOT; a
        // final one opens no empty line, and an empty label draws no text.
        assert_eq!(
            drawn_lines(&lines(&["one\ntwo\r", "three\n"])),
            ["one", "two", "three"]
        );
        assert_eq!(drawn_lines(&lines(&["a", ""])), ["a"]);
        assert_eq!(drawn_lines(&lines(&["a", "", ""])), ["a", ""]);
        assert!(drawn_lines(&lines(&["", "\n"])).is_empty());
        assert!(drawn_lines(&[]).is_empty());
    }

    /// Top to bottom, with a caption of two lines, filled rounded boxes, double
    /// borders, self-loops, parallel and back edges, and a fill colour that
    /// cannot go into an attribute.
    #[test]
    fn top_to_bottom_with_every_feature() {
        let fill = |n: Node, colour: &str| Node {
            fill: Some(colour.to_string()),
            ..n
        };
        let double = |n: Node| Node {
            double_border: true,
            ..n
        };
        let fork = ["x", "y & z"];
        let graph = Digraph {
            name: "G".into(),
            caption: lines(&["cap", "line 2"]),
            rank_direction: RankDirection::TopToBottom,
            rounded_nodes: true,
            nodes: vec![
                fill(node("a", &["a"]), "#ddeeff"),
                fill(node("b", &["b"]), "#ddeeff"),
                node("c", &["c"]),
                node("d", &["d"]),
                double(node("e", &["e"])),
                double(fill(node("f", &["f"]), "red\" onload=\"x")),
            ],
            edges: vec![
                edge(0, 1, &fork),
                edge(0, 2, &fork),
                edge(1, 3, &fork),
                edge(2, 3, &fork),
                edge(5, 4, &[]),
                edge(0, 0, &["self"]),
                edge(0, 0, &[]),
                edge(3, 0, &[]),
                edge(3, 0, &["back"]),
            ],
        };
        let drawing = lay_out(&graph).unwrap();
        assert_tidy(&drawing);
        assert!(drawing.nodes[4].look.double && !drawing.nodes[0].look.double);
        assert_eq!(drawing.caption, ["cap", "line 2"]);
        let svg = drawing.to_svg("s");
        assert!(svg.contains(">x<") && svg.contains(">y &amp; z<"));
        assert_eq!(count(&svg, r#"style="fill:#ddeeff""#), 2);
        assert_eq!(count(&svg, r#"style="fill:lightgrey""#), 1);
        assert!(!svg.contains("onload"));
        assert_eq!(count(&svg, r#"rx="5""#), 6 + 2);
        // Top to bottom: d below a.
        let (a, d) = (drawing.nodes[0].rect, drawing.nodes[3].rect);
        assert!(d.y > a.y + a.h, "{a:?} {d:?}");
        // Every edge has a path and an arrowhead.
        assert_eq!(count(&svg, "<path"), graph.edges.len());
        assert_eq!(count(&svg, "<polygon"), graph.edges.len());
    }

    #[test]
    fn parallel_edges_and_loops_keep_apart() {
        let mut graph = Digraph {
            rank_direction: RankDirection::LeftToRight,
            nodes: vec![node("a", &["a"]), node("b", &["b"])],
            ..Digraph::default()
        };
        for i in 0..6 {
            for (from, to, what) in [(0, 1, "edge"), (1, 0, "back"), (1, 1, "loop")] {
                graph
                    .edges
                    .push(edge(from, to, &[format!("{what} {i}").as_str()]));
            }
        }
        let drawing = lay_out(&graph).unwrap();
        assert_tidy(&drawing);
        let starts: Vec<P> = drawing.edges.iter().map(|e| e.route.start).collect();
        for (i, a) in starts.iter().enumerate() {
            for b in &starts[i + 1..] {
                assert!(a != b, "two edges start at {a:?}");
            }
        }
    }

    /// A random-looking graph of `n` nodes and `m` edges, labelled like a diagnoser's.
    fn big_graph(n: usize, m: usize) -> Digraph {
        let mut graph = Digraph {
            name: "big".into(),
            rank_direction: RankDirection::LeftToRight,
            ..Digraph::default()
        };
        for i in 0..n {
            graph.nodes.push(Node {
                id: format!("d{i}"),
                label: lines(&[&format!("{{F{}}}", i % 7), "A4=1 C4=0 C5=1"]),
                fill: Some("khaki".into()),
                double_border: false,
            });
        }
        let mut x: u64 = 12345;
        for _ in 0..m {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let a = (x >> 33) as usize % n;
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            // Mostly short hops forward, some anywhere.
            let b = if x >> 60 < 12 {
                (a + 1 + (x >> 33) as usize % 4) % n
            } else {
                (x >> 33) as usize % n
            };
            graph.edges.push(edge(a, b, &["RE(C5) [2960, 3060]"]));
        }
        graph
    }

    #[test]
    fn big_graphs_are_laid_out_tidily() {
        let graph = big_graph(300, 1000);
        let started = Instant::now();
        let drawing = lay_out(&graph).unwrap();
        let svg = drawing.to_svg("b");
        let took = started.elapsed();
        eprintln!(
            "built-in layout of 300 nodes, 1000 edges: {took:?}, {} bytes",
            svg.len()
        );
        assert_eq!(count(&svg, r#"<g class="node""#), 300);
        assert_tidy(&drawing);
        // Its speed is measured by scripts/bench-report.sh, not here: a
        // timed assertion fails on a loaded machine, not on a slow layout.
    }

    proptest! {
        #[test]
        fn random_graphs_lay_out_without_overlap(
            edges in proptest::collection::vec((0usize..12, 0usize..12, 0usize..3), 0..40),
            rank_direction in proptest::sample::select(vec![
                RankDirection::LeftToRight,
                RankDirection::TopToBottom,
                RankDirection::RightToLeft,
                RankDirection::BottomToTop,
            ]),
        ) {
            // Nodes named as they are first met, as a DOT text would list them.
            let mut graph = Digraph { rank_direction, ..Digraph::default() };
            let index = |graph: &mut Digraph, n: usize| {
                let id = format!("n{n}");
                graph.nodes.iter().position(|x| x.id == id).unwrap_or_else(|| {
                    graph.nodes.push(node(&id, &[&id]));
                    graph.nodes.len() - 1
                })
            };
            for (a, b, l) in &edges {
                let (from, to) = (index(&mut graph, *a), index(&mut graph, *b));
                let label: &[&str] = [&[][..], &["e"], &["a longer", "label"]][*l];
                graph.edges.push(edge(from, to, label));
            }
            let drawing = lay_out(&graph).unwrap();
            assert_tidy(&drawing);
        }
    }
}
