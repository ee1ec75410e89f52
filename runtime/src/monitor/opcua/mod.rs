//! `--opcua opc.tcp://HOST:PORT`: a PLC's signals as the variables of an
//! OPC UA server, followed with a subscription, and the flags written back
//! to its flag variables.
//!
//! **Mapping.** Each signal and flag is the variable the plant file's
//! `[opcua]` table names by NodeId (`C4 = "ns=2;s=Line.C4"`, or
//! `nsu=URI;…` for a namespace by its URI), or else the variable whose
//! browse name is the signal's (or flag's) name, found by browsing the
//! Objects folder's hierarchy: objects outside namespace 0 are entered, down
//! to [`BROWSE_DEPTH`] levels, and variables in any namespace but 0 count.
//! A signal found nowhere, or twice, stops the monitor (exit code 2); a flag
//! found nowhere cannot be written back (a warning).
//!
//! **Connection.** On each connection the monitor creates one subscription
//! with a monitored item per signal (sampling at the plant's scan period,
//! reporting every change, a queue deep enough for a publishing interval),
//! then reads every signal and flag: see [`session`] for how the values, the
//! SourceTimestamps and the notification messages become scans and
//! watermarks. The publishing interval is half the lateness allowed (in wall
//! time, within 10 ms to 1 s), with a keep-alive in every interval that has
//! no change: each message moves the watermark.
//!
//! **Security.** Security policy None, anonymous: no certificate is made or
//! read (the client's PKI folder is pointed where it cannot be created).
//!
//! **Losses.** A session that closes, a keep-alive that fails (the library
//! closes the session), a lost notification message or a bad value is a lost
//! plant; the connection is closed and opened again every
//! [`RECONNECT_EVERY`] until the server answers, and the plant is read anew.

pub mod session;

use std::collections::HashMap;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Arc;
use std::time::Duration;

use ::opcua::client::browser::{BrowseFilter, BrowseResultItem};
use ::opcua::client::{
    Client, ClientBuilder, IdentityToken, OnSubscriptionNotificationCore, Session as UaSession,
    SessionPollResult,
};
use ::opcua::crypto::SecurityPolicy;
use ::opcua::types::{
    AttributeId, BrowseDescription, DataChangeNotification, DataValue, MessageSecurityMode,
    MonitoredItemCreateRequest, MonitoringMode, MonitoringParameters, NodeClass, NodeClassMask,
    NodeId, NotificationMessage, NumericRange, ObjectId, ReadValueId, StatusChangeNotification,
    StatusCode, TimestampsToReturn, UserTokenPolicy, VariableId, Variant, VariantTypeId,
    WriteValue,
};
use diagnoser::{Failure, Plant, Time, TimeFormat};
use futures_util::StreamExt;
use tokio::sync::mpsc;
use tokio::time::{Instant, MissedTickBehavior};

use self::session::{Command, Notice, Reading, Session, Value};
use super::source::{Item, Link, Source};

/// Wait before opening a connection again, after a loss or a refusal.
pub const RECONNECT_EVERY: Duration = Duration::from_secs(1);
/// How many levels below the Objects folder a variable is looked for by
/// browse name.
pub const BROWSE_DEPTH: usize = 4;
/// How many nodes the browse may visit: a server far larger than a PLC's
/// is mapped in `[opcua]` instead.
const BROWSE_LIMIT: usize = 100_000;
/// Changes a monitored item may queue between two publishes; beyond, the
/// server reports an overflow, which is a lost plant.
const QUEUE_SIZE: u32 = 256;
/// How long one request may wait for its answer.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// How long to wait for the server to close a session on the way out.
const CLOSE_WAIT: Duration = Duration::from_secs(1);
/// How long a connection may take to open, a session to be activated.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// An OPC UA server's variables, through a subscription.
pub struct OpcuaSource {
    plant: Plant,
    url: String,
    speed: f64,
    lateness: Time,
}

impl OpcuaSource {
    /// The source for `plant` from the server at `url`
    /// (`opc.tcp://HOST[:PORT][/PATH]`, port 4840 by default); fails on a
    /// malformed URL.
    pub fn new(
        url: &str,
        plant: &Plant,
        speed: f64,
        lateness: Time,
    ) -> Result<OpcuaSource, Failure> {
        let url = parse_url(url).map_err(|e| Failure::bad(format!("--opcua: {e}")))?;
        Ok(OpcuaSource {
            plant: plant.clone(),
            url,
            speed,
            lateness,
        })
    }
}

/// `opc.tcp://HOST[:PORT][/PATH]`, with the port made explicit.
pub fn parse_url(url: &str) -> Result<String, String> {
    let Some(rest) = url.strip_prefix("opc.tcp://") else {
        return Err(format!(
            "'{url}': expected opc.tcp://HOST:PORT (only OPC UA's binary protocol over TCP)"
        ));
    };
    let (authority, path) = rest.split_once('/').unwrap_or((rest, ""));
    let port = |p: &str| {
        p.parse::<u16>()
            .map_err(|_| format!("'{url}': port '{p}' is not a number from 1 to 65535"))
    };
    // An IPv6 address is written in brackets, its colons inside them.
    let (host, port) = match authority.strip_prefix('[').map(|r| r.split_once(']')) {
        Some(Some((h, ""))) => (format!("[{h}]"), 4840),
        Some(Some((h, after))) => match after.strip_prefix(':') {
            Some(p) => (format!("[{h}]"), port(p)?),
            None => return Err(format!("'{url}': expected opc.tcp://HOST:PORT")),
        },
        Some(None) => return Err(format!("'{url}': no ']' after the IPv6 address")),
        None => match authority.rsplit_once(':') {
            Some((h, p)) => (h.to_string(), port(p)?),
            None => (authority.to_string(), 4840),
        },
    };
    if host.is_empty() || host == "[]" || port == 0 {
        return Err(format!("'{url}': expected opc.tcp://HOST:PORT"));
    }
    Ok(format!("opc.tcp://{host}:{port}/{path}"))
}

impl Source for OpcuaSource {
    fn time_format(&self) -> TimeFormat {
        Session::time_format()
    }

    fn spawn(self: Box<Self>, link: Link) {
        tokio::spawn(run(*self, link));
    }
}

/// Why a connection ended.
enum Ended {
    /// The monitor went, or a fatal item went out.
    Stop,
    /// Open it again after [`RECONNECT_EVERY`].
    Again,
}

/// Follows the server until the monitor goes.
async fn run(source: OpcuaSource, mut link: Link) {
    let mut client = match client() {
        Ok(c) => c,
        Err(e) => {
            let _ = link.items.send(Item::Fatal(e)).await;
            return;
        }
    };
    let mut session = Session::new(&source.plant, &source.url, source.speed, source.lateness);
    // Whether the outage under way was said: one warning each.
    let mut told = false;
    loop {
        match connection(&source, &mut client, &mut session, &mut link, &mut told).await {
            Ended::Stop => return,
            Ended::Again => tokio::time::sleep(RECONNECT_EVERY).await,
        }
    }
}

/// The client: security policy None, anonymous, no reconnection of its own
/// (a loss is the monitor's to handle), nothing written to disk.
fn client() -> Result<Client, Failure> {
    ClientBuilder::new()
        .application_name("gardefou monitor")
        .application_uri("urn:gardefou:monitor")
        .product_uri("urn:gardefou")
        .pki_dir(no_pki())
        .create_sample_keypair(false)
        .trust_server_certs(false)
        .session_retry_limit(0)
        .recreate_subscriptions(false)
        .keep_alive_interval(Duration::from_secs(1))
        .max_failed_keep_alive_count(3)
        .request_timeout(REQUEST_TIMEOUT)
        .session_timeout(30_000)
        .min_publish_interval(Duration::from_millis(10))
        .client()
        .map_err(|e| Failure::Io(format!("opcua: cannot make the client: {}", e.join("; "))))
}

/// Where the client library would keep certificates. Security policy None
/// needs none, but the library makes its PKI folders on start: below a file
/// it cannot, and it leaves the working directory alone.
fn no_pki() -> PathBuf {
    if cfg!(unix) {
        PathBuf::from("/dev/null/gardefou-opcua-pki")
    } else {
        std::env::temp_dir().join("gardefou-opcua-pki")
    }
}

/// Aborts the session's event loop when the connection is done with.
struct Driver(tokio::task::JoinHandle<()>);

impl Drop for Driver {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// What the session's event loop reports.
type Poll = Result<SessionPollResult, StatusCode>;

/// One connection, from opening to loss.
async fn connection(
    source: &OpcuaSource,
    client: &mut Client,
    session: &mut Session,
    link: &mut Link,
    told: &mut bool,
) -> Ended {
    let url = source.url.as_str();
    let mut out = Vec::new();
    let endpoint = (
        url,
        SecurityPolicy::None.to_uri(),
        MessageSecurityMode::None,
        UserTokenPolicy::anonymous(),
    );
    let (ua, event_loop) =
        match client.connect_to_endpoint_directly(endpoint, IdentityToken::Anonymous) {
            Ok(s) => s,
            Err(e) => {
                let m = format!("opcua {url}: {e}");
                let _ = link.items.send(Item::Fatal(Failure::bad(m))).await;
                return Ended::Stop;
            }
        };
    // The monitor reconnects itself: the plant must be read again anyway.
    ua.disable_reconnects();
    let (poll_tx, mut polls) = mpsc::unbounded_channel::<Poll>();
    let _driver = Driver(tokio::spawn(async move {
        let stream = event_loop.enter();
        tokio::pin!(stream);
        while let Some(r) = stream.next().await {
            let end = r.is_err();
            if poll_tx.send(r).is_err() || end {
                return;
            }
        }
    }));
    let activated = tokio::time::timeout(CONNECT_TIMEOUT, connected(&mut polls)).await;
    match activated.unwrap_or_else(|_| Err(format!("no answer in {} s", CONNECT_TIMEOUT.as_secs())))
    {
        Ok(()) => {}
        Err(why) => {
            if !std::mem::replace(told, true) {
                out.push(Item::Warning(format!(
                    "opcua {url}: cannot reach the server ({why}); trying again every {} s",
                    RECONNECT_EVERY.as_secs()
                )));
            }
            return if deliver(link, &mut out).await {
                Ended::Again
            } else {
                Ended::Stop
            };
        }
    }
    let (notices_tx, notices) = mpsc::unbounded_channel::<Notice>();
    let opened = open(source, &ua, session, notices_tx, &mut out).await;
    let ended = match opened {
        Ok((nodes, send)) => {
            *told = false;
            eprintln!(
                "monitor: opcua: connected to {url}: {} signals subscribed, {} of {} flags writable",
                nodes.signals.len(),
                nodes.flags.iter().flatten().count(),
                nodes.flags.len()
            );
            let follower = Follower {
                source,
                ua: &ua,
                nodes,
                send,
            };
            follower.run(session, link, notices, &mut polls, out).await
        }
        Err(Opening::Misfit(m)) => {
            out.push(Item::Fatal(Failure::BadInput(m)));
            let _ = deliver(link, &mut out).await;
            Ended::Stop
        }
        Err(Opening::Unreadable) => {
            if deliver(link, &mut out).await {
                Ended::Again
            } else {
                Ended::Stop
            }
        }
        Err(Opening::Failed(why)) => {
            session.disconnected(&why, &mut out);
            // Once per outage: the next attempts say nothing new.
            if !std::mem::replace(told, true) {
                out.push(Item::Warning(format!(
                    "opcua {url}: {why}; trying again every {} s",
                    RECONNECT_EVERY.as_secs()
                )));
            }
            if deliver(link, &mut out).await {
                Ended::Again
            } else {
                Ended::Stop
            }
        }
    };
    let _ = tokio::time::timeout(CLOSE_WAIT, ua.disconnect()).await;
    ended
}

/// Waits for the session to be created and activated.
async fn connected(polls: &mut mpsc::UnboundedReceiver<Poll>) -> Result<(), String> {
    loop {
        match polls.recv().await {
            Some(Ok(SessionPollResult::Reconnected(_))) => return Ok(()),
            Some(Ok(_)) => {}
            Some(Err(code)) => return Err(code.to_string()),
            None => return Err("the session ended".into()),
        }
    }
}

/// Why a connection could not be opened.
enum Opening {
    /// The server does not fit the plant file: the monitor stops.
    Misfit(String),
    /// A request failed: try again.
    Failed(String),
    /// The plant could not be read whole (the session said why): try again.
    Unreadable,
}

/// The variables of one connection, once found.
struct Nodes {
    signals: Vec<NodeId>,
    flags: Vec<Option<NodeId>>,
}

/// Finds the variables, subscribes to the signals and reads every value:
/// the plant's start, and the commands it gives (the flags to write).
async fn open(
    source: &OpcuaSource,
    ua: &Arc<UaSession>,
    session: &mut Session,
    notices: mpsc::UnboundedSender<Notice>,
    out: &mut Vec<Item>,
) -> Result<(Nodes, Vec<Command>), Opening> {
    let nodes = find(source, ua).await?;
    let failed = |what: &str, e: &dyn std::fmt::Display| Opening::Failed(format!("{what}: {e}"));
    let interval = publishing_interval(source.lateness, source.speed);
    let id = ua
        .create_subscription(interval, 30, 1, 0, 0, true, Notices(notices))
        .await
        .map_err(|e| failed("cannot create the subscription", &e))?;
    let sampling = source.plant.scan_period.max(1) as f64 / 1e6 / source.speed;
    let items: Vec<MonitoredItemCreateRequest> = nodes
        .signals
        .iter()
        .enumerate()
        .map(|(k, node)| {
            MonitoredItemCreateRequest::new(
                ReadValueId::new_value(node.clone()),
                MonitoringMode::Reporting,
                MonitoringParameters {
                    client_handle: handle(k),
                    sampling_interval: sampling,
                    queue_size: QUEUE_SIZE,
                    discard_oldest: true,
                    ..MonitoringParameters::default()
                },
            )
        })
        .collect();
    let created = ua
        .create_monitored_items(id, TimestampsToReturn::Source, items)
        .await
        .map_err(|e| failed("cannot create the monitored items", &e))?;
    let names: Vec<&str> = source
        .plant
        .signals
        .iter()
        .map(|(_, s)| s.name.as_str())
        .collect();
    for (k, c) in created.iter().enumerate() {
        let status = c.result.status_code;
        if !status.is_good() {
            let (name, node) = (names.get(k).copied().unwrap_or("?"), &nodes.signals[k]);
            return Err(Opening::Misfit(format!(
                "opcua {}: {name} ({node}) cannot be monitored: {status}",
                source.url
            )));
        }
    }
    let slow = created
        .iter()
        .map(|c| c.result.revised_sampling_interval)
        .fold(0.0, f64::max);
    if slow > sampling * 2.0 && slow > 1.0 {
        out.push(Item::Warning(format!(
            "opcua {}: the server samples every {slow} ms, slower than the plant's scan ({sampling} ms of wall time): an edge shorter than that may be missed",
            source.url
        )));
    }
    let present = nodes.flags.iter().map(Option::is_some).collect();
    session.opened(present, out);
    let to_read: Vec<ReadValueId> = nodes
        .signals
        .iter()
        .chain(nodes.flags.iter().flatten())
        .cloned()
        .map(ReadValueId::new_value)
        .collect();
    let values = ua
        .read(&to_read, TimestampsToReturn::Source, 0.0)
        .await
        .map_err(|e| failed("cannot read the plant", &e))?;
    if values.len() != to_read.len() {
        return Err(Opening::Failed(format!(
            "the server answered {} values for {} read",
            values.len(),
            to_read.len()
        )));
    }
    let (signals, rest) = values.split_at(nodes.signals.len());
    let signals: Vec<Reading> = signals.iter().map(reading).collect();
    let mut rest = rest.iter();
    let flags: Vec<Option<Reading>> = nodes
        .flags
        .iter()
        .map(|n| n.as_ref().and_then(|_| rest.next()).map(reading))
        .collect();
    let flag_names = source.plant.flags();
    let mut rest = values[nodes.signals.len()..].iter();
    for (k, node) in nodes.flags.iter().enumerate() {
        let Some(node) = node else {
            continue;
        };
        let status = rest.next().and_then(|v| v.status);
        if status == Some(StatusCode::BadNodeIdUnknown) {
            return Err(Opening::Misfit(format!(
                "opcua {}: flag {} ({node}): the server has no such node",
                source.url, flag_names[k]
            )));
        }
    }
    let mut send = Vec::new();
    session.read(&signals, &flags, now(), out, &mut send);
    if send.contains(&Command::Reopen) {
        return Err(Opening::Unreadable);
    }
    Ok((nodes, send))
}

/// The notifications of the subscription, sent on as they come.
struct Notices(mpsc::UnboundedSender<Notice>);

impl OnSubscriptionNotificationCore for Notices {
    fn on_subscription_notification(
        &mut self,
        message: NotificationMessage,
        _items: ::opcua::client::MonitoredItemMap<'_>,
    ) {
        let _ = self.0.send(notice(message));
    }
}

/// A notification message as the session reads it.
fn notice(message: NotificationMessage) -> Notice {
    let data = message.notification_data.unwrap_or_default();
    let mut n = Notice {
        seq: message.sequence_number,
        keep_alive: data.is_empty(),
        changes: Vec::new(),
        status: None,
    };
    for object in &data {
        if let Some(change) = object.inner_as::<DataChangeNotification>() {
            for item in change.monitored_items.iter().flatten() {
                if let Some(k) = (item.client_handle as usize).checked_sub(1) {
                    n.changes.push((k, reading(&item.value)));
                }
            }
        } else if let Some(status) = object.inner_as::<StatusChangeNotification>() {
            n.status = Some(status.status.to_string());
        }
    }
    n
}

/// The client handle of signal `k`: handles start at 1 (0 would be replaced).
fn handle(k: usize) -> u32 {
    u32::try_from(k + 1).unwrap_or(u32::MAX)
}

/// A value as the session reads it: good Booleans, and why not.
fn reading(dv: &DataValue) -> Reading {
    let status = dv.status.unwrap_or(StatusCode::Good);
    let value = if !status.is_good() {
        Value::Bad(status.to_string())
    } else if status.overflow() {
        Value::Bad("an overflow: the server's queue lost changes".into())
    } else {
        match &dv.value {
            Some(Variant::Boolean(b)) => Value::Bool(*b),
            Some(v) => Value::Other(describe(v)),
            None => Value::Bad("no value".into()),
        }
    };
    let picos = i64::from(dv.source_picoseconds.unwrap_or(0)) / 100;
    let t = dv
        .source_timestamp
        .filter(|d| !d.is_null())
        .and_then(|d| d.as_chrono().timestamp_nanos_opt())
        .map(|ns| ns.saturating_add(picos));
    Reading { value, t }
}

/// A value's type, for a message.
fn describe(v: &Variant) -> String {
    match v.type_id() {
        VariantTypeId::Empty => "empty".into(),
        VariantTypeId::Scalar(t) => format!("{t}"),
        VariantTypeId::Array(t, _) => format!("an array of {t}"),
    }
}

/// The publishing interval: half the lateness allowed, in wall time, within
/// 10 ms and 1 s. A message each interval moves the watermark, so a scan is
/// released about one lateness after its time.
fn publishing_interval(lateness: Time, speed: f64) -> Duration {
    let wall = lateness.max(0) as f64 / speed / 2.0;
    Duration::from_nanos(wall.clamp(10e6, 1e9) as u64)
}

/// One connection's subscription, as it is followed.
struct Follower<'a> {
    source: &'a OpcuaSource,
    ua: &'a Arc<UaSession>,
    nodes: Nodes,
    /// Commands of the session not yet carried out.
    send: Vec<Command>,
}

impl Follower<'_> {
    /// Follows the subscription until the connection is lost, writing the
    /// flags as they change.
    async fn run(
        mut self,
        session: &mut Session,
        link: &mut Link,
        mut notices: mpsc::UnboundedReceiver<Notice>,
        polls: &mut mpsc::UnboundedReceiver<Poll>,
        mut out: Vec<Item>,
    ) -> Ended {
        let mut send = std::mem::take(&mut self.send);
        let mut ticker = tokio::time::interval(session::RESEND / 4);
        ticker.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut write: Option<tokio::task::JoinHandle<Result<(), String>>> = None;
        // The flags wanted now, whatever changed while not connected.
        let image = link.flags.borrow_and_update().clone();
        session.flags(&image, now(), &mut send);
        loop {
            for command in send.drain(..) {
                match command {
                    Command::Write(flags) => write = Some(self.write(flags)),
                    Command::Reopen => {
                        if let Some(w) = write.take() {
                            w.abort();
                        }
                        return if deliver(link, &mut out).await {
                            Ended::Again
                        } else {
                            Ended::Stop
                        };
                    }
                }
            }
            if !deliver(link, &mut out).await {
                return Ended::Stop;
            }
            tokio::select! {
                n = notices.recv() => match n {
                    Some(n) => session.notice(n, now(), &mut out, &mut send),
                    None => lost(session, "the subscription ended", &mut out, &mut send),
                },
                poll = polls.recv() => match poll {
                    Some(Ok(SessionPollResult::ConnectionLost(code))) => {
                        lost(session, &format!("connection lost ({code})"), &mut out, &mut send);
                    }
                    Some(Ok(_)) => {}
                    Some(Err(code)) => {
                        lost(session, &format!("session lost ({code})"), &mut out, &mut send);
                    }
                    None => lost(session, "the session closed", &mut out, &mut send),
                },
                result = finished(&mut write) => {
                    write = None;
                    session.written(result, now(), &mut out, &mut send);
                }
                _ = ticker.tick() => session.tick(now(), &mut send),
                changed = link.flags.changed() => {
                    if changed.is_err() {
                        return Ended::Stop;
                    }
                    let image = link.flags.borrow_and_update().clone();
                    session.flags(&image, now(), &mut send);
                }
            }
        }
    }

    /// Starts writing flags (index in [`Plant::flags`] order, value).
    fn write(&self, flags: Vec<(usize, bool)>) -> tokio::task::JoinHandle<Result<(), String>> {
        let names = self.source.plant.flags();
        let writes = flags
            .into_iter()
            .filter_map(|(k, v)| {
                let node = self.nodes.flags.get(k)?.clone()?;
                Some((names.get(k)?.to_string(), node, v))
            })
            .collect();
        tokio::spawn(write_flags(self.ua.clone(), writes))
    }
}

/// The connection is gone: the plant is lost, and the connection opened again.
fn lost(session: &mut Session, why: &str, out: &mut Vec<Item>, send: &mut Vec<Command>) {
    session.disconnected(why, out);
    send.push(Command::Reopen);
}

/// The result of the flag write under way; never, if none is.
async fn finished(
    write: &mut Option<tokio::task::JoinHandle<Result<(), String>>>,
) -> Result<(), String> {
    match write {
        Some(w) => w
            .await
            .unwrap_or_else(|e| Err(format!("the write failed ({e})"))),
        None => std::future::pending().await,
    }
}

/// Writes flag values to their variables (name, node, value), in one Write:
/// `Err` names each refused, with the server's reason.
async fn write_flags(
    ua: Arc<UaSession>,
    writes: Vec<(String, NodeId, bool)>,
) -> Result<(), String> {
    let values: Vec<WriteValue> = writes
        .iter()
        .map(|(_, node, v)| WriteValue {
            node_id: node.clone(),
            attribute_id: AttributeId::Value as u32,
            index_range: NumericRange::None,
            // No timestamps: some servers refuse a write that carries them.
            value: DataValue {
                value: Some(Variant::Boolean(*v)),
                ..DataValue::default()
            },
        })
        .collect();
    let results = ua.write(&values).await.map_err(|e| e.to_string())?;
    let refused: Vec<String> = writes
        .iter()
        .enumerate()
        .filter_map(|(i, (name, _, _))| match results.get(i) {
            Some(s) if s.is_good() => None,
            Some(s) => Some(format!("{name}: {s}")),
            None => Some(format!("{name}: no answer")),
        })
        .collect();
    if refused.is_empty() {
        Ok(())
    } else {
        Err(refused.join(", "))
    }
}

/// Each signal's and flag's variable: the plant file's `[opcua]` NodeId, or
/// found by browse name.
async fn find(source: &OpcuaSource, ua: &UaSession) -> Result<Nodes, Opening> {
    let url = &source.url;
    let plant = &source.plant;
    let signals: Vec<String> = plant.signals.iter().map(|(_, s)| s.name.clone()).collect();
    let flags: Vec<String> = plant.flags().iter().map(ToString::to_string).collect();
    let namespaces = if plant.opcua.iter().any(|e| e.node_id.starts_with("nsu=")) {
        namespaces(ua).await?
    } else {
        Vec::new()
    };
    let mut mapped: HashMap<&str, NodeId> = HashMap::new();
    for e in &plant.opcua {
        let node = node_id(&e.node_id, &namespaces).map_err(|why| {
            Opening::Misfit(format!(
                "opcua {url}: [opcua] {} = \"{}\": {why}",
                e.name, e.node_id
            ))
        })?;
        mapped.insert(e.name.as_str(), node);
    }
    let wanted: Vec<&str> = signals
        .iter()
        .chain(&flags)
        .map(String::as_str)
        .filter(|n| !mapped.contains_key(n))
        .collect();
    let found = if wanted.is_empty() {
        HashMap::new()
    } else {
        browse(ua, &wanted, url).await?
    };
    let pick = |name: &str| -> Result<Option<NodeId>, Opening> {
        if let Some(node) = mapped.get(name) {
            return Ok(Some(node.clone()));
        }
        match found.get(name).map(Vec::as_slice) {
            None | Some([]) => Ok(None),
            Some([node]) => Ok(Some(node.clone())),
            Some(many) => {
                let list: Vec<String> = many.iter().map(ToString::to_string).collect();
                Err(Opening::Misfit(format!(
                    "opcua {url}: {} variables are named {name} ({}): map it in the plant file's [opcua] table",
                    many.len(),
                    list.join(", ")
                )))
            }
        }
    };
    let mut signal_nodes = Vec::with_capacity(signals.len());
    let mut missing = Vec::new();
    for name in &signals {
        match pick(name)? {
            Some(node) => signal_nodes.push(node),
            None => missing.push(name.as_str()),
        }
    }
    if !missing.is_empty() {
        return Err(Opening::Misfit(format!(
            "opcua {url}: no variable for signal {}: a signal is the variable of its name up to {BROWSE_DEPTH} levels below the Objects folder, or the NodeId of the plant file's [opcua] table",
            missing.join(", ")
        )));
    }
    let flag_nodes = flags.iter().map(|f| pick(f)).collect::<Result<_, _>>()?;
    Ok(Nodes {
        signals: signal_nodes,
        flags: flag_nodes,
    })
}

/// A NodeId in its text form, a namespace URI (`nsu=`) looked up in the
/// server's namespace array.
fn node_id(text: &str, namespaces: &[String]) -> Result<NodeId, String> {
    let text = match text.strip_prefix("nsu=") {
        Some(rest) => {
            let (uri, id) = rest.split_once(';').ok_or("no ';' after nsu=")?;
            let ns = namespaces
                .iter()
                .position(|n| n == uri)
                .ok_or_else(|| format!("the server has no namespace {uri}"))?;
            format!("ns={ns};{id}")
        }
        None => text.to_string(),
    };
    NodeId::from_str(&text).map_err(|e| format!("not a NodeId ({e})"))
}

/// The server's namespace array.
async fn namespaces(ua: &UaSession) -> Result<Vec<String>, Opening> {
    let node: NodeId = VariableId::Server_NamespaceArray.into();
    let values = ua
        .read(
            &[ReadValueId::new_value(node)],
            TimestampsToReturn::Neither,
            0.0,
        )
        .await
        .map_err(|e| Opening::Failed(format!("cannot read the namespace array: {e}")))?;
    match values.first().and_then(|v| v.value.as_ref()) {
        Some(Variant::Array(a)) => Ok(a
            .values
            .iter()
            .map(|v| match v {
                Variant::String(s) => s.as_ref().to_string(),
                _ => String::new(),
            })
            .collect()),
        _ => Err(Opening::Failed("the server gave no namespace array".into())),
    }
}

/// The variables named as `wanted`, browsing the Objects folder's hierarchy
/// down to [`BROWSE_DEPTH`] levels: every node of each name.
async fn browse(
    ua: &UaSession,
    wanted: &[&str],
    url: &str,
) -> Result<HashMap<String, Vec<NodeId>>, Opening> {
    let filter = BrowseFilter::new_hierarchical()
        .node_class_mask(NodeClassMask::OBJECT | NodeClassMask::VARIABLE);
    let inner = filter.clone();
    // Objects of the standard's namespace (the Server object) hold no plant.
    let policy = move |item: &BrowseResultItem| -> Vec<BrowseDescription> {
        if item.depth() >= BROWSE_DEPTH {
            return Vec::new();
        }
        item.references()
            .iter()
            .filter(|r| r.node_class == NodeClass::Object && r.node_id.server_index == 0)
            .filter(|r| r.node_id.node_id.namespace != 0)
            .map(|r| inner.new_description_from_node(r.node_id.node_id.clone()))
            .collect()
    };
    let root = filter.new_description_from_node(ObjectId::ObjectsFolder.into());
    let stream = ua.browser().handler(policy).run(vec![root]);
    tokio::pin!(stream);
    let mut found: HashMap<String, Vec<NodeId>> = HashMap::new();
    let mut seen = 0usize;
    while let Some(item) = stream.next().await {
        let item = item.map_err(|e| Opening::Failed(format!("cannot browse the server: {e}")))?;
        seen += item.references().len();
        if seen > BROWSE_LIMIT {
            return Err(Opening::Misfit(format!(
                "opcua {url}: more than {BROWSE_LIMIT} nodes below the Objects folder: map the plant's variables in the plant file's [opcua] table"
            )));
        }
        for r in item.references() {
            let node = &r.node_id.node_id;
            if r.node_class != NodeClass::Variable
                || r.node_id.server_index != 0
                || node.namespace == 0
            {
                continue;
            }
            let name = r.browse_name.name.as_ref();
            if wanted.contains(&name) {
                let nodes = found.entry(name.to_string()).or_default();
                if !nodes.contains(node) {
                    nodes.push(node.clone());
                }
            }
        }
    }
    Ok(found)
}

/// The instant now, as the session takes it.
fn now() -> std::time::Instant {
    Instant::now().into_std()
}

/// Sends the items gathered; false once the monitor has gone or a fatal
/// item went out.
async fn deliver(link: &Link, out: &mut Vec<Item>) -> bool {
    for item in out.drain(..) {
        let fatal = matches!(item, Item::Fatal(_));
        if link.items.send(item).await.is_err() || fatal {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_read_with_their_port() {
        assert_eq!(
            parse_url("opc.tcp://127.0.0.1:4841"),
            Ok("opc.tcp://127.0.0.1:4841/".into())
        );
        assert_eq!(parse_url("opc.tcp://plc"), Ok("opc.tcp://plc:4840/".into()));
        assert_eq!(
            parse_url("opc.tcp://[::1]:4840/UA/Line"),
            Ok("opc.tcp://[::1]:4840/UA/Line".into())
        );
        assert_eq!(
            parse_url("opc.tcp://[::1]"),
            Ok("opc.tcp://[::1]:4840/".into())
        );
        for (bad, why) in [
            ("plc:4840", "expected opc.tcp://"),
            ("opc.https://plc:443", "expected opc.tcp://"),
            ("opc.tcp://plc:http", "port 'http'"),
            ("opc.tcp://:4840", "expected opc.tcp://HOST:PORT"),
            ("opc.tcp://plc:0", "expected opc.tcp://HOST:PORT"),
        ] {
            let m = parse_url(bad).expect_err(bad);
            assert!(m.contains(why), "{bad}: {m}");
        }
    }

    #[test]
    fn node_ids_by_namespace_uri_are_looked_up() {
        let namespaces = [
            "http://opcfoundation.org/UA/".to_string(),
            "urn:line".into(),
        ];
        assert_eq!(
            node_id("nsu=urn:line;s=Line.C4", &namespaces),
            Ok(NodeId::new(1, "Line.C4"))
        );
        assert_eq!(node_id("ns=3;i=1042", &[]), Ok(NodeId::new(3, 1042u32)));
        assert!(
            node_id("nsu=urn:other;s=C4", &namespaces)
                .unwrap_err()
                .contains("no namespace urn:other")
        );
    }

    #[test]
    fn the_publishing_interval_is_half_the_lateness_in_wall_time() {
        let ms = diagnoser::MS;
        assert_eq!(
            publishing_interval(100 * ms, 1.0),
            Duration::from_millis(50)
        );
        assert_eq!(
            publishing_interval(500 * ms, 5.0),
            Duration::from_millis(50)
        );
        assert_eq!(publishing_interval(0, 1.0), Duration::from_millis(10));
        assert_eq!(
            publishing_interval(60_000 * ms, 1.0),
            Duration::from_secs(1)
        );
    }
}
