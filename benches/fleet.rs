//! The fleet at scale: many plants published live to one local `nats-server`,
//! diagnosed by 1, 2 and 4 workers (`gardefou fleet`, release build).
//!
//! Each plant replays one of the shipped runs of the sorting line (F1–F12),
//! from a point drawn so that its fault shows during the round, at the
//! line's own pace on the wall clock: its start, every scan, and a
//! watermark every 10 scan periods, in the monitor's payloads
//! (`runtime::jetstream::record`). With 2 workers or more, one worker is
//! killed (SIGKILL) half-way through, and the others take its plants over.
//!
//! Reports, per round: events published per second, the events the workers
//! diagnosed, the verdict latency from a message's publication to its
//! verdict line (p50, p99: each worker's, the worst given), the takeover
//! time (from the kill to the last plant taken up again), and the resident
//! memory of the workers per plant.
//!
//! ```text
//! cargo bench --bench fleet                 # 1000 plants, 60 s per round
//! PLANTS=200 SECONDS=20 WORKERS="2" cargo bench --bench fleet
//! STAGGER=1 KILL=0 cargo bench --bench fleet   # plants' clocks apart; no kill round
//! ```
//!
//! Needs `nats-server` (`GARDEFOU_NATS_SERVER`, or on PATH; `scripts/test`
//! installs one in target/peers/venv).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use datasets::inject::Injection;
use datasets::sim::SimConfig;
use datasets::sorting::simulate_in_memory;
use diagnoser::{Event, MS, Plant, Time, TimeFormat};
use runtime::jetstream::record::{EventWriter, Subjects, WATERMARK_SCANS};
use runtime::monitor::source::Item;

const MODEL: &str = "diagnoser/tests/fixtures/diagnosis/sorting-model.json";

/// A message: its time in the round, its payload, its events.
type Message = (Time, Vec<u8>, u64);
/// A plant's name and messages.
type Published = (String, Vec<Message>);

/// Simulated time before a plant's messages start: the line is up to speed.
const WARM_UP: Time = 120 * 1_000_000_000;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Plant `i`'s messages over `span` of its time: a simulated run of the
/// sorting line (seed `i`) with one of its faults from a time drawn in the
/// round; its start, every scan, a watermark every 10 scan periods, and its
/// end; each with its time and its events.
fn messages(plant: &Plant, i: usize, span: Time) -> Vec<Message> {
    let fault = &plant.faults[i % plant.faults.len()];
    let config = SimConfig {
        duration: WARM_UP + span,
        scan_period: plant.scan_period,
        seed: i as u64 + 1,
        faults: vec![Injection::new(
            fault.label.clone(),
            fault.template.clone(),
            WARM_UP + span / 10 + (i as Time * 7_919 * MS) % (span * 7 / 10),
        )],
    };
    let (log, _) = simulate_in_memory(&config).expect("a simulation");
    let mut writer = EventWriter::new(plant, TimeFormat::Numeric(plant.time_unit));
    let mut out = Vec::new();
    let mut values = log.initial.clone();
    let mut events = log.events.into_iter().peekable();
    while let Some(e) = events.next_if(|e| e.t <= WARM_UP) {
        values[e.signal.index()] = e.value;
    }
    // Times from the end of the warm-up: the round's clock.
    let mut t = 0;
    out.extend(writer.item(&Item::Start(t, values)).map(|p| (t, p, 0)));
    let mut events = events
        .map(|e| Event {
            t: e.t - WARM_UP,
            ..e
        })
        .peekable();
    let end = span;
    while t < end {
        t += plant.scan_period;
        let mut scan = Vec::new();
        while let Some(e) = events.next_if(|e| e.t <= t) {
            scan.push(e);
        }
        if let Some(at) = scan.first().map(|e| e.t) {
            let n = scan.len() as u64;
            out.extend(writer.item(&Item::Scan(scan)).map(|p| (at, p, n)));
        }
        out.extend(writer.item(&Item::Watermark(t)).map(|p| (t, p, 0)));
    }
    out.push((end, writer.end(end), 0));
    out
}

/// What a worker said at its end.
#[derive(Debug, Default, Clone)]
struct Said {
    events: u64,
    lines: u64,
    p50_us: Option<u64>,
    p99_us: Option<u64>,
    /// When each "taken up" line came.
    taken_up: Vec<Instant>,
    /// Plants taken up.
    served: usize,
    /// Plants given up (handed over, lease lost).
    given_up: usize,
}

fn spawn_worker(url: &str, names: &[String], plant: &Path, i: usize) -> (Child, Arc<Mutex<Said>>) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gardefou"));
    cmd.args([
        "fleet",
        "--nats",
        url,
        "--fleet",
        "bench",
        "--worker",
        &format!("w{i}"),
    ]);
    if let Ok(every) = std::env::var("CHECKPOINT_EVERY") {
        cmd.args(["--checkpoint-every", &every]);
    }
    for n in names {
        cmd.arg("--plant")
            .arg(plant)
            .arg("--model")
            .arg(repo(MODEL));
        cmd.args(["--nats-plant", n]);
    }
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("a worker starts");
    let said = Arc::new(Mutex::new(Said::default()));
    let err = child.stderr.take().expect("stderr");
    let s = said.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            let mut s = s.lock().expect("said");
            if line.contains("served here from") {
                s.served += 1;
            }
            if line.contains("handed over") || line.contains("no more lines from this worker") {
                s.given_up += 1;
            }
            if line.contains("served here from the checkpoint") {
                s.taken_up.push(Instant::now());
            } else if let Some(rest) = line.strip_prefix("fleet: ") {
                parse_summary(rest, &mut s);
            } else if std::env::var_os("VERBOSE").is_some() || line.starts_with("gardefou") {
                eprintln!("  worker {i}: {line}");
            }
        }
    });
    (child, said)
}

/// `N messages, E events, L verdict lines in S s; verdict latency from
/// publication: n N, p50 X µs, p99 Y µs, max Z µs`.
fn parse_summary(line: &str, s: &mut Said) {
    let num = |key: &str| -> Option<u64> {
        let i = line.find(key)?;
        line[..i].split_whitespace().last()?.parse().ok()
    };
    let after = |key: &str| -> Option<u64> {
        let i = line.find(key)? + key.len();
        line[i..].split_whitespace().next()?.parse().ok()
    };
    s.events = num(" events").unwrap_or(0);
    s.lines = num(" verdict lines").unwrap_or(0);
    s.p50_us = after("p50 ");
    s.p99_us = after("p99 ");
}

fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn nats_server(store: &Path, port: u16) -> Server {
    let bin = std::env::var("GARDEFOU_NATS_SERVER").unwrap_or_else(|_| {
        let venv = repo("target/peers/venv/bin/nats-server");
        if venv.exists() {
            venv.display().to_string()
        } else {
            "nats-server".into()
        }
    });
    let child = Command::new(&bin)
        .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
        .arg(store)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("{bin}: {e} (set GARDEFOU_NATS_SERVER)"));
    let until = Instant::now() + Duration::from_secs(10);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < until, "nats-server does not listen");
        std::thread::sleep(Duration::from_millis(50));
    }
    Server(child)
}

/// Publishes every plant's messages on the wall clock from `t0`; gives
/// the events published.
fn publish(url: &str, plants: &[Published], t0: Instant, period: Time) -> u64 {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    rt.block_on(async {
        let client = async_nats::connect(url).await.expect("connects");
        let js = async_nats::jetstream::new(client.clone());
        for (name, _) in plants {
            let subjects = Subjects::of(name).expect("a plant's name");
            runtime::jetstream::make_streams(&js, &subjects)
                .await
                .expect("the streams");
        }
        let mut next = vec![0usize; plants.len()];
        // With STAGGER=1, each plant's clock is shifted by a part of the
        // watermark period: monitors started at different times, not in
        // lockstep (all their watermarks within the same few ms).
        let phase: Vec<Time> = (0..plants.len())
            .map(|p| {
                if env_or("STAGGER", 0u8) == 1 {
                    (p as Time * 7_919 * MS / 10) % period
                } else {
                    0
                }
            })
            .collect();
        let mut events = 0u64;
        let mut tick = tokio::time::interval(Duration::from_millis(5));
        loop {
            tick.tick().await;
            let now = t0.elapsed().as_nanos() as Time;
            let mut left = false;
            for (p, (name, msgs)) in plants.iter().enumerate() {
                let subject = format!("gardefou.events.{name}");
                while let Some((t, payload, n)) = msgs.get(next[p]) {
                    if *t + phase[p] > now {
                        break;
                    }
                    client
                        .publish(subject.clone(), payload.clone().into())
                        .await
                        .expect("publishes");
                    events += n;
                    next[p] += 1;
                }
                left |= next[p] < msgs.len();
            }
            if !left {
                client.flush().await.expect("flushes");
                return events;
            }
        }
    })
}

/// One round: `workers` workers, all given every plant; with `kill`, the
/// first is killed half-way.
fn round(
    workers: usize,
    kill: bool,
    names: &[String],
    plant_file: &Path,
    plants: &[Published],
    seconds: i64,
    period: Time,
) {
    let store = tempfile::tempdir().expect("temp dir");
    let port = free_port();
    let _server = nats_server(store.path(), port);
    let url = format!("nats://127.0.0.1:{port}");
    let mut children: Vec<(Child, Arc<Mutex<Said>>)> = (0..workers)
        .map(|i| spawn_worker(&url, names, plant_file, i))
        .collect();
    // Publishing starts once every plant is served.
    let started = Instant::now();
    let serving = || {
        children
            .iter()
            .map(|(_, s)| {
                let s = s.lock().expect("said");
                s.served.saturating_sub(s.given_up)
            })
            .sum::<usize>()
    };
    // ... and has been for a second.
    let mut steady = 0;
    while steady < 20 && started.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(50));
        steady = if serving() == names.len() {
            steady + 1
        } else {
            0
        };
    }
    let startup = started.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let killed_at: Arc<Mutex<Option<Instant>>> = Arc::new(Mutex::new(None));
    let rss: Arc<Mutex<u64>> = Arc::new(Mutex::new(0));
    let pids: Vec<u32> = children.iter().map(|(c, _)| c.id()).collect();
    let victim = (kill && workers > 1).then(|| pids[0]);
    {
        let (killed_at, rss, pids) = (killed_at.clone(), rss.clone(), pids.clone());
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs(seconds as u64 / 2));
            *rss.lock().expect("rss") = pids.iter().map(|&p| rss_kb(p)).sum();
            if let Some(pid) = victim {
                // SAFETY: kill(2) on a child's pid.
                unsafe { libc::kill(pid as i32, libc::SIGKILL) };
                *killed_at.lock().expect("kill time") = Some(Instant::now());
            }
        });
    }
    let events = publish(&url, plants, t0, period);
    let published_in = t0.elapsed().as_secs_f64();
    let mut said = Vec::new();
    for (c, s) in children.iter_mut() {
        let _ = c.wait();
        said.push(s.lock().expect("said").clone());
    }
    let survivors: Vec<&Said> = said.iter().skip(usize::from(victim.is_some())).collect();
    let diagnosed: u64 = survivors.iter().map(|s| s.events).sum();
    let p99 = survivors.iter().filter_map(|s| s.p99_us).max();
    let p50 = survivors.iter().filter_map(|s| s.p50_us).max();
    let lines: u64 = survivors.iter().map(|s| s.lines).sum();
    let takeover = killed_at.lock().expect("kill time").map(|k| {
        survivors
            .iter()
            .flat_map(|s| s.taken_up.iter())
            .filter(|&&t| t > k)
            .max()
            .map_or(f64::NAN, |t| (*t - k).as_secs_f64())
    });
    let rss = *rss.lock().expect("rss");
    println!(
        "| {} | {workers} | {} | {startup:.1} | {:.0} | {} | {lines} | {} | {} | {} | {:.0} |",
        names.len(),
        if victim.is_some() { "yes" } else { "no" },
        events as f64 / published_in,
        diagnosed,
        p50.map_or("-".into(), |v| format!("{:.1}", v as f64 / 1000.0)),
        p99.map_or("-".into(), |v| format!("{:.1}", v as f64 / 1000.0)),
        takeover.map_or("-".into(), |t| format!("{t:.2}")),
        rss as f64 / names.len() as f64,
    );
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let count: usize = env_or("PLANTS", 1000);
    let seconds: i64 = env_or("SECONDS", 60);
    let rounds: Vec<usize> = std::env::var("WORKERS")
        .unwrap_or_else(|_| "1 2 4".into())
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    let plant_file = repo("datasets/data/sorting/F2/plant.toml");
    let plant = Plant::from_path(&plant_file).expect("the plant");
    let names: Vec<String> = (0..count).map(|i| format!("p{i:05}")).collect();
    let span = seconds * 1_000_000_000;
    let clock = Instant::now();
    let plants: Vec<Published> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.clone(), messages(&plant, i, span)))
        .collect();
    eprintln!(
        "simulated {count} plants in {:.1} s",
        clock.elapsed().as_secs_f64()
    );
    println!(
        "{count} plants, {seconds} s per round; latency in ms; memory in kB per plant (resident, all workers)"
    );
    println!(
        "| plants | workers | one killed | all served after (s) | events/s published | events diagnosed | verdict lines | p50 | p99 | takeover (s) | RSS/plant |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for w in rounds {
        let period = plant.scan_period * WATERMARK_SCANS;
        round(w, false, &names, &plant_file, &plants, seconds, period);
        if w > 1 && env_or("KILL", 1u8) == 1 {
            round(w, true, &names, &plant_file, &plants, seconds, period);
        }
    }
}
