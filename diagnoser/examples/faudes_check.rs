//! Event-diagnosability of libFAUDES models, one line per model, for comparison
//! with libFAUDES itself (`scripts/faudes-compare.py`).
//!
//! Usage: `faudes_check [--explain] GENERATOR FAILURE_TYPES [GENERATOR FAILURE_TYPES ...]`
//!
//! `GENERATOR` may be several files joined by commas: the components of a
//! plant, checked as their product.
//!
//! Prints, per model, `GENERATOR VERDICT TYPE=VERDICT...`, verdicts being
//! `diagnosable` or `not-diagnosable`: first the verdict for the whole map, then
//! the verdict for each failure type alone (what libFAUDES answers for a map holding
//! only that type). With `--explain`, the readable verdict follows, indented. A
//! model that cannot be read prints `GENERATOR error` and its error on stderr; the
//! exit status is then 1.

use std::path::Path;
use std::process::ExitCode;

use diagnoser::faudes::{parse_failure_types, parse_generator, product, render};

fn word(diagnosable: bool) -> &'static str {
    if diagnosable {
        "diagnosable"
    } else {
        "not-diagnosable"
    }
}

fn check(generator: &str, failure_types: &str, explain: bool) -> Result<(), String> {
    let read =
        |path: &str| std::fs::read_to_string(path).map_err(|e| format!("{path}: cannot read: {e}"));
    let components = (generator.split(','))
        .map(|path| parse_generator(&read(path)?, Path::new(path)).map_err(|e| e.to_string()))
        .collect::<Result<Vec<_>, _>>()?;
    let f = parse_failure_types(&read(failure_types)?, Path::new(failure_types))
        .map_err(|e| e.to_string())?;
    let result = product::event_diagnosability(&components, &f, usize::MAX)
        .map_err(|e| format!("{generator}: {e:?}"))?;
    let mut line = format!("{generator} {}", word(result.diagnosable));
    for (name, _) in &f.types {
        let alone = result.type_diagnosable(name).unwrap_or(false);
        line.push_str(&format!(" {name}={}", word(alone)));
    }
    println!("{line}");
    if explain {
        for text in render(&result).lines() {
            println!("  {text}");
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let explain = args.first().is_some_and(|a| a == "--explain");
    if explain {
        args.remove(0);
    }
    if args.is_empty() || !args.len().is_multiple_of(2) {
        eprintln!(
            "usage: faudes_check [--explain] GENERATOR FAILURE_TYPES [GENERATOR FAILURE_TYPES ...]"
        );
        return ExitCode::from(2);
    }
    let mut status = ExitCode::SUCCESS;
    for pair in args.chunks(2) {
        if let Err(message) = check(&pair[0], &pair[1], explain) {
            println!("{} error", pair[0]);
            eprintln!("{message}");
            status = ExitCode::from(1);
        }
    }
    status
}
