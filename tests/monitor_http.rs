//! `gardefou monitor --http`: a flood of idle connections must neither take
//! the file descriptors the PLC link needs nor lock out a fresh client.
//!
//! The limits are `runtime/src/monitor/http.rs`'s: at most `MAX_CONNECTIONS` (256)
//! connections, or a quarter of the soft `RLIMIT_NOFILE` if that is fewer,
//! the oldest closed to make room for a newcomer; a connection is closed
//! after `HEADER_READ_TIMEOUT` (5 s) without a whole request head, and after
//! `IDLE_TIMEOUT` (10 s) without a byte read or written.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tokio::runtime::Runtime;

/// `MAX_CONNECTIONS` in `runtime/src/monitor/http.rs`.
const MAX_CONNECTIONS: usize = 256;
/// `HEADER_READ_TIMEOUT` in `runtime/src/monitor/http.rs`.
const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(5);
/// `IDLE_TIMEOUT` in `runtime/src/monitor/http.rs`.
const IDLE_TIMEOUT: Duration = Duration::from_secs(10);
/// The monitor's descriptor limit (soft and hard) in this test: without a
/// cap, the flood would take all of them.
const MONITOR_NOFILE: u64 = 1024;
/// Idle connections opened by the flood, if the test's own limit allows.
const FLOOD: usize = 20_000;

/// The tests here run one at a time: each floods with nearly as many
/// connections as this process may open.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn path(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// Raises this process's soft descriptor limit to its hard limit; returns it.
fn raise_own_nofile() -> u64 {
    let mut l = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read or write the struct given.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut l), 0);
        l.rlim_cur = l.rlim_max;
        assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &l), 0);
    }
    l.rlim_cur
}

/// `gardefou monitor --stdin --http`, with `MONITOR_NOFILE` descriptors.
fn monitor(http: SocketAddr) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args(["monitor", "--plant", &path("datasets/plants/sorting.toml")])
        .args([
            "--model",
            &path("diagnoser/tests/fixtures/diagnosis/sorting-model.json"),
        ])
        .args(["--stdin", "--http", &http.to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    with_descriptors(&mut cmd);
    cmd.spawn().expect("starts")
}

/// Lets `cmd` open at most `MONITOR_NOFILE` descriptors.
fn with_descriptors(cmd: &mut Command) {
    // SAFETY: setrlimit is async-signal-safe and touches no memory of ours
    // but the struct.
    unsafe {
        cmd.pre_exec(|| {
            let l = libc::rlimit {
                rlim_cur: MONITOR_NOFILE,
                rlim_max: MONITOR_NOFILE,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &l) == 0 {
                Ok(())
            } else {
                Err(std::io::Error::last_os_error())
            }
        });
    }
}

/// The sorting line's initial values, as JSON lines at t = 0, then an order.
fn initial_values() -> String {
    let values = [
        ("C0", 0),
        ("C1", 0),
        ("C2", 0),
        ("C3", 0),
        ("C4", 1),
        ("C5", 0),
        ("C6", 0),
        ("C7", 0),
        ("C8", 0),
        ("C9", 0),
        ("C10", 0),
        ("A0", 1),
        ("A1", 1),
        ("A2", 0),
        ("A3", 0),
        ("A4", 0),
        ("A5", 1),
        ("A6", 1),
    ];
    let line = |(s, v): (&str, u8)| format!("{{\"t\": 0, \"signal\": \"{s}\", \"value\": {v}}}\n");
    let mut lines: String = values.into_iter().map(line).collect();
    // A later time completes the initial values: the monitor starts.
    lines.push_str("{\"t\": 100, \"signal\": \"A4\", \"value\": 1}\n");
    lines
}

fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// `GET /status` on a fresh connection: the status line and the body, or
/// why not, within `within`.
fn get_status(http: SocketAddr, within: Duration) -> Result<(String, String), String> {
    let mut s = TcpStream::connect_timeout(&http, within).map_err(|e| format!("connect: {e}"))?;
    s.set_read_timeout(Some(within))
        .map_err(|e| e.to_string())?;
    write!(
        s,
        "GET /status HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .map_err(|e| format!("request: {e}"))?;
    let mut text = String::new();
    s.read_to_string(&mut text)
        .map_err(|e| format!("response: {e} after {text:?}"))?;
    let (head, body) = text.split_once("\r\n\r\n").ok_or(format!("{text:?}"))?;
    let status = head.lines().next().unwrap_or_default().to_string();
    Ok((status, body.to_string()))
}

/// Waits for the monitor's first answer to `/status`.
fn wait_until_serving(http: SocketAddr) {
    let end = Instant::now() + Duration::from_secs(20);
    while get_status(http, Duration::from_secs(1)).is_err() {
        assert!(Instant::now() < end, "the monitor never answered /status");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The flood's `i`th source address: 100 connections from each of
/// 127.0.1.1, 127.0.1.2, …, since past some 14,000 connections from one
/// address to one port, the kernel's search for a free source port makes
/// every `connect` slow.
fn flood_source(i: usize) -> Ipv4Addr {
    let n = i / 100;
    Ipv4Addr::new(127, 0, 1 + (n / 250) as u8, 1 + (n % 250) as u8)
}

/// A connection from `source` (any port) to `to`, within 5 s.
fn connect_from(rt: &Runtime, source: Ipv4Addr, to: SocketAddr) -> std::io::Result<TcpStream> {
    rt.block_on(async {
        let socket = tokio::net::TcpSocket::new_v4()?;
        socket.bind(SocketAddr::new(source.into(), 0))?;
        let connected = tokio::time::timeout(Duration::from_secs(5), socket.connect(to)).await;
        connected
            .map_err(|_| std::io::ErrorKind::TimedOut)??
            .into_std()
    })
}

/// The connections waiting in the listener on `port`'s accept queue (from
/// `/proc/net/tcp`: a listening socket's `rx_queue`). Listening sockets come
/// first there, so the rest of the table is not read.
fn accept_queue(port: u16) -> Option<usize> {
    let table = BufReader::new(std::fs::File::open("/proc/net/tcp").ok()?);
    let local = format!(":{port:04X}");
    table.lines().skip(1).map_while(Result::ok).find_map(|row| {
        let f: Vec<&str> = row.split_whitespace().collect();
        let listening = f.get(3) == Some(&"0A") && f.get(1)?.ends_with(&local);
        let rx = f.get(4)?.split_once(':')?.1;
        listening.then(|| usize::from_str_radix(rx, 16).ok())?
    })
}

/// Paces the flood by the monitor's accepts: past the listener's queue, a
/// SYN is dropped and its `connect` waits a second to send it again.
fn wait_for_accepts(port: u16, pid: u32) {
    let end = Instant::now() + Duration::from_secs(5);
    while let Some(queued) = accept_queue(port).filter(|&q| q >= 100) {
        assert!(
            Instant::now() < end,
            "the monitor stopped accepting connections: {queued} waiting, and it holds {} \
             descriptors",
            open_fds(pid)
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// How long until the server closes a connection that sends nothing (`None`
/// if not within `within`).
fn closed_after(mut s: TcpStream, opened: Instant, within: Duration) -> Option<Duration> {
    s.set_read_timeout(Some(within)).expect("read timeout");
    let mut buf = [0u8; 64];
    match s.read(&mut buf) {
        Ok(0) => Some(opened.elapsed()),
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => Some(opened.elapsed()),
        _ => None,
    }
}

/// 20,000 idle connections (fewer if this process may not open that many)
/// against a monitor allowed 1024 descriptors: the monitor keeps at most its
/// cap of them open and never runs out, a fresh client's `GET /status` is
/// answered at once, a connection that sends nothing is closed by the server
/// (its header timeout), and SIGTERM still ends the monitor cleanly.
#[test]
fn idle_connections_neither_exhaust_descriptors_nor_lock_out_clients() {
    let _serial = serial();
    let own_limit = raise_own_nofile();
    let flood = FLOOD.min(own_limit.saturating_sub(100) as usize);
    let flood_note = if flood < FLOOD {
        format!(
            "{flood} idle connections, not {FLOOD}: this process's hard RLIMIT_NOFILE is \
             {own_limit}, below 21,000, so the flood is that minus 100"
        )
    } else {
        format!("{flood} idle connections")
    };
    let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().expect("addr");
    let mut child = monitor(http);
    let pid = child.id();
    let mut stdin = child.stdin.take().expect("stdin");
    stdin
        .write_all(initial_values().as_bytes())
        .expect("writes");
    stdin.flush().expect("flushes");
    let mut stderr = child.stderr.take().expect("stderr");
    let errors = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    wait_until_serving(http);
    let baseline = open_fds(pid);
    let cap = MAX_CONNECTIONS.min(MONITOR_NOFILE as usize / 4);
    let bound = cap + 64;

    // The flood: connections that never send a byte, all kept open here.
    let started = Instant::now();
    let mut idle = Vec::with_capacity(flood);
    let mut most_fds = baseline;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    for i in 0..flood {
        let s = connect_from(&rt, flood_source(i), http).unwrap_or_else(|e| {
            let fds = open_fds(pid);
            panic!("connection {i} of {flood_note}: {e} (the monitor holds {fds} descriptors)")
        });
        idle.push(s);
        if i % 200 == 199 {
            most_fds = most_fds.max(open_fds(pid));
            wait_for_accepts(http.port(), pid);
        }
    }
    let flooded_in = started.elapsed();
    most_fds = most_fds.max(open_fds(pid));
    eprintln!(
        "{flood_note} opened in {flooded_in:?}; monitor's descriptors: {baseline} before, at most {most_fds} during"
    );

    // A silent connection, opened after the flood so that no newcomer
    // evicts it: the server's timeouts must close it.
    let silent = TcpStream::connect(http).expect("connects");
    let silent_opened = Instant::now();

    // A fresh client while the flood's connections are still open here.
    let asked = Instant::now();
    let answer = get_status(http, Duration::from_secs(5));
    let answered_in = asked.elapsed();
    let fds_then = open_fds(pid);
    eprintln!("/status answered in {answered_in:?}; monitor's descriptors then: {fds_then}");
    let (status, body) =
        answer.unwrap_or_else(|e| panic!("/status after {flood_note}: {e} ({answered_in:?})"));
    assert!(status.contains(" 200 "), "{status}");
    let json: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    let parts = json["parts"].as_array().expect("parts");
    assert_eq!(parts.len(), 6, "{body}");
    assert!(
        answered_in < Duration::from_secs(3),
        "/status after {flood_note} took {answered_in:?}"
    );
    assert!(
        most_fds.max(fds_then) < bound,
        "the monitor held {} descriptors during {flood_note} (cap {cap}, bound {bound})",
        most_fds.max(fds_then)
    );

    let closed = closed_after(silent, silent_opened, IDLE_TIMEOUT + Duration::from_secs(2));
    let closed = closed.unwrap_or_else(|| {
        panic!(
            "a silent connection still open {:?} after",
            IDLE_TIMEOUT + Duration::from_secs(2)
        )
    });
    eprintln!("a silent connection closed by the server after {closed:?}");
    // It never sends a request head, so the header timeout, the shorter one,
    // closes it.
    assert!(
        closed >= HEADER_READ_TIMEOUT - Duration::from_millis(500)
            && closed <= HEADER_READ_TIMEOUT + Duration::from_secs(2),
        "a silent connection closed after {closed:?}"
    );
    // The flood's last connections, silent too, are gone by now.
    let fds_after = open_fds(pid);
    assert!(
        fds_after <= baseline + 2,
        "{fds_after} descriptors, {baseline} before"
    );

    drop(idle);
    let killed = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .expect("kill runs");
    assert!(killed.success());
    let signalled = Instant::now();
    let code = loop {
        if let Some(s) = child.try_wait().expect("waits") {
            break s;
        }
        if signalled.elapsed() > Duration::from_secs(1) {
            let _ = child.kill();
            panic!("the monitor still runs 1 s after SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    drop(stdin);
    let err = errors.join().expect("stderr");
    assert!(code.success(), "{code:?}: {err}");
    assert!(err.contains("monitor terminated"), "{err}");
    assert!(!err.contains("cannot accept"), "{err}");
}

/// A minimal Modbus TCP server: every read answers zeros, every coil write is
/// echoed and counted. Serves connections until `stop` is set.
struct TinyPlc {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    connections: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    writes: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

impl TinyPlc {
    fn start(port: u16) -> TinyPlc {
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
        let listener = TcpListener::bind(("127.0.0.1", port)).expect("binds");
        listener.set_nonblocking(true).expect("nonblocking");
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let connections = std::sync::Arc::new(AtomicUsize::new(0));
        let writes = std::sync::Arc::new(AtomicUsize::new(0));
        let (s, c, w) = (stop.clone(), connections.clone(), writes.clone());
        std::thread::spawn(move || {
            while !s.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((conn, _)) => {
                        c.fetch_add(1, Ordering::Relaxed);
                        let (s, w) = (s.clone(), w.clone());
                        std::thread::spawn(move || serve_modbus(conn, &s, &w));
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(5)),
                }
            }
        });
        TinyPlc {
            stop,
            connections,
            writes,
        }
    }

    fn count(&self) -> (usize, usize) {
        use std::sync::atomic::Ordering;
        (
            self.connections.load(Ordering::Relaxed),
            self.writes.load(Ordering::Relaxed),
        )
    }
}

impl Drop for TinyPlc {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        // Let the accept loop and the connections see it.
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn serve_modbus(
    mut conn: TcpStream,
    stop: &std::sync::atomic::AtomicBool,
    writes: &std::sync::atomic::AtomicUsize,
) {
    let _ = conn.set_read_timeout(Some(Duration::from_millis(50)));
    let mut header = [0u8; 7];
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        match conn.read_exact(&mut header) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => continue,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(_) => return,
        }
        let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
        let mut pdu = vec![0u8; len.saturating_sub(1)];
        let _ = conn.set_read_timeout(None);
        if conn.read_exact(&mut pdu).is_err() {
            return;
        }
        let _ = conn.set_read_timeout(Some(Duration::from_millis(50)));
        let reply: Vec<u8> = match pdu.first() {
            Some(&code @ (1 | 2)) => {
                let count = usize::from(u16::from_be_bytes([pdu[3], pdu[4]]));
                let bytes = count.div_ceil(8);
                let mut r = vec![code, bytes as u8];
                r.resize(2 + bytes, 0);
                r
            }
            Some(5) => {
                writes.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                pdu.clone()
            }
            _ => vec![pdu.first().copied().unwrap_or(0) | 0x80, 1],
        };
        let mut frame = header[..4].to_vec();
        frame.extend_from_slice(&((reply.len() + 1) as u16).to_be_bytes());
        frame.push(header[6]);
        frame.extend_from_slice(&reply);
        if conn.write_all(&frame).is_err() {
            return;
        }
    }
}

/// The same flood of idle HTTP connections while the PLC restarts: the
/// monitor, allowed 1024 descriptors, still reconnects to it and writes its
/// flag coils again.
#[test]
fn idle_connections_do_not_keep_the_plc_from_being_reconnected() {
    let _serial = serial();
    let own_limit = raise_own_nofile();
    let flood = FLOOD.min(own_limit.saturating_sub(100) as usize);
    let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().expect("addr");
    let plc_port = free_port();
    let plc = TinyPlc::start(plc_port);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args(["monitor", "--plant", &path("datasets/plants/sorting.toml")])
        .args([
            "--model",
            &path("diagnoser/tests/fixtures/diagnosis/sorting-model.json"),
        ])
        .args(["--modbus", &format!("127.0.0.1:{plc_port}")])
        .args(["--http", &http.to_string(), "--duration", "60s"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    with_descriptors(&mut cmd);
    let mut child = cmd.spawn().expect("starts");
    let pid = child.id();
    wait_until_serving(http);
    let end = Instant::now() + Duration::from_secs(10);
    while plc.count().1 == 0 {
        assert!(
            Instant::now() < end,
            "the monitor never wrote its flag coils"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // The PLC goes away, the flood comes, the PLC comes back.
    drop(plc);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let mut idle = Vec::with_capacity(flood);
    for i in 0..flood {
        let s = connect_from(&rt, flood_source(i), http)
            .unwrap_or_else(|e| panic!("connection {i} of {flood}: {e}"));
        idle.push(s);
        if i % 200 == 199 {
            wait_for_accepts(http.port(), pid);
        }
    }
    let back = TinyPlc::start(plc_port);
    let end = Instant::now() + Duration::from_secs(15);
    while back.count().1 == 0 {
        assert!(
            Instant::now() < end,
            "after {flood} idle connections the monitor never reconnected to the PLC \
             ({} descriptors)",
            open_fds(pid)
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let (connections, writes) = back.count();
    eprintln!(
        "{flood} idle connections; the restarted PLC got {connections} connection(s) and {writes} flag write(s); the monitor held {} descriptors",
        open_fds(pid)
    );
    drop(idle);
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let mut stderr = child.stderr.take().expect("stderr");
    let status = child.wait().expect("exits");
    let mut err = String::new();
    let _ = stderr.read_to_string(&mut err);
    assert!(status.success(), "{err}");
    assert!(err.contains("reconnected"), "{err}");
    assert!(!err.contains("Too many open files"), "{err}");
}
