//! What the coordinator forgets: ended jobs past their retention. A job's record is a few
//! hundred bytes, but a farm that runs for months ends hundreds of thousands of jobs, and each
//! one stays in memory, in the store, in every listing and in every restart's load. So an
//! ended job (done, failed or cancelled; a frame range once all its frames have ended) is
//! kept for [`Policy::job_retention`] and at most [`Policy::max_ended_jobs`] of them in all,
//! the oldest going first. Its output files stay where they were written: they are the
//! user's.
//!
//! [`Policy::job_retention`]: super::Policy::job_retention
//! [`Policy::max_ended_jobs`]: super::Policy::max_ended_jobs

use std::collections::BTreeMap;

use tessera_proto::ids::JobId;

use super::Scheduler;
use crate::store::{JobPhase, Op};

impl Scheduler {
    /// Forgets the ended jobs past [`Policy::job_retention`](super::Policy::job_retention)
    /// or, oldest first, past [`Policy::max_ended_jobs`](super::Policy::max_ended_jobs) in
    /// all, with their sums, logs and leases (and the scene of one still retryable, unless
    /// another job keeps it); returns the store changes.
    pub fn sweep_jobs(&mut self, now_ms: i64) -> Vec<Op> {
        let oldest = now_ms.saturating_sub(self.policy.job_retention.as_millis() as i64);
        let ended = self.ended_groups();
        let mut total: usize = ended.iter().map(|(_, _, members)| members.len()).sum();
        let mut ops = Vec::new();
        for (ended_ms, _, members) in ended {
            if ended_ms >= oldest && total <= self.policy.max_ended_jobs {
                break;
            }
            total -= members.len();
            for id in members {
                ops.extend(self.forget_job(id));
            }
        }
        ops
    }

    /// Ended jobs as they are listed (a job, or a frame range with every frame ended), each
    /// with when its last job ended, oldest first.
    fn ended_groups(&self) -> Vec<(i64, JobId, Vec<JobId>)> {
        let mut groups: BTreeMap<JobId, Vec<JobId>> = BTreeMap::new();
        for (&id, job) in &self.jobs {
            let group = job.rec.range.as_ref().map_or(id, |r| JobId(r.id));
            groups.entry(group).or_default().push(id);
        }
        let mut out: Vec<(i64, JobId, Vec<JobId>)> = groups
            .into_iter()
            .filter_map(|(group, members)| {
                let mut ended_ms = i64::MIN;
                for id in &members {
                    let job = self.jobs.get(id)?;
                    if job.rec.phase == JobPhase::Active {
                        return None;
                    }
                    ended_ms = ended_ms.max(job.rec.finished_ms);
                }
                Some((ended_ms, group, members))
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Forgets ended job `id`; returns the store changes.
    fn forget_job(&mut self, id: JobId) -> Vec<Op> {
        let Some(job) = self.jobs.remove(&id) else {
            return Vec::new();
        };
        if let Some(r) = &job.rec.range {
            let range = JobId(r.id);
            if let Some(members) = self.ranges.get_mut(&range) {
                members.retain(|m| *m != id);
                if members.is_empty() {
                    self.ranges.remove(&range);
                }
            }
        }
        self.leases.retain(|_, l| l.job != id);
        self.logs.remove(&id);
        self.stored_logs.remove(&id);
        self.lapses.retain(|(j, _), _| *j != id);
        self.referee_wanted.retain(|(j, _)| *j != id);
        let mut ops = vec![Op::DropSums(id.0), Op::DropLog(id.0), Op::DropJob(id.0)];
        if job.retryable && !self.scene_is_kept(&job.rec.scene_hash) {
            ops.push(Op::DropScene(job.rec.scene_hash.clone()));
        }
        ops
    }
}
