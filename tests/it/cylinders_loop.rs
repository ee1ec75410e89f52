//! The closed loop on the second reference plant, the four-cylinder rig: its
//! GRAFCETs set the plant file's variables, safe control by constraints
//! computes the orders, and the coupling takes the same flags as on the
//! sorting line. Nothing in the loop is written for either plant.

use datasets::cylinders::plant;
use datasets::inject::{FaultSpec, Injection};
use diagnoser::SECOND;
use diagnoser::model::Model;
use filter_coupling::filter::Coupling;
use runtime::closed_loop::{self, LoopOutcome, LoopRun, Rig};

const SEED: u64 = 11;
const ONSET: diagnoser::Time = 300 * SECOND;
const DURATION: diagnoser::Time = 2400 * SECOND;
/// Onsets at several phases of the rig's cycle (a move takes about 1.5 s).
const ONSETS: [diagnoser::Time; 8] = [
    ONSET,
    ONSET + 1_300_000_000,
    ONSET + 2_700_000_000,
    ONSET + 4_100_000_000,
    ONSET + 5_900_000_000,
    ONSET + 7_300_000_000,
    ONSET + 9_500_000_000,
    ONSET + 11_100_000_000,
];

fn learned() -> Model {
    closed_loop::learned(&plant(), 7, 3600 * SECOND).expect("learns")
}

fn run(
    model: &Model,
    fault: Option<&str>,
    onset: diagnoser::Time,
    coupling: Coupling,
) -> LoopOutcome {
    let plant = plant();
    let fault = fault.map(|what| {
        let spec = FaultSpec {
            what: what.to_string(),
            onset,
            factor: None,
        };
        Injection::resolve(&spec, &plant).expect("a fault of the rig")
    });
    let run = LoopRun {
        coupling,
        seed: SEED,
        duration: DURATION,
        fault,
        from: onset,
        probe: coupling == Coupling::FlagsAndSuspects,
    };
    closed_loop::run(&plant, model, &run).expect("runs")
}

#[test]
fn the_rig_runs_in_closed_loop_under_its_grafcets() {
    assert_eq!(Rig::of(&plant()), Ok(Rig::Cylinders));
    let model = learned();
    let normal = run(&model, None, ONSET, Coupling::FlagsAndSuspects);
    // Objects go round: a move takes a stroke of about a second and a half.
    assert!(
        normal.delivered > 100,
        "{} objects moved in 10 min",
        normal.delivered
    );
    assert!(normal.damage.is_empty(), "{:?}", normal.damage);
    assert_eq!(normal.detected, None, "a fault-free run stays normal");
    assert_eq!(normal.halted, 0);
    assert!(normal.flags.is_empty(), "{:?}", normal.flags);
}

/// A retracted switch stuck at 1 lets a neighbour's rod be ordered out into a
/// rod still out, unless the coupling reads the switch from its estimate.
#[test]
fn a_stuck_limit_switch_is_read_from_its_estimate_and_the_rig_goes_on() {
    let model = learned();
    let normal = run(&model, None, ONSET, Coupling::None);
    let mut collisions = 0;
    let mut declared = 0;
    for onset in ONSETS {
        let uncoupled = run(&model, Some("Se0.stuck1"), onset, Coupling::None);
        collisions += uncoupled
            .damage
            .iter()
            .filter(|d| d.cause == "rod_collision")
            .count();
        let coupled = run(
            &model,
            Some("Se0.stuck1"),
            onset,
            Coupling::FlagsAndSuspects,
        );
        let at = onset / SECOND;
        assert!(
            coupled.damage.is_empty(),
            "onset {at} s: {:?}",
            coupled.damage
        );
        assert!(
            coupled.flags.iter().all(|f| f == "def_Se0"),
            "onset {at} s: a wrong flag: {:?}",
            coupled.flags
        );
        if coupled.flags.is_empty() {
            // Left ambiguous, halted safely (see below).
            continue;
        }
        declared += 1;
        let nominal = normal.delivered_from(onset) as f64;
        assert!(
            coupled.delivered as f64 >= 0.9 * nominal,
            "onset {at} s: {} moves against {nominal} without the fault",
            coupled.delivered
        );
    }
    // Where the switch sticks while its rod is between the switches, the
    // part stays ambiguous between it and an unexpected fall of the extended
    // switch, whose union reading then holds the release back: a safe halt,
    // without the wrong flag a late release once caused (held reactions).
    assert!(
        declared >= ONSETS.len() - 1,
        "{declared} of {} runs declare Se0",
        ONSETS.len()
    );
    assert!(
        collisions > 0,
        "without coupling, the stuck switch lets rods collide at some phase"
    );
}
