//! The directed graphs gardefou draws, as typed values: a part's learned model
//! (`learning::graph`) and a compiled diagnoser (`Compiled::to_digraph`).
//!
//! A [`Digraph`] holds what those pictures show and nothing else: boxes with
//! lines of text, a fill colour, a double border; edges with lines of text,
//! bold or not; a caption and a rank direction. Labels are plain text, line by
//! line. [`Digraph::to_dot`] writes the graph as Graphviz DOT text (the files of
//! `learn --dot` and `check --dot`, and what the report pipes into Graphviz's
//! `dot`); the report's built-in layout takes the value itself.
//!
//! It depends on nothing, so that the crates that build graphs and the one
//! that draws them share it at no cost.
//!
//! It is not for: laying graphs out or drawing them (`report::pictures`),
//! reading DOT text, graph algorithms (the diagnoser's exploration has
//! petgraph), or what the nodes mean (the crates that build the graphs know).

use std::fmt::Write as _;

/// A directed graph to draw.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Digraph {
    /// The graph's name: its DOT identifier, the picture's title.
    pub name: String,
    /// Lines of text under the drawing (DOT's graph `label`); none: no caption.
    pub caption: Vec<String>,
    /// Which way edges run from rank to rank.
    pub rank_direction: RankDirection,
    /// Whether every node's box has rounded corners.
    pub rounded_nodes: bool,
    /// The nodes, in the order they are written and numbered.
    pub nodes: Vec<Node>,
    /// The edges, in the order they are written.
    pub edges: Vec<Edge>,
}

/// Which way edges run from rank to rank (DOT's `rankdir`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RankDirection {
    /// Down the page (`TB`, DOT's default).
    #[default]
    TopToBottom,
    /// Across the page, left to right (`LR`).
    LeftToRight,
    /// Up the page (`BT`).
    BottomToTop,
    /// Across the page, right to left (`RL`).
    RightToLeft,
}

impl RankDirection {
    /// Its DOT value: `TB`, `LR`, `BT` or `RL`.
    pub fn dot_value(self) -> &'static str {
        match self {
            RankDirection::TopToBottom => "TB",
            RankDirection::LeftToRight => "LR",
            RankDirection::BottomToTop => "BT",
            RankDirection::RightToLeft => "RL",
        }
    }
}

/// A node: a box with lines of text.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Node {
    /// Its identifier, unique in the graph (e.g. `s0`): its DOT identifier, its
    /// title in the drawing.
    pub id: String,
    /// Lines of text in the box. A line break inside a line breaks it too, as
    /// Graphviz reads it.
    pub label: Vec<String>,
    /// Fill colour: a Graphviz colour name (`salmon`) or `#rrggbb`; none:
    /// unfilled.
    pub fill: Option<String>,
    /// Whether the box is drawn with a second border inside the first (DOT's
    /// `peripheries=2`).
    pub double_border: bool,
}

/// An edge between two nodes.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Edge {
    /// Where it starts: an index in [`Digraph::nodes`].
    pub from: usize,
    /// Where it ends: an index in [`Digraph::nodes`] (`from` itself for a loop).
    pub to: usize,
    /// Lines of text beside it, as in [`Node::label`].
    pub label: Vec<String>,
    /// Whether its line is drawn bold.
    pub bold: bool,
}

impl Digraph {
    /// The graph as Graphviz DOT text: a `digraph` with its rank direction, the
    /// node defaults (boxes, Helvetica), its caption, then one statement per
    /// node and per edge, in order. A graph with a caption writes each setting on
    /// a line of its own; one without writes the rank direction and the node
    /// defaults on one line.
    ///
    /// # Panics
    ///
    /// When an edge names a node index past [`Digraph::nodes`].
    pub fn to_dot(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(out, "digraph {} {{", quoted(&self.name));
        let rankdir = format!("rankdir={};", self.rank_direction.dot_value());
        let rounded = if self.rounded_nodes {
            "style=rounded, "
        } else {
            ""
        };
        let defaults = format!("node [shape=box, {rounded}fontname=\"Helvetica\"];");
        if self.caption.is_empty() {
            let _ = writeln!(out, "  {rankdir} {defaults}");
        } else {
            let _ = writeln!(
                out,
                "  {rankdir}\n  {defaults}\n  label={};",
                text(&self.caption)
            );
        }
        for node in &self.nodes {
            let _ = write!(out, "  {} [label={}", id(&node.id), text(&node.label));
            if let Some(fill) = &node.fill {
                // A node's style replaces the default one.
                let style = if self.rounded_nodes {
                    "\"rounded,filled\""
                } else {
                    "filled"
                };
                let _ = write!(out, ", style={style}, fillcolor={}", id(fill));
            }
            if node.double_border {
                out.push_str(", peripheries=2");
            }
            out.push_str("];\n");
        }
        for edge in &self.edges {
            let _ = write!(
                out,
                "  {} -> {} [label={}",
                id(&self.nodes[edge.from].id),
                id(&self.nodes[edge.to].id),
                text(&edge.label)
            );
            if edge.bold {
                out.push_str(", style=bold");
            }
            out.push_str("];\n");
        }
        out.push_str("}\n");
        out
    }
}

/// Lines of text as one DOT string, broken by `\n`.
fn text(lines: &[String]) -> String {
    let escaped: Vec<String> = lines.iter().map(|l| escape(l)).collect();
    format!("\"{}\"", escaped.join("\\n"))
}

/// A DOT identifier: as it is when it is a plain one, else quoted.
fn id(s: &str) -> String {
    let plain = s
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    let keyword = ["node", "edge", "graph", "digraph", "subgraph", "strict"]
        .iter()
        .any(|k| s.eq_ignore_ascii_case(k));
    if plain && !keyword {
        s.to_string()
    } else {
        quoted(s)
    }
}

fn quoted(s: &str) -> String {
    format!("\"{}\"", escape(s))
}

/// Text inside a DOT string: backslashes and quotes escaped, so that it reads
/// back as itself.
fn escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(l: &[&str]) -> Vec<String> {
        l.iter().map(|s| (*s).to_string()).collect()
    }

    /// A graph in the form of a part's learned model: caption, rounded boxes,
    /// double borders, bold edges.
    #[test]
    fn a_captioned_graph_writes_one_setting_a_line() {
        let graph = Digraph {
            name: "turntable".into(),
            caption: lines(&["sorting — turntable"]),
            rank_direction: RankDirection::LeftToRight,
            rounded_nodes: true,
            nodes: vec![
                Node {
                    id: "s0".into(),
                    label: lines(&["A4=0 C4=1", "(3 visits)"]),
                    double_border: true,
                    ..Node::default()
                },
                Node {
                    id: "s1".into(),
                    label: lines(&["A4=1 C4=1", "(2 visits)"]),
                    ..Node::default()
                },
            ],
            edges: vec![
                Edge {
                    from: 0,
                    to: 1,
                    label: lines(&["RE(A4)", "×2"]),
                    bold: true,
                },
                Edge {
                    from: 1,
                    to: 0,
                    label: lines(&["FE(C4)", "[20, 140] ms", "×2"]),
                    bold: false,
                },
            ],
        };
        assert_eq!(
            graph.to_dot(),
            r#"digraph "turntable" {
  rankdir=LR;
  node [shape=box, style=rounded, fontname="Helvetica"];
  label="sorting — turntable";
  s0 [label="A4=0 C4=1\n(3 visits)", peripheries=2];
  s1 [label="A4=1 C4=1\n(2 visits)"];
  s0 -> s1 [label="RE(A4)\n×2", style=bold];
  s1 -> s0 [label="FE(C4)\n[20, 140] ms\n×2"];
}
"#
        );
    }

    /// A graph in the form of a compiled diagnoser: no caption, filled boxes.
    #[test]
    fn a_graph_without_caption_writes_its_settings_on_one_line() {
        let graph = Digraph {
            name: "diagnoser turntable".into(),
            rank_direction: RankDirection::LeftToRight,
            nodes: vec![Node {
                id: "d0".into(),
                label: lines(&["{F2, F7}", "A4=0"]),
                fill: Some("khaki".into()),
                ..Node::default()
            }],
            edges: vec![Edge {
                from: 0,
                to: 0,
                label: lines(&["RE(C5) [0, 2.96 s]"]),
                bold: false,
            }],
            ..Digraph::default()
        };
        assert_eq!(
            graph.to_dot(),
            r#"digraph "diagnoser turntable" {
  rankdir=LR; node [shape=box, fontname="Helvetica"];
  d0 [label="{F2, F7}\nA4=0", style=filled, fillcolor=khaki];
  d0 -> d0 [label="RE(C5) [0, 2.96 s]"];
}
"#
        );
    }

    #[test]
    fn text_and_identifiers_are_escaped() {
        let graph = Digraph {
            name: r#"a "b" \c"#.into(),
            rounded_nodes: true,
            nodes: vec![
                Node {
                    id: "node".into(),
                    label: lines(&[r#"x "q" \n"#, ""]),
                    fill: Some("#ddeeff".into()),
                    ..Node::default()
                },
                Node {
                    id: "2 b".into(),
                    ..Node::default()
                },
            ],
            edges: vec![Edge {
                from: 0,
                to: 1,
                ..Edge::default()
            }],
            ..Digraph::default()
        };
        assert_eq!(
            graph.to_dot(),
            r##"digraph "a \"b\" \\c" {
  rankdir=TB; node [shape=box, style=rounded, fontname="Helvetica"];
  "node" [label="x \"q\" \\n\n", style="rounded,filled", fillcolor="#ddeeff"];
  "2 b" [label=""];
  "node" -> "2 b" [label=""];
}
"##
        );
    }

    #[test]
    fn rank_directions_are_dots() {
        let values: Vec<&str> = [
            RankDirection::TopToBottom,
            RankDirection::LeftToRight,
            RankDirection::BottomToTop,
            RankDirection::RightToLeft,
        ]
        .into_iter()
        .map(RankDirection::dot_value)
        .collect();
        assert_eq!(values, ["TB", "LR", "BT", "RL"]);
    }
}
