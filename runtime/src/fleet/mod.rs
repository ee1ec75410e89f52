//! Fleet workers (`gardefou fleet`): the diagnosers of many plants run out
//! of their streams on NATS JetStream, with no PLC attached, shared between
//! workers and taken over when one dies.
//!
//! Each plant a worker is given runs as a task of its own:
//!
//! 1. it takes the plant's lease ([`lease`]: one worker at a time, the plant's
//!    preferred live worker first, see [`members`]), or waits;
//! 2. it reads the plant's [`plant::Checkpoint`] from the key-value bucket
//!    `gardefou-FLEET-checkpoints`, and the number of the last verdict line
//!    on `gardefou.fleet.FLEET.PLANT`;
//! 3. it follows the stream `GARDEFOU_EVENTS_PLANT` with an ordered consumer from the
//!    message after the checkpoint, feeds the records to the diagnosers
//!    ([`plant::PlantRun`]), publishes each verdict line not yet published
//!    (message id: fleet, plant, line number) and, once JetStream has it,
//!    prints it;
//! 4. every [`Settings::checkpoint_every`], it writes the checkpoint, with a
//!    compare-and-set on its revision: a worker that finds it moved has lost
//!    the plant, and stops.
//!
//! A killed worker's name expires from the live workers, which frees its
//! leases; the next worker restores the checkpoint, reads again what followed, and
//! skips the lines already published: the lines come out once, as one
//! uninterrupted run gives them. (A worker killed while a line is being
//! published, before its acknowledgement and its write to stdout, leaves
//! that line on the stream only.)
//!
//! Without [`Settings::duration`], a worker stops once every plant it was
//! given has ended (its monitor stopped); with it, it stops then, and gives
//! its plants back after a last checkpoint, so that another takes them at
//! once.

pub mod lease;
pub mod members;
pub mod plant;
pub mod view;

use std::io::Write;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_nats::HeaderMap;
use async_nats::jetstream::{
    self, consumer::DeliverPolicy, consumer::pull::OrderedConfig, kv, message::PublishMessage,
};
use diagnoser::diagnosis::fusion::PLANT_VIEW;
use diagnoser::diagnosis::{DiagnoserOptions, PlantDiagnoser, Verdict};
use diagnoser::{Failure, TimeFormat};
use futures_util::StreamExt;
use tokio::sync::watch;
use tokio::time::Instant;

use self::lease::{Table, Taken};
use self::plant::{Checkpoint, PlantRun, Resumed};
use self::view::View;
use crate::jetstream::connect;
use crate::jetstream::models::{self, Change};
use crate::jetstream::record::{self, Record, Subjects};

/// Wait before trying again after the broker failed a plant's task.
const RETRY_EVERY: Duration = Duration::from_millis(500);
/// Plants taken up at once: a worker starting with a thousand plants makes
/// their consumers a few at a time.
const STARTING: usize = 64;
/// A plant's versions as its task sees them: the latest, or `None` once its
/// model is removed from the store.
type Versions = watch::Receiver<Option<Arc<Served>>>;
/// The plants of the store served, each with the sender of its versions.
type StorePlants = std::collections::HashMap<String, watch::Sender<Option<Arc<Served>>>>;
/// The header with a fleet verdict line's number.
pub const LINE_HEADER: &str = "Gardefou-Line";

/// A plant a worker may serve: its name in the subjects, its plant file,
/// its model and the model's version (named in every verdict line).
pub type Served = crate::jetstream::models::Version;

pub use crate::jetstream::models::model_version;

/// Settings of one worker.
#[derive(Debug, Clone)]
pub struct Settings {
    /// The server: `nats://HOST:PORT`.
    pub url: String,
    /// The fleet's name: its buckets and its verdict subjects. Workers of
    /// one fleet share its plants.
    pub fleet: String,
    /// This worker's name, in the leases.
    pub worker: String,
    /// The plants this worker may serve; empty: every plant of the model
    /// store ([`crate::jetstream::models`]), each at its latest version.
    pub plants: Vec<Served>,
    /// How often a plant's checkpoint is written.
    pub checkpoint_every: Duration,
    /// Wall-clock time after which the worker stops, if any.
    pub duration: Option<Duration>,
    /// Where to serve the fleet view (`/status`, `/metrics`, `/`), if at all.
    pub http: Option<SocketAddr>,
    /// The diagnosers' options.
    pub options: DiagnoserOptions,
}

/// The fleet's buckets and subjects.
#[derive(Debug, Clone)]
struct Names {
    workers: String,
    leases: String,
    checkpoints: String,
    fleet: String,
}

impl Names {
    fn of(fleet: &str) -> Result<Names, String> {
        // The fleet's name is checked as a plant's is: one subject token.
        Subjects::of(fleet).map_err(|e| e.replace("plant's", "fleet's"))?;
        Ok(Names {
            workers: format!("gardefou-{fleet}-workers"),
            leases: format!("gardefou-{fleet}-leases"),
            checkpoints: format!("gardefou-{fleet}-checkpoints"),
            fleet: fleet.to_string(),
        })
    }

    fn verdicts(&self, plant: &str) -> String {
        format!("gardefou.fleet.{}.{plant}", self.fleet)
    }
}

/// What the plants' tasks share.
struct Shared {
    js: jetstream::Context,
    /// `GARDEFOU_FLEET`.
    verdicts: jetstream::stream::Stream,
    /// Plants being taken up at once (their checkpoint read, their consumer
    /// made), at most [`STARTING`].
    starting: tokio::sync::Semaphore,
    leases: kv::Store,
    checkpoints: kv::Store,
    names: Names,
    settings: Settings,
    stop: watch::Receiver<bool>,
    /// The fleet's live workers, sorted.
    live: watch::Receiver<Vec<String>>,
    /// When this worker's name was last written.
    written: Arc<Mutex<Option<Instant>>>,
    /// Every plant's lease.
    table: Table,
    /// Counts changes of the leases and of the live workers.
    changes: watch::Receiver<u64>,
    out: Mutex<Box<dyn Write + Send>>,
    view: Arc<Mutex<View>>,
}

impl Shared {
    /// Whether a plant's task ends with the plant (its monitor stopped): for
    /// plants given, without [`Settings::duration`]. Plants of the store are
    /// served until the worker stops, as a plant may start again.
    fn until_end(&self) -> bool {
        self.settings.duration.is_none() && !self.settings.plants.is_empty()
    }

    /// Whether `plant` prefers this worker among the live ones.
    fn mine(&self, plant: &str) -> bool {
        let live = self.live.borrow();
        members::preferred(plant, &live).is_none_or(|w| w == self.settings.worker)
    }

    /// Whether `worker` is alive.
    fn is_live(&self, worker: &str) -> bool {
        self.live.borrow().iter().any(|w| w == worker)
    }

    /// Whether this worker is surely still taken for alive: its name was
    /// written less than [`lease::TTL`] less [`lease::MARGIN`] ago.
    fn alive(&self) -> bool {
        self.written
            .lock()
            .ok()
            .and_then(|w| *w)
            .is_some_and(|at| at.elapsed() < lease::TTL - lease::MARGIN)
    }

    /// Why this worker may no longer hold `plant`'s lease, if it may not.
    fn lost(&self, plant: &str) -> Option<String> {
        if !self.alive() {
            return Some("this worker's name was not written in time".into());
        }
        let holder = self.table.get(plant).and_then(|s| s.holder);
        (holder.as_deref() != Some(self.settings.worker.as_str())).then(|| {
            format!(
                "the lease is {}",
                holder.map_or("given back".into(), |h| format!("held by {h}"))
            )
        })
    }
}

/// Runs a worker until every plant has ended, [`Settings::duration`], or a
/// signal. Verdict lines go to stdout.
pub fn run(settings: Settings) -> Result<(), Failure> {
    let names = Names::of(&settings.fleet).map_err(|e| Failure::bad(format!("--fleet: {e}")))?;
    for s in &settings.plants {
        Subjects::of(&s.name).map_err(|e| Failure::bad(format!("plant {}: {e}", s.name)))?;
    }
    Subjects::of(&settings.worker)
        .map_err(|e| Failure::bad(format!("--worker: {}", e.replace("plant's", "worker's"))))?;
    // Two threads: the plants' tasks keep one busy, and the worker's name
    // must still be written in time.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    runtime.block_on(work(settings, names))
}

async fn work(settings: Settings, names: Names) -> Result<(), Failure> {
    let url = settings.url.clone();
    let io = |e: String| Failure::Io(format!("nats {url}: {e}"));
    let js = connect(&settings.url).await?;
    for (name, subject) in record::STREAMS {
        crate::jetstream::make_stream(&js, name, subject)
            .await
            .map_err(io)?;
    }
    let bucket = |name: &str, max_age| kv::Config {
        bucket: name.to_string(),
        history: 1,
        max_age,
        storage: jetstream::stream::StorageType::File,
        ..kv::Config::default()
    };
    let leases = js
        .create_or_update_key_value(bucket(&names.leases, Duration::ZERO))
        .await
        .map_err(|e| io(format!("bucket {}: {e}", names.leases)))?;
    let checkpoints = js
        .create_or_update_key_value(bucket(&names.checkpoints, Duration::ZERO))
        .await
        .map_err(|e| io(format!("bucket {}: {e}", names.checkpoints)))?;
    // The worker's name goes on a connection of its own, so that it is not
    // queued behind the plants' traffic.
    let workers = connect(&settings.url)
        .await?
        .create_or_update_key_value(bucket(&names.workers, lease::TTL))
        .await
        .map_err(|e| io(format!("bucket {}: {e}", names.workers)))?;
    let (live_tx, live) = watch::channel(Vec::new());
    let written = Arc::new(Mutex::new(None));
    tokio::spawn(members::keep(
        workers,
        settings.worker.clone(),
        live_tx,
        written.clone(),
    ));
    let (changes_tx, changes) = watch::channel(0u64);
    let table = Table::follow(leases.clone(), changes_tx.clone())
        .await
        .map_err(io)?;
    let mut live_changes = live.clone();
    tokio::spawn(async move {
        while live_changes.changed().await.is_ok() {
            changes_tx.send_modify(|n| *n += 1);
        }
    });
    settle(live.clone()).await;
    let stream = |name: &'static str| {
        let js = js.clone();
        async move {
            js.get_stream(name)
                .await
                .map_err(|e| format!("stream {name}: {e}"))
        }
    };
    let verdicts = stream(record::FLEET_STREAM).await.map_err(io)?;
    let view = Arc::new(Mutex::new(View::new(&settings)));
    if let Some(addr) = settings.http {
        view::serve(addr, view.clone()).await?;
    }
    let (stop_tx, stop) = watch::channel(false);
    let shared = Arc::new(Shared {
        js,
        verdicts,
        starting: tokio::sync::Semaphore::new(STARTING),
        leases,
        checkpoints,
        names,
        settings: settings.clone(),
        stop,
        live,
        written,
        table,
        changes,
        out: Mutex::new(Box::new(std::io::stdout())),
        view,
    });
    let all_ended = if settings.plants.is_empty() {
        let store = models::store(&shared.js).await.map_err(io)?;
        tokio::spawn(from_store(shared.clone(), store))
    } else {
        tokio::spawn(given(shared.clone()))
    };
    tokio::pin!(all_ended);
    let stop_at = settings.duration.map(|d| Instant::now() + d);
    let mut terminate = crate::monitor::terminate_signal()?;
    let outcome = tokio::select! {
        results = &mut all_ended => Some(results),
        _ = sleep_until(stop_at) => None,
        _ = tokio::signal::ctrl_c() => None,
        _ = terminate.recv() => None,
    };
    let results = match outcome {
        Some(results) => results,
        None => {
            let _ = stop_tx.send(true);
            all_ended.await
        }
    };
    let failures: Vec<Failure> = results
        .unwrap_or_default()
        .into_iter()
        .filter_map(Result::err)
        .collect();
    let summary = shared.view.lock().map(|v| v.summary()).unwrap_or_default();
    eprintln!("fleet: {summary}");
    match failures.into_iter().next() {
        Some(f) => Err(f),
        None => Ok(()),
    }
}

/// The plants given, each a task of its own, until each has ended.
async fn given(shared: Arc<Shared>) -> Vec<Result<(), Failure>> {
    let mut versions = Vec::new();
    let tasks: Vec<_> = (shared.settings.plants.iter())
        .map(|s| {
            let (tx, rx) = watch::channel(Some(Arc::new(s.clone())));
            versions.push(tx);
            tokio::spawn(serve(shared.clone(), rx))
        })
        .collect();
    let results = futures_util::future::join_all(tasks).await;
    results.into_iter().filter_map(Result::ok).collect()
}

/// Every plant of the model store, each a task of its own, and each new
/// version given to its task, until the worker stops.
async fn from_store(
    shared: Arc<Shared>,
    store: async_nats::jetstream::object_store::ObjectStore,
) -> Vec<Result<(), Failure>> {
    let mut plants = StorePlants::new();
    let mut tasks = tokio::task::JoinSet::new();
    let mut results = Vec::new();
    let mut stop = shared.stop.clone();
    'watch: loop {
        let mut changes = match models::watch(&store).await {
            Ok(changes) => Box::pin(changes),
            Err(e) => {
                eprintln!("warning: fleet: {e}; trying again");
                pause(&shared, RETRY_EVERY).await;
                if *shared.stop.borrow() {
                    break 'watch;
                }
                continue;
            }
        };
        loop {
            tokio::select! {
                () = stopped(&mut stop) => break 'watch,
                Some(done) = tasks.join_next(), if !tasks.is_empty() => {
                    results.extend(done.ok());
                }
                change = changes.next() => match change {
                    Some(Ok(Change::Stored(name, version))) => {
                        if held_already(&plants, &name, version.as_deref()) {
                            continue;
                        }
                        match models::get(&store, &name).await {
                            Ok(Some(v)) => offer(&shared, &mut plants, &mut tasks, v),
                            Ok(None) => {}
                            Err(e) => eprintln!("warning: fleet: {e}; this version is not taken"),
                        }
                    }
                    Some(Ok(Change::Removed(name))) => {
                        if let Some(tx) = plants.get(&name) {
                            tx.send_replace(None);
                        }
                    }
                    Some(Err(e)) => {
                        eprintln!("warning: fleet: {e}; watching the store again");
                        break;
                    }
                    None => break,
                },
            }
        }
        pause(&shared, RETRY_EVERY).await;
    }
    while let Some(done) = tasks.join_next().await {
        results.extend(done.ok());
    }
    results
}

/// Whether plant `name`'s task already has `version` (then the object is not
/// read again, as when the store's watch starts over).
fn held_already(plants: &StorePlants, name: &str, version: Option<&str>) -> bool {
    plants
        .get(name)
        .filter(|tx| !tx.is_closed())
        .is_some_and(|tx| {
            tx.borrow()
                .as_ref()
                .is_some_and(|v| Some(v.version.as_str()) == version)
        })
}

/// A version read from the store: to its plant's task, or a new task for a
/// plant not served yet (or removed before).
fn offer(
    shared: &Arc<Shared>,
    plants: &mut StorePlants,
    tasks: &mut tokio::task::JoinSet<Result<(), Failure>>,
    v: Served,
) {
    if let Err(e) = Subjects::of(&v.name) {
        eprintln!(
            "warning: fleet: model store object {}: {e}; not served",
            v.name
        );
        return;
    }
    let v = Arc::new(v);
    if let Some(tx) = plants.get(&v.name).filter(|tx| !tx.is_closed()) {
        tx.send_if_modified(|now| {
            let same = now.as_ref().is_some_and(|n| n.version == v.version);
            if !same {
                *now = Some(v.clone());
            }
            !same
        });
        return;
    }
    if let Ok(mut view) = shared.view.lock() {
        view.add(&v.name, &v.version);
    }
    let (tx, rx) = watch::channel(Some(v.clone()));
    plants.insert(v.name.clone(), tx);
    tasks.spawn(serve(shared.clone(), rx));
}

/// Puts the version `next` in the place of `served`'s between two messages:
/// the diagnosers start again from the values read, every clock unknown
/// (see [`plant`]). `false`, with a warning, when it cannot take over; the
/// old version stays.
fn take_version(shared: &Shared, served: &Served, next: &Served, held: &mut Held) -> bool {
    let run = served.takes_over(next).and_then(|()| {
        let diagnoser = PlantDiagnoser::new(&next.plant, &next.model, &shared.settings.options)
            .map_err(|e| format!("model {} of plant {}: {e}", next.version, next.name))?;
        let mut run = PlantRun::new(diagnoser, next.plant.signals.len());
        run.restore(&held.run.checkpoint(&served.version, None), &next.version)?;
        Ok(run)
    });
    match run {
        Ok(run) => {
            eprintln!(
                "fleet: {}: model {} replaces {} after message {}: the diagnosers start again from the values read",
                served.name, next.version, served.version, held.run.seq
            );
            held.run = run;
            true
        }
        Err(e) => {
            eprintln!("warning: fleet: {e}; model {} stays", served.version);
            false
        }
    }
}

/// Waits until the live workers have been the same for two renewals (at
/// most [`lease::TTL`]): only then is it known which plants prefer this
/// worker, and workers started together do not take each other's plants.
async fn settle(mut live: watch::Receiver<Vec<String>>) {
    let quiet = lease::RENEW_EVERY * 2 + Duration::from_millis(100);
    let until = Instant::now() + lease::TTL;
    while Instant::now() < until {
        match tokio::time::timeout(quiet, live.changed()).await {
            Err(_) if !live.borrow().is_empty() => return,
            Ok(Err(_)) => return,
            _ => {}
        }
    }
}

async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Why a plant's following ended.
enum Followed {
    /// The plant's monitor stopped (without [`Settings::duration`]).
    Ended,
    /// The worker stops.
    Stopped,
    /// Another worker holds the plant now, or may.
    LeaseLost(String),
    /// A worker the plant prefers has joined: it takes the plant from the
    /// checkpoint just written.
    HandedOver,
    /// The plant's model was removed from the store.
    Removed,
}

/// How often a plant's task looks again at its lease with no change seen
/// (a plant left free long enough; a holder's name expired).
const LOOK_EVERY: Duration = Duration::from_millis(250);

/// One plant's task: takes the plant's lease when it is free and this
/// worker is the one it prefers, or when it has been free for
/// [`members::ORPHAN_WAIT`]; follows the plant while it holds it; ends when
/// the plant has ended (without [`Settings::duration`]) or the worker stops.
/// A bad message or checkpoint ends the task with an error; the broker's
/// troubles only delay it.
async fn serve(shared: Arc<Shared>, mut versions: Versions) -> Result<(), Failure> {
    let Some(key) = versions.borrow().as_ref().map(|s| s.name.clone()) else {
        return Ok(());
    };
    let until_end = shared.until_end();
    let mut changes = shared.changes.clone();
    let mut free_since: Option<Instant> = None;
    loop {
        if *shared.stop.borrow() {
            return Ok(());
        }
        let Some(served) = versions.borrow_and_update().clone() else {
            eprintln!("fleet: {key}: its model was removed from the store; not served any more");
            return Ok(());
        };
        let seen = shared.table.get(&key);
        let holder = seen.as_ref().and_then(|s| s.holder.clone());
        if until_end && holder.as_deref() == Some(lease::ENDED) {
            return Ok(());
        }
        let free = holder
            .as_deref()
            .is_none_or(|h| h == lease::ENDED || !shared.is_live(h));
        if !free {
            free_since = None;
        } else if shared.alive() {
            let mine = shared.mine(&key);
            let since = *free_since.get_or_insert_with(Instant::now);
            if mine || since.elapsed() >= members::ORPHAN_WAIT {
                let me = &shared.settings.worker;
                match lease::take(&shared.leases, &key, me, seen.as_ref()).await {
                    Ok(Taken::Held(revision)) => {
                        free_since = None;
                        let held = Holding { revision, mine };
                        if let Some(end) = hold(&shared, served, held, &mut versions).await? {
                            return Ok(end);
                        }
                    }
                    Ok(Taken::No) => {}
                    Err(why) => {
                        eprintln!("warning: fleet: {key}: {why}; trying again");
                        pause(&shared, RETRY_EVERY).await;
                    }
                }
                continue;
            }
        }
        tokio::select! {
            _ = tokio::time::timeout(LOOK_EVERY, changes.changed()) => {}
            Ok(()) = versions.changed() => {}
        }
    }
}

/// The lease of a plant this worker holds: its revision, and whether it
/// was taken as the plant's preferred worker.
#[derive(Debug, Clone, Copy)]
struct Holding {
    revision: u64,
    mine: bool,
}

/// Follows a plant held, and says what became of it: `Some(())` when the
/// task is over, `None` when the plant may be taken again later.
async fn hold(
    shared: &Shared,
    served: Arc<Served>,
    held: Holding,
    versions: &mut Versions,
) -> Result<Option<()>, Failure> {
    let key = &served.name.clone();
    let outcome = follow(shared, served, held, versions).await;
    view(shared, key, |p| p.served = false);
    match outcome {
        Ok(Followed::Ended) | Ok(Followed::Stopped) => Ok(Some(())),
        // The task's next look at its versions says so, and ends.
        Ok(Followed::Removed) => Ok(None),
        Ok(Followed::HandedOver) => {
            eprintln!("fleet: {key}: handed over to the worker it prefers");
            Ok(None)
        }
        Ok(Followed::LeaseLost(why)) => {
            eprintln!(
                "warning: fleet: {key}: {why}; no more lines from this worker until it holds the plant again"
            );
            Ok(None)
        }
        Err(Trouble::Broker(why)) => {
            eprintln!("warning: fleet: {key}: {why}; trying again");
            lease::give_back(&shared.leases, key, held.revision, "").await;
            pause(shared, RETRY_EVERY).await;
            Ok(None)
        }
        Err(Trouble::Moved(why)) => {
            eprintln!("warning: fleet: {key}: {why}; another worker has it");
            Ok(None)
        }
        Err(Trouble::Fatal(f)) => {
            lease::give_back(&shared.leases, key, held.revision, "").await;
            Err(f)
        }
    }
}

/// Until the worker stops.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|s| *s).await;
}

/// Waits `d`, or less if the worker stops.
async fn pause(shared: &Shared, d: Duration) {
    let mut stop = shared.stop.clone();
    let _ = tokio::time::timeout(d, stopped(&mut stop)).await;
}

fn view(shared: &Shared, plant: &str, f: impl FnOnce(&mut view::PlantView)) {
    if let Ok(mut v) = shared.view.lock()
        && let Some(p) = v.plant_mut(plant)
    {
        f(p);
    }
}

/// What stops a plant's following.
enum Trouble {
    /// The broker failed: the plant is given back, and taken again later.
    Broker(String),
    /// The checkpoint moved under this worker: another has the plant.
    Moved(String),
    /// The plant's data cannot be read: the worker stops.
    Fatal(Failure),
}

impl From<String> for Trouble {
    fn from(why: String) -> Trouble {
        Trouble::Broker(why)
    }
}

async fn read_checkpoint(shared: &Shared, key: &str) -> Result<Option<(Checkpoint, u64)>, Trouble> {
    let entry = shared
        .checkpoints
        .entry(key)
        .await
        .map_err(|e| format!("checkpoint: {e}"))?;
    let Some(entry) = entry.filter(|e| e.operation == kv::Operation::Put) else {
        return Ok(None);
    };
    let c: Checkpoint = serde_json::from_slice(&entry.value).map_err(|e| {
        Trouble::Fatal(Failure::bad(format!(
            "bucket {}, key {key}, revision {}: not a checkpoint ({e})",
            shared.names.checkpoints, entry.revision
        )))
    })?;
    Ok(Some((c, entry.revision)))
}

/// A plant held: where it was left, and what it has already said.
struct Held {
    run: PlantRun,
    time: TimeFormat,
    /// The checkpoint's revision (`None`: none written yet).
    revision: Option<u64>,
    /// The number of the last line on the stream.
    published: u64,
    /// The sequence of the last checkpoint written.
    written: u64,
}

/// Takes up the plant where its checkpoint left it.
async fn resume(shared: &Shared, served: &Served) -> Result<Held, Trouble> {
    let diagnoser = PlantDiagnoser::new(&served.plant, &served.model, &shared.settings.options)
        .map_err(|e| Trouble::Fatal(Failure::bad(format!("plant {}: {e}", served.name))))?;
    let mut run = PlantRun::new(diagnoser, served.plant.signals.len());
    let mut time = TimeFormat::Rfc3339;
    let mut revision = None;
    if let Some((c, rev)) = read_checkpoint(shared, &served.name).await? {
        let resumed = run.restore(&c, &served.version).map_err(|e| {
            Trouble::Fatal(Failure::bad(format!(
                "bucket {}, key {}: {e}",
                shared.names.checkpoints, served.name
            )))
        })?;
        time = c.time.as_deref().and_then(record::time_of).unwrap_or(time);
        revision = Some(rev);
        let how = match resumed {
            Resumed::Diagnosers => "its diagnosers restored".to_string(),
            Resumed::Restarted => format!(
                "model {} replacing {}: the diagnosers start again from the values there",
                served.version, c.model
            ),
            Resumed::NotStarted => "not started yet".to_string(),
        };
        eprintln!(
            "fleet: {}: served here from the checkpoint at message {} ({how})",
            served.name, c.seq
        );
    } else {
        eprintln!(
            "fleet: {}: served here from the stream's start",
            served.name
        );
    }
    let published = last_line(shared, &served.name).await?;
    let written = run.seq;
    Ok(Held {
        run,
        time,
        revision,
        published,
        written,
    })
}

/// The number of the plant's last verdict line on the fleet's stream.
async fn last_line(shared: &Shared, plant: &str) -> Result<u64, Trouble> {
    let (name, stream) = (record::FLEET_STREAM, &shared.verdicts);
    match stream
        .direct_get_last_for_subject(shared.names.verdicts(plant))
        .await
    {
        Ok(m) => Ok(m
            .headers
            .get(LINE_HEADER)
            .and_then(|v| v.as_str().parse().ok())
            .unwrap_or(0)),
        Err(e) if e.kind() == jetstream::stream::DirectGetErrorKind::NotFound => Ok(0),
        Err(e) => Err(Trouble::Broker(format!("stream {name}: {e}"))),
    }
}

/// Follows a plant held until it ends, the worker stops, or the lease is
/// lost. A plant taken as this worker's (`mine`) is handed over when a
/// worker it prefers joins.
async fn follow(
    shared: &Shared,
    served: Arc<Served>,
    holding: Holding,
    versions: &mut Versions,
) -> Result<Followed, Trouble> {
    let mut served = served;
    let key = &served.name.clone();
    let give_back =
        |value: &'static str| lease::give_back(&shared.leases, key, holding.revision, value);
    let started = shared.starting.acquire().await;
    let mut held = resume(shared, &served).await?;
    let until_end = shared.until_end();
    if until_end && held.run.event_time().ended {
        give_back(lease::ENDED).await;
        return Ok(Followed::Ended);
    }
    view(shared, &served.name, |p| p.served = true);
    let subjects = Subjects::of(&served.name).map_err(|e| Trouble::Fatal(Failure::bad(e)))?;
    let config = OrderedConfig {
        deliver_policy: DeliverPolicy::ByStartSequence {
            start_sequence: held.run.seq + 1,
        },
        ..OrderedConfig::default()
    };
    crate::jetstream::make_stream(&shared.js, &subjects.stream, &subjects.events).await?;
    let consumer = shared
        .js
        .get_stream(&subjects.stream)
        .await
        .map_err(|e| format!("stream {}: {e}", subjects.stream))?
        .create_consumer(config)
        .await
        .map_err(|e| format!("consumer of {}: {e}", subjects.events))?;
    let mut messages = consumer
        .messages()
        .await
        .map_err(|e| format!("consumer of {}: {e}", subjects.events))?;
    drop(started);
    let mut look = tokio::time::interval(LOOK_EVERY);
    let mut checkpoint = tokio::time::interval(shared.settings.checkpoint_every);
    let mut stop = shared.stop.clone();
    // Checkpoints are written beside the reading: a write's round trip does
    // not hold the plant's next message back.
    let mut writing: Option<Writing> = None;
    let mut watching = true;
    loop {
        tokio::select! {
            biased;
            () = stopped(&mut stop) => {
                settle_writing(&mut writing, shared, key, &mut held).await?;
                write_checkpoint(shared, &served, &mut held).await?;
                give_back("").await;
                return Ok(Followed::Stopped);
            }
            _ = look.tick() => {
                if let Some(why) = shared.lost(key) {
                    return Ok(Followed::LeaseLost(why));
                }
                if holding.mine && !shared.mine(key) {
                    settle_writing(&mut writing, shared, key, &mut held).await?;
                    write_checkpoint(shared, &served, &mut held).await?;
                    give_back("").await;
                    return Ok(Followed::HandedOver);
                }
            }
            changed = versions.changed(), if watching => {
                if changed.is_err() {
                    // The plant's versions are given once and for all.
                    watching = false;
                    continue;
                }
                let next = versions.borrow_and_update().clone();
                settle_writing(&mut writing, shared, key, &mut held).await?;
                let Some(next) = next else {
                    write_checkpoint(shared, &served, &mut held).await?;
                    give_back("").await;
                    return Ok(Followed::Removed);
                };
                if next.version != served.version && take_version(shared, &served, &next, &mut held) {
                    served = next;
                    write_checkpoint(shared, &served, &mut held).await?;
                    view(shared, key, |p| p.model = served.version.clone());
                }
            }
            _ = checkpoint.tick(), if writing.is_none() => {
                if held.run.seq != held.written {
                    writing = Some(Writing::start(shared, &served, &held)?);
                }
            }
            done = async { (&mut writing.as_mut().expect("a write under way").task).await }, if writing.is_some() => {
                let seq = writing.take().map_or(0, |w| w.seq);
                match done.map_err(|e| Trouble::Broker(format!("checkpoint: {e}")))? {
                    Ok(revision) => {
                        held.revision = Some(revision);
                        held.written = seq;
                        view(shared, key, |p| p.checkpointed());
                    }
                    Err(Trouble::Moved(why)) => return Ok(Followed::LeaseLost(why)),
                    Err(other) => return Err(other),
                }
            }
            message = messages.next() => {
                let Some(message) = message else {
                    return Err(Trouble::Broker(format!("the consumer of {} ended", subjects.events)));
                };
                let message = message.map_err(|e| format!("consumer of {}: {e}", subjects.events))?;
                if let Some(why) = shared.lost(key) {
                    return Ok(Followed::LeaseLost(why));
                }
                take(shared, &served, &mut held, &message).await?;
                if until_end && held.run.event_time().ended {
                    settle_writing(&mut writing, shared, key, &mut held).await?;
                    write_checkpoint(shared, &served, &mut held).await?;
                    give_back(lease::ENDED).await;
                    return Ok(Followed::Ended);
                }
            }
        }
    }
}

/// Takes in one message of the plant's stream: its verdict lines published
/// (those not yet on the stream), then printed.
async fn take(
    shared: &Shared,
    served: &Served,
    held: &mut Held,
    message: &jetstream::Message,
) -> Result<(), Trouble> {
    let info = message.info().map_err(|e| format!("message info: {e}"))?;
    let (seq, pending) = (info.stream_sequence, info.pending);
    let published_ns = info.published.unix_timestamp_nanos();
    let record = record::read(&message.payload, &served.plant).map_err(|e| {
        Trouble::Fatal(Failure::bad(format!(
            "nats stream GARDEFOU_EVENTS_{}, message {seq}: {e}",
            served.name
        )))
    })?;
    if let Record::Start(_, _, Some(time)) = &record {
        held.time = *time;
    }
    let (t, scan) = match &record {
        Record::Scan(events) => (events.first().map(|e| e.t), events.len() as u64),
        _ => (None, 0),
    };
    let first = held.run.lines + 1;
    let mut verdicts: Vec<Verdict> = Vec::new();
    held.run.take(seq, record, &mut |v| verdicts.push(v));
    // The message's lines go out together, and each is printed once
    // JetStream has it, in order: one round trip for them all.
    let mut sent = Vec::new();
    for (i, v) in verdicts.iter().enumerate() {
        let number = first + i as u64;
        if number <= held.published {
            continue;
        }
        if let Some(why) = shared.lost(&served.name) {
            return Err(Trouble::Moved(why));
        }
        let line = fleet_line(v, held.time, &served.name, &served.version);
        let ack = publish_line(shared, &served.name, number, &line).await?;
        sent.push((number, line, ack));
    }
    for (number, line, ack) in sent {
        tokio::time::timeout(Duration::from_secs(5), ack)
            .await
            .map_err(|_| "no acknowledgement of a verdict line".to_string())?
            .map_err(|e| format!("publish: {e}"))?;
        held.published = number;
        print(shared, &line)?;
    }
    let now_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    let latency = Duration::from_nanos((now_ns - published_ns).max(0) as u64);
    let view_line = verdicts.iter().rev().find(|v| v.part == PLANT_VIEW);
    if let Ok(mut v) = shared.view.lock() {
        v.count(scan, verdicts.len() as u64, latency);
        if let Some(p) = v.plant_mut(&served.name) {
            p.message(seq, pending, t.map(|t| view::time_value(t, held.time)));
            if let Some(line) = view_line {
                p.verdict(line, held.time);
            }
        }
    }
    Ok(())
}

/// A verdict's line as the fleet prints it: the monitor's, with the plant
/// and the model version after the time.
pub fn fleet_line(v: &Verdict, time: TimeFormat, plant: &str, model: &str) -> String {
    record::with_fields(
        &v.json_line(time, None),
        &[("plant", plant), ("model", model)],
    )
}

/// Sends verdict line `number` of `plant` to the fleet's stream; its
/// acknowledgement to come.
async fn publish_line(
    shared: &Shared,
    plant: &str,
    number: u64,
    line: &str,
) -> Result<jetstream::context::PublishAckFuture, Trouble> {
    let mut headers = HeaderMap::new();
    headers.insert(LINE_HEADER, number.to_string().as_str());
    let id = format!("{}.{plant}.{number}", shared.names.fleet);
    let message = PublishMessage::build()
        .payload(line.as_bytes().to_vec().into())
        .headers(headers)
        .message_id(id);
    let subject = shared.names.verdicts(plant);
    let ack = shared
        .js
        .send_publish(subject, message)
        .await
        .map_err(|e| format!("publish: {e}"))?;
    Ok(ack)
}

fn print(shared: &Shared, line: &str) -> Result<(), Trouble> {
    let Ok(mut out) = shared.out.lock() else {
        return Ok(());
    };
    writeln!(out, "{line}")
        .and_then(|()| out.flush())
        .map_err(|e| {
            Trouble::Fatal(if e.kind() == std::io::ErrorKind::BrokenPipe {
                Failure::Closed
            } else {
                Failure::Io(format!("stdout: {e}"))
            })
        })
}

/// The plant's checkpoint now, as the bucket keeps it.
fn checkpoint_bytes(served: &Served, held: &Held) -> Result<Vec<u8>, Trouble> {
    let time = Some(record::time_name(held.time).to_string());
    let c = held.run.checkpoint(&served.version, time);
    serde_json::to_vec(&c).map_err(|e| Trouble::Fatal(Failure::Io(e.to_string())))
}

/// Stores a checkpoint of plant `key` over the entry at `revision` (`None`:
/// none yet); its new revision. [`Trouble::Moved`] when the entry moved.
async fn store_checkpoint(
    bucket: kv::Store,
    key: String,
    bytes: Vec<u8>,
    revision: Option<u64>,
) -> Result<u64, Trouble> {
    let moved = |why: String| Trouble::Moved(format!("its checkpoint moved ({why})"));
    match revision {
        Some(rev) => bucket
            .update(&key, bytes.into(), rev)
            .await
            .map_err(|e| match e.kind() {
                kv::UpdateErrorKind::WrongLastRevision => moved(e.to_string()),
                _ => Trouble::Broker(format!("checkpoint: {e}")),
            }),
        None => bucket
            .create(&key, bytes.into())
            .await
            .map_err(|e| match e.kind() {
                kv::CreateErrorKind::AlreadyExists => moved(e.to_string()),
                _ => Trouble::Broker(format!("checkpoint: {e}")),
            }),
    }
}

/// A checkpoint on its way to the bucket, while the plant's messages go on
/// being read: the sequence it holds.
struct Writing {
    task: tokio::task::JoinHandle<Result<u64, Trouble>>,
    seq: u64,
}

impl Writing {
    /// Starts writing the plant's checkpoint now.
    fn start(shared: &Shared, served: &Served, held: &Held) -> Result<Writing, Trouble> {
        let bytes = checkpoint_bytes(served, held)?;
        let task = tokio::spawn(store_checkpoint(
            shared.checkpoints.clone(),
            served.name.clone(),
            bytes,
            held.revision,
        ));
        Ok(Writing {
            task,
            seq: held.run.seq,
        })
    }

    /// Waits for the write, and notes its revision.
    async fn finish(self, shared: &Shared, key: &str, held: &mut Held) -> Result<(), Trouble> {
        let revision = self
            .task
            .await
            .map_err(|e| Trouble::Broker(format!("checkpoint: {e}")))??;
        held.revision = Some(revision);
        held.written = self.seq;
        view(shared, key, |p| p.checkpointed());
        Ok(())
    }
}

/// Waits for the checkpoint being written, if any.
async fn settle_writing(
    writing: &mut Option<Writing>,
    shared: &Shared,
    key: &str,
    held: &mut Held,
) -> Result<(), Trouble> {
    match writing.take() {
        Some(w) => w.finish(shared, key, held).await,
        None => Ok(()),
    }
}

/// Writes the plant's checkpoint, if the revision is still the one read.
async fn write_checkpoint(
    shared: &Shared,
    served: &Served,
    held: &mut Held,
) -> Result<(), Trouble> {
    let bytes = checkpoint_bytes(served, held)?;
    let key = &served.name;
    let revision = store_checkpoint(
        shared.checkpoints.clone(),
        key.clone(),
        bytes,
        held.revision,
    )
    .await?;
    held.revision = Some(revision);
    held.written = held.run.seq;
    view(shared, key, |p| p.checkpointed());
    Ok(())
}
