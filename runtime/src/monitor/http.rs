//! `--http ADDR`: `/status` (JSON: every part's verdict, the flags, counters)
//! and `/metrics` (Prometheus text format) on a small HTTP/1 server.
//!
//! The server shares the process's file descriptors with the PLC link, so it
//! must never take them all: otherwise a peer opening connections and sending
//! nothing leaves the monitor unable to reconnect to a restarted PLC ("Too
//! many open files"). Hence an accept loop of its own, with hyper:
//!
//! - at most [`MAX_CONNECTIONS`] connections, or a quarter of the soft
//!   `RLIMIT_NOFILE` if that is fewer, the rest left to the PLC link and the
//!   monitor's files. A newcomer beyond the cap closes the oldest connection
//!   rather than waiting: a fresh client is always answered;
//! - a connection is closed after [`HEADER_READ_TIMEOUT`] without a whole
//!   request head, and after [`IDLE_TIMEOUT`] without a byte read or written
//!   (a client that stopped reading its answer);
//! - a failed `accept` (no descriptor left, `EMFILE`/`ENFILE`) is tried again
//!   after [`ACCEPT_PAUSE`]: no busy loop, and the server goes on.

use std::collections::BTreeMap;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::http::header;
use axum::routing::get;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpSocket};
use tokio::sync::oneshot;
use tokio::time::Instant;

use super::status::Status;
use diagnoser::Failure;

/// A connection with no byte read or written for this long is closed.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(10);
/// A connection that has not sent a whole request head this long after it
/// opened (or after its last answer) is closed.
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(5);
/// The most connections open at once (fewer with a low descriptor limit).
pub const MAX_CONNECTIONS: usize = 256;
/// Connections the kernel queues for the accept loop.
pub const BACKLOG: u32 = 1024;
/// The wait before accepting again after `accept` failed.
pub const ACCEPT_PAUSE: Duration = Duration::from_millis(50);

/// Binds `addr` and serves the endpoints in the background. Fails (before
/// anything is read) if the address cannot be bound.
pub async fn serve(addr: SocketAddr, status: Arc<Mutex<Status>>) -> Result<(), Failure> {
    serve_routes(addr, routes(status)).await
}

/// Binds `addr` and serves `routes` in the background, under the same
/// limits (a fleet worker's view).
pub async fn serve_routes(addr: SocketAddr, routes: Router) -> Result<(), Failure> {
    let listener = listen(addr)
        .map_err(|e| Failure::BadInput(format!("--http {addr}: cannot listen: {e}")))?;
    tokio::spawn(accept_loop(listener, routes, Limits::of_process()));
    Ok(())
}

/// A listener whose queue holds a flood's worth of connections waiting to be
/// accepted: past it, a newcomer's SYN is dropped and it waits a second or
/// more to try again.
fn listen(addr: SocketAddr) -> io::Result<TcpListener> {
    let socket = if addr.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(BACKLOG)
}

fn routes(status: Arc<Mutex<Status>>) -> Router {
    let for_status = status.clone();
    Router::new()
        .route(
            "/status",
            get(move || {
                let body = for_status.lock().map(|s| s.json()).unwrap_or_default();
                async move { ([(header::CONTENT_TYPE, "application/json")], body) }
            }),
        )
        .route(
            "/metrics",
            get(move || {
                let body = status.lock().map(|s| s.metrics()).unwrap_or_default();
                async move { ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], body) }
            }),
        )
}

#[derive(Debug, Clone, Copy)]
struct Limits {
    idle: Duration,
    header_read: Duration,
    cap: usize,
}

impl Limits {
    fn of_process() -> Limits {
        Limits {
            idle: IDLE_TIMEOUT,
            header_read: HEADER_READ_TIMEOUT,
            cap: cap_for(soft_nofile()),
        }
    }
}

/// The connection cap under a soft descriptor limit (`None`: unlimited): a
/// quarter of it, at most [`MAX_CONNECTIONS`], at least one.
fn cap_for(soft: Option<u64>) -> usize {
    soft.map_or(MAX_CONNECTIONS, |s| {
        (s / 4).clamp(1, MAX_CONNECTIONS as u64) as usize
    })
}

#[cfg(unix)]
fn soft_nofile() -> Option<u64> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given.
    let known = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0;
    // `rlim_t` is narrower than 64 bits on some targets.
    #[allow(clippy::unnecessary_cast)]
    (known && limit.rlim_cur != libc::RLIM_INFINITY).then_some(limit.rlim_cur as u64)
}

#[cfg(not(unix))]
fn soft_nofile() -> Option<u64> {
    None
}

async fn accept_loop(listener: TcpListener, app: Router, limits: Limits) {
    let mut open = Open::default();
    let mut failing = false;
    loop {
        match listener.accept().await {
            Ok((stream, _)) => {
                failing = false;
                if open.make_room(limits.cap) {
                    // The closed connection's task runs first and gives its
                    // descriptor back before the next accept.
                    tokio::task::yield_now().await;
                }
                tokio::spawn(connection(stream, app.clone(), open.add(), limits));
            }
            Err(e) if gone_before_accepted(&e) => {}
            Err(e) => {
                if !std::mem::replace(&mut failing, true) {
                    eprintln!("warning: --http: cannot accept connections ({e}); trying again");
                }
                tokio::time::sleep(ACCEPT_PAUSE).await;
            }
        }
    }
}

/// An error of one connection that the peer gave up, not of the listener.
fn gone_before_accepted(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionAborted | io::ErrorKind::ConnectionReset
    )
}

/// The open connections, oldest first: each one's sender, whose drop closes
/// the connection.
#[derive(Default)]
struct Open {
    next: u64,
    senders: BTreeMap<u64, oneshot::Sender<()>>,
}

impl Open {
    /// At the cap, forgets the connections that ended, and if still at the
    /// cap, closes the oldest. True if it closed one.
    fn make_room(&mut self, cap: usize) -> bool {
        if self.senders.len() < cap {
            return false;
        }
        self.senders.retain(|_, s| !s.is_closed());
        self.senders.len() >= cap && self.senders.pop_first().is_some()
    }

    /// A newcomer: the receiver that tells it to close.
    fn add(&mut self) -> oneshot::Receiver<()> {
        let (close, closed) = oneshot::channel();
        self.senders.insert(self.next, close);
        self.next += 1;
        closed
    }
}

/// Serves one connection until it ends, times out, or is `closed`; dropping
/// it closes the socket.
async fn connection<I>(io: I, app: Router, closed: oneshot::Receiver<()>, limits: Limits)
where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let activity = Activity::new();
    let io = TokioIo::new(Watched {
        io,
        activity: activity.clone(),
    });
    let conn = http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read)
        .serve_connection(io, TowerToHyperService::new(app));
    tokio::select! {
        _ = conn => {}
        () = activity.idle_for(limits.idle) => {}
        _ = closed => {}
    }
}

/// When a connection last moved a byte, in milliseconds since it opened.
#[derive(Clone)]
struct Activity {
    opened: Instant,
    last_ms: Arc<AtomicU64>,
}

impl Activity {
    fn new() -> Activity {
        Activity {
            opened: Instant::now(),
            last_ms: Arc::new(AtomicU64::new(0)),
        }
    }

    fn touch(&self) {
        let ms = self.opened.elapsed().as_millis() as u64;
        self.last_ms.store(ms, Ordering::Relaxed);
    }

    /// Returns once no byte has moved for `limit`.
    async fn idle_for(&self, limit: Duration) {
        loop {
            let last = Duration::from_millis(self.last_ms.load(Ordering::Relaxed));
            let deadline = self.opened + last + limit;
            if Instant::now() >= deadline {
                return;
            }
            tokio::time::sleep_until(deadline).await;
        }
    }
}

/// A byte stream that stamps its [`Activity`] whenever a byte moves.
struct Watched<I> {
    io: I,
    activity: Activity,
}

impl<I> Watched<I> {
    fn wrote(&self, polled: &Poll<io::Result<usize>>) {
        if matches!(polled, Poll::Ready(Ok(n)) if *n > 0) {
            self.activity.touch();
        }
    }
}

impl<I: AsyncRead + Unpin> AsyncRead for Watched<I> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.io).poll_read(cx, buf);
        if buf.filled().len() > before {
            self.activity.touch();
        }
        polled
    }
}

impl<I: AsyncWrite + Unpin> AsyncWrite for Watched<I> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.io).poll_write(cx, buf);
        self.wrote(&polled);
        polled
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.io).poll_write_vectored(cx, bufs);
        self.wrote(&polled);
        polled
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    const SHORT: Limits = Limits {
        idle: Duration::from_millis(300),
        header_read: Duration::from_secs(5),
        cap: 2,
    };

    fn big_answer() -> Router {
        Router::new().route("/", get(|| async { "x".repeat(100_000) }))
    }

    #[test]
    fn the_cap_is_a_quarter_of_the_descriptors_up_to_the_maximum() {
        assert_eq!(cap_for(None), MAX_CONNECTIONS);
        assert_eq!(cap_for(Some(1_048_576)), MAX_CONNECTIONS);
        assert_eq!(cap_for(Some(1024)), 256);
        assert_eq!(cap_for(Some(256)), 64);
        assert_eq!(cap_for(Some(2)), 1);
    }

    /// A client that asks and then stops reading the answer: once no byte
    /// has moved for the idle limit, the connection ends.
    #[tokio::test]
    async fn a_client_that_stops_reading_is_closed_when_idle() {
        let (mut client, server) = tokio::io::duplex(64);
        let (_close, closed) = oneshot::channel();
        let started = Instant::now();
        let served = tokio::spawn(connection(server, big_answer(), closed, SHORT));
        client
            .write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
            .await
            .expect("asks");
        tokio::time::timeout(Duration::from_secs(3), served)
            .await
            .expect("closed within 3 s")
            .expect("no panic");
        assert!(started.elapsed() >= SHORT.idle);
    }

    /// A slow client that keeps reading is never idle.
    #[tokio::test]
    async fn a_slow_reader_is_not_idle() {
        let (mut client, server) = tokio::io::duplex(64);
        let (_close, closed) = oneshot::channel();
        let served = tokio::spawn(connection(server, big_answer(), closed, SHORT));
        client
            .write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
            .await
            .expect("asks");
        let mut buf = [0u8; 64];
        for _ in 0..20 {
            tokio::time::sleep(Duration::from_millis(50)).await;
            assert!(client.read(&mut buf).await.expect("reads") > 0);
        }
        assert!(!served.is_finished());
    }

    /// Beyond the cap, a newcomer closes the oldest connection.
    #[tokio::test]
    async fn a_newcomer_beyond_the_cap_closes_the_oldest() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("binds");
        let addr = listener.local_addr().expect("address");
        tokio::spawn(accept_loop(listener, big_answer(), SHORT));
        let connect = || tokio::net::TcpStream::connect(addr);
        let mut oldest = connect().await.expect("connects");
        let mut second = connect().await.expect("connects");
        let _newcomer = connect().await.expect("connects");
        let mut buf = [0u8; 8];
        let read = tokio::time::timeout(Duration::from_secs(2), oldest.read(&mut buf)).await;
        assert!(matches!(read, Ok(Ok(0))), "{read:?}");
        let read = tokio::time::timeout(Duration::from_millis(200), second.read(&mut buf)).await;
        assert!(read.is_err(), "the second is still open: {read:?}");
    }
}
