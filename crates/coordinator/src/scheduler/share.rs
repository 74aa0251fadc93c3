//! Sharing workers between users (named tokens, [`crate::auth`]): jobs of equal priority are
//! offered to a worker asking for units in the order of how many units their users hold
//! leased now, fewest first, so that two users who each submit a job share the farm rather
//! than the first to submit taking it all (OpenCue's and Deadline's "balanced" pools); a
//! higher priority still goes first. An optional cap ([`Policy::max_leases_per_user`]) keeps
//! one user's jobs from holding more than so many units at once, whoever else waits.
//!
//! Without named tokens every job has the same (empty) submitter, and the order is plain
//! priority, then submission.

use std::collections::HashMap;

use tessera_proto::ids::JobId;

use super::Scheduler;

impl Scheduler {
    /// Units each user's jobs hold leased now; `None` when nothing depends on it (one user,
    /// no cap), which is every farm without named tokens.
    pub(super) fn user_leases(&self) -> Option<HashMap<String, usize>> {
        let mut live = self.jobs.values().filter(|j| j.is_live());
        let first = live.next().map(|j| j.rec.submitter.as_str());
        let several = live.any(|j| Some(j.rec.submitter.as_str()) != first);
        if !several && self.policy.max_leases_per_user == 0 {
            return None;
        }
        let mut n: HashMap<String, usize> = HashMap::new();
        for l in self.leases.values().filter(|l| l.active) {
            if let Some(j) = self.jobs.get(&l.job) {
                *n.entry(j.rec.submitter.clone()).or_default() += 1;
            }
        }
        Some(n)
    }

    /// Live jobs in the order a lease call offers them: priority (high first), then the units
    /// their users hold (fewest first) when `held` is given, then submission.
    pub(super) fn fair_order(&self, held: Option<&HashMap<String, usize>>) -> Vec<JobId> {
        let Some(held) = held else {
            return self.schedule_order(true);
        };
        let mut ids: Vec<(i32, usize, JobId)> = self
            .jobs
            .values()
            .filter(|j| j.is_live())
            .map(|j| {
                let n = held.get(&j.rec.submitter).copied().unwrap_or(0);
                (j.rec.priority, n, j.id())
            })
            .collect();
        ids.sort_by_key(|&(p, n, id)| (std::cmp::Reverse(p), n, id));
        ids.into_iter().map(|(_, _, id)| id).collect()
    }

    /// Whether user `user` holds as many units as the cap allows.
    pub(super) fn user_capped(&self, held: Option<&HashMap<String, usize>>, user: &str) -> bool {
        let cap = self.policy.max_leases_per_user;
        cap > 0 && held.and_then(|h| h.get(user)).copied().unwrap_or(0) >= cap
    }
}
