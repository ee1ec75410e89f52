//! `gardefou check`: diagnosability of every fault, and the size of each part's
//! compiled diagnoser against the centralised one; with `--filter`, how much the
//! safety filter shrinks each diagnoser (seed 002 §4); or event-diagnosability of
//! a libFAUDES generator.

use std::fs;
use std::io::Write;
use std::path::PathBuf;

use clap::Args;
use diagnoser::diagnosis::compile::{Commands, Compiled, Size};
use diagnoser::diagnosis::diagnosability::{
    FaultDiagnosability, Waiting, check, separate_under_any_order,
};
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::faudes;
use diagnoser::model::Model;
use diagnoser::{Failure, Plant, Time, time};
use filter_coupling::simplify::PartFilter;

/// Why a generator, or a product of them, could not be checked, naming the
/// files.
fn product_error(
    paths: &[PathBuf],
    components: &[faudes::Generator],
    budget: usize,
    error: faudes::product::ProductError,
) -> String {
    use faudes::product::ProductError;
    let files = |members: &[usize]| {
        (members.iter())
            .map(|&i| paths[i].display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let states = |members: &[usize]| {
        (members.iter())
            .map(|&i| components[i].states.len().max(1) as f64)
            .product::<f64>()
    };
    match error {
        ProductError::Observability {
            event,
            observable_in,
            unobservable_in,
        } => format!(
            "{}: event {} is unobservable here but observable in {}: a shared event must be seen alike",
            paths[unobservable_in].display(),
            diagnoser::error::quoted(&event),
            paths[observable_in].display()
        ),
        ProductError::ProductTooLarge {
            components: members,
            reached,
        } => format!(
            "{}: their product grew past {budget} states and transitions (--max-states; {reached} reached) with no answer yet: these components share events, so they are composed as one",
            files(&members)
        ),
        ProductError::VerifierTooLarge {
            components: members,
            too_large,
        } => format!(
            "{}: the verifier of failure type {} grew past {budget} states and transitions (--max-states) with no answer yet: {} states are too many to check as one{}",
            files(&members),
            diagnoser::error::quoted(&too_large.failure_type),
            states(&members),
            if paths.len() == 1 {
                "; give the plant as its components (several --gen files)"
            } else {
                ""
            }
        ),
    }
}

/// Arguments of `gardefou check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// Plant file: parts, faults and partitions.
    #[arg(long, required_unless_present = "generator", requires = "model")]
    plant: Option<PathBuf>,
    /// Learned model (from `gardefou learn`).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Also write each part's compiled diagnoser as Graphviz DOT into this directory.
    #[arg(long, value_name = "DIR")]
    dot: Option<PathBuf>,
    /// Print the verdicts as JSON (one object per part) instead of text.
    #[arg(long)]
    json: bool,
    /// Also size each part's diagnoser with any command, and with only the scans
    /// the safety filter lets through (its constraints stay 0), beside the
    /// learned control's.
    #[arg(long, conflicts_with = "generator")]
    filter: bool,
    /// Longest an unexpected sensor edge shows (as for `diagnose`).
    #[arg(long, value_parser = time::parse_duration, default_value = "100ms")]
    glitch_max: Time,
    /// Instead: a libFAUDES generator file (`.gen`) to check for
    /// event-diagnosability; several are the components of a plant, checked
    /// as their product (shared events move together).
    #[arg(long = "gen", value_name = "GEN", num_args = 1.., conflicts_with_all = ["plant", "model"], requires = "failures")]
    generator: Vec<PathBuf>,
    /// The libFAUDES failure-type map that goes with `--gen`.
    #[arg(long, value_name = "FILE")]
    failures: Option<PathBuf>,
    /// With `--gen`: the largest verifier explored (its states and
    /// transitions, in total) before giving up. About 50 bytes each.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 40_000_000,
        requires = "generator"
    )]
    max_states: usize,
}

/// Runs `gardefou check`.
pub fn run(args: CheckArgs) -> Result<(), Failure> {
    if let (false, Some(map)) = (args.generator.is_empty(), &args.failures) {
        return faudes_check(&args.generator, map, args.json, args.max_states);
    }
    let (Some(plant_path), Some(model_path)) = (&args.plant, &args.model) else {
        return Err(Failure::bad(
            "check needs --plant and --model (or --gen and --failures)",
        ));
    };
    let plant = Plant::from_path(plant_path).map_err(Failure::bad)?;
    let model = Model::from_path(model_path).map_err(Failure::bad)?;
    let diagnoser = PlantDiagnoser::new(
        &plant,
        &model,
        &DiagnoserOptions {
            glitch_max: args.glitch_max,
            ..DiagnoserOptions::default()
        },
    )
    .map_err(|e| Failure::bad(format!("{}: {e}", model_path.display())))?;
    if let Some(dir) = &args.dot {
        fs::create_dir_all(dir)
            .map_err(|e| Failure::Io(format!("cannot create {}: {e}", dir.display())))?;
    }
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let mut product: f64 = 1.0;
    let mut sum = 0usize;
    let mut simplified: Vec<Simplified> = Vec::new();
    for engine in diagnoser.engines() {
        let mut engine = engine.clone();
        let compiled = Compiled::explore(&mut engine, 2);
        let size = compiled.size();
        product *= size.states as f64;
        sum += size.states;
        let mut verdicts = check(&mut engine, &compiled, model.time_unit);
        separate_under_any_order(&engine, &mut verdicts, model.time_unit);
        if let Some(dir) = &args.dot {
            let path = dir.join(format!("{}.diagnoser.dot", engine.part.name));
            fs::write(
                &path,
                compiled.to_digraph(&engine, model.time_unit).to_dot(),
            )
            .map_err(|e| Failure::Io(format!("cannot write {}: {e}", path.display())))?;
        }
        let simple = if args.filter {
            let s = simplify(&plant, &engine, size, compiled.truncated)?;
            simplified.push(s.clone());
            Some(s)
        } else {
            None
        };
        if args.json {
            let mut v = serde_json::json!({
                "part": engine.part.name,
                "diagnoser": size,
                "truncated": compiled.truncated,
                "faults": verdicts,
            });
            if let Some(s) = simple {
                v["filter"] = serde_json::to_value(&s).map_err(|e| Failure::Io(e.to_string()))?;
            }
            writeln!(out, "{v}").map_err(Failure::output)?;
            continue;
        }
        writeln!(
            out,
            "{}: diagnoser of {} states, {} transitions ({} signals, {} faults){}",
            engine.part.name,
            size.states,
            size.transitions,
            engine.part.names.len(),
            engine.part.modes.len() - 1,
            if compiled.truncated {
                " [exploration truncated]"
            } else {
                ""
            }
        )
        .map_err(Failure::output)?;
        for v in &verdicts {
            write_verdict(&mut out, v).map_err(Failure::output)?;
        }
    }
    if args.json {
        let v = serde_json::json!({
            "plant": plant.name,
            "decentralised_states": sum,
            "centralised_states": product,
        });
        writeln!(out, "{v}").map_err(Failure::output)?;
    } else {
        writeln!(
            out,
            "plant {}: the local diagnosers have {sum} states in all; their product, a centralised diagnoser, would have {product:.0}",
            plant.name
        )
        .map_err(Failure::output)?;
        if args.filter {
            write_simplified(&mut out, &simplified).map_err(Failure::output)?;
        }
    }
    Ok(())
}

/// One part's diagnoser sized under the three command policies.
#[derive(Debug, Clone, serde::Serialize)]
struct Simplified {
    part: String,
    /// Any command in any observed state.
    any: Size,
    /// Any command, only the scans the filter lets through.
    filtered: Size,
    /// Commands as in the learned runs (the diagnoser `check` works on).
    learned: Size,
    /// Constraints that remove scans of the part.
    constraints: Vec<String>,
    /// Constraints that read the part but have too many unknowns to be used.
    skipped: Vec<String>,
    /// Whether an exploration stopped at its size limit.
    truncated: bool,
}

/// Explores `engine`'s diagnoser with any command, then with the filter's
/// restriction.
fn simplify(
    plant: &Plant,
    engine: &diagnoser::diagnosis::Engine,
    learned: Size,
    truncated: bool,
) -> Result<Simplified, Failure> {
    let filter = PartFilter::new(plant, &engine.part.names)
        .map_err(|e| Failure::bad(format!("part '{}': {e}", engine.part.name)))?;
    // Orders given anywhere would turn elements in mid-stroke everywhere: each
    // is taken to start a whole stroke, or the exploration would not end.
    let mut e = diagnoser::diagnosis::Engine::new(engine.part.without_reversals());
    let any = Compiled::explore_with(&mut e, 2, Commands::Any);
    let allows = |before: u32, after: u32| filter.allows(before, after);
    let filtered = Compiled::explore_with(&mut e, 2, Commands::Filter(&allows));
    Ok(Simplified {
        part: engine.part.name.clone(),
        any: any.size(),
        filtered: filtered.size(),
        learned,
        constraints: filter.constraints().map(str::to_string).collect(),
        skipped: filter
            .skipped()
            .iter()
            .map(|s| s.constraint.clone())
            .collect(),
        truncated: truncated || any.truncated || filtered.truncated,
    })
}

fn write_simplified(out: &mut impl Write, rows: &[Simplified]) -> std::io::Result<()> {
    writeln!(
        out,
        "filter-based simplification (seed 002 §4): states / transitions of each part's diagnoser"
    )?;
    let cell = |s: &Size| format!("{} / {}", s.states, s.transitions);
    let table: Vec<[String; 5]> = rows
        .iter()
        .map(|r| {
            let mut by = r.constraints.join(", ");
            if by.is_empty() {
                by = "-".to_string();
            }
            if !r.skipped.is_empty() {
                by.push_str(&format!(" (too many unknowns: {})", r.skipped.join(", ")));
            }
            if r.truncated {
                by.push_str(" [exploration truncated]");
            }
            [
                r.part.clone(),
                cell(&r.any),
                cell(&r.filtered),
                cell(&r.learned),
                by,
            ]
        })
        .collect();
    let head = [
        "part",
        "any command",
        "filtered",
        "learned control",
        "removed by",
    ];
    let mut width = head.map(|h| h.chars().count());
    for row in &table {
        for (w, c) in width.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: [&str; 5]| {
        let mut l = String::new();
        for (k, (c, w)) in cells.iter().zip(width).enumerate() {
            if k + 1 == cells.len() {
                l.push_str(&format!("  {c}"));
            } else {
                l.push_str(&format!("  {c:<w$}"));
            }
        }
        l
    };
    writeln!(out, "{}", line(head))?;
    for row in &table {
        writeln!(out, "{}", line(row.each_ref().map(String::as_str)))?;
    }
    Ok(())
}

fn write_verdict(out: &mut impl Write, v: &FaultDiagnosability) -> std::io::Result<()> {
    let state = match (v.detectable, v.isolable) {
        (true, true) if v.isolable_when_waiting => format!(
            "diagnosable: detected and isolated within {} observed scan(s) of showing, also if the control waits for ever",
            v.bound_scans.unwrap_or(0)
        ),
        (true, true) => format!(
            "diagnosable while the plant runs: detected and isolated within {} observed scan(s) of showing; if the control waits for ever, not told from {}",
            v.bound_scans.unwrap_or(0),
            v.confused_when_waiting.join(", ")
        ),
        (true, false) => format!(
            "detectable, not isolable from {}",
            v.confused_with.join(", ")
        ),
        (false, _) => {
            let others: Vec<&str> = v
                .confused_with
                .iter()
                .filter(|l| *l != "N")
                .map(String::as_str)
                .collect();
            if others.is_empty() {
                "not detectable".to_string()
            } else {
                format!("not detectable, not isolable from {}", others.join(", "))
            }
        }
    };
    writeln!(out, "  {} {}: {state}", v.label, v.template)?;
    if let Some(w) = &v.waiting {
        writeln!(out, "    {}", waiting_sentence(&v.label, w))?;
    }
    if let Some(c) = &v.counterexample {
        let other = if c.other == "N" {
            "a normal run".to_string()
        } else {
            format!("a run with {}", c.other)
        };
        writeln!(
            out,
            "    counterexample: these observations repeat for ever and fit both {other} and a run with {}:",
            v.label
        )?;
        writeln!(out, "      observed:      {}", c.observed.join(" → "))?;
        writeln!(
            out,
            "      {:<14} {}",
            format!("{}:", c.other),
            c.other_run.join(" → ")
        )?;
        writeln!(
            out,
            "      {:<14} {}",
            format!("{}:", v.label),
            c.faulty.join(" → ")
        )?;
    }
    Ok(())
}

/// Why a fault is isolable only while the plant runs, in one sentence.
fn waiting_sentence(label: &str, w: &Waiting) -> String {
    let until = match &w.until {
        Some(o) if w.orders_outside_control.is_empty() => format!("until {o}"),
        Some(o) => format!(
            "until {o} ({}: an order the learned control does not give there)",
            w.orders_outside_control.join(", ")
        ),
        None => "for ever (no observation tells them apart)".to_string(),
    };
    let control = if w.control_waits_for.is_empty() {
        "the learned runs never left that state".to_string()
    } else {
        format!(
            "the learned control waits for {} first",
            w.control_waits_for.join(" or ")
        )
    };
    if w.other == "N" {
        format!(
            "{label} goes unnoticed if the plant stops at {}: a normal run looks the same {until}; {control}",
            w.state
        )
    } else {
        format!(
            "{label} and {} look the same once the plant stops at {} {until}; {control}",
            w.other, w.state
        )
    }
}

fn faudes_check(
    gen_paths: &[PathBuf],
    map: &PathBuf,
    json: bool,
    budget: usize,
) -> Result<(), Failure> {
    let read = |p: &PathBuf| {
        fs::read_to_string(p)
            .map_err(|e| Failure::bad(format!("{}: cannot read: {e}", p.display())))
    };
    let components = (gen_paths.iter())
        .map(|p| faudes::parse_generator(&read(p)?, p).map_err(Failure::bad))
        .collect::<Result<Vec<_>, _>>()?;
    let f = faudes::parse_failure_types(&read(map)?, map).map_err(Failure::bad)?;
    let result = faudes::product::event_diagnosability(&components, &f, budget)
        .map_err(|e| Failure::bad(product_error(gen_paths, &components, budget, e)))?;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if json {
        let v = serde_json::to_string(&result).map_err(|e| Failure::Io(e.to_string()))?;
        writeln!(out, "{v}").map_err(Failure::output)?;
    } else {
        write!(out, "{}", faudes::render(&result)).map_err(Failure::output)?;
    }
    Ok(())
}
