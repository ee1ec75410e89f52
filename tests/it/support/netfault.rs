//! A loopback TCP proxy that puts network faults between a Modbus TCP client
//! (the monitor) and a server (a PLC): delayed, reordered and dropped replies,
//! stalls, and connection resets. See docs/network-faults.md.
//!
//! Requests (client → server) pass untouched and at once: the faults a
//! monitor has to live with show in what it reads back. Replies (server →
//! client) are cut into Modbus TCP ADUs by their MBAP header, so every reply
//! is judged on its own even when the client pipelines many requests on one
//! connection and the server's replies arrive glued together in one read.
//! Bytes that are not MBAP pass untouched and at once, and so does everything
//! after them on that connection (a stream out of frame cannot be cut again):
//! a client must see garbage as garbage.
//!
//! Each connection has three threads: requests copied as they come; replies
//! read, cut and given a release instant; and a sender that writes them at
//! their instants from a min-heap keyed by (release, arrival order). Plain
//! threads rather than the runtime: the sender sleeps on a condition variable
//! with a timeout, which wakes within tens of microseconds, where a runtime
//! timer ticks by the millisecond. The fault plan is drawn from a seed, per
//! connection, so a run can be replayed.

use super::Rng;
use std::cmp::Ordering;
use std::collections::{BTreeSet, BinaryHeap};
use std::io::{ErrorKind, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering as AtomicOrdering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// The faults a proxy puts on every connection.
#[derive(Clone, Debug)]
pub struct Faults {
    pub seed: u64,
    /// Share of replies (server→client Modbus ADUs) delayed, 0.0..=1.0.
    pub delay_share: f64,
    /// Delay range for a delayed reply (uniform).
    pub delay: (Duration, Duration),
    /// Whether a delayed reply holds back the replies after it (a TCP stream: in order, true)
    /// or lets later replies overtake it (reordering of replies, false).
    pub in_order: bool,
    /// Share of replies dropped (never forwarded).
    pub drop_share: f64,
    /// Stalls `(every, stall)`: from each multiple of `every` after the
    /// connection opened, hold all replies for `stall` (None: no stalls).
    pub stall: Option<(Duration, Duration)>,
    /// Close both sides of each connection after this long (a reset) (None: never).
    pub reset_after: Option<Duration>,
}

impl Faults {
    /// A transparent proxy.
    pub fn none() -> Faults {
        Faults {
            seed: 0,
            delay_share: 0.0,
            delay: (Duration::ZERO, Duration::ZERO),
            in_order: true,
            drop_share: 0.0,
            stall: None,
            reset_after: None,
        }
    }

    /// A share of replies delayed by `lo..=hi`, in order (a TCP stream).
    pub fn delays(share: f64, lo: Duration, hi: Duration, seed: u64) -> Faults {
        Faults {
            seed,
            delay_share: share,
            delay: (lo, hi),
            ..Faults::none()
        }
    }
}

/// What a proxy did, over all its connections.
#[derive(Clone, Debug, Default)]
pub struct Stats {
    pub connections: u64,
    /// Replies (ADUs) written to the client.
    pub forwarded: u64,
    /// Replies given a delay by the draw (not those only held behind one).
    pub delayed: u64,
    pub dropped: u64,
    /// Replies sent before an earlier reply of their connection.
    pub reordered: u64,
    /// Replies held by a stall.
    pub stalled: u64,
    pub resets: u64,
    /// Bytes passed through untouched because they were not MBAP.
    pub garbage_bytes: u64,
    /// Longest time a forwarded reply spent in the proxy.
    pub max_delay: Duration,
    /// Latest a reply was written after its release instant (the sender's jitter).
    pub max_late: Duration,
}

/// A running proxy; dropping it stops accepting and closes every connection.
pub struct Proxy {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    accept: Option<JoinHandle<()>>,
    conns: Arc<Mutex<Vec<Arc<Conn>>>>,
    stats: Arc<Mutex<Stats>>,
}

impl Proxy {
    /// Listens on 127.0.0.1:0 and forwards every accepted connection to `upstream`.
    pub fn start(upstream: SocketAddr, faults: Faults) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind the proxy");
        let addr = listener.local_addr().expect("proxy address");
        let stop = Arc::new(AtomicBool::new(false));
        let conns = Arc::new(Mutex::new(Vec::new()));
        let stats = Arc::new(Mutex::new(Stats::default()));
        let shared = (stop.clone(), conns.clone(), stats.clone());
        let accept = thread::spawn(move || accept_loop(listener, upstream, faults, shared));
        Proxy {
            addr,
            stop,
            accept: Some(accept),
            conns,
            stats,
        }
    }

    pub fn port(&self) -> u16 {
        self.addr.port()
    }

    pub fn stats(&self) -> Stats {
        lock(&self.stats).clone()
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop.store(true, AtomicOrdering::SeqCst);
        // Wakes the blocking accept, which then sees `stop`.
        let _ = TcpStream::connect(self.addr);
        if let Some(accept) = self.accept.take() {
            let _ = accept.join();
        }
        for conn in lock(&self.conns).drain(..) {
            conn.close();
            let threads: Vec<_> = lock(&conn.threads).drain(..).collect();
            for t in threads {
                let _ = t.join();
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

type Shared = (
    Arc<AtomicBool>,
    Arc<Mutex<Vec<Arc<Conn>>>>,
    Arc<Mutex<Stats>>,
);

fn accept_loop(listener: TcpListener, upstream: SocketAddr, faults: Faults, shared: Shared) {
    let (stop, conns, stats) = shared;
    let faults = Arc::new(faults);
    for (index, client) in listener.incoming().enumerate() {
        if stop.load(AtomicOrdering::SeqCst) {
            return;
        }
        let Ok(client) = client else { continue };
        // A server that is down: the client's connection closes at once.
        let Ok(server) = TcpStream::connect(upstream) else {
            continue;
        };
        lock(&stats).connections += 1;
        let seed = faults.seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let conn = Conn::spawn(client, server, faults.clone(), stats.clone(), seed);
        lock(&conns).push(conn);
    }
}

/// A reply waiting for its release instant.
struct Pending {
    release: Instant,
    seq: u64,
    arrival: Instant,
    bytes: Vec<u8>,
    /// False for passed-through bytes, which are not counted as replies.
    reply: bool,
}

// The heap is a max-heap: order by (release, seq) reversed, so the earliest
// release comes first and equal releases keep their arrival order.
impl Ord for Pending {
    fn cmp(&self, other: &Self) -> Ordering {
        (other.release, other.seq).cmp(&(self.release, self.seq))
    }
}
impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.seq == other.seq
    }
}
impl Eq for Pending {}

#[derive(Default)]
struct State {
    heap: BinaryHeap<Pending>,
    /// Sequence numbers of the replies (ADUs) in the heap, to count overtakes.
    waiting: BTreeSet<u64>,
    upstream_done: bool,
    closed: bool,
}

/// One proxied connection.
struct Conn {
    state: Mutex<State>,
    wake: Condvar,
    /// Clones of both sockets, to close them from any thread.
    sockets: Mutex<Vec<TcpStream>>,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

/// What the sender does next.
enum Next {
    Send(Vec<Pending>, u64),
    Reset,
    UpstreamDone,
    Closed,
}

impl Conn {
    fn spawn(
        client: TcpStream,
        server: TcpStream,
        faults: Arc<Faults>,
        stats: Arc<Mutex<Stats>>,
        seed: u64,
    ) -> Arc<Conn> {
        let _ = client.set_nodelay(true);
        let _ = server.set_nodelay(true);
        let clone = |s: &TcpStream| s.try_clone().expect("clone a socket");
        let conn = Arc::new(Conn {
            state: Mutex::new(State::default()),
            wake: Condvar::new(),
            sockets: Mutex::new(vec![clone(&client), clone(&server)]),
            threads: Mutex::new(Vec::new()),
        });
        let start = Instant::now();
        let plan = Plan::new(faults.clone(), seed, start);
        let (c1, s1) = (clone(&client), clone(&server));
        let (k1, k2) = (conn.clone(), conn.clone());
        let st = stats.clone();
        let reset_at = faults.reset_after.map(|d| start + d);
        let threads = vec![
            thread::spawn(move || forward_requests(c1, s1)),
            thread::spawn(move || read_replies(server, &k1, plan, &st)),
            thread::spawn(move || send_replies(client, &k2, reset_at, &stats)),
        ];
        *lock(&conn.threads) = threads;
        conn
    }

    fn push(&self, p: Pending) {
        let mut s = lock(&self.state);
        if p.reply {
            s.waiting.insert(p.seq);
        }
        s.heap.push(p);
        self.wake.notify_one();
    }

    fn finish_upstream(&self) {
        lock(&self.state).upstream_done = true;
        self.wake.notify_one();
    }

    /// Shuts both sockets down and drops the clones held here: the threads
    /// then see end of stream and end, and the last descriptor is closed.
    fn close(&self) {
        lock(&self.state).closed = true;
        self.wake.notify_all();
        for s in lock(&self.sockets).drain(..) {
            let _ = s.shutdown(Shutdown::Both);
        }
    }

    /// Waits for the next replies due, the reset, or the end.
    fn next(&self, reset_at: Option<Instant>) -> Next {
        let mut s = lock(&self.state);
        loop {
            if s.closed {
                return Next::Closed;
            }
            let now = Instant::now();
            if reset_at.is_some_and(|r| r <= now) {
                return Next::Reset;
            }
            let due = s.heap.peek().map(|p| p.release);
            if due.is_some_and(|d| d <= now) {
                return take_due(&mut s, now);
            }
            if due.is_none() && s.upstream_done {
                return Next::UpstreamDone;
            }
            let until = [due, reset_at].into_iter().flatten().min();
            s = match until {
                Some(t) => {
                    self.wake
                        .wait_timeout(s, t - now)
                        .unwrap_or_else(|e| e.into_inner())
                        .0
                }
                None => self.wake.wait(s).unwrap_or_else(|e| e.into_inner()),
            };
        }
    }
}

/// Pops every reply due by `now`, counting those that overtake an earlier one.
fn take_due(s: &mut State, now: Instant) -> Next {
    let mut batch = Vec::new();
    let mut overtakes = 0;
    while s.heap.peek().is_some_and(|p| p.release <= now) {
        let p = s.heap.pop().expect("peeked");
        s.waiting.remove(&p.seq);
        if p.reply && s.waiting.first().is_some_and(|&first| first < p.seq) {
            overtakes += 1;
        }
        batch.push(p);
    }
    Next::Send(batch, overtakes)
}

/// Client → server: untouched, at once.
fn forward_requests(mut client: TcpStream, mut server: TcpStream) {
    let _ = std::io::copy(&mut client, &mut server);
    let _ = server.shutdown(Shutdown::Write);
}

/// A fragment still incomplete after this long is passed on as it is: a
/// peer that sends a few bytes of garbage and waits must still be seen.
const FRAGMENT_WAIT: Duration = Duration::from_millis(250);

/// Server → heap: cuts the bytes into ADUs and gives each its release.
fn read_replies(mut server: TcpStream, conn: &Conn, mut plan: Plan, stats: &Mutex<Stats>) {
    let _ = server.set_read_timeout(Some(FRAGMENT_WAIT));
    let mut buf = Vec::new();
    let mut chunk = vec![0u8; 64 * 1024];
    loop {
        match server.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => {
                buf.extend_from_slice(&chunk[..n]);
                plan.cut(&mut buf, Instant::now(), conn, stats);
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                if !buf.is_empty() {
                    plan.garbage(&mut buf, Instant::now(), conn, stats);
                }
            }
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
    if !buf.is_empty() {
        plan.garbage(&mut buf, Instant::now(), conn, stats);
    }
    conn.finish_upstream();
}

/// Heap → client: writes the replies at their instants; resets the
/// connection when its time comes.
fn send_replies(
    mut client: TcpStream,
    conn: &Conn,
    reset_at: Option<Instant>,
    stats: &Mutex<Stats>,
) {
    loop {
        match conn.next(reset_at) {
            Next::Send(batch, overtakes) => {
                let sent = Instant::now();
                note_sent(&mut lock(stats), &batch, overtakes, sent);
                let bytes: Vec<u8> = batch.into_iter().flat_map(|p| p.bytes).collect();
                if client.write_all(&bytes).is_err() {
                    conn.close();
                    return;
                }
            }
            Next::Reset => {
                lock(stats).resets += 1;
                conn.close();
                return;
            }
            Next::UpstreamDone => {
                let _ = client.shutdown(Shutdown::Write);
                return;
            }
            Next::Closed => return,
        }
    }
}

fn note_sent(stats: &mut Stats, batch: &[Pending], overtakes: u64, sent: Instant) {
    stats.reordered += overtakes;
    for p in batch.iter().filter(|p| p.reply) {
        stats.forwarded += 1;
        stats.max_delay = stats.max_delay.max(sent - p.arrival);
        stats.max_late = stats
            .max_late
            .max(sent.saturating_duration_since(p.release));
    }
}

/// How the start of a buffer reads as Modbus TCP.
enum Frame {
    /// A whole ADU of this many bytes.
    Adu(usize),
    Incomplete,
    Garbage,
}

/// MBAP: transaction id (2), protocol id (2, always 0), length (2, the bytes
/// after it, counting the unit id), unit id (1).
fn frame(buf: &[u8]) -> Frame {
    if buf.len() >= 4 && buf[2..4] != [0, 0] {
        return Frame::Garbage;
    }
    if buf.len() < 6 {
        return Frame::Incomplete;
    }
    let len = u16::from_be_bytes([buf[4], buf[5]]) as usize;
    if len == 0 || len > 260 {
        Frame::Garbage
    } else if buf.len() < 6 + len {
        Frame::Incomplete
    } else {
        Frame::Adu(6 + len)
    }
}

/// The fault plan of one connection: which replies are dropped or delayed,
/// and when each is released.
struct Plan {
    faults: Arc<Faults>,
    rng: Rng,
    start: Instant,
    seq: u64,
    last_release: Instant,
    passthrough: bool,
}

impl Plan {
    fn new(faults: Arc<Faults>, seed: u64, start: Instant) -> Plan {
        Plan {
            faults,
            rng: Rng::new(seed),
            start,
            seq: 0,
            last_release: start,
            passthrough: false,
        }
    }

    /// Takes every whole ADU off the front of `buf`.
    fn cut(&mut self, buf: &mut Vec<u8>, now: Instant, conn: &Conn, stats: &Mutex<Stats>) {
        loop {
            if self.passthrough {
                return self.garbage(buf, now, conn, stats);
            }
            match frame(buf) {
                Frame::Adu(n) => {
                    let adu: Vec<u8> = buf.drain(..n).collect();
                    self.reply(adu, now, conn, stats);
                }
                Frame::Incomplete => return,
                Frame::Garbage => self.passthrough = true,
            }
        }
    }

    /// Passes the whole buffer on at once (behind held replies in order mode,
    /// as a TCP stream would), and everything after it on this connection.
    fn garbage(&mut self, buf: &mut Vec<u8>, now: Instant, conn: &Conn, stats: &Mutex<Stats>) {
        self.passthrough = true;
        lock(stats).garbage_bytes += buf.len() as u64;
        let release = if self.faults.in_order {
            now.max(self.last_release)
        } else {
            now
        };
        self.last_release = release;
        self.seq += 1;
        let bytes = std::mem::take(buf);
        conn.push(Pending {
            release,
            seq: self.seq,
            arrival: now,
            bytes,
            reply: false,
        });
    }

    fn reply(&mut self, bytes: Vec<u8>, now: Instant, conn: &Conn, stats: &Mutex<Stats>) {
        let f = &self.faults;
        // Both draws every time, so the delays do not shift with drop_share.
        let dropped = self.rng.chance(f.drop_share);
        let delayed = self.rng.chance(f.delay_share);
        let delay = self.rng.between(f.delay.0, f.delay.1);
        let mut s = lock(stats);
        if dropped {
            s.dropped += 1;
            return;
        }
        let wanted = now + if delayed { delay } else { Duration::ZERO };
        let mut release = self.after_stall(wanted);
        s.delayed += delayed as u64;
        s.stalled += (release > wanted) as u64;
        drop(s);
        if f.in_order {
            release = release.max(self.last_release);
        }
        self.last_release = self.last_release.max(release);
        self.seq += 1;
        conn.push(Pending {
            release,
            seq: self.seq,
            arrival: now,
            bytes,
            reply: true,
        });
    }

    /// `t`, or the end of the stall it falls in: stalls run from each
    /// multiple of `every` after the connection opened, for `stall`.
    fn after_stall(&self, t: Instant) -> Instant {
        let Some((every, stall)) = self.faults.stall else {
            return t;
        };
        if every.is_zero() {
            return t;
        }
        let since = t - self.start;
        let k = since.as_nanos() / every.as_nanos();
        let from = self.start + Duration::from_nanos((every.as_nanos() * k) as u64);
        if k >= 1 && t < from + stall {
            from + stall
        } else {
            t
        }
    }
}
