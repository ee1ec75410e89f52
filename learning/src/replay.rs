//! Walking a log scan by scan, as the parts see it: the shared walk of the
//! learner and of the conformance check.

use vocabulary::{Event, Located, SignalId, Time};

use logs::Batches;

/// One part's change in one scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Change {
    /// Index of the part.
    pub part: usize,
    /// The part's state vector before the scan.
    pub from: u64,
    /// Bits that changed in the scan (never 0).
    pub changed: u64,
}

/// Which parts each plant signal belongs to, and at which bit of their state.
#[derive(Debug, Clone)]
pub(crate) struct PartRoutes {
    routes: Vec<Vec<(usize, u8)>>,
    parts: usize,
}

impl PartRoutes {
    /// Routes for a plant of `signals` signals and no part yet.
    pub fn new(signals: usize) -> Self {
        PartRoutes {
            routes: vec![Vec::new(); signals],
            parts: 0,
        }
    }

    /// Adds a part whose state vector holds `ids` in order (at most 64).
    pub fn add_part(&mut self, ids: impl IntoIterator<Item = SignalId>) {
        for (bit, id) in ids.into_iter().enumerate() {
            if let Some(r) = self.routes.get_mut(id.index()) {
                r.push((self.parts, bit as u8));
            }
        }
        self.parts += 1;
    }

    /// Whether a signal belongs to no part.
    pub fn is_unrouted(&self, id: SignalId) -> bool {
        self.routes.get(id.index()).is_none_or(Vec::is_empty)
    }

    /// Each part's state vector given every signal's value.
    pub fn states(&self, values: &[bool]) -> Vec<u64> {
        let mut states = vec![0u64; self.parts];
        for (sig, routes) in self.routes.iter().enumerate() {
            if values.get(sig).copied().unwrap_or(false) {
                for &(p, bit) in routes {
                    states[p] |= 1 << bit;
                }
            }
        }
        states
    }

    /// Walks `batches` from the part states `states`: for every scan, calls
    /// `on_scan(t, changes)` with the changes of the parts it touched (before
    /// `states` is updated), and `progress(events read)` after each batch.
    /// Returns the number of events and the time of the last one (`start` if none).
    pub fn replay(
        &self,
        batches: Batches,
        start: Time,
        states: &mut [u64],
        mut on_scan: impl FnMut(Time, &[Change]),
        mut progress: impl FnMut(u64),
    ) -> Result<(u64, Time), Located> {
        let mut scan: Option<Time> = None;
        let mut changes: Vec<Change> = Vec::new();
        let mut flush = |t: Time, changes: &mut Vec<Change>, states: &mut [u64]| {
            changes.retain(|c| c.changed != 0);
            if !changes.is_empty() {
                on_scan(t, changes);
                for c in changes.iter() {
                    states[c.part] ^= c.changed;
                }
            }
            changes.clear();
        };
        let (mut read, mut last_t) = (0u64, start);
        for batch in batches {
            for Event { t, signal, value } in batch? {
                if scan != Some(t) {
                    if let Some(s) = scan {
                        flush(s, &mut changes, states);
                    }
                    scan = Some(t);
                }
                for &(part, bit) in self
                    .routes
                    .get(signal.index())
                    .map_or(&[][..], Vec::as_slice)
                {
                    let mask = 1u64 << bit;
                    let change = match changes.iter_mut().position(|c| c.part == part) {
                        Some(i) => &mut changes[i],
                        None => {
                            changes.push(Change {
                                part,
                                from: states[part],
                                changed: 0,
                            });
                            changes.last_mut().expect("just pushed")
                        }
                    };
                    // Set the bit to `value`: toggle only when it differs.
                    if ((change.from ^ change.changed) & mask != 0) != value {
                        change.changed ^= mask;
                    }
                }
                last_t = t;
                read += 1;
            }
            progress(read);
        }
        if let Some(s) = scan {
            flush(s, &mut changes, states);
        }
        Ok((read, last_t))
    }
}
