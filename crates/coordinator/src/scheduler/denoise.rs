//! Frames waiting for a worker to denoise them: a job that asks to be denoised, on a
//! coordinator that does not denoise itself, has its finished frame lent to a worker that
//! registered with Open Image Denoise (`tessera worker --denoise`).
//!
//! Invariant: a job is in the queue only while it is active and finishing (every unit merged,
//! its EXR not written); at most one worker holds its claim, and a claim names the worker and
//! a token that only that worker's stream knows. A claim ends with the output (the EXR is
//! written and the job ends), with the stream (the frame waits again), or with the worker's
//! death, noticed when another claims.

use std::time::Instant;

use tessera_proto::ids::JobId;

use super::Scheduler;
use crate::error::Refusal;
use crate::store::{DenoiseRecord, JobPhase, Op};

/// Failures of the filter on one frame (a worker's library refusing it) after which its job
/// fails rather than wait for a worker that can.
pub const FAIL_DENOISE_AFTER: u32 = 3;

/// A finished frame that waits to be denoised.
#[derive(Debug, Default)]
pub(super) struct Waiting {
    /// The worker denoising it now and its claim's token.
    claim: Option<(u64, u64)>,
    /// Workers whose claim on it ended without its output (a broken stream, a lapse, a
    /// failure): it goes to them again only when no other denoiser may take it, so that one
    /// worker that takes frames and never answers cannot hold a frame back from the others.
    lost_by: Vec<u64>,
    /// Times the filter failed on it.
    failures: u32,
    /// The last failure's message.
    last_failure: String,
}

impl Waiting {
    /// Worker `w`'s claim ended without the output.
    fn lost(&mut self, w: u64) {
        if !self.lost_by.contains(&w) {
            self.lost_by.push(w);
        }
    }
}

/// A frame a worker has claimed: what its stream needs to serve it.
#[derive(Clone, Debug)]
pub struct DenoiseClaim {
    /// The job.
    pub job: JobId,
    /// Only the claiming stream knows it: the output is taken under it.
    pub token: u64,
    /// Size in pixels.
    pub size: (u32, u32),
    /// The job's options.
    pub options: DenoiseRecord,
    /// The library version the worker registered with (for the EXR's header).
    pub version: i32,
}

impl Scheduler {
    /// Puts finishing job `id`'s frame in the queue for a denoising worker; false for a job
    /// that is not active and finishing.
    pub fn await_denoise(&mut self, id: JobId) -> bool {
        let ok = self
            .jobs
            .get(&id)
            .is_some_and(|j| j.finishing && j.rec.phase == JobPhase::Active);
        if ok {
            self.denoising.entry(id).or_default();
        }
        ok
    }

    /// Opens worker `w`'s one `Denoise` stream, returning its token; `None` while it has one
    /// open (a worker filters one frame at a time, and a stream that waits holds a task: one
    /// is all it needs).
    pub fn open_denoise_stream(&mut self, w: u64) -> Option<u64> {
        if self.denoise_streams.contains_key(&w) {
            return None;
        }
        self.next_lease += 1;
        self.denoise_streams.insert(w, self.next_lease);
        Some(self.next_lease)
    }

    /// Closes worker `w`'s `Denoise` stream `token` (not a later one of the same worker).
    pub fn close_denoise_stream(&mut self, w: u64, token: u64) {
        if self.denoise_streams.get(&w) == Some(&token) {
            self.denoise_streams.remove(&w);
        }
    }

    /// Whether job `id`'s frame waits for (or is being denoised by) a worker.
    pub fn awaits_denoise(&self, id: JobId) -> bool {
        self.denoising.contains_key(&id)
    }

    /// The oldest waiting frame for worker `w`, claimed for it; `None` when none waits, or
    /// `w` may not denoise (it did not register with the library, or is quarantined or
    /// draining). A claim held by a worker that stopped calling is taken back first.
    pub fn claim_denoise(&mut self, w: u64, now: Instant) -> Result<Option<DenoiseClaim>, Refusal> {
        let worker = self
            .workers
            .get(&w)
            .ok_or_else(|| Refusal::NotFound("unknown worker: register again".into()))?;
        let version = worker.caps.denoise_version;
        if version <= 0 {
            return Err(Refusal::Precondition(
                "this worker did not register as one that denoises (start it with --denoise)"
                    .into(),
            ));
        }
        if worker.draining || worker.quarantined || worker.convicted.is_some() {
            return Ok(None);
        }
        let lease_time = self.policy.lease_time;
        let dead: Vec<u64> = self
            .workers
            .iter()
            .filter(|(_, x)| !x.alive(now, lease_time))
            .map(|(&n, _)| n)
            .collect();
        for q in self.denoising.values_mut() {
            if let Some((holder, _)) = q.claim.filter(|(h, _)| dead.contains(h)) {
                q.claim = None;
                q.lost(holder);
            }
        }
        let denoisers: Vec<u64> = self
            .workers
            .iter()
            .filter(|(_, x)| {
                x.caps.denoise_version > 0
                    && x.alive(now, lease_time)
                    && !x.draining
                    && !x.quarantined
                    && x.convicted.is_none()
            })
            .map(|(&n, _)| n)
            .collect();
        let for_w = |q: &Waiting| {
            q.claim.is_none()
                && (!q.lost_by.contains(&w) || denoisers.iter().all(|d| q.lost_by.contains(d)))
        };
        let Some((&id, q)) = self.denoising.iter_mut().find(|(_, q)| for_w(q)) else {
            return Ok(None);
        };
        let Some(job) = self.jobs.get(&id) else {
            return Ok(None);
        };
        let Some(options) = job.rec.denoise.clone() else {
            return Ok(None);
        };
        self.next_lease += 1;
        let token = self.next_lease;
        q.claim = Some((w, token));
        Ok(Some(DenoiseClaim {
            job: id,
            token,
            size: (job.rec.width, job.rec.height),
            options,
            version,
        }))
    }

    /// Whether worker `w` holds job `id`'s claim under `token`.
    pub fn holds_denoise(&self, w: u64, id: JobId, token: u64) -> bool {
        self.denoising
            .get(&id)
            .is_some_and(|q| q.claim == Some((w, token)))
    }

    /// Ends a claim without output (its stream broke, or the worker stopped): the frame
    /// waits again. A claim that is no longer this one's is left alone.
    pub fn unclaim_denoise(&mut self, id: JobId, token: u64) {
        if let Some(q) = self.denoising.get_mut(&id) {
            if let Some((holder, _)) = q.claim.filter(|&(_, t)| t == token) {
                q.claim = None;
                q.lost(holder);
            }
        }
    }

    /// The filter failed on the frame under this claim: it waits again, and its job fails
    /// after [`FAIL_DENOISE_AFTER`] failures. Returns the store changes.
    pub fn denoise_failed(&mut self, id: JobId, token: u64, why: &str, now_ms: i64) -> Vec<Op> {
        let Some(q) = self.denoising.get_mut(&id) else {
            return Vec::new();
        };
        let Some((holder, _)) = q.claim.filter(|&(_, t)| t == token) else {
            return Vec::new();
        };
        q.claim = None;
        q.lost(holder);
        q.failures += 1;
        q.last_failure = why.to_string();
        if q.failures < FAIL_DENOISE_AFTER {
            return Vec::new();
        }
        let error = format!(
            "denoising failed {} times; the last worker said: {why}",
            q.failures
        );
        self.end_job(id, JobPhase::Failed, error, now_ms)
    }

    /// Why job `id`'s frame is not denoised yet, for its status; `None` for a job whose
    /// frame does not wait for a worker.
    pub(super) fn denoise_waiting(&self, id: JobId, now: Instant) -> Option<String> {
        let q = self.denoising.get(&id)?;
        if let Some((w, _)) = q.claim {
            let name = self.workers.get(&w).map_or("", |x| x.name.as_str());
            return Some(format!("being denoised by worker {name:?}"));
        }
        let lease_time = self.policy.lease_time;
        let denoisers = self
            .workers
            .values()
            .filter(|w| w.caps.denoise_version > 0 && w.alive(now, lease_time))
            .count();
        let failed = if q.failures > 0 {
            format!(
                " (the filter failed {} times; the last: {})",
                q.failures, q.last_failure
            )
        } else {
            String::new()
        };
        Some(if denoisers == 0 {
            format!(
                "rendered; waiting for a worker that denoises (none is connected: start one \
                 with tessera worker --denoise){failed}"
            )
        } else {
            format!("rendered; waiting for a denoising worker to take it{failed}")
        })
    }
}
