//! The bodies of gardefou's fuzz targets: one function per reader, each taking
//! the fuzzer's bytes the way a user's file or stream reaches that reader.
//!
//! A reader may refuse its input (that is an error message, and fine); it must
//! never panic, hang or break its own promises. Where a reader promises
//! something checkable, the target checks it and panics if it does not hold:
//! a log's events come sorted, a parsed expression reads back the same.
//!
//! The targets in `fuzz_targets/` are one line each around these functions.
//! `scripts/fuzz` builds them with libFuzzer's coverage instrumentation on the
//! stable toolchain and runs them on the corpora in `corpus/`.

#[cfg(feature = "runtime")]
use std::io::{Read as _, Write as _};
#[cfg(feature = "runtime")]
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
#[cfg(feature = "runtime")]
use std::time::Duration;

use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser};
use diagnoser::faudes::product::{self, parallel};
use diagnoser::faudes::{
    EventDiagnosability, FailureTypes, Generator, event_diagnosability_within, parse_failure_types,
    parse_generator,
};
use diagnoser::model::Model;
use diagnoser::{Event, Plant, SECOND, SignalId};
use logs::{IngestOptions, LogFormat};
#[cfg(feature = "runtime")]
use runtime::monitor::stdin::{MAX_LINE, Order, parse_record};

/// The plant the log targets read for: the turntable of `logs`'s fixtures,
/// with a CAN mapping for `candump -L` logs.
const LOG_PLANT: &str = r#"
name = "turntable"
time_unit = "ms"

[signals]
C4 = { kind = "sensor", description = "turntable at loading position" }
C5 = { kind = "sensor", description = "turntable at unloading position" }
A4 = { kind = "actuator", description = "rotate turntable to unloading position" }

[can]
C4 = { cob_id = 0x181, bit = 0 }
C5 = { cob_id = 0x181, bit = 1 }
A4 = { cob_id = 0x201, bit = 8 }
"#;

/// The plant the model target's models were learned for (the shipped one).
const MODEL_PLANT: &str = include_str!("../../datasets/data/sorting/normal/plant.toml");

fn log_plant() -> &'static Plant {
    static PLANT: OnceLock<Plant> = OnceLock::new();
    PLANT.get_or_init(|| {
        Plant::parse(LOG_PLANT, Path::new("plant.toml")).expect("the log plant parses")
    })
}

fn model_plant() -> &'static Plant {
    static PLANT: OnceLock<Plant> = OnceLock::new();
    PLANT.get_or_init(|| {
        Plant::parse(MODEL_PLANT, Path::new("plant.toml")).expect("the model plant parses")
    })
}

/// A new file for every input, in a folder of this process's own: logs are
/// read from files, as users give them. Never one file rewritten: a reader
/// thread of the last input may still be reading its file, and must meet the
/// bytes it was given, not the next input's.
fn log_file() -> PathBuf {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    static COUNT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let dir = DIR.get_or_init(|| tempfile::tempdir().expect("a temporary directory"));
    let n = COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    dir.path().join(format!("log{n}"))
}

/// A log in `format` (detected when `None`), opened and read to its end as
/// `diagnose` reads it. Its initial values cover every signal, and its events
/// come in `(t, signal)` order from batch to batch.
pub fn log(data: &[u8], format: Option<LogFormat>) {
    contained_panics_are_not_crashes();
    let path = log_file();
    std::fs::write(&path, data).expect("write the log file");
    read_log(&path, format);
    std::fs::remove_file(&path).expect("remove the log file");
}

fn read_log(path: &Path, format: Option<LogFormat>) {
    let plant = log_plant();
    let options = IngestOptions {
        format,
        // Small batches, so that batch boundaries are crossed.
        batch_rows: 16,
        ..IngestOptions::default()
    };
    let Ok(log) = logs::open(path, plant, &options) else {
        return;
    };
    assert_eq!(
        log.initial.len(),
        plant.signals.len(),
        "an initial value per signal"
    );
    let mut last: Option<(i64, u32)> = None;
    for batch in log.batches {
        let Ok(batch) = batch else { return };
        for Event { t, signal, .. } in batch {
            assert!(
                (signal.0 as usize) < plant.signals.len(),
                "an event of a known signal"
            );
            let key = (t, signal.0);
            assert!(
                last.is_none_or(|l| l < key),
                "events sorted by (t, signal): {last:?} then {key:?}"
            );
            last = Some(key);
        }
    }
}

/// Panics gardefou expects from a dependency (polars on a damaged Parquet
/// file: [`vocabulary::panics::expected`]) are caught and reported as the
/// input's error, and they are not crashes. libFuzzer's hook aborts on every
/// panic: it is kept for the others.
fn contained_panics_are_not_crashes() {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let crash = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !vocabulary::panics::expected() {
                crash(info);
            }
        }));
    });
}

/// A `plant.toml`, parsed; a plant that parses gives its derived tables.
pub fn plant_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(plant) = Plant::parse(text, Path::new("plant.toml")) else {
        return;
    };
    let _ = plant.modbus_map();
    let _ = plant.learning_digest();
}

/// A `model.json`, parsed and validated; a model that fits the plant drives
/// its diagnosers through a short run.
pub fn model_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(model) = Model::parse(text, Path::new("model.json")) else {
        return;
    };
    let plant = model_plant();
    if model.fits(plant).is_err() {
        return;
    }
    let Ok(mut diagnoser) = PlantDiagnoser::new(plant, &model, &DiagnoserOptions::default()) else {
        return;
    };
    let n = plant.signals.len();
    diagnoser.start(0, &vec![false; n]);
    let mut verdicts = 0usize;
    let mut out = |_| verdicts += 1;
    // Every signal rises, one a second, then falls: edges the model may or may not know.
    for (i, value) in (0..2 * n).map(|i| (i % n, i < n)) {
        let t = (i as i64 + 1) * SECOND + if value { 0 } else { 60 * SECOND };
        diagnoser.push(
            Event {
                t,
                signal: SignalId(i as u32),
                value,
            },
            &mut out,
        );
    }
    diagnoser.finish(200 * SECOND, &mut out);
}

/// A libFAUDES `.gen` generator, parsed; one that parses is checked for
/// event-diagnosability of its unobservable events, within a small budget.
pub fn generator(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(g) = parse_generator(text, Path::new("plant.gen")) else {
        return;
    };
    let _ = event_diagnosability_within(&g, &each_unobservable_event(&g), 20_000);
}

/// A failure type per unobservable event of `g`.
fn each_unobservable_event(g: &Generator) -> FailureTypes {
    let unobservable = g.events.iter().zip(&g.observable).filter(|(_, o)| !**o);
    FailureTypes {
        types: unobservable
            .map(|(e, _)| (e.clone(), vec![e.clone()]))
            .collect(),
    }
}

/// A plant as two or three libFAUDES generators separated by NUL bytes: the
/// verdicts of its components, checked as a plant, must be those of their
/// product checked as one generator.
pub fn generator_product(data: &[u8]) {
    const BUDGET: usize = 20_000;
    let components: Vec<Generator> = (data.split(|&b| b == 0).take(3))
        .filter_map(|part| {
            parse_generator(std::str::from_utf8(part).ok()?, Path::new("c.gen")).ok()
        })
        .collect();
    if components.len() < 2 {
        return;
    }
    let refs: Vec<&Generator> = components.iter().collect();
    let Ok(whole) = parallel(&refs, BUDGET) else {
        return;
    };
    let failures = each_unobservable_event(&whole.generator);
    let Ok(ours) = product::event_diagnosability(&components, &failures, BUDGET) else {
        return;
    };
    let Ok(theirs) = event_diagnosability_within(&whole.generator, &failures, BUDGET) else {
        return;
    };
    let verdicts = |r: &EventDiagnosability| {
        let kinds = (r.assumptions.iter())
            .map(|v| std::mem::discriminant(v))
            .collect::<Vec<_>>();
        let types = r.types.iter().map(|t| t.diagnosable).collect::<Vec<_>>();
        (r.diagnosable, kinds, types)
    };
    assert_eq!(
        verdicts(&ours),
        verdicts(&theirs),
        "components and product disagree"
    );
}

/// A libFAUDES failure map (`FailureTypes`), parsed.
pub fn failure_map(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = parse_failure_types(text, Path::new("failures.txt"));
}

#[cfg(feature = "runtime")]
/// JSON lines as `monitor --stdin` reads them: each line parsed, then put in
/// event-time order. Lines longer than the reader takes are skipped, as it
/// skips them.
pub fn stdin_lines(data: &[u8]) {
    let plant = log_plant();
    let mut order = Order::new(
        plant,
        diagnoser::TimeUnit::Ms,
        50 * vocabulary::MS,
        10 * SECOND,
    );
    let mut out = Vec::new();
    for (n, line) in data.split(|&b| b == b'\n').enumerate() {
        let Ok(line) = std::str::from_utf8(line) else {
            continue;
        };
        if line.len() > MAX_LINE || line.trim().is_empty() {
            continue;
        }
        if let Ok(record) = parse_record(line, plant, diagnoser::TimeUnit::Ms) {
            order.push(record, n as u64 + 1, None, &mut out);
        }
    }
    order.end(&mut out);
}

/// A Boolean expression of the constraint syntax, parsed; one that parses
/// reads back the same from its written form.
pub fn expression(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(expr) = vocabulary::expr::Expr::parse(text) else {
        return;
    };
    let written = expr.to_string();
    let again = vocabulary::expr::Expr::parse(&written)
        .unwrap_or_else(|e| panic!("'{written}', written from '{text}', does not parse: {e}"));
    assert_eq!(
        again, expr,
        "'{text}' written as '{written}' reads back differently"
    );
}

#[cfg(feature = "runtime")]
/// The virtual PLC's Modbus TCP server, serving a process image of the log
/// plant's map on loopback for the whole run.
fn modbus_server() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .expect("a tokio runtime");
            rt.block_on(async {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                    .await
                    .expect("bind");
                tx.send(listener.local_addr().expect("address"))
                    .expect("send the address");
                runtime::virtual_plc::serve_image(listener, &log_plant().modbus_map()).await;
            });
        });
        rx.recv().expect("the server's address")
    })
}

#[cfg(feature = "runtime")]
/// Bytes sent by one Modbus TCP client, which then closes its side: the
/// server answers what it can and closes the connection, within a few seconds.
pub fn modbus_requests(data: &[u8]) {
    let mut client = TcpStream::connect(modbus_server()).expect("connect to the virtual PLC");
    client
        .set_read_timeout(Some(Duration::from_secs(5)))
        .expect("timeout");
    // The server may close early (a malformed request); later writes then fail.
    let _ = client.write_all(data);
    let _ = client.shutdown(std::net::Shutdown::Write);
    let mut answers = Vec::new();
    match client.read_to_end(&mut answers) {
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {}
        Err(e) => panic!("the virtual PLC did not close the connection: {e}"),
    }
}
