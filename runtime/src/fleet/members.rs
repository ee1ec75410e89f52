//! Which workers of a fleet are alive, and which of them each plant
//! prefers: how the plants are shared.
//!
//! Every worker writes its name in the bucket `gardefou-FLEET-workers`
//! every [`lease::RENEW_EVERY`], whose entries live [`lease::TTL`], and reads
//! the names there; a name stays alive [`GRACE`] after it was last listed. A plant prefers the live worker with the highest
//! [`weight`] of (plant, worker): rendezvous hashing, so that the plants
//! split evenly, and a worker joining or leaving moves only the plants it
//! takes or leaves. A worker takes the plants it is preferred for; a plant
//! whose preferred worker does not take it (one not given that plant) is
//! taken by any worker once it has been left alone for [`ORPHAN_WAIT`].
//!
//! ```
//! use runtime::fleet::members::preferred;
//!
//! let workers = ["w1".to_string(), "w2".to_string()];
//! let mine = (0..1000).filter(|i| preferred(&format!("p{i}"), &workers) == Some("w1")).count();
//! assert!((400..600).contains(&mine), "{mine}");
//! ```

use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_nats::jetstream::kv;
use futures_util::StreamExt;
use tokio::sync::watch;
use tokio::time::Instant;

use super::lease;

/// How long a plant is left alone before any worker given it takes it.
pub const ORPHAN_WAIT: Duration = Duration::from_millis(1000);

/// The weight of `worker` for `plant`: FNV-1a of both names, mixed (the
/// same on every machine and build).
pub fn weight(plant: &str, worker: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in plant.bytes().chain([0xff]).chain(worker.bytes()) {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    // FNV's low bits mix poorly for short keys: a final avalanche.
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^ (h >> 33)
}

/// The worker `plant` prefers among `workers`, if any.
pub fn preferred<'a>(plant: &str, workers: &'a [String]) -> Option<&'a str> {
    workers
        .iter()
        .max_by_key(|w| (weight(plant, w), w.as_str()))
        .map(String::as_str)
}

/// Keeps this worker's name in the bucket, when it was last written in
/// `written`, and the live workers' names in `live` (sorted), until the
/// process ends.
pub async fn keep(
    bucket: kv::Store,
    me: String,
    live: watch::Sender<Vec<String>>,
    written: Arc<Mutex<Option<Instant>>>,
) {
    let mut tick = tokio::time::interval(lease::RENEW_EVERY);
    let mut seen = Seen::default();
    loop {
        tick.tick().await;
        let at = Instant::now();
        let put = bucket.put(&me, b"alive".to_vec().into());
        if !matches!(
            tokio::time::timeout(lease::RENEW_EVERY, put).await,
            Ok(Ok(_))
        ) {
            continue;
        }
        if let Ok(mut w) = written.lock() {
            *w = Some(at);
        }
        let Ok(keys) = bucket.keys().await else {
            continue;
        };
        let listed: Vec<String> = keys.filter_map(|k| async move { k.ok() }).collect().await;
        let names = seen.list(&me, listed, Instant::now());
        live.send_if_modified(|old| {
            let changed = *old != names;
            *old = names;
            changed
        });
    }
}

/// How long a name missing from the bucket's listing still counts as
/// alive: a listing made while a worker rewrites its name can miss it (the
/// entry it would show is replaced meanwhile), and one miss must not hand
/// that worker's plants to the others.
pub const GRACE: Duration = Duration::from_millis(900);

/// When each worker's name was last listed.
#[derive(Debug, Default)]
pub struct Seen(std::collections::BTreeMap<String, Instant>);

impl Seen {
    /// The live workers, sorted, after a listing of `listed` at `now`: those
    /// listed, this worker `me`, and those listed less than [`GRACE`] ago.
    pub fn list(&mut self, me: &str, listed: Vec<String>, now: Instant) -> Vec<String> {
        for name in listed.into_iter().chain([me.to_string()]) {
            self.0.insert(name, now);
        }
        self.0.retain(|_, at| now.duration_since(*at) < GRACE);
        self.0.keys().cloned().collect()
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    #[test]
    fn a_name_missing_from_one_listing_stays_alive_for_the_grace() {
        let mut seen = Seen::default();
        let t0 = Instant::now();
        let both = vec!["w0".to_string(), "w1".to_string()];
        assert_eq!(seen.list("w0", both.clone(), t0), both);
        let later = t0 + lease::RENEW_EVERY;
        assert_eq!(seen.list("w0", vec!["w0".into()], later), both);
        let gone = t0 + GRACE;
        assert_eq!(seen.list("w0", Vec::new(), gone), ["w0".to_string()]);
    }

    proptest! {
        /// A worker leaving moves only its own plants; the others keep theirs.
        #[test]
        fn a_worker_leaving_moves_only_its_plants(n in 2usize..6, gone in 0usize..6, plants in 1usize..200) {
            let gone = gone % n;
            let all: Vec<String> = (0..n).map(|i| format!("w{i}")).collect();
            let left: Vec<String> = all.iter().filter(|w| **w != all[gone]).cloned().collect();
            for p in (0..plants).map(|i| format!("plant-{i}")) {
                let before = preferred(&p, &all).expect("a worker");
                let after = preferred(&p, &left).expect("a worker");
                if before != all[gone] {
                    prop_assert_eq!(before, after);
                }
            }
        }
    }
}
