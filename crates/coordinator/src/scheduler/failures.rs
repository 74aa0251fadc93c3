//! Units that fail on a worker, handled as render farms handle them (Flamenco's rules).
//!
//! A worker that cannot render a unit says so, with the reason (`ReleaseLeases.cannot_render`:
//! its scene does not load there, breaks the worker's limits, a texture does not fit its
//! decode budget). The unit goes back to the queue for another worker, and the failure is kept
//! in the frame's record. After [`Policy::blocklist_after`](super::Policy) failures of one
//! job's units on one worker (by name, so that a worker that restarts is the same one), that
//! worker is blocklisted for that job alone: it takes other jobs as before. A frame fails, with
//! every reason collected, after [`Policy::fail_frame_after`](super::Policy) failures, or as
//! soon as every connected worker that fits it is blocklisted (nobody is left to try).
//!
//! Toward the frame's limit, one machine's failures count at most `blocklist_after` times,
//! and always fewer than the limit (see [`counted_failures`]): a blocklist is kept by name, so
//! a host registering a new name each time could otherwise report failures until the frame
//! fails, and so fail anybody's job by itself. An honest machine is blocklisted at that many
//! under its one name, so it loses nothing. And once one machine has failed the frame's limit
//! of units (under any names), the machine itself (its address) is blocklisted for the job,
//! and nothing more it reports is recorded: so a host cycling through names cannot grow the
//! record without end either, and a farm of one machine still fails the frame at the limit,
//! as nobody is left.
//!
//! A lease that lapses is not counted against its worker: a worker killed, preempted or cut
//! off costs one unit's time and the unit goes out again at once, and counting it would
//! blocklist healthy machines on a farm of preemptible ones (the chaos test kills a worker
//! every few hundred milliseconds). It is counted against its unit instead: a unit whose lease
//! has lapsed on [`Policy::fail_unit_after_lapses`](super::Policy) different machines (3; the
//! address a worker registered from, or its name where that is unknown) is one that crashes or
//! stalls whoever takes it (a tile that runs a worker out of memory), and its frame fails at
//! once rather than the unit going on round the farm killing workers. Random deaths almost
//! never hit one unit on three machines: a unit is held for the moments it renders. Counting
//! machines rather than names keeps one host (however many names it registers, hostile or
//! not) from failing a frame by itself. Where a unit lapsed is kept in memory only, like the
//! leases.
//!
//! Failures, blocklists and the frame's error are kept in the record, so a restart keeps them.

use std::time::Instant;

use tessera_proto::ids::{JobId, LeaseId};

use super::{Scheduler, Worker};
use crate::job::{Job, Unit};
use crate::store::{JobPhase, Op, UnitFailure};

/// Characters of a failure's reason kept.
const MAX_REASON_CHARS: usize = 300;

/// The failures of a frame as one error: each distinct (worker, reason) once, with its count.
fn summary(failures: &[UnitFailure], why_now: &str) -> String {
    let mut seen: Vec<(&UnitFailure, usize)> = Vec::new();
    for f in failures {
        match seen
            .iter_mut()
            .find(|(g, _)| g.worker == f.worker && g.reason == f.reason)
        {
            Some((_, n)) => *n += 1,
            None => seen.push((f, 1)),
        }
    }
    let parts: Vec<String> = seen
        .iter()
        .map(|(f, n)| {
            let times = if *n > 1 {
                format!(", {n} times")
            } else {
                String::new()
            };
            format!(
                "worker {} ({}){times}: cannot render tile {} batch {}: {}",
                f.worker_id,
                f.worker.escape_debug(),
                f.tile,
                f.batch,
                f.reason
            )
        })
        .collect();
    format!(
        "{} failures ({why_now}): {}",
        failures.len(),
        parts.join("; ")
    )
}

/// The failures that count toward a frame's limit of `fail_after`: each machine's at most
/// `blocklist_after` times and at most `fail_after − 1` times, so that no one machine reaches
/// the limit alone.
fn counted_failures(failures: &[UnitFailure], blocklist_after: u32, fail_after: u32) -> usize {
    let cap = blocklist_after.min(fail_after.saturating_sub(1)).max(1) as usize;
    let mut per_machine: Vec<(&str, usize)> = Vec::new();
    for f in failures {
        match per_machine.iter_mut().find(|(m, _)| *m == f.machine()) {
            Some((_, n)) => *n += 1,
            None => per_machine.push((f.machine(), 1)),
        }
    }
    per_machine.iter().map(|&(_, n)| n.min(cap)).sum()
}

/// Whether `w` is on `blocklist`: by its name, or by its machine's address.
pub(super) fn on_blocklist(blocklist: &[String], w: &Worker) -> bool {
    blocklist.iter().any(|b| *b == w.name || b == w.machine())
}

impl Scheduler {
    /// Worker `w` says it cannot render the units of `ids`, and why: each is a failure of its
    /// job on that worker (the unit itself is put back by the release that follows); returns
    /// the store changes.
    pub fn cannot_render(
        &mut self,
        w: u64,
        ids: &[LeaseId],
        reason: &str,
        now: Instant,
        now_ms: i64,
    ) -> Vec<Op> {
        let reason: String = reason.chars().take(MAX_REASON_CHARS).collect();
        let mut ops = Vec::new();
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get(&n));
            let Some((job, unit)) = lease.filter(|l| l.active).map(|l| (l.job, l.unit)) else {
                continue;
            };
            ops.extend(self.unit_failed(job, w, unit, &reason, now, now_ms));
        }
        ops
    }

    /// Records that `unit` of job `id` failed on worker `w`: blocklists the worker for the job
    /// at the limit, and fails the frame at its limit or when nobody is left to try.
    fn unit_failed(
        &mut self,
        id: JobId,
        w: u64,
        unit: Unit,
        reason: &str,
        now: Instant,
        now_ms: i64,
    ) -> Vec<Op> {
        let worker_id = self.worker_id(w).to_string();
        let Some((name, machine)) = self
            .workers
            .get(&w)
            .map(|x| (x.name.clone(), x.machine().to_string()))
        else {
            return Vec::new();
        };
        let (blocklist_after, fail_after) = (
            self.policy.blocklist_after.max(1),
            self.policy.fail_frame_after.max(1),
        );
        let Some(job) = self.jobs.get_mut(&id).filter(|j| j.is_live()) else {
            return Vec::new();
        };
        let on_machine = job
            .rec
            .failures
            .iter()
            .filter(|f| f.machine() == machine)
            .count();
        if on_machine >= fail_after as usize {
            // Units leased before the machine was blocklisted: they go back, unrecorded.
            return Vec::new();
        }
        if on_machine + 1 >= fail_after as usize && !job.rec.blocklist.contains(&machine) {
            tracing::warn!(
                "{id}: machine {} blocklisted for it after {} failures under any name",
                machine.escape_debug(),
                on_machine + 1
            );
            job.rec.blocklist.push(machine.clone());
        }
        tracing::warn!(
            "{id}: worker {worker_id} ({}) cannot render tile {} batch {}: {reason}",
            name.escape_debug(),
            unit.tile,
            unit.batch
        );
        job.rec.failures.push(UnitFailure {
            worker: name.clone(),
            worker_id,
            tile: unit.tile,
            batch: unit.batch,
            reason: reason.to_string(),
            unix_ms: now_ms,
            machine,
        });
        let mine = job.rec.failures.iter().filter(|f| f.worker == name).count();
        if mine >= blocklist_after as usize && !job.rec.blocklist.contains(&name) {
            tracing::warn!(
                "{id}: worker {} blocklisted for it after {mine} failures",
                name.escape_debug()
            );
            job.rec.blocklist.push(name);
        }
        let why = if counted_failures(&job.rec.failures, blocklist_after, fail_after)
            >= fail_after as usize
        {
            Some(format!("the most a frame may have is {fail_after}"))
        } else if self.nobody_left(id, now) {
            Some("every connected worker that fits it is blocklisted".to_string())
        } else {
            None
        };
        match (why, self.jobs.get(&id)) {
            (Some(why), Some(job)) => {
                let error = summary(&job.rec.failures, &why);
                self.end_job(id, JobPhase::Failed, error, now_ms)
            }
            (None, Some(job)) => vec![Op::PutJob(job.rec.clone())],
            _ => Vec::new(),
        }
    }

    /// The lease of `unit` of job `id` lapsed on worker `w`: at the limit of distinct workers,
    /// the frame fails. Returns the store changes.
    pub(super) fn unit_lapsed(&mut self, id: JobId, unit: Unit, w: u64) -> Vec<Op> {
        let limit = self.policy.fail_unit_after_lapses;
        let Some((name, machine)) = self
            .workers
            .get(&w)
            .map(|x| (x.name.clone(), x.machine().to_string()))
        else {
            return Vec::new();
        };
        if limit == 0 || !self.jobs.get(&id).is_some_and(|j| j.is_live()) {
            return Vec::new();
        }
        // Machines, not names: one host registering many names (or a hostile one taking units
        // to let them lapse) counts once, so it cannot fail a frame by itself.
        let seen = self.lapses.entry((id, unit)).or_default();
        if !seen.iter().any(|(m, _)| *m == machine) {
            seen.push((machine.clone(), name.clone()));
        }
        if seen.len() < limit as usize {
            return Vec::new();
        }
        let on: Vec<String> = seen
            .iter()
            .map(|(_, n)| n.escape_debug().to_string())
            .collect();
        let reason = format!(
            "its lease lapsed on {} different machines (workers {}): each died or stopped \
             answering while it held this unit",
            on.len(),
            on.join(", ")
        );
        let now_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as i64);
        let worker_id = self.worker_id(w).to_string();
        let Some(job) = self.jobs.get_mut(&id) else {
            return Vec::new();
        };
        tracing::warn!(
            "{id}: tile {} batch {}: {reason}; the frame fails",
            unit.tile,
            unit.batch
        );
        job.rec.failures.push(UnitFailure {
            worker: name,
            worker_id,
            tile: unit.tile,
            batch: unit.batch,
            reason,
            unix_ms: now_ms,
            machine,
        });
        let error = summary(
            &job.rec.failures,
            &format!("a unit lapsed on {limit} machines, the most one may"),
        );
        self.end_job(id, JobPhase::Failed, error, now_ms)
    }

    /// Whether worker `w` is blocklisted for `job`.
    pub(super) fn blocklisted(&self, job: &Job, w: u64) -> bool {
        !job.rec.blocklist.is_empty()
            && self
                .workers
                .get(&w)
                .is_some_and(|x| on_blocklist(&job.rec.blocklist, x))
    }

    /// Whether some worker is connected that fits job `id` and every such worker is
    /// blocklisted for it.
    fn nobody_left(&self, id: JobId, now: Instant) -> bool {
        let Some(job) = self.jobs.get(&id) else {
            return false;
        };
        let lease_time = self.policy.lease_time;
        let mut fitting = self.workers.iter().filter(|(_, w)| {
            w.alive(now, lease_time)
                && !w.draining
                && !w.quarantined
                && w.convicted.is_none()
                && w.caps.fits(&job.rec)
        });
        let mut any = false;
        let all_blocked = fitting.all(|(&n, _)| {
            any = true;
            self.blocklisted(job, n)
        });
        any && all_blocked
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failure(worker: &str, reason: &str) -> UnitFailure {
        UnitFailure {
            worker: worker.into(),
            worker_id: format!("w1-{}", worker.len()),
            tile: 0,
            batch: 1,
            reason: reason.into(),
            unix_ms: 0,
            machine: String::new(),
        }
    }

    fn on(machine: &str, worker: &str) -> UnitFailure {
        UnitFailure {
            machine: machine.into(),
            ..failure(worker, "no")
        }
    }

    #[test]
    fn one_machine_counts_toward_a_frames_limit_at_most_its_blocklist_and_below_the_limit() {
        // One host under five names: three count (its blocklist limit), not five.
        let hostile: Vec<_> = (0..5).map(|i| on("10.0.0.9", &format!("w{i}"))).collect();
        assert_eq!(counted_failures(&hostile, 3, 5), 3);
        // Below the limit however high the blocklist limit is.
        assert_eq!(counted_failures(&hostile, 10, 5), 4);
        // Two machines add up; a record without a machine counts by its worker's name.
        let two = [
            hostile.as_slice(),
            &[on("10.0.0.7", "a"), on("10.0.0.7", "a")],
        ]
        .concat();
        assert_eq!(counted_failures(&two, 3, 5), 5);
        let old = [failure("a", "x"), failure("b", "x"), failure("b", "x")];
        assert_eq!(counted_failures(&old, 3, 5), 3);
        // A limit of one fails the frame at its first failure.
        assert_eq!(counted_failures(&hostile[..1], 3, 1), 1);
    }

    #[test]
    fn a_frames_error_names_each_worker_and_reason_once_with_its_count() {
        let f = [
            failure("small", "too wide"),
            failure("small", "too wide"),
            failure("tiny", "no memory"),
        ];
        assert_eq!(
            summary(&f, "the most a frame may have is 3"),
            "3 failures (the most a frame may have is 3): worker w1-5 (small), 2 times: cannot \
             render tile 0 batch 1: too wide; worker w1-4 (tiny): cannot render tile 0 batch \
             1: no memory"
        );
    }
}
