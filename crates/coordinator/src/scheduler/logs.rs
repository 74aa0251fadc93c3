//! Workers' warnings and errors about units, kept with their jobs (`tessera logs`).
//!
//! A worker may only write about units it was leased, so nobody can put lines in another
//! caller's job. What it writes is bounded three ways, so that a chatty or hostile worker
//! cannot fill the coordinator: each line is cut to [`MAX_LINE_CHARS`], each worker has a
//! token bucket ([`PER_SECOND`] sustained, [`BURST`] at once), and each job keeps its last
//! [`MAX_LINES_PER_JOB`] lines. What is dropped is counted, and the count is shown. A job's
//! log is written to the store with the next checkpoint, so a restart keeps it.
//!
//! Only active jobs' logs are held in memory. Once a job ends its log leaves memory at the next
//! sweep ([`Scheduler::sweep_logs`]) and is read from the store when asked for; a restart loads
//! only active jobs' logs. Ended jobs' logs are kept for [`Policy::log_retention`] and at most
//! [`Policy::max_log_bytes`] of them in all, the oldest going first, so a farm that runs
//! thousands of chatty jobs keeps neither memory nor store growing.
//! (3,000 jobs of 200 lines each once took a coordinator from 35 MiB to 1.4 GB.)
//!
//! [`Policy::log_retention`]: super::Policy::log_retention
//! [`Policy::max_log_bytes`]: super::Policy::max_log_bytes

use std::collections::VecDeque;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tessera_proto::ids::{JobId, LeaseId};

use super::Scheduler;
use crate::error::Refusal;
use crate::store::{JobPhase, Op};

/// Lines a job keeps (the oldest go first).
pub const MAX_LINES_PER_JOB: usize = 200;
/// Characters of a line kept.
pub const MAX_LINE_CHARS: usize = 500;
/// Lines one call may carry.
pub const MAX_LINES_PER_CALL: usize = 32;
/// A worker's sustained rate, lines per second.
pub const PER_SECOND: f64 = 5.0;
/// A worker's burst.
pub const BURST: f64 = 50.0;

/// One kept line.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogLine {
    /// Increases with every kept line, across restarts.
    pub seq: u64,
    /// When it arrived, Unix milliseconds.
    pub unix_ms: i64,
    /// The worker's public id, and its name.
    pub worker_id: String,
    /// The worker's name.
    pub worker_name: String,
    /// The unit.
    pub tile: u32,
    /// The unit's batch.
    pub batch: u32,
    /// "info", "warn" or "error".
    pub level: String,
    /// The text, cut to [`MAX_LINE_CHARS`].
    pub message: String,
}

/// A job's kept lines and how many were dropped.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct JobLog {
    /// Oldest first.
    pub lines: VecDeque<LogLine>,
    /// Lines not kept: pushed out by newer ones, or over their worker's rate.
    pub dropped: u64,
}

/// An ended job's log, held by the store alone.
#[derive(Clone, Copy, Debug)]
pub(super) struct StoredLog {
    /// When its job ended, Unix milliseconds.
    ended_ms: i64,
    /// Its size in the store.
    bytes: u64,
}

/// What [`Scheduler::logs`] answers: the lines memory holds, and the jobs whose logs are to be
/// read from the store.
#[derive(Debug)]
pub struct LogQuery {
    /// Lines of active jobs after the asked sequence number.
    pub lines: JobLines,
    /// Lines those jobs dropped.
    pub dropped: u64,
    /// Whether every job asked about has ended (no more lines will come).
    pub ended: bool,
    /// Ended jobs (with their frame) whose logs the store holds: the caller reads them
    /// ([`crate::store::Store::log`]) and adds them with [`add_stored`].
    pub stored: Vec<(JobId, Option<u32>)>,
}

/// Adds job `job`'s stored log `bytes` (of `frame`) to `q`: its lines after `after`, and its
/// dropped count. A log that does not decode is left out, as at start-up.
pub fn add_stored(q: &mut LogQuery, job: JobId, frame: Option<u32>, bytes: &[u8], after: u64) {
    match serde_json::from_slice::<JobLog>(bytes) {
        Ok(log) => {
            q.dropped += log.dropped;
            q.lines.extend(
                log.lines
                    .into_iter()
                    .filter(|l| l.seq > after)
                    .map(|l| (job, frame, l)),
            );
            q.lines.sort_by_key(|(_, _, l)| l.seq);
        }
        Err(e) => tracing::warn!("{job}: its stored log does not decode ({e}); left out"),
    }
}

/// A worker's allowance of lines.
#[derive(Debug)]
pub struct LogBucket {
    tokens: f64,
    at: Option<Instant>,
}

impl Default for LogBucket {
    fn default() -> Self {
        Self {
            tokens: BURST,
            at: None,
        }
    }
}

impl LogBucket {
    /// Takes one line's token if there is one.
    fn take(&mut self, now: Instant) -> bool {
        if let Some(at) = self.at {
            let refill = now.saturating_duration_since(at).as_secs_f64() * PER_SECOND;
            self.tokens = (self.tokens + refill).min(BURST);
        }
        self.at = Some(now);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// One line as a worker sends it.
#[derive(Debug)]
pub struct Reported {
    /// The unit's lease.
    pub lease: LeaseId,
    /// "info", "warn" or "error".
    pub level: &'static str,
    /// The text.
    pub message: String,
}

/// The lines of one job (a frame's own id for a range), with its frame.
pub type JobLines = Vec<(JobId, Option<u32>, LogLine)>;

impl Scheduler {
    /// Keeps worker `w`'s `lines`, each about a unit it was leased; returns (kept, dropped) and
    /// the store changes, to be written at the next checkpoint.
    pub fn report_log(
        &mut self,
        w: u64,
        lines: Vec<Reported>,
        now: Instant,
        now_ms: i64,
    ) -> (u32, u32, Vec<Op>) {
        let worker_id = self.worker_id(w).to_string();
        let Some(worker) = self.workers.get_mut(&w) else {
            return (0, lines.len() as u32, Vec::new());
        };
        let worker_name = worker.name.clone();
        let (mut kept, mut dropped) = (0, 0);
        let mut touched = Vec::new();
        for line in lines {
            // Only about a unit this worker was given, in this boot.
            let unit = (line.lease.epoch == self.epoch)
                .then(|| self.leases.get(&line.lease.n))
                .flatten()
                .filter(|l| l.worker == w)
                .map(|l| (l.job, l.unit))
                // An ended job's log is the store's alone ([`Scheduler::sweep_logs`]): a late
                // line would start a new log over it.
                .filter(|(job, _)| {
                    self.jobs
                        .get(job)
                        .is_some_and(|j| j.rec.phase == JobPhase::Active)
                });
            let Some((job, unit)) = unit else {
                dropped += 1;
                continue;
            };
            let log = self.logs.entry(job).or_default();
            if !worker.log_bucket.take(now) {
                log.dropped += 1;
                dropped += 1;
                touched.push(job);
                continue;
            }
            self.log_seq += 1;
            log.lines.push_back(LogLine {
                seq: self.log_seq,
                unix_ms: now_ms,
                worker_id: worker_id.clone(),
                worker_name: worker_name.clone(),
                tile: unit.tile,
                batch: unit.batch,
                level: line.level.into(),
                message: line.message.chars().take(MAX_LINE_CHARS).collect(),
            });
            while log.lines.len() > MAX_LINES_PER_JOB {
                log.lines.pop_front();
                log.dropped += 1;
            }
            kept += 1;
            touched.push(job);
        }
        touched.dedup();
        let ops = touched
            .into_iter()
            .filter_map(|j| {
                let bytes = serde_json::to_vec(self.logs.get(&j)?).ok()?;
                Some(Op::PutLog(j.0, bytes))
            })
            .collect();
        (kept, dropped, ops)
    }

    /// Notes that ended job `id`'s log, of `bytes`, is in the store alone (at start-up).
    pub(super) fn note_stored_log(&mut self, id: JobId, ended_ms: i64, bytes: u64) {
        self.stored_logs.insert(id, StoredLog { ended_ms, bytes });
    }

    /// Moves the logs of jobs that have ended out of memory (the store has them: each change
    /// was written with its checkpoint), and forgets ended jobs' logs past
    /// [`Policy::log_retention`](super::Policy::log_retention) or, oldest first, past
    /// [`Policy::max_log_bytes`](super::Policy::max_log_bytes) in all; returns the store
    /// changes.
    pub fn sweep_logs(&mut self, now_ms: i64) -> Vec<Op> {
        let ended: Vec<JobId> = self
            .logs
            .keys()
            .filter(|id| {
                self.jobs
                    .get(id)
                    .is_none_or(|j| j.rec.phase != JobPhase::Active)
            })
            .copied()
            .collect();
        for id in ended {
            let Some(log) = self.logs.remove(&id) else {
                continue;
            };
            let bytes = serde_json::to_vec(&log).map_or(0, |b| b.len() as u64);
            let ended_ms = self.jobs.get(&id).map_or(now_ms, |j| j.rec.finished_ms);
            self.stored_logs.insert(id, StoredLog { ended_ms, bytes });
        }
        let oldest = now_ms.saturating_sub(self.policy.log_retention.as_millis() as i64);
        let mut by_age: Vec<(i64, JobId, u64)> = self
            .stored_logs
            .iter()
            .map(|(&id, l)| (l.ended_ms, id, l.bytes))
            .collect();
        by_age.sort_unstable();
        let mut total: u64 = by_age.iter().map(|&(_, _, b)| b).sum();
        let mut ops = Vec::new();
        for (ended_ms, id, bytes) in by_age {
            if ended_ms >= oldest && total <= self.policy.max_log_bytes {
                break;
            }
            self.stored_logs.remove(&id);
            total -= bytes;
            ops.push(Op::DropLog(id.0));
        }
        ops
    }

    /// Bytes of logs memory holds (active jobs') and of ended jobs' logs the store holds.
    pub fn log_bytes(&self) -> (u64, u64) {
        let held = self
            .logs
            .values()
            .map(|l| {
                l.lines
                    .iter()
                    .map(|x| {
                        (x.message.len() + x.worker_id.len() + x.worker_name.len() + 64) as u64
                    })
                    .sum::<u64>()
            })
            .sum();
        (held, self.stored_logs.values().map(|l| l.bytes).sum())
    }

    /// Puts back job `id`'s stored log at start-up; a log that does not decode is left out.
    pub(super) fn restore_log(&mut self, id: JobId, bytes: &[u8]) {
        match serde_json::from_slice::<JobLog>(bytes) {
            Ok(log) => {
                let last = log.lines.back().map_or(0, |l| l.seq);
                self.log_seq = self.log_seq.max(last);
                self.logs.insert(id, log);
            }
            Err(e) => tracing::warn!("{id}: its stored log does not decode ({e}); left out"),
        }
    }

    /// The lines of job `id` (a frame-range job: every frame's, or `frame`'s) after sequence
    /// number `after`, by sequence number, as memory holds them; with the lines dropped,
    /// whether the job has ended (no more will come), and which ended jobs' logs are to be
    /// read from the store.
    pub fn logs(&self, id: JobId, frame: Option<u32>, after: u64) -> Result<LogQuery, Refusal> {
        let members = self.members(id);
        let jobs: Vec<_> = members.iter().filter_map(|m| self.jobs.get(m)).collect();
        if jobs.is_empty() {
            return Err(Refusal::NotFound(format!("unknown job {id}")));
        }
        let frame_of = |j: &&crate::job::Job| j.rec.range.and(j.rec.frame);
        if let Some(f) = frame {
            if !jobs.iter().any(|j| frame_of(j) == Some(f)) {
                return Err(Refusal::NotFound(format!("{id} has no frame {f}")));
            }
        }
        let mut out = Vec::new();
        let mut dropped = 0;
        let mut stored = Vec::new();
        for j in &jobs {
            if frame.is_some() && frame_of(j) != frame {
                continue;
            }
            if self.stored_logs.contains_key(&j.id()) {
                stored.push((j.id(), frame_of(j)));
            }
            let Some(log) = self.logs.get(&j.id()) else {
                continue;
            };
            dropped += log.dropped;
            out.extend(
                log.lines
                    .iter()
                    .filter(|l| l.seq > after)
                    .map(|l| (j.id(), frame_of(j), l.clone())),
            );
        }
        out.sort_by_key(|(_, _, l)| l.seq);
        let ended = jobs.iter().all(|j| j.rec.phase != JobPhase::Active);
        Ok(LogQuery {
            lines: out,
            dropped,
            ended,
            stored,
        })
    }
}
