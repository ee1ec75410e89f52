//! A fleet worker's view (`fleet --http ADDR`): every plant it was given,
//! with its current plant verdict, flags, last event time, consumer lag and
//! checkpoint age, as JSON (`/status`), as a page that refreshes (`/`), and
//! as Prometheus metrics (`/metrics`).

use std::fmt::Write as _;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use axum::http::header;
use axum::routing::get;
use diagnoser::diagnosis::Verdict;
use diagnoser::{Failure, TimeFormat};
use maud::{DOCTYPE, html};
use serde_json::json;
use tokio::time::Instant;

use super::Settings;
use crate::monitor::status::Latency;

/// One plant, as this worker sees it.
#[derive(Debug, Clone)]
pub struct PlantView {
    /// Its name.
    pub name: String,
    /// The model version.
    pub model: String,
    /// Whether this worker diagnoses it now.
    pub served: bool,
    /// The plant view's last verdict: `normal`, `certain` or `ambiguous`.
    pub verdict: Option<String>,
    /// Its labels.
    pub labels: Vec<String>,
    /// The `def_` flags raised.
    pub flags: Vec<String>,
    /// Time of the last scan read, as the verdict lines print it.
    pub t: Option<serde_json::Value>,
    /// Stream sequence of the last message read.
    pub seq: u64,
    /// Messages on the stream not yet read (the consumer's lag).
    pub lag: u64,
    /// When the last checkpoint was written.
    pub checkpoint: Option<Instant>,
}

impl PlantView {
    /// Plant `name` with model version `model`, not served yet.
    pub fn new(name: &str, model: &str) -> PlantView {
        PlantView {
            name: name.to_string(),
            model: model.to_string(),
            served: false,
            verdict: None,
            labels: Vec::new(),
            flags: Vec::new(),
            t: None,
            seq: 0,
            lag: 0,
            checkpoint: None,
        }
    }

    /// The message at stream sequence `seq` was read, `pending` after it;
    /// a scan at `t`, if a scan.
    pub fn message(&mut self, seq: u64, pending: u64, t: Option<serde_json::Value>) {
        self.seq = seq;
        self.lag = pending;
        if t.is_some() {
            self.t = t;
        }
    }

    /// The plant view's verdict `v`, its times printed as `time`.
    pub fn verdict(&mut self, v: &Verdict, time: TimeFormat) {
        self.verdict = Some(v.verdict.name().to_string());
        self.labels = v.labels.clone();
        self.flags = v.flags.clone();
        self.t = Some(time_value(v.t, time));
    }

    /// A checkpoint was written now.
    pub fn checkpointed(&mut self) {
        self.checkpoint = Some(Instant::now());
    }

    fn checkpoint_age(&self) -> Option<f64> {
        self.checkpoint.map(|c| c.elapsed().as_secs_f64())
    }
}

/// A time as the verdict lines print it.
pub fn time_value(t: diagnoser::Time, time: TimeFormat) -> serde_json::Value {
    match time {
        TimeFormat::Numeric(_) => serde_json::from_str(&time.format(t)).unwrap_or_default(),
        TimeFormat::Rfc3339 => json!(time.format(t)),
    }
}

/// The worker's view of its plants.
#[derive(Debug)]
pub struct View {
    worker: String,
    fleet: String,
    plants: Vec<PlantView>,
    started: Instant,
    events: u64,
    messages: u64,
    lines: u64,
    /// From a message's publication to the verdict lines it led to.
    latency: Latency,
}

impl View {
    /// Every plant of `settings`, none served yet.
    pub fn new(settings: &Settings) -> View {
        View {
            worker: settings.worker.clone(),
            fleet: settings.fleet.clone(),
            plants: settings
                .plants
                .iter()
                .map(|s| PlantView::new(&s.name, &s.version))
                .collect(),
            started: Instant::now(),
            events: 0,
            messages: 0,
            lines: 0,
            latency: Latency::default(),
        }
    }

    /// Adds plant `name` (from the model store), if not there yet.
    pub fn add(&mut self, name: &str, model: &str) {
        if self.plant_mut(name).is_none() {
            self.plants.push(PlantView::new(name, model));
        }
    }

    /// The plant named `name`.
    pub fn plant_mut(&mut self, name: &str) -> Option<&mut PlantView> {
        self.plants.iter_mut().find(|p| p.name == name)
    }

    /// Counts a message of `events` events that led to `lines` verdict
    /// lines, `latency` after its publication.
    pub fn count(&mut self, events: u64, lines: u64, latency: Duration) {
        self.messages += 1;
        self.events += events;
        self.lines += lines;
        if lines > 0 {
            self.latency.record(latency);
        }
    }

    /// One line for the end of the run.
    pub fn summary(&self) -> String {
        format!(
            "{} messages, {} events, {} verdict lines in {:.1} s; verdict latency from publication: {}",
            self.messages,
            self.events,
            self.lines,
            self.started.elapsed().as_secs_f64(),
            self.latency.summary()
        )
    }

    /// The `/status` body.
    pub fn json(&self) -> String {
        let plants: Vec<serde_json::Value> = self
            .plants
            .iter()
            .map(|p| {
                json!({
                    "plant": p.name, "served": p.served, "model": p.model,
                    "verdict": p.verdict, "labels": p.labels, "flags": p.flags,
                    "t": p.t, "seq": p.seq, "lag": p.lag,
                    "checkpoint_age_s": p.checkpoint_age(),
                })
            })
            .collect();
        let p99 = self.latency.quantile(0.99).map(|d| d.as_micros() as u64);
        let body = json!({
            "worker": self.worker, "fleet": self.fleet,
            "served": self.plants.iter().filter(|p| p.served).count(),
            "events": self.events, "lines": self.lines,
            "latency_p99_us": p99, "plants": plants,
        });
        serde_json::to_string_pretty(&body).unwrap_or_else(|_| "{}".into())
    }

    /// The `/metrics` body, in the Prometheus text format.
    pub fn metrics(&self) -> String {
        let mut m = String::new();
        let mut metric = |name: &str, kind: &str, help: &str, rows: Vec<(String, f64)>| {
            let _ = writeln!(m, "# HELP gardefou_fleet_{name} {help}");
            let _ = writeln!(m, "# TYPE gardefou_fleet_{name} {kind}");
            for (labels, v) in rows {
                let _ = writeln!(m, "gardefou_fleet_{name}{labels} {v}");
            }
        };
        let served = self.plants.iter().filter(|p| p.served).count();
        metric(
            "plants",
            "gauge",
            "Plants given to this worker, and served by it now.",
            vec![
                ("{state=\"given\"}".into(), self.plants.len() as f64),
                ("{state=\"served\"}".into(), served as f64),
            ],
        );
        metric(
            "events_total",
            "counter",
            "Events read from the plants' streams.",
            vec![(String::new(), self.events as f64)],
        );
        let up = self.started.elapsed().as_secs_f64().max(1e-9);
        metric(
            "events_per_second",
            "gauge",
            "Events read per second since the worker started.",
            vec![(String::new(), self.events as f64 / up)],
        );
        metric(
            "verdict_lines_total",
            "counter",
            "Verdict lines printed.",
            vec![(String::new(), self.lines as f64)],
        );
        let q = |q: f64| {
            self.latency
                .quantile(q)
                .map_or(f64::NAN, |d| d.as_secs_f64())
        };
        metric(
            "verdict_latency_seconds",
            "gauge",
            "From a message's publication to the verdict lines it led to.",
            vec![
                ("{quantile=\"0.5\"}".into(), q(0.5)),
                ("{quantile=\"0.99\"}".into(), q(0.99)),
            ],
        );
        let per_plant = |f: &dyn Fn(&PlantView) -> Option<f64>| {
            self.plants
                .iter()
                .filter(|p| p.served)
                .filter_map(|p| f(p).map(|v| (format!("{{plant=\"{}\"}}", p.name), v)))
                .collect()
        };
        metric(
            "consumer_lag",
            "gauge",
            "Messages of the plant's stream not yet read.",
            per_plant(&|p| Some(p.lag as f64)),
        );
        metric(
            "checkpoint_age_seconds",
            "gauge",
            "Time since the plant's last checkpoint.",
            per_plant(&|p| p.checkpoint_age()),
        );
        m
    }

    /// The page: a table of the plants, refreshed every 2 s.
    pub fn page(&self) -> String {
        let markup = html! {
            (DOCTYPE)
            html lang="en" {
                head {
                    meta charset="utf-8";
                    meta http-equiv="refresh" content="2";
                    title { "gardefou fleet " (self.fleet) " — " (self.worker) }
                    style { "body{font-family:sans-serif}td,th{padding:2px 8px;text-align:left}.certain{color:#b00}.ambiguous{color:#b60}" }
                }
                body {
                    h1 { "Fleet " (self.fleet) ", worker " (self.worker) }
                    table {
                        tr { th { "plant" } th { "served" } th { "verdict" } th { "labels" } th { "flags" } th { "last event" } th { "lag" } th { "checkpoint age (s)" } th { "model" } }
                        @for p in &self.plants {
                            tr {
                                td { (p.name) }
                                td { @if p.served { "here" } @else { "elsewhere" } }
                                td class=(p.verdict.clone().unwrap_or_default()) { (p.verdict.clone().unwrap_or_else(|| "-".into())) }
                                td { (p.labels.join(" ")) }
                                td { (p.flags.join(" ")) }
                                td { (p.t.as_ref().map(ToString::to_string).unwrap_or_default()) }
                                td { (p.lag) }
                                td { (p.checkpoint_age().map(|a| format!("{a:.1}")).unwrap_or_default()) }
                                td { (p.model) }
                            }
                        }
                    }
                }
            }
        };
        markup.into_string()
    }
}

/// Serves the view on `addr` in the background.
pub async fn serve(addr: SocketAddr, view: Arc<Mutex<View>>) -> Result<(), Failure> {
    let read = |f: fn(&View) -> String| {
        let view = view.clone();
        move || {
            let body = view.lock().map(|v| f(&v)).unwrap_or_default();
            async move { body }
        }
    };
    let (status, metrics, page) = (read(View::json), read(View::metrics), read(View::page));
    let routes =
        Router::new()
            .route(
                "/status",
                get(move || async move {
                    ([(header::CONTENT_TYPE, "application/json")], status().await)
                }),
            )
            .route(
                "/metrics",
                get(move || async move {
                    (
                        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
                        metrics().await,
                    )
                }),
            )
            .route(
                "/",
                get(move || async move {
                    (
                        [(header::CONTENT_TYPE, "text/html; charset=utf-8")],
                        page().await,
                    )
                }),
            );
    crate::monitor::http::serve_routes(addr, routes).await
}
