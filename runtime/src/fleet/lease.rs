//! Which worker diagnoses a plant: a lease in a JetStream key-value bucket.
//!
//! The bucket's entries live [`TTL`] after their last write. A worker holds a
//! plant while its entry is the worker's: it takes the plant by creating the
//! entry (which fails while another holds it), renews it every
//! [`RENEW_EVERY`] by a compare-and-set on its revision, and gives it back
//! by deleting it. A killed worker renews nothing, its entry expires, and
//! the next worker to try creates it: a takeover within [`TTL`] plus
//! [`CLAIM_EVERY`].
//!
//! A worker that cannot renew (a revision that moved, the broker away) has
//! lost the plant, and stops diagnosing it at once. It also stops if its
//! last renewal is older than [`TTL`] less [`MARGIN`]: a worker paused
//! longer than that may have been replaced, and must not print another line
//! before it knows.

use std::time::Duration;

use async_nats::jetstream::kv;
use tokio::time::Instant;

/// How long an entry lives after its last write.
pub const TTL: Duration = Duration::from_secs(2);
/// How often the holder renews.
pub const RENEW_EVERY: Duration = Duration::from_millis(400);
/// How often a worker tries to take a plant that another holds.
pub const CLAIM_EVERY: Duration = Duration::from_millis(250);
/// A holder whose last renewal is older than [`TTL`] less this stops.
pub const MARGIN: Duration = Duration::from_millis(500);

/// A plant held by this worker.
#[derive(Debug)]
pub struct Lease {
    key: String,
    worker: String,
    revision: u64,
    renewed: Instant,
}

impl Lease {
    /// Takes plant `key` for `worker`: `None` while another holds it.
    pub async fn claim(
        bucket: &kv::Store,
        key: &str,
        worker: &str,
    ) -> Result<Option<Lease>, String> {
        let at = Instant::now();
        match bucket.create(key, worker.to_string().into()).await {
            Ok(revision) => Ok(Some(Lease {
                key: key.to_string(),
                worker: worker.to_string(),
                revision,
                renewed: at,
            })),
            Err(e) if e.kind() == kv::CreateErrorKind::AlreadyExists => Ok(None),
            Err(e) => Err(format!("lease of {key}: {e}")),
        }
    }

    /// Renews the lease; an error when it is lost.
    pub async fn renew(&mut self, bucket: &kv::Store) -> Result<(), String> {
        let at = Instant::now();
        let value = self.worker.clone().into();
        match bucket.update(&self.key, value, self.revision).await {
            Ok(revision) => {
                self.revision = revision;
                self.renewed = at;
                Ok(())
            }
            Err(e) => Err(format!("the lease of {} is lost ({e})", self.key)),
        }
    }

    /// Whether the lease is surely still this worker's.
    pub fn fresh(&self) -> bool {
        self.renewed.elapsed() < TTL - MARGIN
    }

    /// Gives the plant back, so that another worker may take it at once.
    pub async fn release(self, bucket: &kv::Store) {
        // Only if still ours: a delete expecting our revision.
        let key = self.key.clone();
        let _ = tokio::time::timeout(
            Duration::from_secs(1),
            bucket.delete_expect_revision(key, Some(self.revision)),
        )
        .await;
    }
}
