//! `gardefou report`: the HTML fault review of logs (the `report` crate), written
//! to a file.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use diagnoser::model::Model;
use diagnoser::{Failure, Plant};
use report::pictures::Layout;

use crate::args::{CouplingArg, ReplayArgs};

/// How the model pictures are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LayoutArg {
    /// Graphviz `dot` when installed, else the built-in layout.
    Auto,
    /// Graphviz `dot` (an error when it cannot run).
    Graphviz,
    /// The built-in layered layout.
    Builtin,
    /// No pictures.
    None,
}

/// Arguments of `gardefou report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    #[command(flatten)]
    replay: ReplayArgs,
    /// The HTML file to write (`-`: standard output). A file is replaced whole
    /// or not at all; a symbolic link is written through; a device or FIFO is
    /// written to.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Which flags the replayed safety filter reads.
    #[arg(long, value_enum, default_value = "def")]
    coupling: CouplingArg,
    /// How the pictures of the models are drawn.
    #[arg(long, value_enum, default_value = "auto")]
    layout: LayoutArg,
}

/// Runs `gardefou report`.
pub fn run(args: ReportArgs) -> Result<(), Failure> {
    let plant = Plant::from_path(&args.replay.plant).map_err(Failure::bad)?;
    let model = Model::from_path(&args.replay.model).map_err(Failure::bad)?;
    let request = report::Request {
        replay: args.replay.for_report(&plant)?,
        coupling: args.coupling.into(),
        layout: match args.layout {
            LayoutArg::Auto => Some(Layout::Auto),
            LayoutArg::Graphviz => Some(Layout::Graphviz),
            LayoutArg::Builtin => Some(Layout::BuiltIn),
            LayoutArg::None => None,
        },
    };
    let page = report::build(&plant, &model, &request)?;
    diagnoser::output::write_file(&args.output, page.as_bytes())?;
    eprintln!(
        "report written to {} ({} bytes)",
        args.output.display(),
        page.len()
    );
    Ok(())
}
