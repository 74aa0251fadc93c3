//! Dependencies between jobs (`submit --after JOB`): a job starts only when the job it names
//! (a frame-range job: every frame) is done, and fails, with the reason, when that one fails or
//! is cancelled. The dependency is kept in the job's record, so a restart keeps the job waiting;
//! it can only name a job admitted before it, so dependencies never form a cycle.

use tessera_proto::ids::JobId;

use super::Scheduler;
use crate::error::Refusal;
use crate::store::{JobPhase, Op};

/// How [`Scheduler::end_dependents`] begins the error of a job it fails: a retry of the job
/// waited for puts such a job back.
pub(super) const DEPENDENCY_ENDED: &str = "the job it waits for (--after) ended";

/// Where a dependency error names the job that ended first, down a chain of `--after` jobs.
const FIRST_CAUSE: &str = "; first cause: ";

/// Most characters of a failed job's own error that a dependent's error repeats.
const MAX_CAUSE_CHARS: usize = 300;

/// Where the job a dependent waits for stands.
#[derive(Debug, PartialEq)]
pub(super) enum Dependency {
    /// Done, or none: the dependent may run.
    Met,
    /// Still queued or rendering.
    Waiting,
    /// Failed or cancelled: the dependent fails, for this reason.
    Ended(String),
}

impl Scheduler {
    /// Where job (or frame range) `after` stands, for a job that waits for it. One the
    /// coordinator no longer knows is taken as met: it ran here before, and nothing says it
    /// failed.
    pub(super) fn dependency(&self, after: JobId) -> Dependency {
        let mut waiting = false;
        for id in self.members(after) {
            let Some(job) = self.jobs.get(&id) else {
                continue;
            };
            match job.rec.phase {
                JobPhase::Done => {}
                JobPhase::Active => waiting = true,
                JobPhase::Cancelled => return Dependency::Ended(format!("{after} was cancelled")),
                JobPhase::Failed => {
                    return Dependency::Ended(failed_because(after, &job.rec.error))
                }
            }
        }
        if waiting {
            Dependency::Waiting
        } else {
            Dependency::Met
        }
    }

    /// Whether job `id` waits for another that is not done yet (or has ended without being
    /// done, until [`Scheduler::end_dependents`] fails it).
    pub(super) fn waits(&self, id: JobId) -> bool {
        self.jobs
            .get(&id)
            .and_then(|j| j.rec.after)
            .is_some_and(|a| self.dependency(JobId(a)) != Dependency::Met)
    }

    /// Refuses a dependency on a job the coordinator does not know, or on one that already
    /// failed or was cancelled (the new job could only fail).
    pub(super) fn check_dependency(&self, after: JobId) -> Result<(), Refusal> {
        if !self
            .members(after)
            .iter()
            .any(|m| self.jobs.contains_key(m))
        {
            return Err(Refusal::NotFound(format!(
                "--after {after}: no such job on this coordinator"
            )));
        }
        match self.dependency(after) {
            Dependency::Ended(why) => Err(Refusal::Precondition(format!(
                "--after {after}: the job could never start, because {why}"
            ))),
            Dependency::Met | Dependency::Waiting => Ok(()),
        }
    }

    /// Fails every active job that waits for `ended` (a job that just failed or was
    /// cancelled, or a frame of a range that did), and those that wait for them in turn;
    /// returns the store changes.
    pub(super) fn end_dependents(&mut self, ended: JobId, now_ms: i64) -> Vec<Op> {
        let mut ops = Vec::new();
        for (id, after) in self.dependents(ended) {
            if let Dependency::Ended(why) = self.dependency(after) {
                let why = format!("{DEPENDENCY_ENDED}: {why}");
                ops.extend(self.end_job(id, JobPhase::Failed, why, now_ms));
            }
        }
        ops
    }

    /// Whether an active job waits for job `id` (or for the range it is a frame of): when `id`
    /// ends, workers waiting for units are to be woken.
    pub fn has_dependents(&self, id: JobId) -> bool {
        !self.dependents(id).is_empty()
    }

    /// The active jobs that wait for job `id` or for the range it is a frame of, each with the
    /// id it names.
    fn dependents(&self, id: JobId) -> Vec<(JobId, JobId)> {
        let range = self
            .jobs
            .get(&id)
            .and_then(|j| j.rec.range)
            .map(|r| JobId(r.id));
        self.jobs
            .iter()
            .filter(|(_, j)| j.rec.phase == JobPhase::Active)
            .filter_map(|(&dependent, j)| Some((dependent, JobId(j.rec.after?))))
            .filter(|&(_, after)| after == id || Some(after) == range)
            .collect()
    }
}

/// Why job `id`, which failed with `error`, stops the jobs that wait for it, in bounded text:
/// its own error (cut to [`MAX_CAUSE_CHARS`]), or, if it failed because a job it waited for
/// ended, that and the first cause its error names. Each dependent names the job it waits for
/// and the chain's first cause once, instead of nesting every error of a chain in the next
/// (a 998-job chain once made a 57 KB error and a `ListJobs` past the gRPC limit).
fn failed_because(id: JobId, error: &str) -> String {
    match error.strip_prefix(DEPENDENCY_ENDED) {
        Some(rest) => {
            let rest = rest.trim_start_matches(": ");
            let first = rest
                .split_once(FIRST_CAUSE)
                .map_or(rest, |(_, first)| first);
            format!("{id} failed waiting for another job{FIRST_CAUSE}{first}")
        }
        None => {
            let mut own: String = error.chars().take(MAX_CAUSE_CHARS).collect();
            if own.len() < error.len() {
                own.push('…');
            }
            format!("{id} failed: {own}")
        }
    }
}
