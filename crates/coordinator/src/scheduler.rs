//! Who gets which unit: workers and their registrations, leases and their deadlines, the
//! queue of each job, speculation past slow holders, quarantine, and admission of new jobs.
//! Every method is synchronous and short; the caller holds one mutex around [`Scheduler`] and
//! turns the returned [`Op`]s into a durable commit before replying.
//!
//! Ids arrive typed ([`tessera_proto::ids`]): the handlers parse the wire's strings, and the
//! scheduler only checks that an id is one it issued, in this boot, to this caller.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::{Duration, Instant};

use tessera_proto::ids::{JobId, LeaseId, WorkerCredential, WorkerId};
use tessera_render::{RenderSettings, TileSums, IMAGE_REVISION};

use crate::error::Refusal;
use crate::job::{same_bits, AuditHold, Job, KeptUnits, Rate, Source, Unit, NOBODY};
use crate::output::OutputNames;
use crate::store::{AuditRecord, JobPhase, JobRecord, LoadedJob, Op, RangeRef, StoredScene};
use tessera_render::scene::FrameRange;

/// A lease: a unit lent to a worker until `deadline`.
#[derive(Debug)]
pub struct Lease {
    /// Job id.
    pub job: JobId,
    /// The unit.
    pub unit: Unit,
    /// Worker id.
    pub worker: u64,
    /// When it was issued: a holder that keeps a unit far longer than a unit takes is slow
    /// (or hoarding), and others may race it.
    pub issued: Instant,
    /// When it lapses unless renewed.
    pub deadline: Instant,
    /// False once lapsed or handed back: the unit is back in the queue, but a late result
    /// quoting this lease is still merged (once) if the unit is not done by then.
    pub active: bool,
}

/// A worker as seen by the coordinator.
#[derive(Debug)]
pub struct Worker {
    /// The secret half of its id, issued at registration: every later call must quote it, so
    /// nobody who only saw the public id (`tessera workers` lists it) can act as this worker.
    pub secret: String,
    /// Name it gave.
    pub name: String,
    /// Cores it reported.
    pub cores: u32,
    /// Its version.
    pub version: String,
    /// Last call.
    pub last_seen: Instant,
    /// Units merged from it.
    pub units_done: u64,
    /// Samples merged from it.
    pub samples_done: u64,
    /// Results refused as invalid.
    pub bad_results: u64,
    /// Said goodbye.
    pub gone: bool,
    /// Sent too many invalid results, or convicted by an audit: gets no more work.
    pub quarantined: bool,
    /// Why an audit convicted it, if one did.
    pub convicted: Option<String>,
    /// Audited units whose copies disagree and that it rendered, until the coordinator's own
    /// render of each decides (shown as "suspect"; it keeps working meanwhile).
    pub disputes: BTreeSet<(JobId, Unit)>,
    /// Its results that another worker's copy matched bit for bit.
    pub audits_passed: u64,
    /// Audited jobs it gave results to: those already ended when it is convicted are named
    /// in the conviction's record.
    pub jobs: BTreeSet<JobId>,
    /// The address it registered from (empty when unknown).
    pub host: String,
    /// Its merged samples over the last seconds.
    pub rate: Rate,
}

impl Worker {
    /// Whether it counts as alive at `now`: it called within `lease_time` and has not said
    /// goodbye.
    pub fn alive(&self, now: Instant, lease_time: Duration) -> bool {
        !self.gone && now.duration_since(self.last_seen) <= lease_time
    }

    /// Why this worker, whose public id is `id`, gets nothing: quarantined after invalid
    /// results, or convicted by an audit; `None` if it may work.
    fn refusal(&self, id: WorkerId) -> Option<Refusal> {
        if let Some(why) = &self.convicted {
            return Some(Refusal::Denied(format!(
                "worker {id} is quarantined: {why}"
            )));
        }
        self.quarantined.then(|| {
            Refusal::Denied(format!(
                "worker {id} is quarantined after {} invalid results",
                self.bad_results
            ))
        })
    }
}

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

/// A job to admit: a parsed scene and checked settings.
#[derive(Debug)]
pub struct Admission {
    /// The scene's content hash.
    pub scene_hash: String,
    /// The scene as submitted (kept for workers to fetch).
    pub scene: StoredScene,
    /// Image width, from the scene.
    pub width: u32,
    /// Image height, from the scene.
    pub height: u32,
    /// Render settings, checked against the coordinator's limits.
    pub settings: RenderSettings,
    /// Tile edge, checked.
    pub tile_size: u32,
    /// The output name asked for (checked for form), or none for the job's own.
    pub output_name: Option<String>,
    /// Priority (higher first).
    pub priority: i32,
    /// Write variance channels.
    pub variance: bool,
    /// Write the sample-count channel.
    pub sample_count: bool,
    /// The frames of a frame-range job (`settings.frame` is then each frame's own); `None`
    /// for a job of one frame.
    pub frames: Option<FrameRange>,
}

/// Bounds admission enforces.
#[derive(Clone, Copy, Debug)]
pub struct AdmissionLimits {
    /// Most jobs queued or running at once.
    pub max_active_jobs: usize,
    /// Most work units one job may have (one frame of a frame-range job).
    pub max_units_per_job: u64,
    /// Most frames one frame-range job may have.
    pub max_frames_per_job: u64,
}

/// All scheduling state.
#[derive(Debug)]
pub struct Scheduler {
    /// Boot counter: part of every lease and worker id.
    pub epoch: u64,
    /// Jobs by id.
    pub jobs: BTreeMap<JobId, Job>,
    /// Frame-range jobs: each range's id and its frames' jobs, in frame order. A range has no
    /// job of its own; its state is its frames'.
    pub ranges: BTreeMap<JobId, Vec<JobId>>,
    /// Next job id.
    pub next_job: u64,
    /// Leases by number.
    pub leases: HashMap<u64, Lease>,
    /// Next lease number.
    pub next_lease: u64,
    /// Workers by number.
    pub workers: BTreeMap<u64, Worker>,
    /// Next worker number.
    pub next_worker: u64,
    /// How long a lease lasts.
    pub lease_time: Duration,
    /// Invalid results after which a worker is quarantined.
    pub quarantine_after: u64,
    /// Most leases one registration may hold at once.
    pub max_leases_per_worker: usize,
    /// Fraction of the units of audited jobs rendered a second time by another worker; jobs
    /// admitted while it is above 0 are audited ([`JobRecord::audited`]).
    pub audit: f64,
    /// State of the generator that picks audited units. Workers cannot see it, so a worker
    /// cannot tell which of its units will be checked.
    pub audit_rng: u64,
    /// Serial of the last merge into an audited job ([`Source`]); starts at `epoch << 40` so
    /// that serials are not reused across boots.
    pub serial: u64,
    /// Convictions in this boot.
    pub convictions: u64,
    /// Most live registrations from one host (the address a worker registered from).
    pub max_workers_per_host: usize,
    /// Audited units for the coordinator to render itself ([`Scheduler::take_referee_work`]):
    /// their copies disagree, or no worker on another host took the second copy in time.
    referee_wanted: BTreeSet<(JobId, Unit)>,
    /// What happened to units and results since this boot, for metrics.
    pub counters: Counters,
}

/// Totals since the coordinator started, exported as Prometheus counters (docs/farm.md,
/// "Metrics"). Kept by the scheduler, under its lock, because it is the one place that knows
/// what became of each lease and result.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Units handed out (a unit raced by several workers counts once a lease).
    pub units_leased: u64,
    /// Units merged into their tiles.
    pub units_merged: u64,
    /// Results for units merged already (a raced or retried unit).
    pub units_duplicate: u64,
    /// Results for jobs that had ended.
    pub units_discarded: u64,
    /// Results held for an audit.
    pub units_held: u64,
    /// Units the coordinator rendered itself to settle an audit.
    pub units_refereed: u64,
    /// Results refused (malformed, forged, quoting another's lease, from a quarantined worker).
    pub results_refused: u64,
    /// Samples in the merged units.
    pub samples_merged: u64,
}

/// Whether unit `u` of `job` has a live lease.
fn has_active_lease(job: &Job, u: Unit, leases: &HashMap<u64, Lease>) -> bool {
    job.issued
        .get(&u)
        .is_some_and(|ids| ids.iter().any(|l| leases.get(l).is_some_and(|x| x.active)))
}

/// A copy of a unit that is out already, for worker `w` to race, among those `w` does not
/// hold: the one leased longest ago that has exactly one live lease, or else one whose live
/// leases are all older than `slow` (held by slow or hoarding workers, which renew their leases
/// but never finish). Near the end of a job this keeps a slow, stuck or hostile worker from
/// holding everyone up; the first result is merged and the others are duplicates.
///
/// Copies are limited in rate, not in number: a new copy is fresh, so the next one waits until
/// it too is `slow`. A cap on the number would let as many hoarding registrations fill it and
/// keep the unit from every honest worker for good.
fn speculative_unit(
    job: &Job,
    w: u64,
    host: &str,
    leases: &HashMap<u64, Lease>,
    now: Instant,
    slow: Duration,
) -> Option<Unit> {
    let mut best: Option<(u64, Unit)> = None;
    for (u, ids) in &job.issued {
        if job.is_done(*u) {
            continue;
        }
        let live: Vec<(u64, &Lease)> = ids
            .iter()
            .filter_map(|l| leases.get(l).filter(|x| x.active).map(|x| (*l, x)))
            .collect();
        let Some(&(oldest, _)) = live.first() else {
            continue;
        };
        let all_slow = live
            .iter()
            .all(|(_, x)| now.saturating_duration_since(x.issued) >= slow);
        let eligible = !live.iter().any(|(_, x)| x.worker == w)
            && !audit_excludes(job, *u, w, host)
            && (live.len() == 1 || all_slow);
        if eligible && best.is_none_or(|(b, _)| oldest < b) {
            best = Some((oldest, *u));
        }
    }
    best.map(|(_, u)| u)
}

/// The next unit of `job` to hand out: one put back first, then the next of every tile's first
/// batches in batch-major order (all tiles' batch 0, then batch 1, …), so the image converges
/// evenly and few results wait out of order; then, with a noise target, the batches that
/// tiles' noise decisions released, lowest first.
fn next_unit(job: &mut Job, w: u64, host: &str, leases: &HashMap<u64, Lease>) -> Option<Unit> {
    // An audited unit goes to a worker on a host that has not rendered it: those set aside
    // wait at the front for the next worker.
    let mut aside = Vec::new();
    let mut found = None;
    while let Some(u) = job.requeue.pop_front() {
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            if audit_excludes(job, u, w, host) {
                aside.push(u);
                continue;
            }
            found = Some(u);
            break;
        }
    }
    for u in aside.into_iter().rev() {
        job.requeue.push_front(u);
    }
    if found.is_some() {
        return found;
    }
    let n_tiles = (job.tiles.len() as u64).max(1);
    while job.cursor < job.units_first() {
        let u = Unit {
            tile: (job.cursor % n_tiles) as u32,
            batch: (job.cursor / n_tiles) as u32,
        };
        job.cursor += 1;
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            return Some(u);
        }
    }
    while let Some((batch, tile)) = job.ready.pop_first() {
        let u = Unit { tile, batch };
        if !job.is_done(u) && !has_active_lease(job, u, leases) {
            return Some(u);
        }
    }
    None
}

/// Whether worker `w`, registered from `host`, may not give unit `u` its audit copy: it, or a
/// worker on its host, has a copy held already (or the unit waits for the referee). Copies from
/// one host are one vote, however many registrations it makes.
fn audit_excludes(job: &Job, u: Unit, w: u64, host: &str) -> bool {
    job.audits.get(&u).is_some_and(|h| {
        h.disputed
            || h.results.iter().any(|(k, _)| *k == w)
            || (!host.is_empty() && h.hosts.contains(host))
    })
}

/// Puts the unit of `lease` back at the front of its job's queue, if the job still needs it:
/// a lease that lapsed, was handed back, or was taken from a quarantined worker. Returns
/// whether the unit went back.
fn requeue(jobs: &mut BTreeMap<JobId, Job>, lease: &mut Lease) -> bool {
    lease.active = false;
    match jobs.get_mut(&lease.job) {
        Some(job) if job.is_live() && !job.is_done(lease.unit) => {
            job.requeue.push_front(lease.unit);
            true
        }
        _ => false,
    }
}

impl Scheduler {
    /// Empty state for boot `epoch`.
    pub fn new(epoch: u64, lease_time: Duration) -> Self {
        Self {
            epoch,
            jobs: BTreeMap::new(),
            ranges: BTreeMap::new(),
            next_job: 1,
            leases: HashMap::new(),
            next_lease: 1,
            workers: BTreeMap::new(),
            next_worker: 1,
            lease_time,
            quarantine_after: 5,
            max_leases_per_worker: 8,
            audit: 0.0,
            audit_rng: epoch.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1,
            serial: epoch << 40,
            convictions: 0,
            max_workers_per_host: 256,
            referee_wanted: BTreeSet::new(),
            counters: Counters::default(),
        }
    }

    /// Whether the next unit of an audited job is checked: a draw from a xorshift generator
    /// the service seeds from the operating system.
    fn draw_audit(&mut self) -> bool {
        if self.audit <= 0.0 {
            return false;
        }
        let mut x = self.audit_rng;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.audit_rng = x;
        ((x >> 11) as f64 / (1u64 << 53) as f64) < self.audit
    }

    /// Takes back the jobs a store held at start-up. Returns the store changes to make (a job
    /// of another renderer revision fails; scenes no live job needs go) and the jobs whose
    /// units were all in at the last stop, whose EXR is still to be written.
    pub fn restore(
        &mut self,
        loaded: Vec<LoadedJob>,
        stored_scenes: Vec<String>,
        now_ms: i64,
    ) -> Result<(Vec<Op>, Vec<JobId>), String> {
        let mut to_finish = Vec::new();
        let mut ops = Vec::new();
        let mut failing = Vec::new();
        for loaded in loaded {
            let id = JobId(loaded.record.id);
            let scale = loaded.record.adaptive_scale;
            let mut job = Job::restore(loaded).map_err(|e| format!("{id}: {e}"))?;
            if job.rec.adaptive_scale != scale {
                // The last pilot was merged just before the stop; the scale is computed once
                // more from the same sums, and kept now.
                ops.push(Op::PutJob(job.rec.clone()));
            }
            if job.rec.phase == JobPhase::Active && job.lost_scale() {
                failing.push((
                    id,
                    "an adaptive job accepted by a coordinator with an earlier adaptive rule, \
                     whose tiles went past their pilots under it: its decisions cannot be made \
                     again; resubmit the job"
                        .to_string(),
                ));
            } else if job.rec.phase == JobPhase::Active && job.all_closed() {
                job.finishing = true;
                to_finish.push(id);
            } else if job.rec.phase == JobPhase::Active && job.rec.image_revision != IMAGE_REVISION
            {
                // Accepted by a coordinator of another renderer revision. Its merged sums are
                // that revision's bits; adding this revision's would give an image neither
                // renders.
                if job.started {
                    failing.push((
                        id,
                        format!(
                            "rendered in part by renderer image revision {}, and this \
                             coordinator renders revision {IMAGE_REVISION}: its results cannot \
                             be mixed; resubmit the job",
                            job.rec.image_revision
                        ),
                    ));
                } else {
                    job.rec.image_revision = IMAGE_REVISION;
                    ops.push(Op::PutJob(job.rec.clone()));
                }
            }
            self.next_job = self.next_job.max(id.0 + 1);
            if let Some(r) = job.rec.range {
                // Loaded in id order, which is frame order.
                self.ranges.entry(JobId(r.id)).or_default().push(id);
            }
            self.jobs.insert(id, job);
        }
        // Failed once every job is in, so that a scene another job still needs is kept.
        for (id, why) in failing {
            tracing::warn!("{id}: {why}");
            ops.extend(self.end_job(id, JobPhase::Failed, why, now_ms));
        }
        // Scenes that no live job needs (left by a coordinator that kept them all) go.
        for hash in stored_scenes {
            if !self.scene_is_live(&hash) {
                ops.push(Op::DropScene(hash));
            }
        }
        Ok((ops, to_finish))
    }

    /// Whether an active job renders the scene of this hash.
    fn scene_is_live(&self, hash: &str) -> bool {
        self.jobs
            .values()
            .any(|j| j.rec.phase == JobPhase::Active && j.rec.scene_hash == hash)
    }

    /// Admits a job: checks the coordinator's bounds, gives it an id and an output name no
    /// other job or file has, and returns the store changes that record it. A frame-range job
    /// becomes one job per frame, in frame order (the scheduling order then finishes the first
    /// frames first), under the range's id, which is returned.
    pub fn admit(
        &mut self,
        a: Admission,
        limits: AdmissionLimits,
        names: &OutputNames<'_>,
        now_ms: i64,
    ) -> Result<(JobId, Vec<Op>), Refusal> {
        // A frame-range job counts once, as its user submitted it.
        let mut ranges = std::collections::BTreeSet::new();
        let active = self
            .jobs
            .values()
            .filter(|j| j.rec.phase == JobPhase::Active)
            .filter(|j| j.rec.range.is_none_or(|r| ranges.insert(r.id)))
            .count();
        if active >= limits.max_active_jobs {
            return Err(Refusal::Exhausted(format!(
                "{active} jobs are already queued or running, the limit is {}",
                limits.max_active_jobs
            )));
        }
        if let Some(r) = a.frames {
            if r.len() > limits.max_frames_per_job {
                return Err(Refusal::Exhausted(format!(
                    "frames {r} are {} frames, above the limit of {} per job",
                    r.len(),
                    limits.max_frames_per_job
                )));
            }
        }
        let s = &a.settings;
        let record = |frame: Option<u32>| JobRecord {
            id: 0,
            scene_hash: a.scene_hash.clone(),
            scene_name: a.scene.name.clone(),
            width: a.width,
            height: a.height,
            spp: s.spp,
            seed: s.seed,
            batch: s.batch,
            strategy: s.strategy,
            tile_size: a.tile_size,
            output_name: String::new(),
            priority: a.priority,
            variance: a.variance,
            sample_count: a.sample_count,
            phase: JobPhase::Active,
            error: String::new(),
            submitted_ms: now_ms,
            finished_ms: 0,
            final_noise: (0.0, 0.0),
            image_revision: IMAGE_REVISION,
            noise_target: s.adaptive.map_or(0.0, |a| a.noise_target),
            final_counts: (0, 0),
            frame,
            range: None,
            adaptive_scale: None,
            // An adaptive job's decisions follow its merged sums; taking results back would
            // need them made again from the start, which is not built: such jobs are not
            // audited (docs/farm.md).
            audited: self.audit > 0.0 && s.adaptive.is_none(),
        };
        // The job's own count, so that admission and scheduling cannot disagree on it; a job
        // costs nothing per unit until its units render, so making it first is free. Every
        // frame of a range has the same count.
        let first = Job::new(record(a.frames.map_or(s.frame, |r| Some(r.first))));
        let units = first.units_total();
        if units > limits.max_units_per_job {
            return Err(Refusal::Exhausted(format!(
                "the job would have {units} work units{}, above the limit of {} (use larger \
                 tiles or batches)",
                if a.frames.is_some() { " per frame" } else { "" },
                limits.max_units_per_job
            )));
        }
        let taken = self
            .jobs
            .values()
            .map(|j| (j.id(), j.rec.output_name.as_str()));
        let Some(frames) = a.frames else {
            let (id, output_name) = names.choose(JobId(self.next_job), a.output_name, taken)?;
            let mut job = first;
            self.next_job = id.0 + 1;
            job.rec.id = id.0;
            job.rec.output_name = output_name;
            let ops = vec![
                Op::PutScene(a.scene_hash, a.scene),
                Op::PutJob(job.rec.clone()),
            ];
            self.jobs.insert(id, job);
            return Ok((id, ops));
        };
        let (range_id, output_names) =
            names.choose_range(JobId(self.next_job), a.output_name, frames, taken)?;
        let range = RangeRef {
            id: range_id.0,
            frames,
        };
        let mut ops = vec![Op::PutScene(a.scene_hash.clone(), a.scene.clone())];
        let mut members = Vec::with_capacity(output_names.len());
        for ((frame, output_name), id) in frames.iter().zip(output_names).zip(range_id.0 + 1..) {
            let mut job = Job::new(record(Some(frame)));
            job.rec.id = id;
            job.rec.output_name = output_name;
            job.rec.range = Some(range);
            ops.push(Op::PutJob(job.rec.clone()));
            members.push(JobId(id));
            self.jobs.insert(JobId(id), job);
        }
        self.next_job = members.last().map_or(range_id.0, |m| m.0) + 1;
        self.ranges.insert(range_id, members);
        Ok((range_id, ops))
    }

    /// The jobs `id` names: a frame-range job's frames, or the job itself.
    pub fn members(&self, id: JobId) -> Vec<JobId> {
        self.ranges.get(&id).cloned().unwrap_or_else(|| vec![id])
    }

    /// A lease's id as sent: this boot and its number.
    pub fn lease_id(&self, n: u64) -> LeaseId {
        LeaseId {
            epoch: self.epoch,
            n,
        }
    }

    /// The number of a lease issued in this boot. One from before a restart is stale rather
    /// than confused with a new lease of the same number.
    pub fn lease_number(&self, id: LeaseId) -> Result<u64, Refusal> {
        if id.epoch != self.epoch {
            return Err(Refusal::Precondition(format!(
                "lease {id} is from before the coordinator restarted; drop it"
            )));
        }
        Ok(id.n)
    }

    /// A worker's public id, as listed.
    pub fn worker_id(&self, n: u64) -> WorkerId {
        WorkerId {
            epoch: self.epoch,
            n,
        }
    }

    /// The credential a worker quotes in its calls: the public id and its secret. Only
    /// `Register`'s reply carries it.
    pub fn worker_credential(&self, n: u64) -> Option<WorkerCredential> {
        let w = self.workers.get(&n)?;
        Some(WorkerCredential {
            id: self.worker_id(n),
            secret: w.secret.clone(),
        })
    }

    /// Looks up a worker by the credential it quotes and marks it seen. A credential with a
    /// wrong secret is as unknown as one never issued, so guessing reveals nothing.
    pub fn touch_worker(&mut self, cred: &WorkerCredential, now: Instant) -> Result<u64, Refusal> {
        use subtle::ConstantTimeEq;
        let unknown = || {
            Refusal::NotFound(format!(
                "unknown worker {} (the coordinator may have restarted): register again",
                cred.id
            ))
        };
        if cred.id.epoch != self.epoch {
            return Err(unknown());
        }
        let n = cred.id.n;
        let w = self.workers.get_mut(&n).ok_or_else(unknown)?;
        if !bool::from(w.secret.as_bytes().ct_eq(cred.secret.as_bytes())) {
            return Err(unknown());
        }
        w.last_seen = now;
        w.gone = false;
        match w.refusal(cred.id) {
            Some(r) => Err(r),
            None => Ok(n),
        }
    }

    /// Registers a worker and returns its number. `secret` must be unguessable (the service
    /// draws it from the operating system's random source).
    pub fn register(
        &mut self,
        name: String,
        cores: u32,
        version: String,
        secret: String,
        now: Instant,
    ) -> u64 {
        let n = self.next_worker;
        self.next_worker += 1;
        self.workers.insert(
            n,
            Worker {
                secret,
                name,
                cores,
                version,
                last_seen: now,
                units_done: 0,
                samples_done: 0,
                bad_results: 0,
                gone: false,
                quarantined: false,
                convicted: None,
                disputes: BTreeSet::new(),
                audits_passed: 0,
                jobs: BTreeSet::new(),
                host: String::new(),
                rate: Rate::default(),
            },
        );
        n
    }

    /// Jobs in scheduling order: priority (high first), then submission order; only those
    /// still taking leases if `live_only` (finished jobs accumulate, and leasing runs often).
    pub fn schedule_order(&self, live_only: bool) -> Vec<JobId> {
        let mut ids: Vec<(i32, JobId)> = self
            .jobs
            .values()
            .filter(|j| !live_only || j.is_live())
            .map(|j| (j.rec.priority, j.id()))
            .collect();
        ids.sort_by_key(|&(p, id)| (std::cmp::Reverse(p), id));
        ids.into_iter().map(|(_, id)| id).collect()
    }

    /// Lapses overdue leases, putting their units back at the front of their job's queue.
    /// Returns whether any unit became available.
    pub fn expire(&mut self, now: Instant) -> bool {
        let mut any = false;
        for lease in self.leases.values_mut() {
            if lease.active && lease.deadline <= now {
                any |= requeue(&mut self.jobs, lease);
            }
        }
        // A held unit that no worker on another host has taken within a lease time (a farm of
        // one host, or the other hosts gone) goes to the referee rather than wait for ever.
        for (id, job) in &mut self.jobs {
            if !job.is_live() {
                continue;
            }
            let stale: Vec<Unit> = job
                .audits
                .iter()
                .filter(|(u, hold)| {
                    !hold.disputed
                        && hold
                            .since
                            .is_some_and(|t| now.saturating_duration_since(t) >= self.lease_time)
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
        any
    }

    /// Leases up to `max` units to worker `w`: fresh units first (by job priority), then, if
    /// there are none anywhere, speculative copies of outstanding ones.
    pub fn lease(&mut self, w: u64, max: usize, now: Instant) -> Vec<Granted> {
        self.expire(now);
        let mut out = Vec::new();
        if self.workers.get(&w).is_some_and(|x| x.quarantined) {
            return out;
        }
        // A worker in a dispute keeps working: the coordinator's own render settles the dispute
        // (the referee), and a conviction takes back whatever it gave live jobs meanwhile.
        let host = self
            .workers
            .get(&w)
            .map(|x| x.host.clone())
            .unwrap_or_default();
        // A worker that already holds its share gets nothing more, however much it asks for:
        // one registration cannot take a job's units out of everyone else's reach.
        let max = max.min(self.max_leases_per_worker.saturating_sub(self.leases_of(w)));
        let slow = self.lease_time;
        for speculate in [false, true] {
            for id in self.schedule_order(true) {
                while out.len() < max {
                    let Some(job) = self.jobs.get_mut(&id) else {
                        break;
                    };
                    if !job.is_live() {
                        break;
                    }
                    let next = if speculate {
                        speculative_unit(job, w, &host, &self.leases, now, slow)
                    } else {
                        next_unit(job, w, &host, &self.leases)
                    };
                    let Some(unit) = next else {
                        break;
                    };
                    let n = self.next_lease;
                    self.next_lease += 1;
                    job.issued.entry(unit).or_default().push(n);
                    job.started = true;
                    self.leases.insert(
                        n,
                        Lease {
                            job: id,
                            unit,
                            worker: w,
                            issued: now,
                            deadline: now + self.lease_time,
                            active: true,
                        },
                    );
                    out.push(Granted {
                        lease: self.lease_id(n),
                        job: id,
                        unit,
                    });
                }
            }
        }
        self.counters.units_leased += out.len() as u64;
        out
    }

    /// The number of lease `id` if it was issued in this boot to worker `w`.
    fn held_by(&self, w: u64, id: LeaseId) -> Option<u64> {
        let n = self.lease_number(id).ok()?;
        self.leases
            .get(&n)
            .is_some_and(|l| l.worker == w)
            .then_some(n)
    }

    /// Renews worker `w`'s leases; returns those it should drop.
    pub fn heartbeat(&mut self, w: u64, ids: &[LeaseId], now: Instant) -> Vec<LeaseId> {
        let deadline = now + self.lease_time;
        let mut revoked = Vec::new();
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get_mut(&n));
            let keep = lease.is_some_and(|l| {
                let live = self
                    .jobs
                    .get(&l.job)
                    .is_some_and(|j| j.is_live() && !j.is_done(l.unit));
                if live && l.active {
                    l.deadline = deadline;
                }
                live
            });
            if !keep {
                revoked.push(id);
            }
        }
        revoked
    }

    /// Hands leases back: their units go to the front of the queue.
    pub fn release(&mut self, w: u64, ids: &[LeaseId]) -> u32 {
        let mut released = 0;
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get_mut(&n));
            if let Some(lease) = lease.filter(|l| l.active) {
                released += u32::from(requeue(&mut self.jobs, lease));
            }
        }
        released
    }

    /// Fails the jobs of the leases that worker `w` says it can never render, with its
    /// reason; returns the store changes. Handing such a unit out again would only send it
    /// back and forth (with its scene) for ever.
    pub fn cannot_render(&mut self, w: u64, ids: &[LeaseId], reason: &str, now_ms: i64) -> Vec<Op> {
        let who = format!(
            "worker {} ({})",
            self.worker_id(w),
            self.workers
                .get(&w)
                .map(|x| x.name.escape_debug().to_string())
                .unwrap_or_default()
        );
        let reason: String = reason.chars().take(500).collect();
        let mut ops = Vec::new();
        for &id in ids {
            let lease = self.held_by(w, id).and_then(|n| self.leases.get(&n));
            let Some((job, unit)) = lease.filter(|l| l.active).map(|l| (l.job, l.unit)) else {
                continue;
            };
            if !self.jobs.get(&job).is_some_and(|j| j.is_live()) {
                continue;
            }
            let why = format!(
                "{who} cannot render tile {} batch {}: {reason}",
                unit.tile, unit.batch
            );
            tracing::warn!("{job}: {why}");
            ops.extend(self.end_job(job, JobPhase::Failed, why, now_ms));
        }
        ops
    }

    /// Merges a result from worker `w`; in an audited job, it may instead be held for its
    /// audit (convictions happen in [`Scheduler::referee`]).
    pub fn submit(
        &mut self,
        w: u64,
        lease: LeaseId,
        job_id: JobId,
        unit: Unit,
        sums: TileSums,
        now: Instant,
    ) -> Result<Merged, Refusal> {
        let samples = sums.rect.area() as u64 * sums.samples.len() as u64;
        let outcome = self.take_result(w, lease, job_id, unit, sums, now);
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

    /// [`Scheduler::submit`] without the counting.
    fn take_result(
        &mut self,
        w: u64,
        lease: LeaseId,
        job_id: JobId,
        unit: Unit,
        sums: TileSums,
        now: Instant,
    ) -> Result<Merged, Refusal> {
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
        if let Err(e) = job.check_result(unit, &sums) {
            self.count_bad_result(w);
            return Err(Refusal::Invalid(format!(
                "{job_id} tile {} batch {}: {e}",
                unit.tile, unit.batch
            )));
        }
        let samples = sums.rect.area() as u64 * sums.samples.len() as u64;
        for l in job.issued.remove(&unit).unwrap_or_default() {
            self.leases.remove(&l);
        }
        let (sums, from, mut ops) = if job.rec.audited {
            match self.audit_step(w, job_id, unit, sums, now) {
                Some(settled) => settled,
                None => return Ok(Merged::Held),
            }
        } else {
            (sums, w, Vec::new())
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(Merged::Discarded);
        };
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
    fn audit_step(
        &mut self,
        w: u64,
        job_id: JobId,
        unit: Unit,
        sums: TileSums,
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
                    results: vec![(w, sums)],
                    hosts: std::iter::once(host).filter(|h| !h.is_empty()).collect(),
                    disputed: false,
                    since: Some(now),
                },
            );
            job.requeue.push_front(unit);
            return None;
        };
        if !hold.results.iter().any(|(_, s)| same_bits(s, &sums)) {
            hold.results.push((w, sums));
            if !host.is_empty() {
                hold.hosts.insert(host);
            }
            hold.disputed = true;
            let involved: Vec<u64> = hold.results.iter().map(|(k, _)| *k).collect();
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
        for (k, _) in &hold.results {
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
    pub fn referee(
        &mut self,
        job_id: JobId,
        unit: Unit,
        sums: TileSums,
        now: Instant,
        kept: &dyn KeptUnits,
        now_ms: i64,
    ) -> Result<Merged, Refusal> {
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
        for (k, copy) in &hold.results {
            if let Some(x) = self.workers.get_mut(k) {
                x.disputes.remove(&(job_id, unit));
            }
            if same_bits(copy, &sums) {
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

    /// Whether `host` may register one more worker: it has fewer than
    /// [`Scheduler::max_workers_per_host`] live registrations. An unknown host (no address)
    /// is not counted.
    pub fn host_may_register(&self, host: &str, now: Instant) -> Result<(), Refusal> {
        if host.is_empty() {
            return Ok(());
        }
        let live = self
            .workers
            .values()
            .filter(|x| x.host == host && x.alive(now, self.lease_time) && !x.quarantined)
            .count();
        if live >= self.max_workers_per_host {
            return Err(Refusal::Exhausted(format!(
                "{host} has {live} live worker registrations, the most one host may have \
                 (tessera coordinator --max-workers-per-host)"
            )));
        }
        Ok(())
    }

    /// Takes back worker `w`'s live leases: their units go to the front of their queues.
    fn take_leases(&mut self, w: u64) {
        for lease in self.leases.values_mut() {
            if lease.worker == w && lease.active {
                requeue(&mut self.jobs, lease);
            }
        }
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
            let (job_ops, taken) = job.take_back(w, kept);
            if !job_ops.is_empty() || taken > 0 {
                rebuilt.push(job_id.0);
            }
            units += taken;
            ops.extend(job_ops);
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

    /// Ends a job (done, cancelled or failed): frees its units, leases and sums.
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
        let mut ops = vec![Op::PutJob(job.rec.clone()), Op::DropSums(id.0)];
        // A scene is kept while a live job needs it; without this every distinct scene ever
        // submitted (cancelled ones too) would stay in the store for good.
        let hash = job.rec.scene_hash.clone();
        if !self.scene_is_live(&hash) {
            ops.push(Op::DropScene(hash));
        }
        ops
    }

    /// Counts an invalid result against worker `w`, quarantining it (and taking back its
    /// leases) once it reaches the limit.
    pub fn count_bad_result(&mut self, w: u64) {
        let id = self.worker_id(w);
        let Some(worker) = self.workers.get_mut(&w) else {
            return;
        };
        worker.bad_results += 1;
        if worker.bad_results >= self.quarantine_after && !worker.quarantined {
            worker.quarantined = true;
            tracing::warn!(
                "worker {id} ({}) quarantined after {} invalid results",
                worker.name.escape_debug(),
                worker.bad_results
            );
            for lease in self.leases.values_mut() {
                if lease.worker == w && lease.active {
                    requeue(&mut self.jobs, lease);
                }
            }
        }
    }

    /// Leases held now by worker `w`.
    pub fn leases_of(&self, w: u64) -> usize {
        self.leases
            .values()
            .filter(|l| l.worker == w && l.active)
            .count()
    }

    /// Live leases of a job's units.
    pub fn units_leased(&self, job: &Job) -> u64 {
        job.issued
            .values()
            .filter(|ids| {
                ids.iter()
                    .any(|l| self.leases.get(l).is_some_and(|x| x.active))
            })
            .count() as u64
    }
}
