//! A monitor's plant on NATS JetStream (`monitor --nats URL`): every event
//! as read, every verdict line and the flags, on the subjects and in the
//! payloads of [`record`], so that the stream is the plant's archive.
//!
//! The monitor never waits for the broker. What it hands over goes to an
//! [`outbox::Outbox`], and a task of its own publishes the outbox in order,
//! one message at a time, each acknowledged by JetStream before the next
//! goes. Each message carries a JetStream message id (`Nats-Msg-Id`: the
//! plant, the run, the message's number), so a message sent again after a
//! lost acknowledgement is stored once. While the broker is away the outbox
//! fills, in memory and then in a file of its own, up to its bound; beyond,
//! messages are dropped and counted, with a warning. When the broker comes
//! back, the outbox goes out in order.
//!
//! The streams are made on first connection if missing: file storage,
//! limits retention without limits (an archive; set limits on the streams
//! with the NATS tools), and a duplicate window of [`DUPLICATE_WINDOW`].

pub mod models;
pub mod outbox;
pub mod record;

use std::path::PathBuf;
use std::time::Duration;

use async_nats::jetstream::{self, message::PublishMessage, stream};
use diagnoser::{Failure, Plant, Time, TimeFormat};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use self::outbox::{Message, Outbox, Refused};
use self::record::{EventWriter, STREAMS, Subjects};
use crate::monitor::source::Item;

/// How long JetStream remembers a message id: a message sent again within
/// it is stored once. A broker away for longer may store a message twice.
pub const DUPLICATE_WINDOW: Duration = Duration::from_secs(600);
/// How long a publication waits for its acknowledgement before it is sent
/// again.
const ACK_WAIT: Duration = Duration::from_secs(2);
/// Wait before trying again after a failure.
const RETRY_EVERY: Duration = Duration::from_millis(250);
/// How long connecting waits for the server.
const CONNECT_WAIT: Duration = Duration::from_secs(5);
/// Messages kept in memory before the outbox spills to disk.
const IN_MEMORY: usize = 4096;

/// Connects to the server at `url` (`nats://HOST:PORT`), waiting at most
/// [`CONNECT_WAIT`].
pub async fn connect(url: &str) -> Result<jetstream::Context, Failure> {
    let client = tokio::time::timeout(CONNECT_WAIT, async_nats::connect(url))
        .await
        .map_err(|_| {
            Failure::Io(format!(
                "nats {url}: no answer within {} s",
                CONNECT_WAIT.as_secs()
            ))
        })?
        .map_err(|e| Failure::Io(format!("nats {url}: {e}")))?;
    Ok(jetstream::new(client))
}

/// Where and how to publish.
#[derive(Debug, Clone)]
pub struct Settings {
    /// The server: `nats://HOST:PORT`.
    pub url: String,
    /// The plant's name in the subjects.
    pub plant: String,
    /// The outbox's file, used while the broker is away.
    pub outbox: PathBuf,
    /// Bytes the outbox may hold.
    pub outbox_bytes: u64,
}

/// The monitor's side: hands messages to the publishing task.
pub struct Publisher {
    tx: mpsc::UnboundedSender<Message>,
    next: u64,
    subjects: Subjects,
    events: EventWriter,
    task: JoinHandle<Summary>,
}

/// What the publishing task did.
#[derive(Debug, Default, Clone, Copy)]
pub struct Summary {
    /// Messages acknowledged.
    pub published: u64,
    /// Messages the broker had already (sent again after a lost
    /// acknowledgement).
    pub duplicates: u64,
    /// Messages dropped, the outbox full.
    pub dropped: u64,
    /// Messages still in the outbox when the task ended.
    pub left: usize,
}

impl Publisher {
    /// Starts publishing `plant`, whose verdicts print times as `time`, as
    /// `settings` say, on the current runtime.
    pub fn start(
        settings: Settings,
        plant: &Plant,
        time: TimeFormat,
    ) -> Result<Publisher, Failure> {
        let subjects = Subjects::of(&settings.plant)
            .map_err(|e| Failure::bad(format!("--nats-plant: {e}")))?;
        let (tx, rx) = mpsc::unbounded_channel();
        // The run's name: message numbers start again at 0 with every run.
        let run = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let ids = format!("{}-{run}-{}", settings.plant, std::process::id());
        let task = tokio::spawn(publish(settings, ids, rx));
        Ok(Publisher {
            tx,
            next: 0,
            subjects,
            events: EventWriter::new(plant, time),
            task,
        })
    }

    fn send(&mut self, subject: &str, payload: Vec<u8>) {
        let m = Message {
            seq: self.next,
            subject: subject.to_string(),
            payload,
        };
        self.next += 1;
        let _ = self.tx.send(m);
    }

    /// What the source showed, if the stream keeps it.
    pub fn item(&mut self, item: &Item) {
        if let Some(payload) = self.events.item(item) {
            let subject = self.subjects.events.clone();
            self.send(&subject, payload);
        }
    }

    /// A verdict line.
    pub fn verdict(&mut self, line: &str) {
        let subject = self.subjects.verdicts.clone();
        self.send(&subject, line.as_bytes().to_vec());
    }

    /// The flags up now, as the monitor writes them to the PLC, stamped
    /// with the time of the last event published.
    pub fn flags(&mut self, up: &[String]) {
        let subject = self.subjects.flags.clone();
        let payload = record::flags(self.events.last(), up);
        self.send(&subject, payload);
    }

    /// The monitor stops at `t`; waits up to `within` for the outbox to go.
    /// `None`: it had not gone by then, and what was left is lost.
    pub async fn finish(mut self, t: Time, within: Duration) -> Option<Summary> {
        let payload = self.events.end(t);
        let subject = self.subjects.events.clone();
        self.send(&subject, payload);
        let Publisher { tx, task, .. } = self;
        drop(tx);
        let abort = task.abort_handle();
        match tokio::time::timeout(within, task).await {
            Ok(Ok(summary)) => Some(summary),
            _ => {
                abort.abort();
                None
            }
        }
    }
}

/// The publishing task: until the monitor is done and the outbox empty.
async fn publish(
    settings: Settings,
    ids: String,
    mut rx: mpsc::UnboundedReceiver<Message>,
) -> Summary {
    let mut summary = Summary::default();
    // Checked by `Publisher::start`.
    let Ok(subjects) = Subjects::of(&settings.plant) else {
        return summary;
    };
    let mut outbox = Outbox::new(settings.outbox.clone(), IN_MEMORY, settings.outbox_bytes);
    let client = async_nats::ConnectOptions::new()
        .retry_on_initial_connect()
        .max_reconnects(None)
        .connection_timeout(Duration::from_secs(2))
        .reconnect_delay_callback(|n| Duration::from_millis((100 * n as u64).min(1000)))
        .connect(settings.url.as_str())
        .await;
    let client = match client {
        Ok(c) => c,
        Err(e) => {
            eprintln!("warning: nats {}: {e}; nothing is published", settings.url);
            return summary;
        }
    };
    let mut js = jetstream::new(client);
    js.set_timeout(ACK_WAIT);
    let mut state = Broker::new(&settings);
    let mut open = true;
    loop {
        open &= take(&mut rx, &mut outbox, &mut summary, &mut state);
        if !state.streams {
            state.streams = make_streams(&js, &subjects)
                .await
                .map_err(|e| state.trouble(&e))
                .is_ok();
            if !state.streams {
                open &= wait(&mut rx, &mut outbox, &mut summary, &mut state).await;
                continue;
            }
        }
        let front = match outbox.front() {
            Ok(f) => f.cloned(),
            Err(e) => {
                eprintln!(
                    "warning: nats outbox {}: {e}; the messages in it are lost",
                    settings.outbox.display()
                );
                outbox = Outbox::new(settings.outbox.clone(), IN_MEMORY, settings.outbox_bytes);
                continue;
            }
        };
        let Some(m) = front else {
            if !open {
                break;
            }
            // Nothing to send: wait for the monitor.
            match rx.recv().await {
                Some(m) => take_one(m, &mut outbox, &mut summary, &mut state),
                None => open = false,
            }
            continue;
        };
        match send(&js, &ids, &m).await {
            Ok(duplicate) => {
                outbox.pop();
                summary.published += 1;
                summary.duplicates += u64::from(duplicate);
                state.back();
            }
            Err(e) => {
                state.trouble(&e);
                open &= wait(&mut rx, &mut outbox, &mut summary, &mut state).await;
            }
        }
    }
    summary.left = outbox.len();
    summary
}

/// Whether the broker is there, and what has been said about it.
struct Broker {
    url: String,
    streams: bool,
    failing: bool,
    full: bool,
}

impl Broker {
    fn new(settings: &Settings) -> Broker {
        Broker {
            url: settings.url.clone(),
            streams: false,
            failing: false,
            full: false,
        }
    }

    /// A failure to publish: said once, until publishing works again.
    fn trouble(&mut self, why: &str) {
        if !std::mem::replace(&mut self.failing, true) {
            eprintln!(
                "warning: nats {}: {why}; the monitor goes on and keeps what it could not publish",
                self.url
            );
        }
    }

    fn back(&mut self) {
        if std::mem::replace(&mut self.failing, false) {
            eprintln!("monitor: nats {}: publishing again", self.url);
        }
        self.full = false;
    }
}

/// Puts one message handed over in the outbox, or counts it dropped.
fn take_one(m: Message, outbox: &mut Outbox, summary: &mut Summary, state: &mut Broker) {
    match outbox.push(m) {
        Ok(()) => {}
        Err(Refused::Full) => {
            summary.dropped += 1;
            if !std::mem::replace(&mut state.full, true) {
                eprintln!(
                    "warning: nats {}: the outbox is full ({} bytes): messages are dropped until the broker takes them",
                    state.url,
                    outbox.bytes()
                );
            }
        }
        Err(Refused::Io(e)) => {
            summary.dropped += 1;
            eprintln!("warning: nats outbox: {e}; a message is dropped");
        }
    }
}

/// Moves what the monitor handed over into the outbox, without waiting.
/// False once the monitor is done.
fn take(
    rx: &mut mpsc::UnboundedReceiver<Message>,
    outbox: &mut Outbox,
    summary: &mut Summary,
    state: &mut Broker,
) -> bool {
    loop {
        match rx.try_recv() {
            Ok(m) => take_one(m, outbox, summary, state),
            Err(mpsc::error::TryRecvError::Empty) => return true,
            Err(mpsc::error::TryRecvError::Disconnected) => return false,
        }
    }
}

/// Waits [`RETRY_EVERY`], taking what the monitor hands over meanwhile.
async fn wait(
    rx: &mut mpsc::UnboundedReceiver<Message>,
    outbox: &mut Outbox,
    summary: &mut Summary,
    state: &mut Broker,
) -> bool {
    let until = tokio::time::Instant::now() + RETRY_EVERY;
    loop {
        match tokio::time::timeout_at(until, rx.recv()).await {
            Ok(Some(m)) => take_one(m, outbox, summary, state),
            Ok(None) => {
                tokio::time::sleep_until(until).await;
                return false;
            }
            Err(_) => return true,
        }
    }
}

/// Publishes one message and waits for its acknowledgement: whether
/// JetStream had it already.
async fn send(js: &jetstream::Context, ids: &str, m: &Message) -> Result<bool, String> {
    let id = format!("{ids}-{}", m.seq);
    let publish = PublishMessage::build()
        .payload(m.payload.clone().into())
        .message_id(id);
    let ack = tokio::time::timeout(ACK_WAIT * 2, async {
        js.send_publish(m.subject.clone(), publish)
            .await
            .map_err(|e| e.to_string())?
            .await
            .map_err(|e| e.to_string())
    })
    .await
    .map_err(|_| "no acknowledgement".to_string())??;
    Ok(ack.duplicate)
}

/// Makes the streams that are missing: those every plant shares, and the
/// events stream of the plant of `subjects` (a monitor, on its first
/// connection; a fleet worker, as it takes a plant up).
pub async fn make_streams(js: &jetstream::Context, subjects: &Subjects) -> Result<(), String> {
    for (name, subject) in STREAMS {
        make_stream(js, name, subject).await?;
    }
    make_stream(js, &subjects.stream, &subjects.events).await
}

/// Makes the stream `name` of `subject`, if missing.
pub async fn make_stream(js: &jetstream::Context, name: &str, subject: &str) -> Result<(), String> {
    let config = stream::Config {
        name: name.to_string(),
        subjects: vec![subject.to_string()],
        storage: stream::StorageType::File,
        retention: stream::RetentionPolicy::Limits,
        duplicate_window: DUPLICATE_WINDOW,
        // A fleet worker reads a plant's last verdict line directly.
        allow_direct: true,
        ..stream::Config::default()
    };
    js.get_or_create_stream(config)
        .await
        .map_err(|e| format!("stream {name}: {e}"))?;
    Ok(())
}
