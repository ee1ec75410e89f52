//! A plant's events read back from its stream (`gardefou fleet`): a monitor
//! [`Source`] with no PLC attached, fed by an ordered JetStream consumer of
//! `gardefou.events.PLANT` from the stream's first message.
//!
//! Each message becomes the item the publishing monitor took in: a start, a
//! scan (complete at its time), a watermark, a lost plant. The monitor's end is a watermark at its time, after which the
//! source ends. So the verdict lines are those the publishing monitor
//! printed, in the same time format (the start message names it). A message
//! that does not read as an event stops the source with an error naming its
//! stream sequence.

use std::time::Duration;

use async_nats::jetstream::{self, consumer::DeliverPolicy, consumer::pull::OrderedConfig};
use diagnoser::{Failure, Plant, TimeFormat};
use futures_util::StreamExt;

use super::record::{self, Record, Subjects};
use crate::monitor::source::{Item, Link, Source};

/// How long opening waits for the server.
const CONNECT_WAIT: Duration = Duration::from_secs(5);

/// The events of one plant, from its stream.
pub struct StreamSource {
    url: String,
    subjects: Subjects,
    plant: Plant,
    time: TimeFormat,
}

impl StreamSource {
    /// Opens the stream of the plant named `name` on the server at `url`,
    /// and reads the time format from its first message (RFC 3339 if it has
    /// none yet). Runs a runtime of its own: call it outside one.
    pub fn open(url: &str, name: &str, plant: &Plant) -> Result<StreamSource, Failure> {
        let subjects =
            Subjects::of(name).map_err(|e| Failure::bad(format!("--nats-plant: {e}")))?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
        let first = runtime.block_on(first_message(url, &subjects.events))?;
        let time = first
            .and_then(|bytes| match record::read(&bytes, plant) {
                Ok(Record::Start(_, _, time)) => time,
                _ => None,
            })
            .unwrap_or(TimeFormat::Rfc3339);
        Ok(StreamSource {
            url: url.to_string(),
            subjects,
            plant: plant.clone(),
            time,
        })
    }
}

/// The first message on `subject`, if any.
async fn first_message(url: &str, subject: &str) -> Result<Option<Vec<u8>>, Failure> {
    let js = connect(url).await?;
    let Ok(stream) = js.get_stream(record::STREAMS[0].0).await else {
        return Ok(None);
    };
    Ok(stream
        .direct_get_first_for_subject(subject)
        .await
        .ok()
        .map(|m| m.payload.to_vec()))
}

async fn connect(url: &str) -> Result<jetstream::Context, Failure> {
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

impl Source for StreamSource {
    fn time_format(&self) -> TimeFormat {
        self.time
    }

    fn spawn(self: Box<Self>, link: Link) {
        tokio::spawn(async move {
            if let Err(f) = consume(&self, &link).await {
                let _ = link.items.send(Item::Fatal(f)).await;
            }
        });
    }
}

/// Reads the plant's messages in order until its end or the monitor's.
async fn consume(source: &StreamSource, link: &Link) -> Result<(), Failure> {
    let (name, _) = record::STREAMS[0];
    let js = connect(&source.url).await?;
    let stream = js
        .get_stream(name)
        .await
        .map_err(|e| Failure::Io(format!("nats {}: stream {name}: {e}", source.url)))?;
    let config = OrderedConfig {
        filter_subject: source.subjects.events.clone(),
        deliver_policy: DeliverPolicy::All,
        ..OrderedConfig::default()
    };
    let consumer = stream.create_consumer(config).await.map_err(|e| {
        Failure::Io(format!(
            "nats {}: consumer of {}: {e}",
            source.url, source.subjects.events
        ))
    })?;
    let mut messages = consumer
        .messages()
        .await
        .map_err(|e| Failure::Io(format!("nats {}: {e}", source.url)))?;
    while let Some(message) = messages.next().await {
        let message = message.map_err(|e| Failure::Io(format!("nats {}: {e}", source.url)))?;
        let seq = message.info().map_or(0, |i| i.stream_sequence);
        let record = record::read(&message.payload, &source.plant)
            .map_err(|e| Failure::bad(format!("nats stream {name}, message {seq}: {e}")))?;
        let (items, end) = items(record);
        for item in items {
            if link.items.send(item).await.is_err() {
                return Ok(());
            }
        }
        if end {
            return Ok(());
        }
    }
    Ok(())
}

/// The items a message stands for, and whether the plant's run ended.
fn items(record: Record) -> (Vec<Item>, bool) {
    match record {
        Record::Start(t, values, _) => (vec![Item::Start(t, values)], false),
        // A scan is complete at its time: no watermark needed.
        Record::Scan(events) => (vec![Item::Scan(events)], false),
        Record::Watermark(t) => (vec![Item::Watermark(t)], false),
        Record::Lost(t, why) => (vec![Item::Lost(t, why)], false),
        Record::End(t) => (vec![Item::Watermark(t)], true),
    }
}
