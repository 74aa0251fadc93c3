//! Audits: a share of an audited job's units is rendered twice, by workers on two hosts, and
//! merged only once the copies agree bit for bit. Rendering is deterministic, so a copy that
//! differs is a wrong one: the coordinator then renders the unit itself (the referee), and
//! convicts whoever differs from that. A convicted worker gets no more work, and every result
//! it gave a live audited job is taken back and rendered again (docs/farm.md, "Audits").
//!
//! One host is one vote however many registrations it makes, and a worker cannot tell an
//! audited unit from another: the draw uses a generator it cannot see, and a held result is
//! acknowledged as merged.

use std::time::Instant;

use tessera_proto::ids::JobId;
use tessera_render::guide::SdTree;
use tessera_render::TileSums;

use super::leases::has_active_lease;
use super::{Merged, Scheduler, UnitResult};
use crate::error::Refusal;
use crate::job::{same_result, AuditHold, Job, KeptUnits, Source, Unit, NOBODY};
use crate::store::{AuditRecord, Op};

/// Whether worker `w`, registered from `host`, may not give unit `u` its audit copy: it, or a
/// worker on its host, has a copy held already (or the unit waits for the referee). Copies from
/// one host are one vote, however many registrations it makes.
pub(super) fn audit_excludes(job: &Job, u: Unit, w: u64, host: &str) -> bool {
    job.audits.get(&u).is_some_and(|h| {
        h.disputed
            || h.results.iter().any(|(k, ..)| *k == w)
            || (!host.is_empty() && h.hosts.contains(host))
    })
}

impl Scheduler {
    /// Whether the next unit of an audited job is checked: a draw from a xorshift generator
    /// the service seeds from the operating system.
    fn draw_audit(&mut self) -> bool {
        if self.policy.audit <= 0.0 {
            return false;
        }
        let mut x = self.audit_rng;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.audit_rng = x;
        ((x >> 11) as f64 / (1u64 << 53) as f64) < self.policy.audit
    }

    /// The audit of a checked result for `unit` of audited job `job_id` from worker `w`.
    /// Returns the result to merge now, the worker it counts as from, and the store changes of
    /// any conviction; or `None` if it is held.
    ///
    /// A unit drawn for an audit is held and handed to a worker on another host (one host is
    /// one vote, however many registrations it makes). When that copy matches bit for bit, the
    /// unit is settled and merged (as from [`NOBODY`]: two hosts vouch for it). When it
    /// differs, nobody's vote decides: the unit goes to the coordinator's referee, which
    /// renders it itself ([`Scheduler::referee`]) and convicts whoever differs from that. The
    /// same happens to a held unit no other host takes within a lease time ([`Self::expire`]),
    /// so a farm of one or two hosts still finishes every job.
    pub(super) fn audit_step(
        &mut self,
        w: u64,
        job_id: JobId,
        unit: Unit,
        (sums, train): (TileSums, Option<&SdTree>),
        now: Instant,
    ) -> Option<(TileSums, u64, Vec<Op>)> {
        let host = self
            .workers
            .get(&w)
            .map(|x| x.host.clone())
            .unwrap_or_default();
        let job = self.jobs.get_mut(&job_id)?;
        let Some(hold) = job.audits.get_mut(&unit) else {
            if !self.draw_audit() {
                return Some((sums, w, Vec::new()));
            }
            let job = self.jobs.get_mut(&job_id)?;
            job.audits.insert(
                unit,
                AuditHold {
                    results: vec![(w, sums, train.cloned())],
                    hosts: std::iter::once(host).filter(|h| !h.is_empty()).collect(),
                    disputed: false,
                    since: Some(now),
                },
            );
            job.requeue.push_front(unit);
            return None;
        };
        if !(hold.results.iter()).any(|(_, s, t)| same_result((s, t.as_ref()), (&sums, train))) {
            hold.results.push((w, sums, train.cloned()));
            if !host.is_empty() {
                hold.hosts.insert(host);
            }
            hold.disputed = true;
            let involved: Vec<u64> = hold.results.iter().map(|(k, ..)| *k).collect();
            tracing::warn!(
                "{job_id} tile {} batch {}: {} workers' copies differ; the coordinator renders \
                 the unit to decide",
                unit.tile,
                unit.batch,
                involved.len()
            );
            for k in involved {
                if let Some(x) = self.workers.get_mut(&k) {
                    x.disputes.insert((job_id, unit));
                }
            }
            self.referee_wanted.insert((job_id, unit));
            return None;
        }
        let hold = job.audits.remove(&unit).unwrap_or_default();
        for (k, ..) in &hold.results {
            if let Some(x) = self.workers.get_mut(k) {
                x.audits_passed += 1;
            }
        }
        if let Some(x) = self.workers.get_mut(&w) {
            x.audits_passed += 1;
        }
        Some((sums, NOBODY, Vec::new()))
    }

    /// Audited units the coordinator must render itself, each once: their copies disagree,
    /// or no worker on another host took the second copy within a lease time. The service
    /// renders each and hands the result to [`Scheduler::referee`].
    pub fn take_referee_work(&mut self) -> Vec<(JobId, Unit)> {
        std::mem::take(&mut self.referee_wanted)
            .into_iter()
            .collect()
    }

    /// The coordinator's own render of held `unit` of `job_id`: the truth, since rendering is
    /// deterministic and the coordinator trusts itself. Every held copy that differs from it
    /// convicts its worker; those that match pass; the referee's sums are merged (as from
    /// [`NOBODY`]).
    ///
    /// In a guided job's training epoch the render comes with its training tree, which the
    /// copies' must equal too, and which is added to the epoch's with the merge.
    pub fn referee(
        &mut self,
        job_id: JobId,
        unit: Unit,
        result: impl Into<UnitResult>,
        now: Instant,
        kept: &dyn KeptUnits,
        now_ms: i64,
    ) -> Result<Merged, Refusal> {
        let UnitResult { sums, train } = result.into();
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(Merged::Discarded);
        };
        if !job.is_live() {
            return Ok(Merged::Discarded);
        }
        if job.is_done(unit) {
            return Ok(Merged::Duplicate);
        }
        let hold = job.audits.remove(&unit).unwrap_or_default();
        for l in job.issued.remove(&unit).unwrap_or_default() {
            self.leases.remove(&l);
        }
        let mut ops = Vec::new();
        for (k, copy, copy_train) in &hold.results {
            if let Some(x) = self.workers.get_mut(k) {
                x.disputes.remove(&(job_id, unit));
            }
            if same_result((copy, copy_train.as_ref()), (&sums, train.as_ref())) {
                if let Some(x) = self.workers.get_mut(k) {
                    x.audits_passed += 1;
                }
                continue;
            }
            let why = format!(
                "an audit found its result for {job_id} tile {} batch {} differs from the \
                 coordinator's own render of it",
                unit.tile, unit.batch
            );
            ops.extend(self.convict(*k, why, (job_id, unit), kept, now_ms));
        }
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(Merged::Discarded);
        };
        // A conviction may have taken results back, this unit among them if it had been
        // merged; it is not done until this merge either way.
        if job.is_done(unit) {
            return Ok(Merged::Duplicate);
        }
        if let Some(g) = &mut job.guiding {
            // A conviction may have rewound the epochs since this render began: a unit past
            // the barrier now, or of an epoch no longer training, sampled a guide that is gone.
            let area = sums.rect.area() as u64;
            if unit.batch >= g.released() || g.check(unit.batch, area, train.as_ref()).is_err() {
                return Ok(Merged::Discarded);
            }
            if let Some(t) = &train {
                g.add(t);
            }
        }
        self.serial += 1;
        let source = Source {
            worker: NOBODY,
            serial: self.serial,
        };
        let (merge_ops, finished) = job.merge(unit, sums, source, now)?;
        ops.extend(merge_ops);
        self.counters.units_refereed += 1;
        Ok(Merged::New { ops, finished })
    }

    /// Convicts worker `w` of returning wrong results: it gets no more work, and every result
    /// it gave a live audited job is taken back ([`Job::take_back`]) and rendered again by
    /// others. Returns the store changes, a durable [`AuditRecord`] among them.
    pub fn convict(
        &mut self,
        w: u64,
        why: String,
        caught_on: (JobId, Unit),
        kept: &dyn KeptUnits,
        now_ms: i64,
    ) -> Vec<Op> {
        let id = self.worker_id(w);
        let Some(worker) = self.workers.get_mut(&w) else {
            return Vec::new();
        };
        if worker.convicted.is_some() {
            return Vec::new();
        }
        worker.convicted = Some(why.clone());
        worker.quarantined = true;
        worker.disputes.clear();
        let name = worker.name.clone();
        let contributed = std::mem::take(&mut worker.jobs);
        self.take_leases(w);
        let mut ops = Vec::new();
        let mut rebuilt = Vec::new();
        let mut finished = Vec::new();
        let mut units = 0;
        for (job_id, job) in &mut self.jobs {
            if !job.rec.audited {
                continue;
            }
            if !job.is_live() {
                if contributed.contains(job_id) {
                    finished.push(job_id.0);
                }
                continue;
            }
            let back = job.take_back(w, kept);
            if !back.ops.is_empty() || back.units > 0 {
                rebuilt.push(job_id.0);
            }
            units += back.units;
            ops.extend(back.ops);
            for l in back.stale_leases {
                self.leases.remove(&l);
            }
        }
        self.convictions += 1;
        tracing::warn!(
            "worker {id} ({}) convicted: {why}; {units} of its units in {} live jobs go back to \
             be rendered again{}",
            name.escape_debug(),
            rebuilt.len(),
            if finished.is_empty() {
                String::new()
            } else {
                format!(
                    "; it also gave results to jobs that had already finished: {}",
                    finished
                        .iter()
                        .map(|j| JobId(*j).to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        );
        ops.push(Op::PutAudit(AuditRecord {
            epoch: self.epoch,
            n: self.convictions,
            time_ms: now_ms,
            worker: id.to_string(),
            name,
            caught_on: (caught_on.0 .0, caught_on.1.tile, caught_on.1.batch),
            units_requeued: units,
            jobs_rebuilt: rebuilt,
            jobs_finished: finished,
        }));
        ops
    }

    /// Sends to the referee each held unit that no worker on another host has taken within a
    /// lease time (a farm of one host, or the other hosts gone), rather than let it wait for
    /// ever.
    pub(super) fn referee_stale_holds(&mut self, now: Instant) {
        for (id, job) in &mut self.jobs {
            if !job.is_live() {
                continue;
            }
            let stale: Vec<Unit> = job
                .audits
                .iter()
                .filter(|(u, hold)| {
                    !hold.disputed
                        && hold.since.is_some_and(|t| {
                            now.saturating_duration_since(t) >= self.policy.lease_time
                        })
                        && !has_active_lease(job, **u, &self.leases)
                })
                .map(|(u, _)| *u)
                .collect();
            for u in stale {
                if let Some(hold) = job.audits.get_mut(&u) {
                    hold.disputed = true;
                }
                self.referee_wanted.insert((*id, u));
            }
        }
    }
}
