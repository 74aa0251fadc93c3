//! Workers' warnings and errors about units, kept with their jobs (`tessera logs`).
//!
//! A worker may only write about units it was leased, so nobody can put lines in another
//! caller's job. What it writes is bounded three ways, so that a chatty or hostile worker
//! cannot fill the coordinator: each line is cut to [`MAX_LINE_CHARS`], each worker has a
//! token bucket ([`PER_SECOND`] sustained, [`BURST`] at once), and each job keeps its last
//! [`MAX_LINES_PER_JOB`] lines. What is dropped is counted, and the count is shown. A job's
//! log is written to the store with the next checkpoint, so a restart keeps it.

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
                .map(|l| (l.job, l.unit));
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
    /// number `after`, by sequence number; with the lines dropped and whether the job has
    /// ended (no more will come).
    pub fn logs(
        &self,
        id: JobId,
        frame: Option<u32>,
        after: u64,
    ) -> Result<(JobLines, u64, bool), Refusal> {
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
        for j in &jobs {
            if frame.is_some() && frame_of(j) != frame {
                continue;
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
        Ok((out, dropped, ended))
    }
}
