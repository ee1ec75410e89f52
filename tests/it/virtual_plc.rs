//! `gardefou simulate --control constraints` and the virtual PLC of
//! `gardefou simulate --serve-modbus`: the real binary, real files, real Modbus
//! TCP clients.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::support::gardefou;
use diagnoser::plant::ModbusTable;
use serde_json::Value;
use tokio_modbus::ExceptionCode;
use tokio_modbus::client::{Context, Reader, Writer};

fn ok(o: Output) -> Output {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Simulates an hour under safe control by constraints into `out`.
fn constraint_run(out: &Path, seed: &str, extra: &[&str]) {
    let mut args = vec![
        "simulate",
        "--control",
        "constraints",
        "--duration",
        "1h",
        "--seed",
        seed,
        "--out",
        path(out),
    ];
    args.extend_from_slice(extra);
    ok(gardefou(&args));
}

/// Learns a model from one fault-free hour under safe control by constraints.
fn learn_constraint_model(dir: &Path) -> std::path::PathBuf {
    let run = dir.join("learn");
    constraint_run(&run, "7", &[]);
    let model = dir.join("model.json");
    ok(gardefou(&[
        "learn",
        "--plant",
        path(&run.join("plant.toml")),
        path(&run.join("events.csv")),
        "-o",
        path(&model),
    ]));
    model
}

fn diagnose(model: &Path, log: &Path) -> Vec<Value> {
    let o = ok(gardefou(&[
        "diagnose",
        "--plant",
        path(&log.join("plant.toml")),
        "--model",
        path(model),
        path(&log.join("events.csv")),
    ]));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON verdict line"))
        .collect()
}

#[test]
fn constraint_control_logs_are_learnable() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = learn_constraint_model(dir.path());

    // The orders really come from the constraints: the program's run of the
    // same seed differs.
    let program = dir.path().join("program");
    ok(gardefou(&[
        "simulate",
        "--duration",
        "1h",
        "--seed",
        "7",
        "--out",
        path(&program),
    ]));
    let events = |d: &Path| std::fs::read(d.join("events.csv")).expect("events.csv");
    assert_ne!(events(&program), events(&dir.path().join("learn")));

    // Fault-free runs of other seeds: no verdict ever leaves normal.
    for seed in ["11", "12"] {
        let run = dir.path().join(format!("normal{seed}"));
        constraint_run(&run, seed, &[]);
        let damage: Value =
            serde_json::from_slice(&std::fs::read(run.join("damage.json")).expect("damage.json"))
                .expect("JSON");
        assert_eq!(damage["damage"], serde_json::json!([]), "{damage}");
        let verdicts = diagnose(&model, &run);
        assert!(verdicts.is_empty(), "seed {seed}: {verdicts:?}");
    }

    // The same diagnosers do see a fault under this control.
    let faulty = dir.path().join("f2");
    constraint_run(&faulty, "11", &["--fault", "F2@600s"]);
    let verdicts = diagnose(&model, &faulty);
    assert!(
        verdicts.iter().any(|v| v["part"] == "turntable"
            && v["verdict"] == "certain"
            && v["labels"] == serde_json::json!(["F2"])),
        "{verdicts:?}"
    );
}

#[test]
fn bad_arguments_fail_with_one_line() {
    let cylinders = crate::support::repo("datasets/plants/cylinders.toml");
    let cases: [&[&str]; 7] = [
        &["--plant", "cylinders", "--control", "constraints"],
        &["--plant-file", &cylinders],
        // The virtual PLC runs the sorting line: another plant's file is refused.
        &[
            "--serve-modbus",
            "127.0.0.1:0",
            "--realtime",
            "--model",
            "m.json",
            "--plant-file",
            &cylinders,
        ],
        &["--serve-modbus", "127.0.0.1:0", "--model", "m.json"],
        &["--serve-modbus", "127.0.0.1:0", "--realtime"],
        &["--realtime", "--speed", "10"],
        &[
            "--serve-modbus",
            "nowhere",
            "--realtime",
            "--model",
            "m.json",
        ],
    ];
    for args in cases {
        let mut all = vec!["simulate", "--duration", "1s"];
        all.extend_from_slice(args);
        let o = gardefou(&all);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
    }
}

/// A running virtual PLC: its process, address and the rest of its stderr.
struct VirtualPlc {
    child: Child,
    addr: SocketAddr,
    stderr: mpsc::Receiver<String>,
}

fn start_virtual_plc(model: &Path, extra: &[&str]) -> VirtualPlc {
    let mut args = vec![
        "simulate",
        "--serve-modbus",
        "127.0.0.1:0",
        "--realtime",
        "--model",
        path(model),
    ];
    args.extend_from_slice(extra);
    let mut child = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(&args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("runs the binary");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let first = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("the start line");
    let addr = first
        .strip_prefix("virtual PLC: serving Modbus TCP on ")
        .and_then(|rest| rest.split(' ').next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("no address in {first:?}"));
    VirtualPlc {
        child,
        addr,
        stderr: rx,
    }
}

impl VirtualPlc {
    /// Waits for the end; the exit status, the JSON summary and stderr.
    fn finish(mut self) -> (std::process::ExitStatus, Value, String) {
        let mut stdout = String::new();
        self.child
            .stdout
            .take()
            .expect("stdout")
            .read_to_string(&mut stdout)
            .expect("reads stdout");
        let status = self.child.wait().expect("waits");
        let stderr: Vec<String> = self.stderr.iter().collect();
        let summary = serde_json::from_str(stdout.trim())
            .unwrap_or_else(|e| panic!("summary {stdout:?}: {e}; stderr {stderr:?}"));
        (status, summary, stderr.join("\n"))
    }
}

fn image_addresses(name: &str) -> (ModbusTable, u16) {
    let plant = datasets::sorting::plant();
    let id = plant.signals.id(name).expect("a signal");
    plant.modbus_map().signals[id.index()]
}

async fn read_image(ctx: &mut Context) -> (Vec<bool>, Vec<bool>) {
    let inputs = ctx
        .read_discrete_inputs(0, 11)
        .await
        .expect("transport")
        .expect("no exception");
    let coils = ctx
        .read_coils(0, 7)
        .await
        .expect("transport")
        .expect("no exception");
    (inputs, coils)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn virtual_plc_serves_the_running_line_over_modbus() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = learn_constraint_model(dir.path());
    let plant = datasets::sorting::plant();
    let map = plant.modbus_map();
    let c4 = plant
        .partitions
        .iter()
        .position(|p| p.name == "C4")
        .expect("partition C4");
    let def_c4 = 100 + c4 as u16;
    assert_eq!(map.flag(&diagnoser::Flag::def("C4")), Some(def_c4));
    assert_eq!(image_addresses("C4"), (ModbusTable::DiscreteInput, 4));
    assert_eq!(image_addresses("C5"), (ModbusTable::DiscreteInput, 5));
    assert_eq!(image_addresses("A4"), (ModbusTable::Coil, 4));

    let started = Instant::now();
    let plc = start_virtual_plc(&model, &["--speed", "10", "--duration", "2min"]);
    let mut ctx = tokio_modbus::client::tcp::connect(plc.addr)
        .await
        .expect("connects");

    // About 50 simulated seconds, read every 20 ms (0.2 s simulated).
    let mut seen: Vec<(Vec<bool>, Vec<bool>)> = Vec::new();
    for _ in 0..250 {
        let image = read_image(&mut ctx).await;
        assert!(!(image.0[4] && image.0[5]), "C4 and C5 both on: {image:?}");
        if seen.last() != Some(&image) {
            seen.push(image);
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let ever = |table: usize, i: usize, v: bool| {
        seen.iter()
            .any(|s| (if table == 0 { &s.0 } else { &s.1 })[i] == v)
    };
    for (table, i, name) in [(0, 4, "C4"), (0, 5, "C5"), (1, 4, "A4")] {
        assert!(
            ever(table, i, true) && ever(table, i, false),
            "{name} never changed: {seen:?}"
        );
    }
    assert!(seen.len() >= 6, "the line hardly moved: {seen:?}");

    // Flags are written and read back; actuators and holes are read-only;
    // reads past the map are refused.
    ctx.write_single_coil(def_c4, true)
        .await
        .expect("transport")
        .expect("a flag coil is writable");
    let back = ctx.read_coils(def_c4, 1).await.expect("transport");
    assert_eq!(back, Ok(vec![true]));
    let refused = ctx.write_single_coil(4, true).await.expect("transport");
    assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
    let both = ctx
        .write_multiple_coils(def_c4, &[true, true])
        .await
        .expect("transport");
    assert_eq!(both, Ok(()), "def_C4 and def_C5 are neighbours");
    let refused = ctx.write_multiple_coils(6, &[false; 95]).await;
    assert_eq!(
        refused.expect("transport"),
        Err(ExceptionCode::IllegalDataAddress)
    );
    let past = ctx.read_discrete_inputs(0, 12).await.expect("transport");
    assert_eq!(past, Err(ExceptionCode::IllegalDataAddress));
    let other = ctx.read_holding_registers(0, 1).await.expect("transport");
    assert_eq!(other, Err(ExceptionCode::IllegalFunction));

    // Clients sending garbage lose their own connection only.
    let garbage: [&[u8]; 2] = [
        // A zero length field.
        &[0, 1, 0, 0, 0, 0, 1, 1],
        // A complete frame with another protocol's identifier.
        &[0, 1, 0xbe, 0xef, 0, 6, 1, 1, 0, 0, 0, 1],
    ];
    for bytes in garbage {
        let mut raw = TcpStream::connect(plc.addr).expect("connects");
        raw.set_read_timeout(Some(Duration::from_secs(5)))
            .expect("timeout");
        raw.write_all(bytes).expect("writes");
        let mut buf = [0u8; 64];
        let n = raw.read(&mut buf).unwrap_or(0);
        assert_eq!(n, 0, "the server answered garbage: {:?}", &buf[..n]);
    }
    let mut second = tokio_modbus::client::tcp::connect(plc.addr)
        .await
        .expect("a new client connects");
    let (inputs, coils) = read_image(&mut second).await;
    assert_eq!((inputs.len(), coils.len()), (11, 7));
    assert_eq!(
        second.read_coils(def_c4, 2).await.expect("transport"),
        Ok(vec![true, true]),
        "both clients see the same flags"
    );
    read_image(&mut ctx).await;

    let (status, summary, stderr) = plc.finish();
    let wall = started.elapsed();
    assert!(status.success(), "{stderr}");
    // 2 min at speed 10: 12 s of scans, paced (never ahead of time).
    assert!(wall >= Duration::from_secs(12), "{wall:?}");
    assert!(wall < Duration::from_secs(40), "{wall:?}");
    assert_eq!(summary["scans"], 12_001, "{summary}");
    assert!(summary["delivered"].as_u64().unwrap_or(0) > 0, "{summary}");
    assert_eq!(summary["damage"], serde_json::json!([]), "{summary}");
    let flags: Vec<&str> = summary["flags"]
        .as_array()
        .expect("flags")
        .iter()
        .filter_map(|f| f["flag"].as_str())
        .collect();
    assert_eq!(flags, ["def_C4", "def_C5"], "{summary}");
    let first = summary["flags"][0]["t_ms"].as_i64().expect("t_ms");
    assert!((40_000..=120_000).contains(&first), "{summary}");
    assert_eq!(summary["interrupted"], false);
    assert!(stderr.contains("dropped a client"), "{stderr}");
}

#[test]
fn virtual_plc_stops_cleanly_on_sigterm_and_sigint() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = learn_constraint_model(dir.path());
    for signal in ["-TERM", "-INT"] {
        let plc = start_virtual_plc(&model, &["--duration", "1h"]);
        let started = Instant::now();
        std::thread::sleep(Duration::from_millis(500));
        ok(Command::new("kill")
            .args([signal, &plc.child.id().to_string()])
            .output()
            .expect("kill runs"));
        let (status, summary, stderr) = plc.finish();
        assert!(status.success(), "{signal}: {stderr}");
        assert!(started.elapsed() < Duration::from_secs(10));
        assert_eq!(summary["interrupted"], true, "{summary}");
        // Speed 1: about 50 scans of 10 ms in half a second.
        let scans = summary["scans"].as_u64().expect("scans");
        assert!((20..=500).contains(&scans), "{signal}: {summary}");
        assert!(
            stderr.contains("virtual PLC: interrupted after"),
            "{stderr}"
        );
    }
}

#[test]
fn a_malformed_request_ends_its_connection_in_one_line_and_others_are_served() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = learn_constraint_model(dir.path());
    let plc = start_virtual_plc(&model, &["--duration", "1h"]);
    // Write Multiple Coils: 100 coils, a byte count of 2 and 2 bytes.
    let request = [0, 7, 0, 0, 0, 9, 1, 0x0F, 0, 0, 0, 100, 2, 0xFF, 0x03];
    let mut client = TcpStream::connect(plc.addr).expect("connects");
    client
        .set_read_timeout(Some(Duration::from_secs(10)))
        .expect("timeout");
    client.write_all(&request).expect("sends");
    let mut reply = Vec::new();
    let read = client.read_to_end(&mut reply);
    assert!(read.is_ok() && reply.is_empty(), "{read:?} {reply:?}");
    // Another client is served.
    let mut other = TcpStream::connect(plc.addr).expect("connects");
    other
        .set_read_timeout(Some(Duration::from_secs(10)))
        .expect("timeout");
    other
        .write_all(&[0, 8, 0, 0, 0, 6, 1, 0x01, 0, 0, 0, 7])
        .expect("sends");
    let mut answer = [0u8; 10];
    other
        .read_exact(&mut answer)
        .expect("a reply to Read Coils");
    assert_eq!(&answer[..2], &[0, 8]);
    ok(Command::new("kill")
        .args(["-TERM", &plc.child.id().to_string()])
        .output()
        .expect("kill runs"));
    let (status, _, stderr) = plc.finish();
    assert!(status.success(), "{stderr}");
    let dropped: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("malformed request"))
        .collect();
    assert_eq!(dropped.len(), 1, "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// A probing move asked over Modbus (`monitor --probe` writes the same
/// coils): the virtual PLC's filter takes it where no safety constraint
/// forbids it, and keeps the control's order and sets `_PROBE_REFUSED` where
/// one does. At the start the turntable waits at loading, away from
/// unloading, so CSs5 (`!C5 & A3`) forbids the right evacuation rollers A3;
/// no safety constraint reads the right evacuation conveyor A6.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_virtual_plc_takes_a_probing_move_only_where_its_filter_allows_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = learn_constraint_model(dir.path());
    let plant = datasets::sorting::plant();
    let map = plant.modbus_map();
    let coils = |name: &str| {
        let id = plant.signals.id(name).expect("an actuator");
        let p = map.probe(id).expect("probe coils");
        (map.signals[id.index()].1, p.probe, p.value, p.refused)
    };
    let (a3, a3_probe, a3_value, a3_refused) = coils("A3");
    let (a6, a6_probe, a6_value, a6_refused) = coils("A6");
    // The default map: three coils per actuator from 200, in file order.
    assert_eq!((a3_probe, a3_value, a3_refused), (209, 210, 211));
    assert_eq!((a6_probe, a6_value, a6_refused), (218, 219, 220));

    let plc = start_virtual_plc(&model, &["--duration", "1h"]);
    let mut ctx = tokio_modbus::client::tcp::connect(plc.addr)
        .await
        .expect("connects");
    let (_, before) = read_image(&mut ctx).await;
    let a6_asked = !before[usize::from(a6)];
    // A6 first: the scan that refuses A3 has then read A6's request too.
    write(&mut ctx, a6_value, a6_asked).await;
    write(&mut ctx, a6_probe, true).await;
    write(&mut ctx, a3_value, true).await;
    write(&mut ctx, a3_probe, true).await;
    // Every coil up to A6_PROBE_REFUSED in one read: one image of the PLC.
    let n = a6_refused + 1;
    // The scans that take the requests come within a few scan periods.
    let waited = Instant::now();
    let mut image = coils_up_to(&mut ctx, n).await;
    while !image[usize::from(a3_refused)] && waited.elapsed() < Duration::from_secs(10) {
        tokio::time::sleep(Duration::from_millis(20)).await;
        image = coils_up_to(&mut ctx, n).await;
    }
    let (inputs, _) = read_image(&mut ctx).await;
    assert!(!inputs[5], "the turntable reached unloading: C5 is on");
    assert!(image[usize::from(a3_refused)], "A3 = 1 not refused");
    assert!(!image[usize::from(a3)], "A3 went to 1 against CSs5");
    assert_eq!(image[usize::from(a6)], a6_asked, "A6's move not taken");
    assert!(!image[usize::from(a6_refused)], "A6's move refused");

    // The PLC alone writes the refusals.
    let refused = ctx
        .write_single_coil(a3_refused, false)
        .await
        .expect("transport");
    assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
    // Released: the refusal goes down with the request.
    write(&mut ctx, a3_probe, false).await;
    write(&mut ctx, a6_probe, false).await;
    let waited = Instant::now();
    let mut image = coils_up_to(&mut ctx, n).await;
    while image[usize::from(a3_refused)] && waited.elapsed() < Duration::from_secs(10) {
        tokio::time::sleep(Duration::from_millis(20)).await;
        image = coils_up_to(&mut ctx, n).await;
    }
    assert!(
        !image[usize::from(a3_refused)],
        "A3_PROBE_REFUSED stayed up"
    );
    assert!(!image[usize::from(a3)]);

    ok(Command::new("kill")
        .args(["-TERM", &plc.child.id().to_string()])
        .output()
        .expect("kill runs"));
    let (status, summary, stderr) = plc.finish();
    assert!(status.success(), "{stderr}");
    assert_eq!(summary["probe_writes"], 6, "{summary}");
    assert_eq!(summary["probe_requests"], 2, "{summary}");
    assert!(
        summary["probe_refused_scans"].as_u64().unwrap_or(0) > 0,
        "{summary}"
    );
    assert_eq!(summary["damage"], serde_json::json!([]), "{summary}");
    assert!(stderr.contains("2 probing move(s) requested"), "{stderr}");
}

async fn write(ctx: &mut Context, coil: u16, value: bool) {
    ctx.write_single_coil(coil, value)
        .await
        .expect("transport")
        .expect("a probe coil is writable");
}

/// Coils `0..n`, in one read.
async fn coils_up_to(ctx: &mut Context, n: u16) -> Vec<bool> {
    ctx.read_coils(0, n)
        .await
        .expect("transport")
        .expect("no exception")
}
