//! The coordinator's in-memory scheduling state: jobs and their work units, leases, workers,
//! and per-tile accumulators. Every method is synchronous and short; the caller holds one
//! mutex around [`Core`] and turns the returned [`Op`]s into a durable commit before replying.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::ops::Range;
use std::time::{Duration, Instant};

use tessera_render::{PixelRect, RenderSettings, Strategy, TileSums};

use crate::store::{decode_sums, encode_sums, JobPhase, JobRecord, LoadedJob, Op};

/// One work unit: a tile and a batch of sample indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Unit {
    /// Tile index (row-major).
    pub tile: u32,
    /// Batch index.
    pub batch: u32,
}

/// A lease: a unit lent to a worker until `deadline`.
#[derive(Debug)]
pub struct Lease {
    /// Job id.
    pub job: u64,
    /// The unit.
    pub unit: Unit,
    /// Worker id.
    pub worker: u64,
    /// When it lapses unless renewed.
    pub deadline: Instant,
    /// False once lapsed or handed back: the unit is back in the queue, but a late result
    /// quoting this lease is still merged (once) if the unit is not done by then.
    pub active: bool,
}

/// A worker as seen by the coordinator.
#[derive(Debug)]
pub struct Worker {
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
    /// Sent too many invalid results: gets no more work.
    pub quarantined: bool,
}

/// Merged sums of one tile: batches `0..next` folded in order, plus results that arrived early.
#[derive(Debug, Default)]
pub struct TileAcc {
    /// Sums of batches `0..next` (allocated at the first merge).
    pub sums: Option<TileSums>,
    /// First batch not yet folded in.
    pub next: u32,
    /// Results for batches after `next`, waiting for their turn.
    pub pending: BTreeMap<u32, TileSums>,
    /// [`TileSums::noise_parts`] of `sums`.
    pub noise: (f64, f64, u64),
}

/// A job in memory.
#[derive(Debug)]
pub struct Job {
    /// What is stored.
    pub rec: JobRecord,
    /// Its tiles, row-major.
    pub tiles: Vec<PixelRect>,
    /// Batches per tile.
    pub n_batches: u32,
    /// Per-tile accumulators (empty once the job has ended).
    pub acc: Vec<TileAcc>,
    /// Next unit to hand out, in batch-major order (all tiles' batch 0, then batch 1, …), so
    /// the image converges evenly and few results wait out of order.
    pub cursor: u64,
    /// Units whose lease lapsed or was handed back; served before the cursor.
    pub requeue: VecDeque<Unit>,
    /// Leases issued for units not yet merged.
    pub issued: HashMap<Unit, Vec<u64>>,
    /// Units merged or waiting in order.
    pub units_done: u64,
    /// Samples in those.
    pub samples_done: u64,
    /// Non-finite samples reported.
    pub nonfinite: u64,
    /// (time, samples_done) over the last seconds, for the rate.
    pub rate: VecDeque<(Instant, u64)>,
    /// A unit has been leased.
    pub started: bool,
    /// Every unit is in; the EXR is being written.
    pub finishing: bool,
}

/// Job id as shown to users.
pub fn job_name(id: u64) -> String {
    format!("job-{id:06}")
}

/// Inverse of [`job_name`].
pub fn parse_job(s: &str) -> Option<u64> {
    s.strip_prefix("job-")
        .filter(|d| !d.is_empty() && d.len() <= 20 && d.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|d| d.parse().ok())
}

impl Job {
    /// A job from its record, with the stored sums folded back in.
    pub fn new(rec: JobRecord) -> Self {
        let tiles = PixelRect::tiles(rec.width, rec.height, rec.tile_size);
        let n_batches = rec.spp.div_ceil(rec.batch.max(1));
        let acc = if rec.phase == JobPhase::Active {
            tiles.iter().map(|_| TileAcc::default()).collect()
        } else {
            Vec::new()
        };
        Self {
            rec,
            tiles,
            n_batches,
            acc,
            cursor: 0,
            requeue: VecDeque::new(),
            issued: HashMap::new(),
            units_done: 0,
            samples_done: 0,
            nonfinite: 0,
            rate: VecDeque::new(),
            started: false,
            finishing: false,
        }
    }

    /// Rebuilds a job after a restart from what the store held.
    pub fn restore(loaded: LoadedJob) -> Result<Self, String> {
        let mut job = Self::new(loaded.record);
        if job.rec.phase != JobPhase::Active {
            return Ok(job);
        }
        for (tile, bytes) in loaded.tiles {
            let rect = *job
                .tiles
                .get(tile as usize)
                .ok_or_else(|| format!("tile {tile} is outside the job"))?;
            let sums = decode_sums(&bytes, rect).map_err(|e| format!("tile {tile}: {e}"))?;
            let batches = sums.samples.end.div_ceil(job.rec.batch);
            if sums.samples.start != 0
                || job.batch_range(batches.saturating_sub(1)).end != sums.samples.end
            {
                return Err(format!(
                    "tile {tile}: sums cover samples {:?}",
                    sums.samples
                ));
            }
            job.units_done += batches as u64;
            job.samples_done += rect.area() as u64 * sums.samples.end as u64;
            job.nonfinite += sums.nonfinite;
            let acc = &mut job.acc[tile as usize];
            acc.next = batches;
            acc.noise = sums.noise_parts();
            acc.sums = Some(sums);
        }
        for ((tile, batch), bytes) in loaded.pending {
            let rect = *job
                .tiles
                .get(tile as usize)
                .ok_or_else(|| format!("tile {tile} is outside the job"))?;
            let sums = decode_sums(&bytes, rect).map_err(|e| format!("tile {tile}: {e}"))?;
            if sums.samples != job.batch_range(batch) {
                return Err(format!(
                    "tile {tile} batch {batch}: samples {:?}",
                    sums.samples
                ));
            }
            job.units_done += 1;
            job.samples_done += rect.area() as u64 * sums.samples.len() as u64;
            job.nonfinite += sums.nonfinite;
            job.acc[tile as usize].pending.insert(batch, sums);
        }
        job.started = job.units_done > 0;
        Ok(job)
    }

    /// Units in the job.
    pub fn units_total(&self) -> u64 {
        self.tiles.len() as u64 * self.n_batches as u64
    }

    /// Sample indices of batch `b`.
    pub fn batch_range(&self, b: u32) -> Range<u32> {
        let s = b.saturating_mul(self.rec.batch).min(self.rec.spp);
        s..s.saturating_add(self.rec.batch).min(self.rec.spp)
    }

    /// The renderer settings of this job.
    pub fn settings(&self) -> RenderSettings {
        RenderSettings {
            seed: self.rec.seed,
            spp: self.rec.spp,
            batch: self.rec.batch,
            strategy: Strategy::from_name(&self.rec.strategy).unwrap_or_default(),
            ..RenderSettings::default()
        }
    }

    /// Whether the unit has been merged or is waiting its turn.
    pub fn is_done(&self, u: Unit) -> bool {
        self.acc
            .get(u.tile as usize)
            .is_none_or(|a| u.batch < a.next || a.pending.contains_key(&u.batch))
    }

    /// Whether the job still takes leases and results.
    pub fn is_live(&self) -> bool {
        self.rec.phase == JobPhase::Active && !self.finishing
    }

    fn has_active_lease(&self, u: Unit, leases: &HashMap<u64, Lease>) -> bool {
        self.issued
            .get(&u)
            .is_some_and(|ids| ids.iter().any(|l| leases.get(l).is_some_and(|x| x.active)))
    }

    /// A copy of a unit that is out already, for worker `w` to race: the one leased longest
    /// ago that has exactly one live lease, held by another worker. Near the end of a job this
    /// keeps a slow or stuck worker from holding everyone up; the first result is merged and
    /// the other is a duplicate.
    fn speculative_unit(&self, w: u64, leases: &HashMap<u64, Lease>) -> Option<Unit> {
        let mut best: Option<(u64, Unit)> = None;
        for (u, ids) in &self.issued {
            if self.is_done(*u) {
                continue;
            }
            let mut live = ids
                .iter()
                .filter(|l| leases.get(l).is_some_and(|x| x.active));
            let (Some(&l), None) = (live.next(), live.next()) else {
                continue;
            };
            if leases.get(&l).is_some_and(|x| x.worker != w) && best.is_none_or(|(b, _)| l < b) {
                best = Some((l, *u));
            }
        }
        best.map(|(_, u)| u)
    }

    fn next_unit(&mut self, leases: &HashMap<u64, Lease>) -> Option<Unit> {
        while let Some(u) = self.requeue.pop_front() {
            if !self.is_done(u) && !self.has_active_lease(u, leases) {
                return Some(u);
            }
        }
        let n_tiles = self.tiles.len() as u64;
        while self.cursor < self.units_total() {
            let u = Unit {
                tile: (self.cursor % n_tiles) as u32,
                batch: (self.cursor / n_tiles) as u32,
            };
            self.cursor += 1;
            if !self.is_done(u) && !self.has_active_lease(u, leases) {
                return Some(u);
            }
        }
        None
    }

    /// Merged samples per second over the last few seconds.
    pub fn rate(&self) -> f64 {
        match (self.rate.front(), self.rate.back()) {
            (Some(a), Some(b)) if b.0 > a.0 => {
                (b.1 - a.1) as f64 / b.0.duration_since(a.0).as_secs_f64()
            }
            _ => 0.0,
        }
    }

    /// RMS standard error of merged pixel means, and the same relative to the mean.
    pub fn noise(&self) -> (f64, f64) {
        if self.acc.is_empty() {
            return self.rec.final_noise;
        }
        let (mut var, mut mean, mut n) = (0.0, 0.0, 0u64);
        for a in &self.acc {
            var += a.noise.0;
            mean += a.noise.1;
            n += a.noise.2;
        }
        if n == 0 {
            return (0.0, 0.0);
        }
        let rms = (var / n as f64).sqrt();
        let mean = mean / n as f64;
        (rms, if mean > 0.0 { rms / mean } else { 0.0 })
    }

    /// Checks a result against the unit it claims to be.
    pub fn check_result(&self, u: Unit, r: &TileSums) -> Result<(), String> {
        let rect = self.tiles[u.tile as usize];
        if r.rect != rect {
            return Err(format!(
                "result covers {}×{} at ({}, {}) but tile {} is {}×{} at ({}, {})",
                r.rect.width,
                r.rect.height,
                r.rect.x0,
                r.rect.y0,
                u.tile,
                rect.width,
                rect.height,
                rect.x0,
                rect.y0
            ));
        }
        let range = self.batch_range(u.batch);
        if r.samples != range {
            return Err(format!(
                "result covers samples {:?} but batch {} is samples {:?}",
                r.samples, u.batch, range
            ));
        }
        r.check_shape().map_err(|e| e.to_string())?;
        let per_pixel = range.len() as u64;
        let mut missing = 0u64;
        for (i, (s, q)) in r.sum.iter().zip(&r.sum_sq).enumerate() {
            if s.iter().chain(q).any(|v| !v.is_finite() || *v < 0.0) {
                return Err(format!(
                    "pixel {i} of the result has a negative or non-finite sum ({s:?}, {q:?})"
                ));
            }
            let k = r.count[i] as u64;
            if k > per_pixel {
                return Err(format!(
                    "pixel {i} counts {k} samples in a batch of {per_pixel}"
                ));
            }
            missing += per_pixel - k;
        }
        if missing != r.nonfinite {
            return Err(format!(
                "result drops {missing} samples but reports {} non-finite",
                r.nonfinite
            ));
        }
        Ok(())
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
}

/// Why a worker call was refused.
#[derive(Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Unknown id (worker, job).
    NotFound(String),
    /// Malformed or inconsistent.
    Invalid(String),
    /// Not allowed in the current state (unknown lease).
    Precondition(String),
    /// The worker is quarantined.
    Denied(String),
}

/// A unit handed to a worker.
pub struct Granted {
    /// Lease number.
    pub lease: u64,
    /// Job id.
    pub job: u64,
    /// Unit.
    pub unit: Unit,
}

/// All scheduling state.
#[derive(Debug)]
pub struct Core {
    /// Boot counter: part of every lease and worker id.
    pub epoch: u64,
    /// Jobs by id.
    pub jobs: BTreeMap<u64, Job>,
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
}

impl Core {
    /// Empty state for boot `epoch`.
    pub fn new(epoch: u64, lease_time: Duration) -> Self {
        Self {
            epoch,
            jobs: BTreeMap::new(),
            next_job: 1,
            leases: HashMap::new(),
            next_lease: 1,
            workers: BTreeMap::new(),
            next_worker: 1,
            lease_time,
            quarantine_after: 5,
        }
    }

    /// Lease id as sent: epoch and number, so a lease from before a restart is recognised as
    /// stale rather than confused with a new one.
    pub fn lease_name(&self, n: u64) -> String {
        format!("L{}-{n}", self.epoch)
    }

    /// Inverse of [`Core::lease_name`] for this epoch.
    pub fn parse_lease(&self, s: &str) -> Result<u64, Refusal> {
        let bad = || Refusal::Invalid(format!("malformed lease id {:?}", truncate(s)));
        let (e, n) = s
            .strip_prefix('L')
            .and_then(|r| r.split_once('-'))
            .ok_or_else(bad)?;
        let (e, n): (u64, u64) = (e.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
        if e != self.epoch {
            return Err(Refusal::Precondition(format!(
                "lease {s} is from before the coordinator restarted; drop it"
            )));
        }
        Ok(n)
    }

    /// Worker id as sent.
    pub fn worker_name(&self, n: u64) -> String {
        format!("w{}-{n}", self.epoch)
    }

    /// Looks up a worker by id and marks it seen.
    pub fn touch_worker(&mut self, id: &str, now: Instant) -> Result<u64, Refusal> {
        let unknown = || {
            Refusal::NotFound(format!(
                "unknown worker {:?} (the coordinator may have restarted): register again",
                truncate(id)
            ))
        };
        let n = id
            .strip_prefix('w')
            .and_then(|r| r.split_once('-'))
            .and_then(|(e, n)| Some((e.parse::<u64>().ok()?, n.parse::<u64>().ok()?)))
            .filter(|(e, _)| *e == self.epoch)
            .map(|(_, n)| n)
            .ok_or_else(unknown)?;
        let w = self.workers.get_mut(&n).ok_or_else(unknown)?;
        w.last_seen = now;
        w.gone = false;
        if w.quarantined {
            return Err(Refusal::Denied(format!(
                "worker {} is quarantined after {} invalid results",
                truncate(id),
                w.bad_results
            )));
        }
        Ok(n)
    }

    /// Registers a worker and returns its number.
    pub fn register(&mut self, name: String, cores: u32, version: String, now: Instant) -> u64 {
        let n = self.next_worker;
        self.next_worker += 1;
        self.workers.insert(
            n,
            Worker {
                name,
                cores,
                version,
                last_seen: now,
                units_done: 0,
                samples_done: 0,
                bad_results: 0,
                gone: false,
                quarantined: false,
            },
        );
        n
    }

    /// Jobs in scheduling order: priority (high first), then submission order; only those
    /// still taking leases if `live_only` (finished jobs accumulate, and leasing runs often).
    pub fn schedule_order(&self, live_only: bool) -> Vec<u64> {
        let mut ids: Vec<(i32, u64)> = self
            .jobs
            .values()
            .filter(|j| !live_only || j.is_live())
            .map(|j| (j.rec.priority, j.rec.id))
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
                lease.active = false;
                if let Some(job) = self.jobs.get_mut(&lease.job) {
                    if job.is_live() && !job.is_done(lease.unit) {
                        job.requeue.push_front(lease.unit);
                        any = true;
                    }
                }
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
                        job.speculative_unit(w, &self.leases)
                    } else {
                        job.next_unit(&self.leases)
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
                            deadline: now + self.lease_time,
                            active: true,
                        },
                    );
                    out.push(Granted {
                        lease: n,
                        job: id,
                        unit,
                    });
                }
            }
        }
        out
    }

    /// Renews worker `w`'s leases; returns those it should drop.
    pub fn heartbeat(&mut self, w: u64, ids: &[String], now: Instant) -> Vec<String> {
        let mut revoked = Vec::new();
        for id in ids {
            let keep = match self.parse_lease(id) {
                Ok(n) => match self.leases.get_mut(&n) {
                    Some(l) if l.worker == w => {
                        let live = self
                            .jobs
                            .get(&l.job)
                            .is_some_and(|j| j.is_live() && !j.is_done(l.unit));
                        if live && l.active {
                            l.deadline = now + self.lease_time;
                        }
                        live
                    }
                    _ => false,
                },
                Err(_) => false,
            };
            if !keep {
                revoked.push(id.clone());
            }
        }
        revoked
    }

    /// Hands leases back: their units go to the front of the queue.
    pub fn release(&mut self, w: u64, ids: &[String]) -> u32 {
        let mut n = 0;
        for id in ids {
            let Ok(l) = self.parse_lease(id) else {
                continue;
            };
            let Some(lease) = self.leases.get_mut(&l) else {
                continue;
            };
            if lease.worker != w || !lease.active {
                continue;
            }
            lease.active = false;
            if let Some(job) = self.jobs.get_mut(&lease.job) {
                if job.is_live() && !job.is_done(lease.unit) {
                    job.requeue.push_front(lease.unit);
                    n += 1;
                }
            }
        }
        n
    }

    /// Merges a result from worker `w`.
    pub fn submit(
        &mut self,
        w: u64,
        lease_id: &str,
        job_id: u64,
        unit: Unit,
        sums: TileSums,
        now: Instant,
    ) -> Result<Merged, Refusal> {
        let lease_n = self.parse_lease(lease_id);
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Err(Refusal::NotFound(format!(
                "unknown job {}",
                job_name(job_id)
            )));
        };
        if !job.is_live() {
            return Ok(Merged::Discarded);
        }
        if unit.tile as usize >= job.tiles.len() || unit.batch >= job.n_batches {
            return Err(Refusal::Invalid(format!(
                "{} has no tile {} batch {} ({} tiles × {} batches)",
                job_name(job_id),
                unit.tile,
                unit.batch,
                job.tiles.len(),
                job.n_batches
            )));
        }
        if job.is_done(unit) {
            return Ok(Merged::Duplicate);
        }
        let lease_n = lease_n?;
        match self.leases.get(&lease_n) {
            Some(l) if l.job == job_id && l.unit == unit => {}
            _ => {
                return Err(Refusal::Precondition(format!(
                    "lease {lease_id} was not issued for {} tile {} batch {}",
                    job_name(job_id),
                    unit.tile,
                    unit.batch
                )))
            }
        }
        if let Err(e) = job.check_result(unit, &sums) {
            self.count_bad_result(w);
            return Err(Refusal::Invalid(format!(
                "{} tile {} batch {}: {e}",
                job_name(job_id),
                unit.tile,
                unit.batch
            )));
        }
        let samples = sums.rect.area() as u64 * sums.samples.len() as u64;
        job.units_done += 1;
        job.samples_done += samples;
        job.nonfinite += sums.nonfinite;
        job.rate.push_back((now, job.samples_done));
        while job.rate.len() > 2
            && job
                .rate
                .front()
                .is_some_and(|f| now.duration_since(f.0) > Duration::from_secs(10))
        {
            job.rate.pop_front();
        }
        for l in job.issued.remove(&unit).unwrap_or_default() {
            self.leases.remove(&l);
        }
        let mut ops = Vec::new();
        let rect = sums.rect;
        let acc = &mut job.acc[unit.tile as usize];
        if unit.batch == acc.next {
            let total = acc.sums.get_or_insert_with(|| TileSums::empty(rect, 0));
            total
                .merge(&sums)
                .map_err(|e| Refusal::Invalid(e.to_string()))?;
            acc.next += 1;
            while let Some(p) = acc.pending.remove(&acc.next) {
                total
                    .merge(&p)
                    .map_err(|e| Refusal::Invalid(e.to_string()))?;
                ops.push(Op::DelPending(job_id, unit.tile, acc.next));
                acc.next += 1;
            }
            acc.noise = total.noise_parts();
            ops.push(Op::PutTile(job_id, unit.tile, encode_sums(total)));
        } else {
            ops.push(Op::PutPending(
                job_id,
                unit.tile,
                unit.batch,
                encode_sums(&sums),
            ));
            acc.pending.insert(unit.batch, sums);
        }
        let finished = job.units_done == job.units_total();
        if finished {
            job.finishing = true;
        }
        if let Some(worker) = self.workers.get_mut(&w) {
            worker.units_done += 1;
            worker.samples_done += samples;
        }
        Ok(Merged::New { ops, finished })
    }

    /// Ends a job (cancelled or failed): frees its units, leases and sums.
    pub fn end_job(&mut self, id: u64, phase: JobPhase, error: String, now_ms: i64) -> Vec<Op> {
        let Some(job) = self.jobs.get_mut(&id) else {
            return Vec::new();
        };
        if phase == JobPhase::Done {
            job.rec.final_noise = job.noise();
        }
        job.rec.phase = phase;
        job.rec.error = error;
        job.rec.finished_ms = now_ms;
        job.acc = Vec::new();
        job.requeue.clear();
        for (_, ids) in job.issued.drain() {
            for l in ids {
                self.leases.remove(&l);
            }
        }
        vec![Op::PutJob(job.rec.clone()), Op::DropSums(id)]
    }

    /// Counts an invalid result against worker `w`, quarantining it (and taking back its
    /// leases) once it reaches the limit.
    pub fn count_bad_result(&mut self, w: u64) {
        let name = self.worker_name(w);
        let Some(worker) = self.workers.get_mut(&w) else {
            return;
        };
        worker.bad_results += 1;
        if worker.bad_results >= self.quarantine_after && !worker.quarantined {
            worker.quarantined = true;
            tracing::warn!(
                "worker {name} ({}) quarantined after {} invalid results",
                worker.name,
                worker.bad_results
            );
            for lease in self.leases.values_mut() {
                if lease.worker == w && lease.active {
                    lease.active = false;
                    if let Some(job) = self.jobs.get_mut(&lease.job) {
                        if job.is_live() && !job.is_done(lease.unit) {
                            job.requeue.push_front(lease.unit);
                        }
                    }
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
}

/// At most 64 characters of a peer-supplied string, for error messages.
pub fn truncate(s: &str) -> String {
    s.chars().take(64).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(spp: u32, batch: u32) -> JobRecord {
        JobRecord {
            id: 1,
            spp,
            batch,
            width: 4,
            height: 2,
            seed: 0,
            strategy: "mis".into(),
            tile_size: 2,
            output_name: "o.exr".into(),
            submitted_ms: 0,
            ..JobRecord::default()
        }
    }

    fn result(job: &Job, u: Unit, value: f64) -> TileSums {
        let rect = job.tiles[u.tile as usize];
        let mut t = TileSums::empty(rect, 0);
        t.samples = job.batch_range(u.batch);
        let k = t.samples.len() as u32;
        for i in 0..rect.area() {
            t.sum[i] = [value; 3];
            t.sum_sq[i] = [value * value; 3];
            t.count[i] = k;
        }
        t
    }

    #[test]
    fn units_are_batch_major_and_the_last_batch_is_short() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(5, 2)));
        let now = Instant::now();
        let w = core.register("w".into(), 1, "v".into(), now);
        let got: Vec<Unit> = core.lease(w, 100, now).iter().map(|g| g.unit).collect();
        assert_eq!(got.len(), 6);
        let want: Vec<Unit> = [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2), (1, 2)]
            .map(|(tile, batch)| Unit { tile, batch })
            .to_vec();
        assert_eq!(got, want);
        assert_eq!(core.jobs[&1].batch_range(2), 4..5);
    }

    #[test]
    fn out_of_order_results_merge_in_batch_order_once() {
        let mut core = Core::new(3, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(6, 2)));
        let now = Instant::now();
        let w = core.register("w".into(), 1, "v".into(), now);
        let granted = core.lease(w, 100, now);
        let names: Vec<(String, Unit)> = granted
            .iter()
            .map(|g| (core.lease_name(g.lease), g.unit))
            .collect();
        // Tile 0's batches arrive 2, 0, 1; a copy of batch 0 arrives again.
        let order = [2u32, 0, 1];
        for b in order {
            let (name, u) = names
                .iter()
                .find(|(_, u)| u.tile == 0 && u.batch == b)
                .cloned()
                .expect("leased");
            let r = result(&core.jobs[&1], u, b as f64 + 1.0);
            let m = core.submit(w, &name, 1, u, r, now).expect("merged");
            assert!(matches!(m, Merged::New { .. }));
        }
        let (name, u) = names[0].clone();
        let r = result(&core.jobs[&1], u, 1.0);
        assert!(matches!(
            core.submit(w, &name, 1, u, r, now),
            Ok(Merged::Duplicate)
        ));
        let acc = &core.jobs[&1].acc[0];
        assert_eq!(acc.next, 3);
        let sums = acc.sums.as_ref().expect("sums");
        assert_eq!(sums.sum[0], [((0.0 + 1.0) + 2.0) + 3.0; 3]);
        assert_eq!(sums.samples, 0..6);
    }

    #[test]
    fn bad_results_are_refused_and_counted() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(4, 2)));
        let now = Instant::now();
        let w = core.register("w".into(), 1, "v".into(), now);
        let g = core.lease(w, 1, now).remove(0);
        let name = core.lease_name(g.lease);
        let job = &core.jobs[&1];
        let mut nan = result(job, g.unit, 1.0);
        nan.sum[1][2] = f64::NAN;
        let mut short = result(job, g.unit, 1.0);
        short.count.pop();
        let mut wrong_range = result(job, g.unit, 1.0);
        wrong_range.samples = 1..3;
        let mut lying = result(job, g.unit, 1.0);
        lying.count[0] = 1;
        for bad in [nan, short, wrong_range, lying] {
            assert!(matches!(
                core.submit(w, &name, 1, g.unit, bad, now),
                Err(Refusal::Invalid(_))
            ));
        }
        assert_eq!(core.workers[&w].bad_results, 4);
        let other = Unit { tile: 1, batch: 0 };
        let r = result(&core.jobs[&1], other, 1.0);
        assert!(matches!(
            core.submit(w, &name, 1, other, r, now),
            Err(Refusal::Precondition(_))
        ));
        let r = result(&core.jobs[&1], g.unit, 1.0);
        assert!(matches!(
            core.submit(w, "L0-1", 1, g.unit, r, now),
            Err(Refusal::Precondition(_))
        ));
        assert_eq!(core.jobs[&1].units_done, 0);
    }

    #[test]
    fn lapsed_leases_requeue_and_late_results_still_count_once() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(2, 2)));
        let t0 = Instant::now();
        let a = core.register("a".into(), 1, "v".into(), t0);
        let b = core.register("b".into(), 1, "v".into(), t0);
        let first = core.lease(a, 1, t0).remove(0);
        let later = t0 + Duration::from_secs(6);
        let again = core.lease(b, 1, later).remove(0);
        assert_eq!(first.unit, again.unit, "the lapsed unit is served first");
        let r = result(&core.jobs[&1], first.unit, 1.0);
        let name = core.lease_name(first.lease);
        assert!(matches!(
            core.submit(a, &name, 1, first.unit, r.clone(), later),
            Ok(Merged::New { .. })
        ));
        let name = core.lease_name(again.lease);
        assert!(matches!(
            core.submit(b, &name, 1, again.unit, r, later),
            Ok(Merged::Duplicate)
        ));
        assert_eq!(
            core.heartbeat(b, std::slice::from_ref(&name), later),
            vec![name]
        );
    }

    #[test]
    fn idle_workers_race_the_oldest_outstanding_unit_once_the_queue_is_empty() {
        let mut core = Core::new(1, Duration::from_secs(60));
        core.jobs.insert(1, Job::new(record(2, 2)));
        let now = Instant::now();
        let slow = core.register("slow".into(), 1, "v".into(), now);
        let fast = core.register("fast".into(), 1, "v".into(), now);
        let held = core.lease(slow, 2, now);
        assert_eq!(held.len(), 2);
        // No fresh unit is left: the fast worker gets a copy of the oldest unit, then of the
        // other, and nothing more (each unit is raced at most once).
        let copies = core.lease(fast, 5, now);
        let units: Vec<Unit> = copies.iter().map(|g| g.unit).collect();
        assert_eq!(units, vec![held[0].unit, held[1].unit]);
        assert!(core.lease(fast, 5, now).is_empty());
        // The copy's result wins; the slow original is then a duplicate.
        let r = result(&core.jobs[&1], copies[0].unit, 1.0);
        let name = core.lease_name(copies[0].lease);
        assert!(matches!(
            core.submit(fast, &name, 1, copies[0].unit, r.clone(), now),
            Ok(Merged::New { .. })
        ));
        let name = core.lease_name(held[0].lease);
        assert!(matches!(
            core.submit(slow, &name, 1, held[0].unit, r, now),
            Ok(Merged::Duplicate)
        ));
    }

    #[test]
    fn a_worker_that_keeps_sending_bad_results_is_quarantined() {
        let mut core = Core::new(1, Duration::from_secs(60));
        core.quarantine_after = 3;
        core.jobs.insert(1, Job::new(record(8, 2)));
        let now = Instant::now();
        let w = core.register("bad".into(), 1, "v".into(), now);
        let id = core.worker_name(w);
        let g = core.lease(w, 2, now);
        let name = core.lease_name(g[0].lease);
        for _ in 0..3 {
            let mut r = result(&core.jobs[&1], g[0].unit, 1.0);
            r.sum[0][0] = f64::INFINITY;
            assert!(matches!(
                core.submit(w, &name, 1, g[0].unit, r, now),
                Err(Refusal::Invalid(_))
            ));
        }
        assert!(core.workers[&w].quarantined);
        assert!(matches!(
            core.touch_worker(&id, now),
            Err(Refusal::Denied(_))
        ));
        assert!(core.lease(w, 1, now).is_empty());
        assert_eq!(core.leases_of(w), 0, "its leases were taken back");
        let other = core.register("good".into(), 1, "v".into(), now);
        let mut units: Vec<Unit> = core.lease(other, 2, now).iter().map(|g| g.unit).collect();
        units.sort();
        let mut want = vec![g[0].unit, g[1].unit];
        want.sort();
        assert_eq!(units, want, "its units are handed out again first");
    }
}
