//! Which worker diagnoses a plant: its lease, an entry of the key-value
//! bucket `gardefou-FLEET-leases` whose value is the holder's name.
//!
//! A lease is only as alive as its holder: a worker is alive while its
//! name is in the bucket of live workers ([`super::members`]), which it
//! writes every [`RENEW_EVERY`] and whose entries live [`TTL`]. So a worker
//! renews one entry, whatever the number of its plants. A lease is free when
//! the plant has none, or when its holder is not alive; a worker takes a
//! free lease by a compare-and-set on the entry's revision, so that of two
//! workers trying, one wins. A killed worker's plants are free once its
//! name has expired: a takeover within [`TTL`].
//!
//! Every worker follows the whole bucket ([`Table`]): it sees at once a
//! lease taken, given back, or marked [`ENDED`] (the plant's monitor
//! stopped and its stream is diagnosed to the end).
//!
//! A worker whose last write of its name is older than [`TTL`] less
//! [`MARGIN`] may have been taken for dead: it prints nothing more until
//! its name is written again and it still holds the lease.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_nats::jetstream::kv;
use futures_util::StreamExt;
use tokio::sync::watch;

/// How long a worker's name lives after its last write.
pub const TTL: Duration = Duration::from_secs(2);
/// How often a worker writes its name.
pub const RENEW_EVERY: Duration = Duration::from_millis(400);
/// A worker whose name is older than [`TTL`] less this prints nothing.
pub const MARGIN: Duration = Duration::from_millis(500);
/// The value of the lease of a plant whose run has ended.
pub const ENDED: &str = ":ended";

/// A lease as last seen: its holder (or [`ENDED`]) and its revision.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seen {
    /// The holder's name, or [`ENDED`]; `None`: given back (written empty).
    pub holder: Option<String>,
    /// The entry's revision.
    pub revision: u64,
}

/// Every plant's lease, as the bucket says, kept up to date.
#[derive(Debug, Clone, Default)]
pub struct Table {
    leases: Arc<Mutex<HashMap<String, Seen>>>,
}

impl Table {
    /// Follows `bucket` from its present entries on, until the process ends;
    /// `changed` counts every change.
    pub async fn follow(bucket: kv::Store, changed: watch::Sender<u64>) -> Result<Table, String> {
        let mut watch = bucket
            .watch_with_history(">")
            .await
            .map_err(|e| format!("leases: {e}"))?;
        let table = Table::default();
        let leases = table.leases.clone();
        tokio::spawn(async move {
            while let Some(Ok(entry)) = watch.next().await {
                // Given back: deleted, or written empty.
                let holder = (entry.operation == kv::Operation::Put && !entry.value.is_empty())
                    .then(|| String::from_utf8_lossy(&entry.value).to_string());
                if let Ok(mut l) = leases.lock() {
                    l.insert(
                        entry.key.clone(),
                        Seen {
                            holder,
                            revision: entry.revision,
                        },
                    );
                }
                changed.send_modify(|n| *n += 1);
            }
        });
        Ok(table)
    }

    /// The lease of `plant`, if it ever had one.
    pub fn get(&self, plant: &str) -> Option<Seen> {
        self.leases.lock().ok()?.get(plant).cloned()
    }
}

/// What taking a lease gave.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Taken {
    /// It is this worker's, at this revision.
    Held(u64),
    /// Another worker was quicker, or holds it.
    No,
}

/// Takes the lease of `plant` for `worker`, free as `seen` says (`None`:
/// the plant never had one).
pub async fn take(
    bucket: &kv::Store,
    plant: &str,
    worker: &str,
    seen: Option<&Seen>,
) -> Result<Taken, String> {
    let value = worker.to_string().into();
    let result = match seen {
        None => bucket.create(plant, value).await.map_err(|e| {
            (
                e.kind() == kv::CreateErrorKind::AlreadyExists,
                e.to_string(),
            )
        }),
        Some(s) => bucket.update(plant, value, s.revision).await.map_err(|e| {
            (
                e.kind() == kv::UpdateErrorKind::WrongLastRevision,
                e.to_string(),
            )
        }),
    };
    match result {
        Ok(revision) => Ok(Taken::Held(revision)),
        Err((true, _)) => Ok(Taken::No),
        Err((false, e)) => Err(format!("lease of {plant}: {e}")),
    }
}

/// Gives the lease of `plant` back (as `value`: empty, or [`ENDED`]), if
/// still at `revision`.
pub async fn give_back(bucket: &kv::Store, plant: &str, revision: u64, value: &str) {
    let write = bucket.update(plant, value.to_string().into(), revision);
    let _ = tokio::time::timeout(Duration::from_secs(1), write).await;
}
