//! Who gets which unit, and what becomes of each result: the scheduling state of every job
//! and worker of this boot. Every method is synchronous and short; the caller holds one mutex
//! around [`Scheduler`] and turns the returned [`Op`]s into a durable commit before replying.
//!
//! By concept:
//! - [`pick`]: the next unit for a worker, speculation past slow holders, requeueing.
//! - [`leases`]: leases, their deadlines, heartbeats and hand-backs.
//! - [`workers`]: registration, credentials, hosts and quarantine.
//! - [`logs`]: workers' lines about units, kept with their jobs, bounded.
//! - [`failures`]: units that fail on workers, blocklists, frames that fail.
//! - [`fit`]: workers' capabilities against jobs' requirements, and draining.
//! - [`audit`]: units rendered twice, the referee, and convictions.
//! - [`admit`]: admission of new jobs and restore at start-up.
//! - [`denoise`]: finished frames waiting for a worker to denoise them.
//! - [`view`]: the read model the API and the dashboard both answer from.
//!
//! This file keeps what ties them together: the state, the merge of a result
//! ([`Scheduler::submit`]) and the end of a job ([`Scheduler::end_job`]). The state's fields
//! are private: callers use verbs and read methods, so an invariant (a lease's unit is in its
//! job's `issued`, a counter moves with what it counts) is kept in this module alone.
//!
//! Ids arrive typed ([`tessera_proto::ids`]): the handlers parse the wire's strings, and the
//! scheduler only checks that an id is one it issued, in this boot, to this caller.

mod admit;
mod after;
mod audit;
mod control;
mod denoise;
mod failures;
mod fit;
mod forget;
mod leases;
mod logs;
mod pick;
mod retry;
mod share;
mod view;
mod workers;

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::{Duration, Instant};

use tessera_proto::ids::{JobId, LeaseId};
use tessera_render::{PixelRect, RenderSettings, TileSums};

use crate::config::{
    DEFAULT_BLOCKLIST_AFTER, DEFAULT_EVICT_OPEN_OVER, DEFAULT_FAIL_FRAME_AFTER,
    DEFAULT_FAIL_UNIT_AFTER_LAPSES, DEFAULT_JOB_RETENTION, DEFAULT_LOG_RETENTION,
    DEFAULT_MAX_ENDED_JOBS, DEFAULT_MAX_LEASES_PER_WORKER, DEFAULT_MAX_LOG_BYTES,
    DEFAULT_MAX_UNSTORED_BYTES, DEFAULT_MAX_WORKERS_PER_HOST, DEFAULT_QUARANTINE_AFTER,
    DEFAULT_RETRY_WINDOW,
};
use crate::error::Refusal;
use crate::job::{FrameTile, Job, Snapshot, Source, Unit, MAX_DIRTY_BYTES};
use crate::metrics::Counters;
use crate::store::{JobPhase, JobRecord, Op};
use audit::audit_excludes;

pub use admit::{Admission, AdmissionLimits, Asked, Checked};
pub use denoise::{DenoiseClaim, FAIL_DENOISE_AFTER};
pub use fit::Capabilities;
pub use leases::Lease;
pub use logs::{add_stored, JobLines, JobLog, LogLine, LogQuery, Reported, MAX_LINES_PER_CALL};
pub use view::{JobView, WorkerView};
pub use workers::Worker;

/// What happened to a result.
#[derive(Debug)]
pub enum Merged {
    /// Merged; commit these ops, then reply. `finished` if it was the job's last unit.
    New {
        /// Store changes.
        ops: Vec<Op>,
        /// The job is complete.
        finished: bool,
    },
    /// Already merged.
    Duplicate,
    /// Job ended.
    Discarded,
    /// Accepted and held for an audit: another worker renders the unit too, and it is merged
    /// once two copies agree. Held results live in memory only (a restart renders the unit
    /// again), so there is nothing to commit; the worker is told it was merged, so that it
    /// cannot tell an audited unit from another.
    Held,
}

/// A unit handed to a worker.
#[derive(Debug)]
pub struct Granted {
    /// The lease.
    pub lease: LeaseId,
    /// The job.
    pub job: JobId,
    /// The unit.
    pub unit: Unit,
}

/// How the scheduler treats workers and audits: fixed when the coordinator starts, from
/// `tessera coordinator`'s flags.
#[derive(Clone, Copy, Debug)]
pub struct Policy {
    /// How long a lease lasts.
    pub lease_time: Duration,
    /// Invalid results after which a worker is quarantined.
    pub quarantine_after: u64,
    /// Most leases one registration may hold at once.
    pub max_leases_per_worker: usize,
    /// Most live registrations from one host (the address a worker registered from).
    pub max_workers_per_host: usize,
    /// Fraction of the units of audited jobs rendered a second time by another worker; jobs
    /// admitted while it is above 0 are audited ([`crate::store::JobRecord::audited`]).
    pub audit: f64,
    /// Bytes of a job's whole frame of sums ([`Job::frame_bytes`]) above which its open tiles
    /// leave memory between batches once stored, and are read back for their next merge
    /// (see [`crate::job`]'s `resident` module).
    pub evict_open_over: u64,
    /// Bytes of merged sums not yet in the store ([`Scheduler::unstored_bytes`]) at which
    /// results are deferred (the worker is told to retry) until a checkpoint commits: the
    /// bound on that memory when results arrive faster than the store takes them.
    pub max_unstored_bytes: u64,
    /// Failures of one job's units on one worker after which it is blocklisted for that job.
    pub blocklist_after: u32,
    /// Failures after which a frame fails.
    pub fail_frame_after: u32,
    /// Distinct machines one unit's lease may lapse on before its frame fails; 0: never.
    pub fail_unit_after_lapses: u32,
    /// How long a failed job stays retryable: its scene is kept that long.
    pub retry_window: Duration,
    /// Most units one user's jobs may hold leased at once (0: no cap).
    pub max_leases_per_user: usize,
    /// How long an ended job's log is kept (in the store only).
    pub log_retention: Duration,
    /// Most bytes of ended jobs' logs kept in all: past it the oldest go first.
    pub max_log_bytes: u64,
    /// How long an ended job's record is kept ([`Scheduler::sweep_jobs`]).
    pub job_retention: Duration,
    /// Most ended jobs kept in all: past it the oldest go first.
    pub max_ended_jobs: usize,
}

impl Policy {
    /// Leases of `lease_time`, and the coordinator's defaults for the rest (no audits).
    pub fn new(lease_time: Duration) -> Self {
        Self {
            lease_time,
            quarantine_after: DEFAULT_QUARANTINE_AFTER,
            max_leases_per_worker: DEFAULT_MAX_LEASES_PER_WORKER,
            max_workers_per_host: DEFAULT_MAX_WORKERS_PER_HOST,
            audit: 0.0,
            evict_open_over: DEFAULT_EVICT_OPEN_OVER,
            max_unstored_bytes: DEFAULT_MAX_UNSTORED_BYTES,
            blocklist_after: DEFAULT_BLOCKLIST_AFTER,
            fail_frame_after: DEFAULT_FAIL_FRAME_AFTER,
            fail_unit_after_lapses: DEFAULT_FAIL_UNIT_AFTER_LAPSES,
            retry_window: DEFAULT_RETRY_WINDOW,
            max_leases_per_user: 0,
            log_retention: DEFAULT_LOG_RETENTION,
            max_log_bytes: DEFAULT_MAX_LOG_BYTES,
            job_retention: DEFAULT_JOB_RETENTION,
            max_ended_jobs: DEFAULT_MAX_ENDED_JOBS,
        }
    }
}

/// A finished job's frame to write: its record, settings and every tile (its sums, or where
/// the store holds them).
pub type Frame = (JobRecord, RenderSettings, Vec<FrameTile>);

/// All scheduling state.
#[derive(Debug)]
pub struct Scheduler {
    /// Boot counter: part of every lease and worker id.
    epoch: u64,
    /// Fixed bounds and rates.
    policy: Policy,
    /// Jobs by id.
    jobs: BTreeMap<JobId, Job>,
    /// Frame-range jobs: each range's id and its frames' jobs, in frame order. A range has no
    /// job of its own; its state is its frames'.
    ranges: BTreeMap<JobId, Vec<JobId>>,
    /// Next job id.
    next_job: u64,
    /// Leases by number.
    leases: HashMap<u64, Lease>,
    /// Next lease number.
    next_lease: u64,
    /// Workers by number.
    workers: BTreeMap<u64, Worker>,
    /// Next worker number.
    next_worker: u64,
    /// State of the generator that picks audited units. Workers cannot see it, so a worker
    /// cannot tell which of its units will be checked.
    audit_rng: u64,
    /// Serial of the last merge into an audited job ([`Source`]); starts at `epoch << 40` so
    /// that serials are not reused across boots.
    serial: u64,
    /// Convictions in this boot.
    convictions: u64,
    /// Audited units for the coordinator to render itself ([`Scheduler::take_referee_work`]):
    /// their copies disagree, or no worker on another host took the second copy in time.
    referee_wanted: BTreeSet<(JobId, Unit)>,
    /// What happened to units and results since this boot, for metrics.
    counters: Counters,
    /// An early checkpoint has been asked for since the last one ([`Scheduler::wants_checkpoint`]).
    checkpoint_asked: bool,
    /// Bytes of tile sums in the last checkpoint's snapshot, until the store has them
    /// ([`Scheduler::evict`]): with the tiles dirty since, what memory holds that only a
    /// commit can let go ([`Scheduler::unstored_bytes`]).
    storing_bytes: u64,
    /// Workers' lines about each active job's units ([`logs`]).
    logs: BTreeMap<JobId, logs::JobLog>,
    /// The logs of ended jobs, which only the store holds: when each job ended and its size.
    stored_logs: BTreeMap<JobId, logs::StoredLog>,
    /// The last log line's sequence number.
    log_seq: u64,
    /// The machines (a worker's host, or its name where that is unknown) and worker names each
    /// unit's lease lapsed on, for live jobs (in memory only: a restart forgets them, as it
    /// forgets leases).
    lapses: HashMap<(JobId, Unit), Vec<(String, String)>>,
    /// Store changes made where no caller takes them (a lapse that fails a frame, noticed
    /// while leasing); the server's ticker commits them ([`Scheduler::take_deferred`]).
    deferred: Vec<Op>,
    /// Finished frames waiting for a worker to denoise them ([`denoise`]).
    denoising: BTreeMap<JobId, denoise::Waiting>,
    /// Workers with a `Denoise` stream open, and each stream's token.
    denoise_streams: BTreeMap<u64, u64>,
}

/// What a worker returns for one unit: its sums, and for a guided job's unit of a training
/// epoch, the tree it recorded into.
#[derive(Debug)]
pub struct UnitResult {
    /// The sums.
    pub sums: TileSums,
    /// What it trained.
    pub train: Option<tessera_render::guide::SdTree>,
}

impl From<TileSums> for UnitResult {
    fn from(sums: TileSums) -> Self {
        Self { sums, train: None }
    }
}

impl Scheduler {
    /// Empty state for boot `epoch`.
    pub fn new(epoch: u64, policy: Policy) -> Self {
        Self {
            epoch,
            policy,
            jobs: BTreeMap::new(),
            ranges: BTreeMap::new(),
            next_job: 1,
            leases: HashMap::new(),
            next_lease: 1,
            workers: BTreeMap::new(),
            next_worker: 1,
            audit_rng: epoch.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1,
            serial: epoch << 40,
            convictions: 0,
            referee_wanted: BTreeSet::new(),
            counters: Counters::default(),
            checkpoint_asked: false,
            storing_bytes: 0,
            logs: BTreeMap::new(),
            stored_logs: BTreeMap::new(),
            log_seq: 0,
            lapses: HashMap::new(),
            deferred: Vec::new(),
            denoising: BTreeMap::new(),
            denoise_streams: BTreeMap::new(),
        }
    }

    /// Seeds the generator that draws audited units; the service seeds it from the operating
    /// system, so that no worker can predict the draws.
    pub fn seed_audits(&mut self, seed: u64) {
        self.audit_rng = seed | 1;
    }

    /// The boot counter.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// The bounds and rates it schedules by.
    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    /// The bounds and rates, to change (tests, and the fuzz targets' scenarios).
    pub fn policy_mut(&mut self) -> &mut Policy {
        &mut self.policy
    }

    /// Job `id` (one frame of a range, or a one-frame job).
    pub fn job(&self, id: JobId) -> Option<&Job> {
        self.jobs.get(&id)
    }

    /// Whether `id` is a frame-range job's (whose frames are jobs of their own).
    pub fn is_range(&self, id: JobId) -> bool {
        self.ranges.contains_key(&id)
    }

    /// Every job, by id.
    pub fn jobs(&self) -> impl Iterator<Item = &Job> {
        self.jobs.values()
    }

    /// Adds a job as it stands, under its own id. Admission ([`Scheduler::admit`]) is how a
    /// submitted job gets here; this is for jobs made elsewhere (tests, the fuzz targets).
    pub fn insert_job(&mut self, job: Job) {
        let id = job.id();
        self.next_job = self.next_job.max(id.0 + 1);
        self.jobs.insert(id, job);
    }

    /// Worker number `n`.
    pub fn worker(&self, n: u64) -> Option<&Worker> {
        self.workers.get(&n)
    }

    /// Every worker registered in this boot, by number.
    pub fn workers(&self) -> impl Iterator<Item = (u64, &Worker)> {
        self.workers.iter().map(|(&n, w)| (n, w))
    }

    /// Leases live now.
    pub fn leases_live(&self) -> u64 {
        self.leases.values().filter(|l| l.active).count() as u64
    }

    /// What happened to units and results since this boot.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Merges a result from worker `w`; in an audited job, it may instead be held for its
    /// audit (convictions happen in [`Scheduler::referee`]).
    pub fn submit(
        &mut self,
        w: u64,
        lease: LeaseId,
        job_id: JobId,
        unit: Unit,
        result: impl Into<UnitResult>,
        now: Instant,
    ) -> Result<Merged, Refusal> {
        let result = result.into();
        let samples = result.sums.rect.area() as u64 * result.sums.samples.len() as u64;
        let outcome = self.take_result(w, lease, job_id, unit, result, now);
        let c = &mut self.counters;
        match &outcome {
            Ok(Merged::New { .. }) => {
                c.units_merged += 1;
                c.samples_merged += samples;
            }
            Ok(Merged::Duplicate) => c.units_duplicate += 1,
            Ok(Merged::Discarded) => c.units_discarded += 1,
            Ok(Merged::Held) => c.units_held += 1,
            Err(_) => c.results_refused += 1,
        }
        outcome
    }

    /// A result refused before it reached the scheduler (it did not decode): counted against
    /// worker `w` like an invalid one.
    pub fn refuse_result(&mut self, w: u64) {
        self.count_bad_result(w);
        self.counters.results_refused += 1;
    }

    /// [`Scheduler::submit`] without the counting.
    fn take_result(
        &mut self,
        w: u64,
        lease: LeaseId,
        job_id: JobId,
        unit: Unit,
        result: UnitResult,
        now: Instant,
    ) -> Result<Merged, Refusal> {
        let UnitResult { sums, train } = result;
        // The handlers refuse a quarantined worker's calls already (`touch_worker`); refused here
        // too, so that no path merges a result from a worker an audit convicted after its results
        // were taken back.
        if let Some(r) = self
            .workers
            .get(&w)
            .and_then(|x| x.refusal(self.worker_id(w)))
        {
            return Err(r);
        }
        let lease_n = self.lease_number(lease);
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Err(Refusal::NotFound(format!("unknown job {job_id}")));
        };
        if !job.is_live() {
            return Ok(Merged::Discarded);
        }
        if unit.tile as usize >= job.tiles.len() || unit.batch >= job.n_batches {
            return Err(Refusal::Invalid(format!(
                "{job_id} has no tile {} batch {} ({} tiles × {} batches)",
                unit.tile,
                unit.batch,
                job.tiles.len(),
                job.n_batches
            )));
        }
        if job.is_done(unit) {
            return Ok(Merged::Duplicate);
        }
        // A copy from a worker (or host) whose copy is held already must not count as a second
        // one: a liar would settle its own lie.
        let host = self.workers.get(&w).map_or("", |x| x.host.as_str());
        if audit_excludes(job, unit, w, host) {
            return Ok(Merged::Duplicate);
        }
        let lease_n = lease_n?;
        match self.leases.get(&lease_n) {
            Some(l) if l.job == job_id && l.unit == unit && l.worker == w => {}
            _ => {
                return Err(Refusal::Precondition(format!(
                    "lease {lease} was not issued to this worker for {job_id} tile {} batch {}",
                    unit.tile, unit.batch
                )))
            }
        }
        let checked = job
            .check_result(unit, &sums)
            .and_then(|()| match &job.guiding {
                Some(g) => g.check(unit.batch, sums.rect.area() as u64, train.as_ref()),
                None if train.is_some() => {
                    Err("the job is not guided, and the result has a training tree".into())
                }
                None => Ok(()),
            });
        if let Err(e) = checked {
            self.count_bad_result(w);
            return Err(Refusal::Invalid(format!(
                "{job_id} tile {} batch {}: {e}",
                unit.tile, unit.batch
            )));
        }
        if job.needs_reload(unit).is_some() {
            // The caller reads the tile back first (`needs_reload`); merging now would fold the
            // batch into an empty tile. The lease stays, so the worker's retry merges it.
            return Err(Refusal::Unavailable(format!(
                "{job_id} tile {}: its sums are being read back from the store; retry",
                unit.tile
            )));
        }
        let samples = sums.rect.area() as u64 * sums.samples.len() as u64;
        for l in job.issued.remove(&unit).unwrap_or_default() {
            self.leases.remove(&l);
        }
        let (sums, from, mut ops) = if job.rec.audited {
            match self.audit_step(w, job_id, unit, (sums, train.as_ref()), now) {
                Some(settled) => settled,
                None => return Ok(Merged::Held),
            }
        } else {
            (sums, w, Vec::new())
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(Merged::Discarded);
        };
        // The result checked above (or, settled by an audit, the same bits as the copy held
        // before it); added once, as its sums are merged once.
        if let (Some(g), Some(t)) = (&mut job.guiding, &train) {
            g.add(t);
        }
        self.serial += 1;
        let source = Source {
            worker: from,
            serial: self.serial,
        };
        let (merge_ops, finished) = job.merge(unit, sums, source, now)?;
        ops.extend(merge_ops);
        if let Some(worker) = self.workers.get_mut(&w) {
            worker.units_done += 1;
            worker.samples_done += samples;
            worker.rate.record(now, worker.samples_done);
            if job.rec.audited {
                worker.jobs.insert(job_id);
            }
        }
        Ok(Merged::New { ops, finished })
    }

    /// Cancels job `id`, or every frame of a frame-range job that is still going. Returns the
    /// store changes, or `None` if nothing was left to cancel (the job had ended already).
    pub fn cancel(&mut self, id: JobId, now_ms: i64) -> Option<Vec<Op>> {
        let live: Vec<JobId> = self
            .members(id)
            .into_iter()
            .filter(|m| {
                self.jobs
                    .get(m)
                    .is_some_and(|j| j.rec.phase == JobPhase::Active && !j.finishing)
                    // A frame waiting for a denoising worker may wait long (for good, if none
                    // comes): it can be cancelled.
                    || self.denoising.contains_key(m)
            })
            .collect();
        if live.is_empty() {
            return None;
        }
        Some(
            live.into_iter()
                .flat_map(|m| self.end_job(m, JobPhase::Cancelled, String::new(), now_ms))
                .collect(),
        )
    }

    /// Records that job `id`'s EXR is written, with the noise of the finished image and whether
    /// it is black (its checks, [`tessera_render::OutputChecks`]), and ends it as done; returns
    /// the store changes.
    pub fn written(&mut self, id: JobId, noise: (f64, f64), black: bool, now_ms: i64) -> Vec<Op> {
        if let Some(job) = self.jobs.get_mut(&id) {
            job.image_noise = Some(noise);
            // Every unit is merged, so the count of dropped samples is the image's.
            job.rec.checks = tessera_render::OutputChecks {
                black,
                nonfinite: job.nonfinite,
            };
        }
        self.end_job(id, JobPhase::Done, String::new(), now_ms)
    }

    /// A job whose every unit is in, for writing its frame: its record, settings and tiles'
    /// sums, moved out ([`Job::take_frame_tiles`]), with the store changes that checkpoint
    /// them first (so that a crash while a large frame is written costs no rendering). `None`
    /// for a job that is not finishing.
    pub fn take_frame(&mut self, id: JobId) -> Option<(Frame, Vec<Op>)> {
        let job = self
            .jobs
            .get_mut(&id)
            .filter(|j| j.finishing && j.rec.phase == JobPhase::Active)?;
        // Encoded here, once per job, so that the tiles can be moved out of the job rather
        // than copied away from a snapshot still holding them.
        let ops = job.checkpoint().ops();
        Some((
            (job.rec.clone(), job.settings(), job.take_frame_tiles()),
            ops,
        ))
    }

    /// Every job's tiles merged since the last checkpoint, as they are now ([`Job::checkpoint`]):
    /// taken under the lock, encoded outside it ([`Snapshot::ops`]).
    pub fn checkpoint(&mut self) -> Snapshot {
        self.checkpoint_asked = false;
        let mut all = Snapshot::default();
        self.storing_bytes = 0;
        for job in self.jobs.values_mut() {
            self.storing_bytes += job.dirty_bytes;
            all.extend(job.checkpoint());
        }
        all
    }

    /// Bytes of merged tile sums that only a commit can let go: the tiles merged since the
    /// last checkpoint, and that checkpoint's until it is committed.
    pub fn unstored_bytes(&self) -> u64 {
        self.storing_bytes + self.jobs.values().map(|j| j.dirty_bytes).sum::<u64>()
    }

    /// Whether a result should wait ([`Policy::max_unstored_bytes`]): merged sums are arriving
    /// faster than checkpoints store them. Counted in [`Counters::results_deferred`].
    pub fn defer_result(&mut self) -> bool {
        let defer = self.unstored_bytes() >= self.policy.max_unstored_bytes;
        self.counters.results_deferred += u64::from(defer);
        defer
    }

    /// Whether the tiles merged since the last checkpoint have reached [`MAX_DIRTY_BYTES`]
    /// (their accumulators cannot leave memory before a checkpoint) and no early checkpoint
    /// has been asked for yet: true once per checkpoint at most.
    pub fn wants_checkpoint(&mut self) -> bool {
        if self.checkpoint_asked {
            return false;
        }
        let dirty: u64 = self.jobs.values().map(|j| j.dirty_bytes).sum();
        self.checkpoint_asked = dirty >= MAX_DIRTY_BYTES;
        self.checkpoint_asked
    }

    /// After a restart, whose tiles all came from the store: drops from memory those that no
    /// result will change ([`Job::evict`]). Returns the bytes freed.
    pub fn evict_restored(&mut self) -> u64 {
        self.jobs
            .values_mut()
            .map(|job| {
                let tiles: Vec<u32> = job.acc.keys().copied().collect();
                evict_in(job, tiles, &self.policy)
            })
            .sum()
    }

    /// After a checkpoint that wrote `tiles` ((job, tile) pairs): drops from memory those
    /// that no result will change ([`Job::evict`]). Returns the bytes freed.
    pub fn evict(&mut self, tiles: &[(u64, u32)]) -> u64 {
        self.storing_bytes = 0;
        let mut by_job: BTreeMap<u64, Vec<u32>> = BTreeMap::new();
        for &(j, t) in tiles {
            by_job.entry(j).or_default().push(t);
        }
        by_job
            .into_iter()
            .filter_map(|(j, ts)| Some(evict_in(self.jobs.get_mut(&JobId(j))?, ts, &self.policy)))
            .sum()
    }

    /// Whether worker `w`'s result for `unit` under `lease` must first read its tile back
    /// from the store ([`Job::needs_reload`]): only for a lease this worker holds for that unit,
    /// so a forged result costs no store read. Returns the tile's rectangle.
    pub fn needs_reload(
        &self,
        w: u64,
        lease: LeaseId,
        job_id: JobId,
        unit: Unit,
    ) -> Option<PixelRect> {
        let n = self.held_by(w, lease)?;
        let l = self.leases.get(&n)?;
        if l.job != job_id || l.unit != unit {
            return None;
        }
        self.jobs.get(&job_id)?.needs_reload(unit)
    }

    /// Puts back a tile read from the store for a merge ([`Job::reload`]); whether it went
    /// back. Counted in [`Counters::tiles_reloaded`].
    pub fn reload(&mut self, job_id: JobId, tile: u32, sums: TileSums) -> bool {
        let back = self
            .jobs
            .get_mut(&job_id)
            .is_some_and(|j| j.reload(tile, sums));
        self.counters.tiles_reloaded += u64::from(back);
        back
    }

    /// Ends a job (done, cancelled or failed): frees its units, leases and sums; a job that
    /// fails or is cancelled fails the jobs that wait for it ([`Scheduler::end_dependents`]).
    pub fn end_job(&mut self, id: JobId, phase: JobPhase, error: String, now_ms: i64) -> Vec<Op> {
        let Some(job) = self.jobs.get_mut(&id) else {
            return Vec::new();
        };
        if phase == JobPhase::Done {
            job.rec.final_noise = job.image_noise.unwrap_or_else(|| job.noise());
            job.rec.final_counts = (job.units_done, job.samples_done);
            job.final_tile_noise =
                (job.tiles.len() <= crate::job::MAX_KEPT_TILE_NOISE).then(|| job.tile_noise());
        }
        job.rec.phase = phase;
        job.rec.error = error;
        job.rec.finished_ms = now_ms;
        for l in job.clear() {
            self.leases.remove(&l);
        }
        // A dispute over a unit of a job that has ended will never be settled: its suspects
        // are cleared of it rather than kept from work for good.
        for w in self.workers.values_mut() {
            w.disputes.retain(|(j, _)| *j != id);
        }
        self.lapses.retain(|&(j, _), _| j != id);
        self.denoising.remove(&id);
        // A failed job's scene is kept for `tessera retry` ([`retry`]).
        job.retryable = phase == JobPhase::Failed && !self.policy.retry_window.is_zero();
        let mut ops = vec![Op::PutJob(job.rec.clone()), Op::DropSums(id.0)];
        // A scene is kept while a live or retryable job needs it; without this every distinct
        // scene ever submitted (cancelled ones too) would stay in the store for good.
        let hash = job.rec.scene_hash.clone();
        if !self.scene_is_kept(&hash) {
            ops.push(Op::DropScene(hash));
        }
        if matches!(phase, JobPhase::Failed | JobPhase::Cancelled) {
            ops.extend(self.end_dependents(id, now_ms));
        }
        ops
    }
}

/// [`Job::evict`] of `tiles` under `policy`: open tiles too for a job over
/// [`Policy::evict_open_over`].
fn evict_in(job: &mut Job, tiles: impl IntoIterator<Item = u32>, policy: &Policy) -> u64 {
    let open = job.frame_bytes() > policy.evict_open_over;
    job.evict(tiles, open)
}
