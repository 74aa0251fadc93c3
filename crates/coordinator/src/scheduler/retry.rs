//! Retrying failed frames (`tessera retry JOB [--frame N]`), as farm managers requeue them.
//!
//! A failed frame's sums are dropped when it fails, but its scene (and so the files the scene
//! names, which the asset store keeps while a stored scene names them) is kept for
//! [`Policy::retry_window`](super::Policy). A retry puts the frame back as it was admitted:
//! no failures, no blocklist (the operator has fixed something, or wants to try again), no
//! sums, the current renderer revision. It renders from the first batch, and since every
//! sample is a function of the job's seed, pixel and index, it gives the bits an unfailed run
//! gives. Jobs that failed only because they waited (`submit --after`) for a retried frame are
//! put back too, waiting for it again. Once the window has passed the scene goes, and a retry
//! says to submit the job again.

use tessera_proto::ids::JobId;
use tessera_render::IMAGE_REVISION;

use super::after::DEPENDENCY_ENDED;
use super::Scheduler;
use crate::error::Refusal;
use crate::job::Job;
use crate::store::{JobPhase, Op};

impl Scheduler {
    /// Whether a job that needs the scene of this hash is active, or failed and still
    /// retryable: the scene stays in the store while so.
    pub(super) fn scene_is_kept(&self, hash: &str) -> bool {
        self.jobs
            .values()
            .any(|j| (j.rec.phase == JobPhase::Active || j.retryable) && j.rec.scene_hash == hash)
    }

    /// Puts back the failed frames of job `id` (a frame-range job: every failed frame, or
    /// frame `frame` alone), and the jobs that failed only because they waited for one of
    /// them, unless that would take the active jobs past `max_active` (the coordinator's
    /// `max_active_jobs`, which a submission keeps to as well). Returns the ids put back and
    /// the store changes.
    pub fn retry(
        &mut self,
        id: JobId,
        frame: Option<u32>,
        max_active: usize,
    ) -> Result<(Vec<JobId>, Vec<Op>), Refusal> {
        let members: Vec<JobId> = self
            .members(id)
            .into_iter()
            .filter(|m| self.jobs.contains_key(m))
            .collect();
        if members.is_empty() {
            return Err(Refusal::NotFound(format!("unknown job {id}")));
        }
        let members: Vec<JobId> = match frame {
            None => members,
            Some(f) => {
                let m: Vec<JobId> = members
                    .into_iter()
                    .filter(|m| self.jobs.get(m).is_some_and(|j| j.rec.frame == Some(f)))
                    .collect();
                if m.is_empty() {
                    return Err(Refusal::NotFound(format!("{id} has no frame {f}")));
                }
                m
            }
        };
        let failed: Vec<JobId> = members
            .iter()
            .copied()
            .filter(|m| {
                self.jobs
                    .get(m)
                    .is_some_and(|j| j.rec.phase == JobPhase::Failed)
            })
            .collect();
        if failed.is_empty() {
            let what = frame.map_or_else(|| id.to_string(), |f| format!("{id} frame {f}"));
            return Err(Refusal::Precondition(format!(
                "{what} has no failed frame to retry (only failed frames are retried; a \
                 cancelled job is submitted again)"
            )));
        }
        let window_h = self.policy.retry_window.as_secs_f64() / 3600.0;
        for &m in &failed {
            let job = &self.jobs[&m];
            if !job.retryable {
                return Err(Refusal::Precondition(format!(
                    "{m} failed more than the retry window (tessera coordinator \
                     --retry-window, {window_h:.0} h) ago, and its scene is no longer kept: \
                     submit it again"
                )));
            }
            if let Some(after) = job.rec.after {
                if let super::after::Dependency::Ended(why) = self.dependency(JobId(after)) {
                    return Err(Refusal::Precondition(format!(
                        "{m} waits for {} (--after), which cannot finish: {why}; retry that \
                         one first",
                        JobId(after)
                    )));
                }
            }
        }
        let back = self.retry_closure(failed);
        // What comes back counts against the active-job limit as a submission does: a range
        // once, and only if none of its frames is active still.
        let active = self.active_jobs();
        let mut ranges = std::collections::BTreeSet::new();
        let adding = back
            .iter()
            .filter_map(|m| self.jobs.get(m))
            .filter(|j| {
                j.rec.range.is_none_or(|r| {
                    ranges.insert(r.id)
                        && !self.members(JobId(r.id)).iter().any(|f| {
                            self.jobs
                                .get(f)
                                .is_some_and(|x| x.rec.phase == JobPhase::Active)
                        })
                })
            })
            .count();
        if active + adding > max_active {
            return Err(Refusal::Exhausted(format!(
                "retrying {id} would put back {adding} jobs over the {active} queued or running, \
                 and the limit is {max_active}; retry it once some have finished"
            )));
        }
        let mut put_back = Vec::new();
        let mut ops = Vec::new();
        for m in back {
            let Some(job) = self.jobs.get_mut(&m) else {
                continue;
            };
            let mut rec = job.rec.clone();
            rec.phase = JobPhase::Active;
            rec.error.clear();
            rec.finished_ms = 0;
            rec.failures.clear();
            rec.blocklist.clear();
            rec.adaptive_scale = None;
            rec.checks = Default::default();
            rec.image_revision = IMAGE_REVISION;
            rec.retries += 1;
            *job = Job::new(rec);
            ops.push(Op::PutJob(job.rec.clone()));
            // Its log starts again: the run that failed logged to the row it will write.
            if self.stored_logs.remove(&m).is_some() {
                ops.push(Op::DropLog(m.0));
            }
            tracing::info!("{m} retried");
            put_back.push(m);
        }
        put_back.sort_unstable();
        Ok((put_back, ops))
    }

    /// The failed, retryable jobs a retry of `failed` puts back: those, and the jobs that
    /// failed only because they waited (`--after`) for one put back, in turn.
    fn retry_closure(&self, failed: Vec<JobId>) -> Vec<JobId> {
        let mut back = std::collections::BTreeSet::new();
        let mut todo = failed;
        while let Some(m) = todo.pop() {
            let Some(job) = self.jobs.get(&m) else {
                continue;
            };
            if job.rec.phase != JobPhase::Failed || !job.retryable || !back.insert(m) {
                continue;
            }
            let range = job.rec.range.map(|r| r.id);
            todo.extend(self.jobs.iter().filter_map(|(&d, j)| {
                let waits = j.rec.after.is_some_and(|a| a == m.0 || Some(a) == range);
                (waits
                    && j.rec.phase == JobPhase::Failed
                    && j.rec.error.starts_with(DEPENDENCY_ENDED))
                .then_some(d)
            }));
        }
        back.into_iter().collect()
    }

    /// Jobs queued or running, a frame-range job once: what the active-job limit counts.
    pub(super) fn active_jobs(&self) -> usize {
        let mut ranges = std::collections::BTreeSet::new();
        self.jobs
            .values()
            .filter(|j| j.rec.phase == JobPhase::Active)
            .filter(|j| j.rec.range.is_none_or(|r| ranges.insert(r.id)))
            .count()
    }

    /// Drops the scenes of failed jobs whose retry window has passed (those no other job
    /// keeps); returns the store changes.
    pub fn sweep_failed(&mut self, now_ms: i64) -> Vec<Op> {
        let window = self.policy.retry_window.as_millis() as i64;
        let mut hashes = Vec::new();
        for job in self.jobs.values_mut() {
            if job.retryable && job.rec.finished_ms.saturating_add(window) <= now_ms {
                job.retryable = false;
                hashes.push(job.rec.scene_hash.clone());
            }
        }
        hashes.sort_unstable();
        hashes.dedup();
        hashes
            .into_iter()
            .filter(|h| !self.scene_is_kept(h))
            .map(Op::DropScene)
            .collect()
    }
}
