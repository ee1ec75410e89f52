//! Active diagnosis in closed loop: where the safety constraints allow a
//! separating move, the coupling makes it and the verdict says what it told;
//! where they do not (the shipped sorting line), it says which constraint
//! forbids each move, and the line halts without damage.

use datasets::inject::{FaultSpec, Injection};
use datasets::sorting::{PLANT_TOML, plant};
use diagnoser::model::Model;
use diagnoser::{MS, Plant, SECOND, Time};
use filter_coupling::filter::Coupling;
use runtime::closed_loop::{self, LoopOutcome, LoopRun};

/// A model of `plant` learned from 20 fault-free minutes under safe control.
fn learned(plant: &Plant) -> Model {
    closed_loop::learned(plant, 7, 1200 * SECOND).expect("learns")
}

/// The first time after `after` the fault-free line of the runs' seed brings
/// the turntable back to loading, plus a scan: a fault of C5 or of the plate
/// starting then shows on the next rotation, as an ambiguity.
fn back_at_loading(plant: &Plant, after: Time) -> Time {
    let normal = closed_loop::record(plant, SEED, after + 120 * SECOND).expect("records");
    let c4 = plant.signals.id("C4").expect("C4");
    let back = normal
        .events
        .iter()
        .find(|e| e.signal == c4 && e.value && e.t > after)
        .expect("the turntable comes back");
    back.t + 10 * MS
}

const SEED: u64 = 11;

/// Mode (c) with probing, `fault` from `onset`, for `duration`.
fn run(plant: &Plant, model: &Model, fault: &str, onset: Time, duration: Time) -> LoopOutcome {
    let spec = FaultSpec {
        what: fault.to_string(),
        onset,
        factor: None,
    };
    let fault = Injection::resolve(&spec, plant).expect("a fault of the plant");
    let run = LoopRun {
        coupling: Coupling::FlagsAndSuspects,
        seed: SEED,
        duration,
        fault: Some(fault),
        from: onset,
        probe: true,
    };
    closed_loop::run(plant, model, &run).expect("runs")
}

/// The sorting line without the four constraints that forbid reversing the
/// turntable away from a position (CSs8, CSs13, CSs14, CSs15): there,
/// releasing A4 tells C5 stuck at 0 (the plate comes back to C4) from the
/// plate blocked in transit (it does not).
fn reversible_plant() -> Plant {
    let mut p = Plant::parse(PLANT_TOML, std::path::Path::new("sorting.toml")).expect("plant");
    p.constraints
        .retain(|c| !["CSs8", "CSs13", "CSs14", "CSs15"].contains(&c.name.as_str()));
    p
}

#[test]
fn a_probe_tells_a_stuck_sensor_from_a_blocked_plate_where_the_constraints_allow_it() {
    let plant = reversible_plant();
    let model = learned(&plant);
    let onset = back_at_loading(&plant, 120 * SECOND);
    for (fault, told, flag) in [("F3", "so F3", "def_C5"), ("F11", "so F11", "def_P")] {
        let out = run(&plant, &model, fault, onset, 600 * SECOND);
        assert!(out.damage.is_empty(), "{fault}: {:?}", out.damage);
        let probe = out
            .probes
            .first()
            .unwrap_or_else(|| panic!("{fault}: no probe: {:?}", out.no_probe));
        assert!(
            probe
                .reason
                .starts_with("released A4 to tell F3, F11 apart"),
            "{fault}: {}",
            probe.reason
        );
        assert!(probe.reason.ends_with(told), "{fault}: {}", probe.reason);
        assert!(
            out.flags.iter().any(|f| f == flag),
            "{fault}: {:?}",
            out.flags
        );
        // Within 10 s of the ambiguity, which the detection opens.
        let ambiguous = out.detected.expect("detected");
        assert!(
            probe.t >= ambiguous && probe.t - ambiguous <= 10 * SECOND,
            "{fault}: probe at {} ms, ambiguous from {} ms",
            probe.t / MS,
            ambiguous / MS
        );
    }
}

#[test]
fn on_the_shipped_line_no_move_is_safe_and_the_reason_names_the_constraints() {
    let plant = plant();
    let model = learned(&plant);
    let onset = back_at_loading(&plant, 120 * SECOND);
    for (fault, forbidden) in [
        (
            "F3",
            "A4 = 0: forbidden by CSs8 (C5 & C6 & !A4) and CSs15 (!C5 & FE(A4))",
        ),
        (
            "F12",
            "A4 = 1: forbidden by CSs13 (C4 & !C6 & A4) and CSs14 (!C4 & RE(A4))",
        ),
    ] {
        let out = run(&plant, &model, fault, onset, 400 * SECOND);
        assert!(out.probes.is_empty(), "{fault}: {:?}", out.probes);
        assert!(
            out.no_probe.iter().any(|r| r.ends_with(forbidden)),
            "{fault}: {:?}",
            out.no_probe
        );
        assert!(out.damage.is_empty(), "{fault}: {:?}", out.damage);
    }
}
