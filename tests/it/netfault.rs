//! The network-fault harness itself (tests/support): the proxy's delays,
//! reordering, drops, stalls, resets and garbage, measured from a client that
//! pipelines requests to a small Modbus-like server; and the stdin feeder.

use crate::support;

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread;
use std::time::{Duration, Instant};
use support::feeder::{Pace, feed, json_lines};
use support::netfault::{Faults, Proxy, Stats};

const MS: Duration = Duration::from_millis(1);
const N: u16 = 2000;

/// The proxy tests run one at a time: each measures delays in real time,
/// which another test's 2,000 replies/s on a two-core machine would blur.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// A Modbus-like server: reads 12-byte requests (MBAP + function 3) and
/// answers each with a 10-byte ADU echoing the transaction id.
fn echo_server() -> SocketAddr {
    serve(|mut s| {
        let mut req = [0u8; 12];
        while s.read_exact(&mut req).is_ok() {
            assert_eq!(&req[2..6], &[0, 0, 0, 6], "request MBAP");
            let reply = [req[0], req[1], 0, 0, 0, 4, req[6], 3, 1, 0x2A];
            if s.write_all(&reply).is_err() {
                return;
            }
        }
    })
}

/// A server running `handle` on every connection, each on its own thread.
fn serve(handle: fn(TcpStream)) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    thread::spawn(move || {
        for s in listener.incoming().flatten() {
            s.set_nodelay(true).unwrap();
            thread::spawn(move || handle(s));
        }
    });
    addr
}

fn request(tid: u16) -> [u8; 12] {
    let t = tid.to_be_bytes();
    [t[0], t[1], 0, 0, 0, 6, 1, 3, 0, 0, 0, 1]
}

/// A reply as the client saw it.
struct Reply {
    tid: u16,
    rtt: Duration,
}

/// Sends `n` requests (tids 0..n) at 2,000/s on one connection, without
/// waiting for replies, and collects the replies until 800 ms pass with none
/// after the last request (longer than any delay the tests apply).
fn pipeline(port: u16, n: u16) -> Vec<Reply> {
    let stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream.set_nodelay(true).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let reader = {
        let (s, done) = (stream.try_clone().unwrap(), done.clone());
        thread::spawn(move || read_replies(s, &done))
    };
    let sent = send_requests(stream, n);
    done.store(true, Ordering::SeqCst);
    let got = reader.join().unwrap();
    got.into_iter()
        .map(|(tid, at)| Reply {
            tid,
            rtt: at - sent[tid as usize],
        })
        .collect()
}

/// Writes the requests on a schedule of 0.5 ms each; returns when each left.
fn send_requests(mut s: TcpStream, n: u16) -> Vec<Instant> {
    let start = Instant::now();
    let mut sent = Vec::with_capacity(n as usize);
    for tid in 0..n {
        sent.push(Instant::now());
        s.write_all(&request(tid)).unwrap();
        if tid % 10 == 9 {
            let next = start + Duration::from_micros(500) * (tid as u32 + 1);
            thread::sleep(next.saturating_duration_since(Instant::now()));
        }
    }
    sent
}

/// Reads 10-byte replies; returns (tid, arrival) in arrival order.
fn read_replies(mut s: TcpStream, done: &AtomicBool) -> Vec<(u16, Instant)> {
    s.set_read_timeout(Some(Duration::from_millis(800)))
        .unwrap();
    let (mut buf, mut got) = (Vec::new(), Vec::new());
    let mut chunk = [0u8; 4096];
    loop {
        match s.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                if done.load(Ordering::SeqCst) {
                    break;
                }
                continue;
            }
            Err(e) => panic!("reading replies: {e}"),
        }
        let at = Instant::now();
        for reply in buf.chunks_exact(10) {
            assert_eq!(&reply[2..6], &[0, 0, 0, 4], "reply MBAP");
            got.push((u16::from_be_bytes([reply[0], reply[1]]), at));
        }
        buf.drain(..buf.len() / 10 * 10);
    }
    got
}

/// Every tid at most once; returns how many arrived after a higher one.
fn out_of_order(replies: &[Reply]) -> usize {
    let mut seen = vec![false; N as usize];
    let mut highest = None;
    let mut late = 0;
    for r in replies {
        assert!(!seen[r.tid as usize], "tid {} arrived twice", r.tid);
        seen[r.tid as usize] = true;
        late += highest.is_some_and(|h| r.tid < h) as usize;
        highest = highest.max(Some(r.tid));
    }
    late
}

fn slow(replies: &[Reply], at_least: Duration) -> usize {
    replies.iter().filter(|r| r.rtt >= at_least).count()
}

fn report(name: &str, replies: &[Reply], st: &Stats) {
    let max_rtt = replies.iter().map(|r| r.rtt).max().unwrap_or_default();
    eprintln!(
        "{name}: {} replies, {} out of order at the client, {} ≥ 50 ms, max rtt {max_rtt:?}; {st:?}",
        replies.len(),
        out_of_order(replies),
        slow(replies, 50 * MS)
    );
}

/// 5 % of 2,000: mean 100, standard deviation 9.7; four of them either side.
fn assert_plausible_share(count: u64, share: f64) {
    let mean = share * N as f64;
    let sd = (mean * (1.0 - share)).sqrt();
    let (lo, hi) = (mean - 4.0 * sd, mean + 4.0 * sd);
    assert!(
        (lo..=hi).contains(&(count as f64)),
        "{count} not in {lo:.0}..={hi:.0}"
    );
}

/// How late the proxy may release a delayed reply. Its timer is exact to a
/// millisecond on an idle machine; the test binary's other threads, on two
/// cores, have been seen to add 20 ms. A proxy that polled, or slept on top
/// of the delay, would be late by a whole period or delay.
const MOST_LATE: Duration = Duration::from_millis(50);

#[test]
fn in_order_delays_hold_later_replies_back() {
    let _serial = serial();
    let proxy = Proxy::start(echo_server(), Faults::delays(0.05, 50 * MS, 300 * MS, 7));
    let replies = pipeline(proxy.port(), N);
    let st = proxy.stats();
    report("in order", &replies, &st);
    assert_eq!(replies.len(), N as usize, "every reply arrives");
    assert_eq!(out_of_order(&replies), 0, "a TCP stream keeps its order");
    assert_eq!((st.forwarded, st.dropped, st.reordered), (N as u64, 0, 0));
    assert_plausible_share(st.delayed, 0.05);
    // Held behind a delayed reply, later ones are slow too.
    assert!(slow(&replies, 50 * MS) as u64 >= st.delayed);
    assert!(
        st.max_delay >= 50 * MS && st.max_delay <= 320 * MS,
        "{:?}",
        st.max_delay
    );
    assert!(st.max_late < MOST_LATE, "sender late by {:?}", st.max_late);
}

#[test]
fn reorder_mode_lets_later_replies_overtake() {
    let _serial = serial();
    let faults = Faults {
        in_order: false,
        ..Faults::delays(0.05, 50 * MS, 300 * MS, 11)
    };
    let proxy = Proxy::start(echo_server(), faults);
    let replies = pipeline(proxy.port(), N);
    let st = proxy.stats();
    report("reordering", &replies, &st);
    assert_eq!(replies.len(), N as usize, "every reply arrives");
    assert!(
        out_of_order(&replies) > 0,
        "some replies come back out of order"
    );
    assert!(st.reordered > 0);
    assert_plausible_share(st.delayed, 0.05);
    // Every delayed reply took its minimum delay; the others went straight
    // through (a few may be slow on a loaded machine).
    let slow = slow(&replies, 50 * MS) as u64;
    assert!(
        slow >= st.delayed && slow <= st.delayed + 20,
        "{slow} slow, {} delayed",
        st.delayed
    );
    let max_rtt = replies.iter().map(|r| r.rtt).max().unwrap();
    assert!(max_rtt <= 300 * MS + MOST_LATE + 20 * MS, "{max_rtt:?}");
    assert!(st.max_late < MOST_LATE, "sender late by {:?}", st.max_late);
}

#[test]
fn dropped_replies_never_arrive() {
    let _serial = serial();
    let faults = Faults {
        drop_share: 0.1,
        seed: 3,
        ..Faults::none()
    };
    let proxy = Proxy::start(echo_server(), faults);
    let replies = pipeline(proxy.port(), N);
    let st = proxy.stats();
    report("drops", &replies, &st);
    assert_eq!(out_of_order(&replies), 0);
    assert_eq!(replies.len() as u64, N as u64 - st.dropped);
    assert_eq!(st.forwarded + st.dropped, N as u64);
    assert_plausible_share(st.dropped, 0.1);
}

#[test]
fn stalls_hold_every_reply() {
    let _serial = serial();
    let faults = Faults {
        stall: Some((300 * MS, 150 * MS)),
        ..Faults::none()
    };
    let proxy = Proxy::start(echo_server(), faults);
    let replies = pipeline(proxy.port(), N);
    let st = proxy.stats();
    report("stalls", &replies, &st);
    assert_eq!(replies.len(), N as usize);
    assert_eq!(out_of_order(&replies), 0);
    // Three stalls in the second of requests, each holding ~300 replies.
    assert!(st.stalled >= 500, "{} stalled", st.stalled);
    let max_rtt = replies.iter().map(|r| r.rtt).max().unwrap();
    assert!(max_rtt >= 140 * MS && max_rtt <= 170 * MS, "{max_rtt:?}");
}

#[test]
fn a_reset_closes_the_clients_socket() {
    let _serial = serial();
    let faults = Faults {
        reset_after: Some(200 * MS),
        ..Faults::none()
    };
    let proxy = Proxy::start(echo_server(), faults);
    let start = Instant::now();
    let mut s = TcpStream::connect(("127.0.0.1", proxy.port())).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    s.write_all(&request(42)).unwrap();
    let mut reply = [0u8; 10];
    s.read_exact(&mut reply).unwrap();
    assert_eq!(&reply[..2], &42u16.to_be_bytes(), "served before the reset");
    let end = s.read(&mut reply);
    let took = start.elapsed();
    assert!(
        matches!(end, Ok(0))
            || end
                .as_ref()
                .is_err_and(|e| e.kind() != ErrorKind::WouldBlock),
        "{end:?}"
    );
    assert!(
        took >= 200 * MS && took < 1000 * MS,
        "closed after {took:?}"
    );
    assert_eq!(proxy.stats().resets, 1);
}

#[test]
fn garbage_passes_through_untouched() {
    let _serial = serial();
    let server = serve(|mut s| {
        let _ = s.write_all(b"HTTP/1.1 400 Bad Request\r\n\r\n");
    });
    let proxy = Proxy::start(server, Faults::delays(1.0, 200 * MS, 300 * MS, 1));
    let mut s = TcpStream::connect(("127.0.0.1", proxy.port())).unwrap();
    let start = Instant::now();
    let mut got = Vec::new();
    s.read_to_end(&mut got).unwrap();
    assert_eq!(got, b"HTTP/1.1 400 Bad Request\r\n\r\n");
    assert!(
        start.elapsed() < 100 * MS,
        "garbage is not delayed: {:?}",
        start.elapsed()
    );
    // A fragment too short to judge, from a peer that then waits, is passed on.
    let server = serve(|mut s| {
        let _ = s.write_all(b"xyz");
        thread::sleep(Duration::from_secs(2));
    });
    let proxy = Proxy::start(server, Faults::none());
    let mut s = TcpStream::connect(("127.0.0.1", proxy.port())).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(1))).unwrap();
    let mut got = [0u8; 3];
    s.read_exact(&mut got).unwrap();
    assert_eq!(&got, b"xyz");
    assert_eq!(proxy.stats().garbage_bytes, 3);
}

#[test]
fn json_lines_has_every_event_of_f2() {
    let csv = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/data/sorting/F2/events.csv"),
    )
    .unwrap();
    let rows = csv
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(1).is_some_and(|s| !s.is_empty()));
    let lines = json_lines(&csv);
    assert_eq!(lines.len(), rows.count());
    for (line, row) in lines.iter().zip(csv.lines().skip(1)) {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let f: Vec<&str> = row.split(',').collect();
        assert_eq!(v["t"].to_string(), f[0]);
        assert_eq!(v["signal"], f[1]);
        assert_eq!(v["value"].to_string(), f[2]);
    }
    assert_eq!(
        json_lines("t,signal,value\n5,C4,1\n9,,\n"),
        [r#"{"t": 5, "signal": "C4", "value": 1}"#]
    );
}

fn numbered(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("line {i}")).collect()
}

#[test]
fn feed_writes_every_line_at_its_pace() {
    let lines = numbered(6);
    let expected: String = lines.iter().map(|l| format!("{l}\n")).collect();
    let paces = [
        (Pace::AllAtOnce, Duration::ZERO),
        (Pace::Steady(10 * MS), 50 * MS),
        (Pace::Pauses(vec![(1, 150 * MS), (4, 50 * MS)]), 200 * MS),
        (
            Pace::Jitter {
                seed: 5,
                max: 5 * MS,
            },
            Duration::ZERO,
        ),
    ];
    for (pace, at_least) in paces {
        let (mut out, start) = (Vec::new(), Instant::now());
        feed(&mut out, &lines, &pace).unwrap();
        assert!(
            start.elapsed() >= at_least,
            "{pace:?} took {:?}",
            start.elapsed()
        );
        assert_eq!(String::from_utf8(out).unwrap(), expected, "{pace:?}");
    }
}

/// A pipe whose reader is gone.
struct Closed;

impl Write for Closed {
    fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
        Err(ErrorKind::BrokenPipe.into())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn feed_reports_a_closed_pipe() {
    for pace in [Pace::AllAtOnce, Pace::Steady(MS)] {
        let err = feed(&mut Closed, &numbered(3), &pace).unwrap_err();
        assert_eq!(err.kind(), ErrorKind::BrokenPipe);
    }
}
