//! Support code shared by the integration tests: the binary and the shipped
//! data, a proxy that puts network faults between a Modbus TCP client and
//! server (`netfault`), and a feeder that writes lines to a child's stdin at a
//! chosen pace (`feeder`).

// Each test module uses only part of this module.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};
use std::sync::OnceLock;

pub mod feeder;
pub mod netfault;

/// Runs the `gardefou` binary with `args`.
pub fn gardefou(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(args)
        .output()
        .expect("runs the binary")
}

/// A file of the repository, as text.
pub fn repo(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

/// A file of the shipped logs (`datasets/data/<rel>`), as text.
pub fn data(rel: &str) -> String {
    repo(&format!("datasets/data/{rel}"))
}

/// The sorting line's plant file, as shipped beside its logs.
pub fn plant() -> String {
    data("sorting/normal/plant.toml")
}

/// The model `gardefou learn` gives on the shipped normal run, learned once
/// for all the tests of the binary.
pub fn learned_model() -> &'static str {
    static MODEL: OnceLock<(tempfile::TempDir, String)> = OnceLock::new();
    &MODEL
        .get_or_init(|| {
            let dir = tempfile::tempdir().expect("temp dir");
            let path = dir.path().join("model.json").display().to_string();
            let o = gardefou(&[
                "learn",
                "--plant",
                &plant(),
                "-q",
                "-o",
                &path,
                &data("sorting/normal/events.csv"),
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            (dir, path)
        })
        .1
}

/// A free TCP port on loopback, for a server a test starts.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// `GET route` on loopback `port`, on a fresh connection: the whole response.
pub fn http_get(port: u16, route: &str) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).expect("HTTP connects");
    write!(
        s,
        "GET {route} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .expect("request");
    let mut response = String::new();
    s.read_to_string(&mut response).expect("response");
    response
}

/// Waits (at most 10 s) until `what` listens on loopback `port`.
pub fn wait_for_port(port: u16, what: &str) {
    let end = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            std::time::Instant::now() < end,
            "{what} did not listen on {port}"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// A peer the test needs is missing: a failure when `scripts/test` asked
/// for every peer (`GARDEFOU_REQUIRE_PEERS=1`, as in CI), else a message
/// and the test is skipped.
pub fn peer_missing(test: &str, why: &str) {
    let required = std::env::var("GARDEFOU_REQUIRE_PEERS").is_ok_and(|v| v == "1");
    assert!(!required, "GARDEFOU_REQUIRE_PEERS=1 but {test} {why}");
    eprintln!("skipped: {test} {why}");
}

/// A tiny deterministic generator (SplitMix64): a fault plan or a pace drawn
/// from a seed is the same on every run, so a failing run can be replayed,
/// and no crate is needed for it.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0.0..1.0`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// True with probability `p` (never for 0.0, always for 1.0).
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// Uniform in `lo..=hi`.
    pub fn between(
        &mut self,
        lo: std::time::Duration,
        hi: std::time::Duration,
    ) -> std::time::Duration {
        lo + hi.saturating_sub(lo).mul_f64(self.unit())
    }
}

/// Asserts a bad-input exit (code 2) in one of the two forms errors take:
/// one line `gardefou: …` (a file's or a value's error), or clap's whole
/// message for a command line it rejects (`error: …`, the arguments it
/// concerns, the usage where it helps, a hint), ending with a newline.
/// `needle` is in the message, before the usage.
pub fn assert_bad_input(o: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "stderr: {stderr}");
    assert!(stderr.ends_with('\n'), "no final newline: {stderr:?}");
    let message = if stderr.starts_with("error: ") {
        let hint = "\nFor more information, try '--help'.\n";
        assert!(
            stderr.ends_with(hint),
            "clap's message without its hint: {stderr}"
        );
        stderr
            .split("\nUsage: ")
            .next()
            .unwrap_or_default()
            .to_string()
    } else {
        assert!(stderr.starts_with("gardefou: "), "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "one line expected: {stderr}");
        stderr.to_string()
    };
    assert!(message.contains(needle), "'{needle}' not in: {stderr}");
}
