//! Job control while a job runs: pausing, resuming and changing its priority (`tessera pause`,
//! `resume`, `priority`). A paused job keeps its held leases, whose results merge as usual, and
//! is leased nothing new; the flag is kept in the job's record, so a restart keeps it paused.

use tessera_proto::ids::JobId;

use super::Scheduler;
use crate::error::Refusal;
use crate::store::{JobPhase, Op};

impl Scheduler {
    /// Pauses or resumes job `id` (a frame-range job: every frame still active) and sets its
    /// priority, each where given; returns the store changes.
    pub fn update(
        &mut self,
        id: JobId,
        paused: Option<bool>,
        priority: Option<i32>,
    ) -> Result<Vec<Op>, Refusal> {
        let members = self.members(id);
        if !members.iter().any(|m| self.jobs.contains_key(m)) {
            return Err(Refusal::NotFound(format!("unknown job {id}")));
        }
        let live: Vec<JobId> = members
            .into_iter()
            .filter(|m| {
                self.jobs
                    .get(m)
                    .is_some_and(|j| j.rec.phase == JobPhase::Active)
            })
            .collect();
        if live.is_empty() {
            return Err(Refusal::Precondition(format!(
                "{id} has ended: there is nothing to pause, resume or reprioritise"
            )));
        }
        let mut ops = Vec::with_capacity(live.len());
        for m in live {
            let Some(job) = self.jobs.get_mut(&m) else {
                continue;
            };
            if let Some(p) = paused {
                job.rec.paused = p;
            }
            if let Some(p) = priority {
                job.rec.priority = p;
            }
            ops.push(Op::PutJob(job.rec.clone()));
        }
        Ok(ops)
    }

    /// Who submitted job `id` (a range: its first frame's submitter, which is every frame's);
    /// `None` for an unknown job.
    pub fn submitter(&self, id: JobId) -> Option<&str> {
        self.members(id)
            .iter()
            .find_map(|m| self.jobs.get(m))
            .map(|j| j.rec.submitter.as_str())
    }

    /// Whether job `id` is held back from new leases: paused, or waiting for another job.
    pub(super) fn held(&self, id: JobId) -> bool {
        self.jobs.get(&id).is_some_and(|j| j.rec.paused) || self.waits(id)
    }
}
