//! Leases: a unit lent to a worker until a deadline that heartbeats renew. A lease that
//! lapses, is handed back, or is taken from a quarantined worker puts its unit back at the
//! front of its job's queue; a late result quoting it is still merged once if the unit is not
//! done by then.
//!
//! Lease ids carry the boot's epoch, so a lease from before a restart is stale rather than
//! confused with a new lease of the same number.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::Instant;

use tessera_proto::ids::{JobId, LeaseId};

use super::Scheduler;
use crate::error::Refusal;
use crate::job::{Job, Unit};
use crate::store::Op;

/// A lease: a unit lent to a worker until `deadline`.
#[derive(Debug)]
pub struct Lease {
    /// Job id.
    pub job: JobId,
    /// The unit.
    pub unit: Unit,
    /// Worker id.
    pub worker: u64,
    /// When it was issued: a holder that keeps a unit far longer than a unit takes is slow
    /// (or hoarding), and others may race it.
    pub issued: Instant,
    /// When it lapses unless renewed.
    pub deadline: Instant,
    /// False once lapsed or handed back: the unit is back in the queue, but a late result
    /// quoting this lease is still merged (once) if the unit is not done by then.
    pub active: bool,
}

/// Whether unit `u` of `job` has a live lease.
pub(super) fn has_active_lease(job: &Job, u: Unit, leases: &HashMap<u64, Lease>) -> bool {
    job.issued
        .get(&u)
        .is_some_and(|ids| ids.iter().any(|l| leases.get(l).is_some_and(|x| x.active)))
}

/// Puts the unit of `lease` back at the front of its job's queue, if the job still needs it:
/// a lease that lapsed, was handed back, or was taken from a quarantined worker. Returns
/// whether the unit went back.
pub(super) fn requeue(jobs: &mut BTreeMap<JobId, Job>, lease: &mut Lease) -> bool {
    lease.active = false;
    match jobs.get_mut(&lease.job) {
        Some(job) if job.is_live() && !job.is_done(lease.unit) => {
            job.requeue.push_front(lease.unit);
            true
        }
        _ => false,
    }
}

impl Scheduler {
    /// A lease's id as sent: this boot and its number.
    pub fn lease_id(&self, n: u64) -> LeaseId {
        LeaseId {
            epoch: self.epoch,
            n,
        }
    }

    /// The number of a lease issued in this boot. One from before a restart is stale rather
    /// than confused with a new lease of the same number.
    pub fn lease_number(&self, id: LeaseId) -> Result<u64, Refusal> {
        if id.epoch != self.epoch {
            return Err(Refusal::Precondition(format!(
                "lease {id} is from before the coordinator restarted; drop it"
            )));
        }
        Ok(id.n)
    }

    /// The number of lease `id` if it was issued in this boot to worker `w`.
    pub(super) fn held_by(&self, w: u64, id: LeaseId) -> Option<u64> {
        let n = self.lease_number(id).ok()?;
        self.leases
            .get(&n)
            .is_some_and(|l| l.worker == w)
            .then_some(n)
    }

    /// Lapses overdue leases, putting their units back at the front of their job's queue.
    /// Returns whether any unit became available (or a frame failed: its waiters wake too). A
    /// unit that has now lapsed on too many workers fails its frame
    /// ([`Scheduler::unit_lapsed`]); those store changes wait in [`Scheduler::take_deferred`].
    pub fn expire(&mut self, now: Instant) -> bool {
        let mut lapsed = Vec::new();
        for lease in self.leases.values_mut() {
            if lease.active && lease.deadline <= now && requeue(&mut self.jobs, lease) {
                lapsed.push((lease.job, lease.unit, lease.worker));
            }
        }
        let any = !lapsed.is_empty();
        // In unit order, so that which lapse fails a frame does not depend on the map's order.
        lapsed.sort_unstable_by_key(|&(job, unit, w)| (job, unit, w));
        for (job, unit, w) in lapsed {
            let ops = self.unit_lapsed(job, unit, w);
            self.deferred.extend(ops);
        }
        self.referee_stale_holds(now);
        any
    }

    /// Store changes made while leasing or lapsing that are still to be committed.
    pub fn take_deferred(&mut self) -> Vec<Op> {
        std::mem::take(&mut self.deferred)
    }

    /// Renews worker `w`'s leases; returns those it should drop.
    pub fn heartbeat(&mut self, w: u64, ids: &[LeaseId], now: Instant) -> Vec<LeaseId> {
        let deadline = now + self.policy.lease_time;
        let mut revoked = Vec::new();
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get_mut(&n));
            let keep = lease.is_some_and(|l| {
                let live = self
                    .jobs
                    .get(&l.job)
                    .is_some_and(|j| j.is_live() && !j.is_done(l.unit));
                if live && l.active {
                    l.deadline = deadline;
                }
                live
            });
            if !keep {
                revoked.push(id);
            }
        }
        revoked
    }

    /// Hands leases back: their units go to the front of the queue.
    pub fn release(&mut self, w: u64, ids: &[LeaseId]) -> u32 {
        let mut released = 0;
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get_mut(&n));
            if let Some(lease) = lease.filter(|l| l.active) {
                released += u32::from(requeue(&mut self.jobs, lease));
            }
        }
        released
    }

    /// Takes back worker `w`'s live leases: their units go to the front of their queues.
    pub(super) fn take_leases(&mut self, w: u64) {
        for lease in self.leases.values_mut() {
            if lease.worker == w && lease.active {
                requeue(&mut self.jobs, lease);
            }
        }
    }

    /// Leases held now by worker `w`.
    pub fn leases_of(&self, w: u64) -> usize {
        self.leases
            .values()
            .filter(|l| l.worker == w && l.active)
            .count()
    }

    /// The live jobs of which worker `w` holds a lease (live, or lapsed but not yet
    /// forgotten), in id order: what a worker may read of the farm's scenes, files and guides.
    /// A worker token is not a pass to every user's files.
    pub fn jobs_leased_by(&self, w: u64) -> Vec<&Job> {
        let ids: BTreeSet<JobId> = self
            .leases
            .values()
            .filter(|l| l.worker == w)
            .map(|l| l.job)
            .collect();
        ids.into_iter()
            .filter_map(|id| self.jobs.get(&id))
            .filter(|j| j.is_live())
            .collect()
    }

    /// The encoding of guide `hash` of a live guided job of which worker `w` holds a lease.
    pub fn guide_leased_by(&self, w: u64, hash: &str) -> Option<std::sync::Arc<Vec<u8>>> {
        self.jobs_leased_by(w)
            .into_iter()
            .find_map(|j| j.guiding.as_ref()?.by_hash(hash))
    }

    /// Live leases of a job's units.
    pub fn units_leased(&self, job: &Job) -> u64 {
        job.issued
            .values()
            .filter(|ids| {
                ids.iter()
                    .any(|l| self.leases.get(l).is_some_and(|x| x.active))
            })
            .count() as u64
    }
}
