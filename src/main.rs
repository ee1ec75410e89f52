//! `gardefou`: the command line.
//!
//! Every verb prints machine-readable output (JSON lines) on stdout and messages on
//! stderr. Bad input ends with a one-line error on stderr and exit code 2.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use diagnoser::Failure;

mod args;
mod check;
mod demo;
mod diagnose;
mod filter;
mod fleet;
mod interrupt;
mod learn;
mod monitor;
mod progress;
mod report;
mod simulate;

/// Decentralised timed fault diagnosis for PLC-controlled plants, coupled to the
/// PLC's safety filter.
#[derive(Debug, Parser)]
#[command(name = "gardefou", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The whole chain on the embedded sorting plant, in closed loop: safe control,
    /// diagnosers and the rewritten filter through each turntable fault.
    Demo(demo::DemoArgs),
    /// The safety filter: constraints rewritten with fault flags and estimates,
    /// Structured Text, and logs checked against the constraints.
    Filter(filter::FilterArgs),
    /// Diagnose online: events from a live source, deadlines fired on time.
    // Boxed: its many sources' arguments make it several times the others.
    Monitor(Box<monitor::MonitorArgs>),
    /// Diagnose a plant out of its NATS JetStream stream (as `monitor --nats`
    /// published it), with no PLC attached.
    Fleet(fleet::FleetArgs),
    /// Learn one timed model per plant part from logs of normal operation.
    Learn(learn::LearnArgs),
    /// Replay logs through every part's diagnoser: verdict changes as JSON lines.
    Diagnose(diagnose::DiagnoseArgs),
    /// Diagnosability of every fault, and the size of each part's diagnoser.
    Check(check::CheckArgs),
    /// Simulate a reference plant (with injected faults) and write its logs.
    Simulate(simulate::SimulateArgs),
    /// A self-contained HTML fault review: verdicts, timelines, explanations and
    /// pictures of the models.
    Report(report::ReportArgs),
}

/// Runs one verb.
fn run(command: Command) -> Result<(), Failure> {
    match command {
        Command::Learn(args) => learn::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Diagnose(args) => diagnose::run(args),
        Command::Check(args) => check::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Filter(args) => filter::run(args),
        Command::Monitor(args) => monitor::run(*args),
        Command::Fleet(args) => fleet::run(args),
        Command::Report(args) => report::run(args),
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // clap's whole message: the problem, the arguments it concerns, a
            // suggestion and the usage. Help and version exit 0, errors 2.
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    diagnoser::panics::install_hook();
    // With RUST_BACKTRACE set, Rust has reported the panic in full.
    let result = match std::panic::catch_unwind(move || run(cli.command)) {
        Ok(result) => result,
        Err(payload) => {
            if std::env::var_os("RUST_BACKTRACE").is_none() {
                let message = diagnoser::panics::message(payload.as_ref());
                eprintln!("gardefou: internal error: {message} (RUST_BACKTRACE=1 shows where)");
            }
            return ExitCode::from(101);
        }
    };
    match result {
        Ok(()) | Err(Failure::Closed) => ExitCode::SUCCESS,
        Err(Failure::BadInput(message)) => {
            eprintln!("gardefou: {message}");
            ExitCode::from(2)
        }
        Err(Failure::Io(message)) => {
            eprintln!("gardefou: {message}");
            ExitCode::from(1)
        }
    }
}
