//! Which unit a worker gets next: units put back first, then every tile's first batches in
//! batch-major order, then the batches that noise decisions released; and, once nothing is
//! fresh anywhere, a speculative copy of a unit a slow (or hoarding) holder keeps.
//!
//! Every pick skips a unit that is done or has a live lease, and an audited unit goes only to
//! a worker on a host that has no copy of it ([`super::audit`]).

use std::collections::HashMap;
use std::time::{Duration, Instant};

use tessera_proto::ids::JobId;

use super::audit::audit_excludes;
use super::leases::{has_active_lease, Lease};
use super::{Granted, Scheduler};
use crate::job::{Job, Unit};

/// A copy of a unit that is out already, for worker `w` to race, among those `w` does not
/// hold: the one leased longest ago that has exactly one live lease, or else one whose live
/// leases are all older than `slow` (held by slow or hoarding workers, which renew their leases
/// but never finish). Near the end of a job this keeps a slow, stuck or hostile worker from
/// holding everyone up; the first result is merged and the others are duplicates.
///
/// Copies are limited in rate, not in number: a new copy is fresh, so the next one waits until
/// it too is `slow`. A cap on the number would let as many hoarding registrations fill it and
/// keep the unit from every honest worker for good.
fn speculative_unit(
    job: &Job,
    w: u64,
    host: &str,
    leases: &HashMap<u64, Lease>,
    now: Instant,
    slow: Duration,
) -> Option<Unit> {
    let mut best: Option<(u64, Unit)> = None;
    for (u, ids) in &job.issued {
        if job.is_done(*u) {
            continue;
        }
        let live: Vec<(u64, &Lease)> = ids
            .iter()
            .filter_map(|l| leases.get(l).filter(|x| x.active).map(|x| (*l, x)))
            .collect();
        let Some(&(oldest, _)) = live.first() else {
            continue;
        };
        let all_slow = live
            .iter()
            .all(|(_, x)| now.saturating_duration_since(x.issued) >= slow);
        let eligible = !live.iter().any(|(_, x)| x.worker == w)
            && !audit_excludes(job, *u, w, host)
            && (live.len() == 1 || all_slow);
        if eligible && best.is_none_or(|(b, _)| oldest < b) {
            best = Some((oldest, *u));
        }
    }
    best.map(|(_, u)| u)
}

/// The next unit of `job` to hand out: one put back first, then the next of every tile's first
/// batches in batch-major order (all tiles' batch 0, then batch 1, …), so the image converges
/// evenly and few results wait out of order; then, with a noise target, the batches that
/// tiles' noise decisions released, lowest first.
///
/// `max_batch` holds the cursor back at that batch (a progressive range's frames wait for each
/// other), and a guided job's cursor waits at the end of the epoch whose guide is not trained
/// yet; units put back and released ones are not held.
fn next_unit(
    job: &mut Job,
    w: u64,
    host: &str,
    leases: &HashMap<u64, Lease>,
    max_batch: u32,
) -> Option<Unit> {
    // An audited unit goes to a worker on a host that has not rendered it: those set aside
    // wait at the front for the next worker.
    let mut aside = Vec::new();
    let mut found = None;
    while let Some(u) = job.requeue.pop_front() {
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            if audit_excludes(job, u, w, host) {
                aside.push(u);
                continue;
            }
            found = Some(u);
            break;
        }
    }
    for u in aside.into_iter().rev() {
        job.requeue.push_front(u);
    }
    if found.is_some() {
        return found;
    }
    let n_tiles = (job.tiles.len() as u64).max(1);
    // A guided job's next epoch waits for the guide its last one trains.
    let released = job.guiding.as_ref().map_or(u32::MAX, |g| g.released());
    while job.cursor < job.units_first() {
        let u = Unit {
            tile: (job.cursor % n_tiles) as u32,
            batch: (job.cursor / n_tiles) as u32,
        };
        if u.batch > max_batch || u.batch >= released {
            break;
        }
        job.cursor += 1;
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            return Some(u);
        }
    }
    while let Some((batch, tile)) = job.ready.pop_first() {
        let u = Unit { tile, batch };
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            return Some(u);
        }
    }
    None
}

impl Scheduler {
    /// The batch a progressive range's frames may hand out up to: the lowest batch any of its
    /// live frames' cursors is still on, so that no frame starts batch b + 1 before every frame
    /// has handed out its batch b. A frame held back (paused on its own) does not hold back the
    /// others.
    fn progressive_level(&self, range: JobId) -> u32 {
        self.members(range)
            .iter()
            .filter_map(|m| self.jobs.get(m))
            .filter(|j| j.is_live() && !self.held(j.id()) && j.cursor < j.units_first())
            .map(|j| (j.cursor / (j.tiles.len() as u64).max(1)) as u32)
            .min()
            .unwrap_or(u32::MAX)
    }

    /// Jobs in scheduling order: priority (high first), then submission order; only those
    /// still taking leases if `live_only` (finished jobs accumulate, and leasing runs often).
    pub fn schedule_order(&self, live_only: bool) -> Vec<JobId> {
        let mut ids: Vec<(i32, JobId)> = self
            .jobs
            .values()
            .filter(|j| !live_only || j.is_live())
            .map(|j| (j.rec.priority, j.id()))
            .collect();
        ids.sort_by_key(|&(p, id)| (std::cmp::Reverse(p), id));
        ids.into_iter().map(|(_, id)| id).collect()
    }

    /// Leases up to `max` units to worker `w`: fresh units first (by job priority), then, if
    /// there are none anywhere, speculative copies of outstanding ones.
    pub fn lease(&mut self, w: u64, max: usize, now: Instant) -> Vec<Granted> {
        self.expire(now);
        let mut out = Vec::new();
        let Some(worker) = self.workers.get(&w) else {
            return out;
        };
        if worker.quarantined || worker.draining {
            return out;
        }
        let caps = worker.caps.clone();
        // A worker in a dispute keeps working: the coordinator's own render settles the dispute
        // (the referee), and a conviction takes back whatever it gave live jobs meanwhile.
        let host = self
            .workers
            .get(&w)
            .map(|x| x.host.clone())
            .unwrap_or_default();
        // A worker that already holds its share gets nothing more, however much it asks for:
        // one registration cannot take a job's units out of everyone else's reach.
        let max = max.min(
            self.policy
                .max_leases_per_worker
                .saturating_sub(self.leases_of(w)),
        );
        let slow = self.policy.lease_time;
        // Each progressive range's batch, read once a call: a level that rises during the
        // call is seen by the next one.
        let mut levels: HashMap<u64, u32> = HashMap::new();
        // Units each user holds, as fair share and the per-user cap count them
        // (`scheduler/share.rs`), kept up to date as this call grants more.
        let mut held = self.user_leases();
        for speculate in [false, true] {
            for id in self.fair_order(held.as_ref()) {
                let Some(user) = self.jobs.get(&id).map(|j| j.rec.submitter.clone()) else {
                    continue;
                };
                if self.held(id)
                    || self.user_capped(held.as_ref(), &user)
                    || !self
                        .jobs
                        .get(&id)
                        .is_some_and(|j| caps.fits(&j.rec) && !self.blocklisted(j, w))
                {
                    continue;
                }
                let max_batch = match self
                    .jobs
                    .get(&id)
                    .and_then(|j| j.rec.range.filter(|_| j.rec.progressive))
                {
                    Some(r) => *levels
                        .entry(r.id)
                        .or_insert_with(|| self.progressive_level(JobId(r.id))),
                    None => u32::MAX,
                };
                while out.len() < max && !self.user_capped(held.as_ref(), &user) {
                    let Some(job) = self.jobs.get_mut(&id) else {
                        break;
                    };
                    if !job.is_live() {
                        break;
                    }
                    let next = if speculate {
                        speculative_unit(job, w, &host, &self.leases, now, slow)
                    } else {
                        next_unit(job, w, &host, &self.leases, max_batch)
                    };
                    let Some(unit) = next else {
                        break;
                    };
                    let n = self.next_lease;
                    self.next_lease += 1;
                    job.issued.entry(unit).or_default().push(n);
                    job.started = true;
                    self.leases.insert(
                        n,
                        Lease {
                            job: id,
                            unit,
                            worker: w,
                            issued: now,
                            deadline: now + self.policy.lease_time,
                            active: true,
                        },
                    );
                    out.push(Granted {
                        lease: self.lease_id(n),
                        job: id,
                        unit,
                    });
                    if let Some(h) = held.as_mut() {
                        *h.entry(user.clone()).or_default() += 1;
                    }
                }
            }
        }
        self.counters.units_leased += out.len() as u64;
        out
    }
}
