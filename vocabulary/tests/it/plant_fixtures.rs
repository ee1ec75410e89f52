//! Data-driven tests of `plant.toml` parsing: every `tests/fixtures/plants/*.toml`
//! whose name starts with `good` must parse; every other must fail with exactly the
//! one-line message of the `.err` file beside it.
//!
//! Run with `UPDATE_EXPECT=1` to (re)write the `.err` files, then review the diff.

use std::fs;
use std::path::{Path, PathBuf};

use vocabulary::fault::FaultTemplate;
use vocabulary::plant::ObserverRule;
use vocabulary::{Plant, SignalKind, TimeUnit};

fn fixtures() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/plants");
    let mut files: Vec<PathBuf> = fs::read_dir(&dir)
        .expect("fixture directory")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

fn parse(path: &Path) -> Result<Plant, vocabulary::Located> {
    let text = fs::read_to_string(path).expect("fixture reads");
    let name = path.file_name().expect("file name");
    Plant::parse(&text, &Path::new("tests/fixtures/plants").join(name))
}

#[test]
fn bad_plant_files_fail_with_the_expected_message() {
    let update = std::env::var_os("UPDATE_EXPECT").is_some();
    let mut checked = 0;
    for path in fixtures() {
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .expect("utf-8 name");
        if stem.starts_with("good") {
            continue;
        }
        let err = parse(&path).expect_err(stem).to_string();
        assert_eq!(err.lines().count(), 1, "{stem}: multi-line error: {err}");
        let expected_path = path.with_extension("err");
        if update {
            fs::write(&expected_path, format!("{err}\n")).expect("writes .err");
        }
        let expected =
            fs::read_to_string(&expected_path).unwrap_or_else(|_| panic!("{stem}.err missing"));
        assert_eq!(err, expected.trim_end(), "{stem}");
        checked += 1;
    }
    assert!(checked >= 15, "only {checked} bad fixtures");
}

#[test]
fn the_spec_form_is_accepted_as_written() {
    let plant = parse(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/plants/good_spec_example.toml"),
    )
    .expect("SPEC §3 form parses");
    assert_eq!(plant.name, "sorting");
    assert_eq!(plant.scan_period, 10 * vocabulary::MS);
    assert_eq!(plant.time_unit, TimeUnit::Ms);
    let turntable = plant.part("turntable").expect("part");
    assert_eq!(turntable.element.as_deref(), Some("P"));
    assert_eq!(turntable.sensors.len(), 2);
    assert_eq!(
        plant.fault("F11").map(|f| &f.template),
        Some(&FaultTemplate::BlockedBetween {
            element: "P".into(),
            from: "C4".into(),
            to: "C5".into()
        })
    );
    assert_eq!(
        plant.partition_of("F5").map(|p| p.flag().to_string()),
        Some("def_P".to_string())
    );
    assert!(matches!(
        plant.observers[0].rule,
        ObserverRule::SetReset { .. }
    ));
    let csc1 = &plant.constraints[1];
    assert_eq!(csc1.priority.map(|id| plant.signals.name(id)), Some("A1"));
    assert_eq!(csc1.expr.to_string(), "C0 & A0 & !A1");
    assert_eq!(plant.functional[0].name, "CFs1");
    assert_eq!(plant.can.len(), 3);
    assert_eq!((plant.can[1].cob_id, plant.can[1].bit), (0x181, 1));
    assert_eq!(plant.signals.name(plant.can[2].signal), "A4");
}

#[test]
fn without_faults_every_template_is_generated() {
    let plant = parse(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/plants/good_default_faults.toml"),
    )
    .expect("parses");
    let labels: Vec<&str> = plant.faults.iter().map(|f| f.label.as_str()).collect();
    for want in [
        "C4.stuck0",
        "C4.stuck1",
        "C4.unexpected_rise",
        "C5.unexpected_fall",
        "A4.actuator_stuck1",
        "P.blocked_at.C4",
        "P.blocked_between.C5.C4",
        "P.slow",
    ] {
        assert!(labels.contains(&want), "{want} missing from {labels:?}");
    }
    // 4 per sensor, 2 per actuator, 2 blocked_at, 2 blocked_between, 1 slow.
    assert_eq!(plant.faults.len(), 4 * 2 + 2 + 2 + 2 + 1);
    let names: Vec<&str> = plant.partitions.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["C4", "C5", "P"]);
    // Actuator faults and a slow element join the part's element.
    assert!(plant.partition_of("P.slow").is_some_and(|p| p.name == "P"));
    assert!(
        plant
            .partition_of("A4.actuator_stuck0")
            .is_some_and(|p| p.name == "P")
    );
    assert_eq!(plant.signals.of_kind(SignalKind::Sensor).count(), 2);
}

#[test]
fn the_modbus_map_is_the_default_with_the_file_s_overrides() {
    use vocabulary::plant::{ModbusMap, ModbusTable};
    let plant = parse(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/plants/good_modbus.toml"),
    )
    .expect("parses");
    let map = plant.modbus_map();
    let at = |name: &str| map.signals[plant.signals.id(name).expect("signal").index()];
    // C4 keeps the default (the first sensor); C5 and A4 are moved.
    assert_eq!(at("C4"), (ModbusTable::DiscreteInput, 0));
    assert_eq!(at("C5"), (ModbusTable::DiscreteInput, 17));
    assert_eq!(at("A4"), (ModbusTable::Coil, 8));
    // Flags: def_ first, in partition order, then suspect_, from coil 100.
    let names: Vec<String> = map.flags.iter().map(|f| f.0.to_string()).collect();
    let partitions: Vec<String> = plant.partitions.iter().map(|p| p.name.clone()).collect();
    let expected: Vec<String> = partitions
        .iter()
        .map(|p| format!("def_{p}"))
        .chain(partitions.iter().map(|p| format!("suspect_{p}")))
        .collect();
    assert_eq!(names, expected);
    for (i, (name, coil)) in map.flags.iter().enumerate() {
        let default = ModbusMap::FLAGS_FROM + i as u16;
        let want = if name.to_string() == "suspect_C4" {
            200
        } else {
            default
        };
        assert_eq!(*coil, want, "{name}");
    }
    assert_eq!(map.flag(&vocabulary::Flag::suspect("C4")), Some(200));
    // Probe coils: past the highest flag coil (200 here), one moved.
    let a4 = plant.signals.id("A4").expect("A4");
    let probe = map.probe(a4).expect("A4's probe coils");
    assert_eq!((probe.probe, probe.value, probe.refused), (201, 300, 203));
}

#[test]
fn the_opcua_table_keeps_each_node_id_as_written() {
    let plant =
        parse(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/plants/good_opcua.toml"))
            .expect("parses");
    let entries: Vec<(&str, &str)> = plant
        .opcua
        .iter()
        .map(|e| (e.name.as_str(), e.node_id.as_str()))
        .collect();
    assert_eq!(
        entries,
        [
            ("C4", "ns=2;s=Line.Turntable.AtLoading"),
            ("A4", "ns=3;i=1042"),
            ("def_C4", "nsu=urn:example:line;s=Flags.def_C4"),
            ("C5", "ns=2;g=72962b91-fa75-4ae6-8d28-b404dc7daf63"),
        ]
    );
}

#[test]
fn each_actuator_has_three_probe_coils_from_200_and_clashes_are_refused() {
    use vocabulary::plant::{ModbusMap, ProbeCoil};
    let text = |modbus: &str| {
        format!(
            "name = \"p\"\n[signals]\nC1 = {{ kind = \"sensor\" }}\nA1 = {{ kind = \"actuator\" }}\n\
             A2 = {{ kind = \"actuator\" }}\n[[parts]]\nname = \"x\"\nactuators = [\"A1\", \"A2\"]\n\
             sensors = [\"C1\"]\n[modbus]\n{modbus}"
        )
    };
    let plant = Plant::parse(&text(""), Path::new("p.toml")).expect("parses");
    let map = plant.modbus_map();
    let coils: Vec<(String, u16)> = map
        .probes
        .iter()
        .flat_map(|p| {
            let a = plant.signals.name(p.actuator).to_string();
            ProbeCoil::ALL.map(|c| (c.name(&a), p.coil(c)))
        })
        .collect();
    let want = [
        "A1_PROBE",
        "A1_PROBE_VALUE",
        "A1_PROBE_REFUSED",
        "A2_PROBE",
        "A2_PROBE_VALUE",
        "A2_PROBE_REFUSED",
    ];
    let from = ModbusMap::PROBES_FROM;
    assert_eq!(
        coils,
        want.iter()
            .zip(from..)
            .map(|(n, a)| (n.to_string(), a))
            .collect::<Vec<_>>()
    );
    assert_eq!(
        ProbeCoil::parse("A2_PROBE_REFUSED"),
        Some(("A2", ProbeCoil::Refused))
    );

    let moved =
        Plant::parse(&text("A2_PROBE = { coil = 300 }\n"), Path::new("p.toml")).expect("parses");
    let a2 = moved.signals.id("A2").expect("A2");
    let p = *moved.modbus_map().probe(a2).expect("A2's coils");
    assert_eq!((p.probe, p.value, p.refused), (300, from + 4, from + 5));

    for (entry, message) in [
        (
            "A2_PROBE = { coil = 200 }\n",
            "p.toml:11:1: field 'modbus': 'A1_PROBE' and 'A2_PROBE' are both at coil 200; give one of them another address",
        ),
        (
            "A1_PROBE_REFUSED = { coil = 1 }\n",
            "p.toml:11:1: field 'modbus': 'A2' and 'A1_PROBE_REFUSED' are both at coil 1; give one of them another address",
        ),
        (
            "A1_PROBE = { discrete_input = 0 }\n",
            "p.toml:11:12: field 'modbus': probe coil 'A1_PROBE' must be a coil: the monitor writes it",
        ),
    ] {
        let e = Plant::parse(&text(entry), Path::new("p.toml")).expect_err(entry);
        assert_eq!(e.to_string(), message, "{entry}");
    }
}

#[test]
fn an_element_blocks_only_the_sensors_it_drives() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/plants/good_drives_inputs.toml");
    let plant = parse(&path).expect("parses");
    let part = &plant.parts[0];
    let names = |ids: &[vocabulary::SignalId]| -> Vec<String> {
        ids.iter()
            .map(|&s| plant.signals.name(s).to_string())
            .collect()
    };
    assert_eq!(names(&part.drives), ["B1", "B2"]);
    assert_eq!(names(part.inputs.as_deref().expect("declared")), ["B4"]);
    // Default faults block the element at, and between, the sensors it drives
    // only: the vacuum switch and the magazine's sensor are not positions.
    let labels: Vec<&str> = plant.faults.iter().map(|f| f.label.as_str()).collect();
    assert!(labels.contains(&"A.blocked_at.B1"), "{labels:?}");
    assert!(labels.contains(&"A.blocked_between.B2.B1"), "{labels:?}");
    assert!(
        !labels
            .iter()
            .any(|l| l.contains("blocked") && l.contains("B3"))
    );
    assert!(
        !labels
            .iter()
            .any(|l| l.contains("blocked") && l.contains("B4"))
    );

    // Without `drives`, the element drives every sensor but the inputs.
    let text = fs::read_to_string(&path)
        .expect("reads")
        .replace("drives = [\"B1\", \"B2\"]\n", "");
    let plant = Plant::parse(&text, Path::new("x.toml")).expect("parses");
    assert_eq!(names(&plant.parts[0].drives), ["B1", "B2", "B3"]);
}
