//! A running total's recent rate: how a job's and a worker's samples per second are measured.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// A running total's recent rate: what it grew by over the last [`Rate::WINDOW`], per second.
/// Points are (time, total); one at or before the window's start is kept as the baseline, so
/// the rate falls to 0 once nothing has been added for a window, however long ago the last
/// point was (a worker that stopped, a job that ended).
#[derive(Debug, Default)]
pub struct Rate(VecDeque<(Instant, u64)>);

impl Rate {
    /// The window the rate is measured over.
    pub const WINDOW: Duration = Duration::from_secs(10);

    /// Notes that the total was `total` at `now`.
    pub fn record(&mut self, now: Instant, total: u64) {
        self.0.push_back((now, total));
        // The second point is at or before the window's start: the first is not needed.
        while self.0.len() > 2 && self.0[1].0 + Self::WINDOW <= now {
            self.0.pop_front();
        }
    }

    /// Growth per second over the window that ends at `now` (0 when unknown). The total holds
    /// its value between points, so its value at the window's start is the newest point's at
    /// or before it; a total younger than the window is measured from its first point.
    pub fn per_second(&self, now: Instant) -> f64 {
        let Some(&(_, last)) = self.0.back() else {
            return 0.0;
        };
        let start = now.checked_sub(Self::WINDOW);
        let base = self
            .0
            .iter()
            .rev()
            .find(|(t, _)| start.is_some_and(|s| *t <= s))
            .or(self.0.front());
        let Some(&(t0, v0)) = base else {
            return 0.0;
        };
        let from = start.map_or(t0, |s| s.max(t0));
        let span = now.saturating_duration_since(from).as_secs_f64();
        if span > 0.0 {
            last.saturating_sub(v0) as f64 / span
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// #55: a worker's or job's rate kept its last value for ever after the last merge. Now it
    /// is what was merged over the last window, so it falls to 0 a window after the last one.
    #[test]
    fn a_rate_decays_to_zero_a_window_after_the_last_point() {
        let t0 = Instant::now();
        let s = |x: f64| Duration::from_secs_f64(x);
        let mut r = Rate::default();
        assert_eq!(r.per_second(t0), 0.0);
        for i in 0..=20u64 {
            r.record(t0 + s(i as f64 * 0.5), i * 1000);
        }
        // 2000 a second while merging, measured over the window.
        let now = t0 + s(10.0);
        assert!(
            (r.per_second(now) - 2000.0).abs() < 1e-6,
            "{}",
            r.per_second(now)
        );
        // Five seconds without a merge: half the window had none.
        assert!((r.per_second(now + s(5.0)) - 1000.0).abs() < 1e-6);
        assert_eq!(r.per_second(now + s(10.0)), 0.0);
        assert_eq!(r.per_second(now + s(3600.0)), 0.0);
        // A young total is measured from its first point.
        let mut young = Rate::default();
        young.record(t0, 0);
        young.record(t0 + s(2.0), 500);
        assert!((young.per_second(t0 + s(2.0)) - 250.0).abs() < 1e-6);
    }
}
