//! Histograms of durations: one per transition and clock, fed on every event,
//! and the distribution the learner reads from each once the logs are read.

use vocabulary::Time;
use vocabulary::model::Guard;

use super::{LearnOptions, Widening};

/// Most distinct durations a histogram keeps before it coarsens its bins.
pub(super) const MAX_BINS: usize = 4096;

/// Fewest samples of one log for its mean duration to count in the drift
/// between logs.
const MIN_LOG_SAMPLES: u64 = 5;

/// A histogram of durations, exact while they take few distinct values (PLC logs
/// are quantised by the scan period); beyond `LIMIT` values (by default
/// [`MAX_BINS`]) it merges bins pairwise, one level after such a sample, so
/// quantiles stay within one bin width and memory does not grow with the log.
/// It also keeps each log's sample count and sum, for the drift between logs.
#[derive(Debug, Clone, Default)]
pub(super) struct Hist<const LIMIT: usize = MAX_BINS> {
    bins: Bins,
    /// Samples added.
    pub n: u64,
    /// Bins are `1 << shift` nanoseconds wide.
    shift: u32,
    /// Samples and their sum in each earlier log that had any, in log order.
    earlier_logs: Vec<(u64, i128)>,
    /// The log samples come from now (by index), its samples and their sum:
    /// kept inline, as every sample updates them.
    log: usize,
    log_n: u64,
    log_sum: i128,
}

impl<const LIMIT: usize> Hist<LIMIT> {
    /// Adds duration `d` measured in log `log` (logs come in increasing order).
    #[inline]
    pub fn add(&mut self, d: Time, log: usize) {
        if log != self.log {
            self.next_log(log);
        }
        self.log_n += 1;
        self.log_sum += i128::from(d);
        self.bins.add(d >> self.shift, 1);
        self.n += 1;
        if self.bins.len > LIMIT {
            self.shift += 1;
            self.bins.halve_keys();
        }
    }

    #[cold]
    fn next_log(&mut self, log: usize) {
        if self.log_n > 0 {
            self.earlier_logs.push((self.log_n, self.log_sum));
        }
        (self.log, self.log_n, self.log_sum) = (log, 0, 0);
    }

    /// What the learner reads: the bins in order, with each log's statistics.
    pub fn distribution(&self) -> Distribution {
        let mut bins: Vec<(i64, u64)> = self
            .bins
            .iter()
            .map(|(k, c)| (k << self.shift, c))
            .collect();
        bins.sort_unstable();
        let mut logs = self.earlier_logs.clone();
        if self.log_n > 0 {
            logs.push((self.log_n, self.log_sum));
        }
        Distribution {
            bins,
            n: self.n,
            shift: self.shift,
            logs,
        }
    }
}

/// Counts by key, in open addressing with linear probing. The home slot is
/// taken from the high bits of a multiplicative hash, which spread both runs
/// of consecutive keys and multiples of a scan period (whose low bits are
/// all zero) over the table.
#[derive(Debug, Clone, Default)]
struct Bins {
    /// `(key, count)`; a count of 0 marks a free slot. Empty, or a power of two
    /// long, at most three quarters full.
    slots: Vec<(i64, u64)>,
    /// Occupied slots.
    len: usize,
}

impl Bins {
    /// Slots of a table's first allocation.
    const FIRST: usize = 8;

    /// The home slot of `key` (the table is not empty).
    #[inline]
    fn home(&self, key: i64) -> usize {
        let bits = self.slots.len().trailing_zeros();
        ((key as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> (64 - bits)) as usize
    }

    #[inline]
    fn add(&mut self, key: i64, count: u64) {
        if (self.len + 1) * 4 > self.slots.len() * 3 {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut i = self.home(key);
        loop {
            let slot = &mut self.slots[i];
            if slot.1 == 0 {
                *slot = (key, count);
                self.len += 1;
                return;
            }
            if slot.0 == key {
                slot.1 += count;
                return;
            }
            i = (i + 1) & mask;
        }
    }

    /// The occupied slots, in no particular order.
    fn iter(&self) -> impl Iterator<Item = (i64, u64)> + '_ {
        self.slots.iter().copied().filter(|&(_, c)| c != 0)
    }

    #[cold]
    fn grow(&mut self) {
        let size = (self.slots.len() * 2).max(Self::FIRST);
        let old = std::mem::replace(&mut self.slots, vec![(0, 0); size]);
        self.len = 0;
        for (k, c) in old.into_iter().filter(|&(_, c)| c != 0) {
            self.add(k, c);
        }
    }

    /// Merges the bins pairwise: key `k` becomes `k >> 1`. The table keeps its
    /// size, so coarsening allocates nothing but the copy of the entries.
    #[cold]
    fn halve_keys(&mut self) {
        let entries: Vec<(i64, u64)> = self.iter().collect();
        self.slots.fill((0, 0));
        self.len = 0;
        for (k, c) in entries {
            self.add(k >> 1, c);
        }
    }
}

/// A histogram's durations as the learner reads them once the logs are read.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Distribution {
    /// `(lower end of the bin, samples)`, by increasing duration.
    bins: Vec<(i64, u64)>,
    /// Samples.
    pub n: u64,
    /// Bins are `1 << shift` nanoseconds wide.
    shift: u32,
    /// Samples and their sum in each log that had any, in log order.
    logs: Vec<(u64, i128)>,
}

impl Distribution {
    /// The mean duration of each log with at least [`MIN_LOG_SAMPLES`] samples.
    pub fn log_means(&self) -> Vec<f64> {
        self.logs
            .iter()
            .filter(|(n, _)| *n >= MIN_LOG_SAMPLES)
            .map(|&(n, sum)| sum as f64 / n as f64)
            .collect()
    }

    /// Whether the durations keep close together (the learner's test of a
    /// timed transition): a spread of at most `timed_spread`, or at most
    /// `timed_relative` of the median.
    pub fn tight(&self, options: &LearnOptions) -> bool {
        let q = |p: f64| self.quantile(p) as f64;
        let spread = q(0.99) - q(0.01);
        spread <= options.timed_spread as f64 || spread <= options.timed_relative * q(0.5)
    }

    /// Whether the outermost durations stay near the bulk: at most three times
    /// its spread (or two `margin`s, the scan's jitter) beyond `q01`–`q99`.
    /// Far outliers mean something outside the part sometimes holds the motion
    /// back (a starved conveyor, the next machine): its time is then the
    /// product flow's, not the part's own.
    pub fn light_tails(&self, margin: Time) -> bool {
        let s = &self.bins;
        let q = |p: f64| self.quantile(p);
        let (min, max) = (s.first().map_or(0, |x| x.0), s.last().map_or(0, |x| x.0));
        let reach = 3 * (q(0.99) - q(0.01)).max(2 * margin);
        q(0.01) - min <= reach && max - q(0.99) <= reach
    }

    /// How far beyond its learned logs' means, below and above, a new run's mean
    /// may land: `reach` (relative drift times deviations) around their mean,
    /// scaled for the few logs it is estimated from. A transition seen often
    /// in one log only still drifts as much as the plant's others: its mean over
    /// every sample stands for that one log's.
    fn drift_reach(&self, reach: f64) -> (f64, f64) {
        let mut means = self.log_means();
        if means.len() < 2 {
            let sum: i128 = self.logs.iter().map(|&(_, s)| s).sum();
            means = vec![sum as f64 / self.n.max(1) as f64];
        }
        if self.n == 0 || reach <= 0.0 {
            return (0.0, 0.0);
        }
        let k = means.len() as f64;
        let mean = means.iter().sum::<f64>() / k;
        let half = reach * mean * (1.0 + 1.0 / k).sqrt();
        let (lo, hi) = means
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), &m| (lo.min(m), hi.max(m)));
        ((lo - (mean - half)).max(0.0), (mean + half - hi).max(0.0))
    }

    /// The sample of rank `k` (0 is the smallest).
    fn nth(&self, k: u64) -> i64 {
        let mut acc = 0;
        for &(v, c) in &self.bins {
            acc += c;
            if acc > k {
                return v;
            }
        }
        self.bins.last().map_or(0, |&(v, _)| v)
    }

    /// The smallest sample `x` with at least `p·n` samples at or below it.
    fn quantile(&self, p: f64) -> i64 {
        let want = ((p * self.n as f64).ceil() as u64).max(1);
        let mut acc = 0;
        for &(v, c) in &self.bins {
            acc += c;
            if acc >= want {
                return v;
            }
        }
        self.bins.last().map_or(0, |&(v, _)| v)
    }

    /// The learned interval widened into a guard, in the plant's time unit
    /// (`scale` nanoseconds).
    pub fn guard(&self, options: &LearnOptions, widening: Widening, scale: f64) -> Guard {
        let s = &self.bins;
        let n = self.n;
        let min = s.first().map_or(0, |&(v, _)| v);
        let max = s.last().map_or(0, |&(v, _)| v + (1 << self.shift) - 1);
        let q = |p: f64| self.quantile(p);
        let (lo, hi) = if options.trim > 0.0 {
            (q(options.trim), q(1.0 - options.trim))
        } else {
            // A fresh log's extremes land beyond the learned ones about as far
            // as the learned tails reach past their last percent: each side
            // is widened by that reach (nothing, where the samples bunch).
            let k = (n / 100).max(1);
            (
                min - (self.nth(k) - min),
                max + (max - self.nth(n.saturating_sub(1 + k))),
            )
        };
        let widen = widening.margin as f64 + options.margin_relative * (hi - lo) as f64;
        let (below, above) = self.drift_reach(widening.drift);
        Guard {
            n,
            min: min as f64 / scale,
            q01: q(0.01) as f64 / scale,
            q50: q(0.5) as f64 / scale,
            q99: q(0.99) as f64 / scale,
            max: max as f64 / scale,
            lo: ((lo as f64 - widen - below).max(0.0)) / scale,
            hi: (hi as f64 + widen + above) / scale,
        }
    }

    /// From the lowest bin to the highest (`i64::MAX` with no sample).
    pub fn width(&self) -> i64 {
        match (self.bins.first(), self.bins.last()) {
            (Some(a), Some(b)) => b.0 - a.0,
            _ => i64::MAX,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use proptest::prelude::*;

    use super::*;

    /// The histogram written plainly: an ordered map of bins, coarsened by
    /// one level after any sample that leaves more than `limit` of them, and
    /// every sample kept, to read quantiles from directly.
    struct Reference {
        limit: usize,
        bins: BTreeMap<i64, u64>,
        shift: u32,
        /// By log index: samples and their sum.
        logs: Vec<(u64, i128)>,
        samples: Vec<i64>,
    }

    impl Reference {
        fn new(limit: usize) -> Self {
            Reference {
                limit,
                bins: BTreeMap::new(),
                shift: 0,
                logs: Vec::new(),
                samples: Vec::new(),
            }
        }

        fn add(&mut self, d: Time, log: usize) {
            if self.logs.len() <= log {
                self.logs.resize(log + 1, (0, 0));
            }
            self.logs[log].0 += 1;
            self.logs[log].1 += i128::from(d);
            self.samples.push(d);
            *self.bins.entry(d >> self.shift).or_default() += 1;
            if self.bins.len() > self.limit {
                self.shift += 1;
                let old = std::mem::take(&mut self.bins);
                for (k, c) in old {
                    *self.bins.entry(k >> 1).or_default() += c;
                }
            }
        }

        fn distribution(&self) -> Distribution {
            Distribution {
                bins: self
                    .bins
                    .iter()
                    .map(|(&k, &c)| (k << self.shift, c))
                    .collect(),
                n: self.samples.len() as u64,
                shift: self.shift,
                logs: self.logs.iter().copied().filter(|l| l.0 > 0).collect(),
            }
        }

        /// The bin of the sample of rank `k`, read from the samples themselves.
        fn bin_of_rank(&self, k: usize) -> i64 {
            let mut sorted = self.samples.clone();
            sorted.sort_unstable();
            sorted[k] >> self.shift << self.shift
        }
    }

    /// Durations as logs give them: repeated multiples of a scan period, a few
    /// values with jitter, and rare long ones; now and then the next log.
    fn samples() -> impl Strategy<Value = Vec<(Time, bool)>> {
        let duration = prop_oneof![
            4 => (1i64..400).prop_map(|k| k * 10_000_000),
            2 => 0i64..60,
            1 => 0i64..1 << 42,
        ];
        prop::collection::vec((duration, prop::bool::weighted(0.02)), 1..600)
    }

    /// Feeds `samples` to both; checks every reading the learner makes.
    fn check<const LIMIT: usize>(samples: &[(Time, bool)]) -> Result<(), TestCaseError> {
        let mut hist = Hist::<LIMIT>::default();
        let mut reference = Reference::new(LIMIT);
        let mut log = 0;
        for &(d, next_log) in samples {
            log += usize::from(next_log);
            hist.add(d, log);
            reference.add(d, log);
            prop_assert_eq!(
                (hist.shift, hist.bins.len),
                (reference.shift, reference.bins.len())
            );
            // One coarsening per sample may leave more than the limit, but
            // keys merge within the 64 bits of a duration.
            prop_assert!(hist.bins.len <= LIMIT + 64);
        }
        let got = hist.distribution();
        prop_assert_eq!(&got, &reference.distribution());
        prop_assert_eq!(got.n, hist.n);
        let n = samples.len();
        for k in [0, n / 100, n / 2, n - 1 - n / 100, n - 1] {
            prop_assert_eq!(got.nth(k as u64), reference.bin_of_rank(k));
        }
        for p in [0.001, 0.01, 0.5, 0.99, 0.999] {
            let want = ((p * n as f64).ceil() as usize).max(1);
            prop_assert_eq!(got.quantile(p), reference.bin_of_rank(want - 1));
        }
        let width = reference.bin_of_rank(n - 1) - reference.bin_of_rank(0);
        prop_assert_eq!(got.width(), width);
        let means: Vec<f64> = reference
            .logs
            .iter()
            .filter(|l| l.0 >= MIN_LOG_SAMPLES)
            .map(|&(k, sum)| sum as f64 / k as f64)
            .collect();
        prop_assert_eq!(got.log_means(), means);
        Ok(())
    }

    proptest! {
        #[test]
        fn coarsened_often_it_reads_as_the_reference(samples in samples()) {
            check::<8>(&samples)?;
        }

        #[test]
        fn coarsened_sometimes_it_reads_as_the_reference(samples in samples()) {
            check::<64>(&samples)?;
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(8))]

        #[test]
        fn at_the_learner_s_limit_it_reads_as_the_reference(
            samples in prop::collection::vec(((0i64..1 << 40), prop::bool::weighted(0.001)), 4000..12000)
        ) {
            check::<MAX_BINS>(&samples)?;
        }
    }

    #[test]
    fn an_empty_histogram_has_no_width() {
        let d = Hist::<MAX_BINS>::default().distribution();
        assert_eq!((d.n, d.width(), d.quantile(0.5)), (0, i64::MAX, 0));
    }
}
