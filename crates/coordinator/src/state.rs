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

/// A job's tiles, row-major, as arithmetic: a rectangle is computed when asked for, so a job
/// of millions of tiles costs nothing at admission (or at a restart) for tiles not yet
/// rendered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    width: u32,
    height: u32,
    size: u32,
    cols: u32,
    rows: u32,
}

impl TileGrid {
    /// The grid [`PixelRect::tiles`] cuts a `width` × `height` image into.
    pub fn new(width: u32, height: u32, size: u32) -> Self {
        let size = size.max(1);
        Self {
            width,
            height,
            size,
            cols: width.div_ceil(size),
            rows: height.div_ceil(size),
        }
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.cols as usize * self.rows as usize
    }

    /// Whether the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Tile `i`'s rectangle, if there is such a tile.
    pub fn get(&self, i: u32) -> Option<PixelRect> {
        if i as usize >= self.len() {
            return None;
        }
        let (x0, y0) = ((i % self.cols) * self.size, (i / self.cols) * self.size);
        Some(PixelRect {
            x0,
            y0,
            width: self.size.min(self.width - x0),
            height: self.size.min(self.height - y0),
        })
    }
}

/// A job in memory.
#[derive(Debug)]
pub struct Job {
    /// What is stored.
    pub rec: JobRecord,
    /// Its tiles, row-major.
    pub tiles: TileGrid,
    /// Batches per tile.
    pub n_batches: u32,
    /// Accumulators of the tiles that have results, made at a tile's first result (none
    /// once the job has ended).
    pub acc: BTreeMap<u32, TileAcc>,
    /// The sum of every accumulator's `noise`, kept as results merge so that a status does
    /// not walk every tile under the lock.
    pub noise_total: (f64, f64, u64),
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
        let tiles = TileGrid::new(rec.width, rec.height, rec.tile_size);
        let n_batches = rec.spp.div_ceil(rec.batch.max(1));
        Self {
            rec,
            tiles,
            n_batches,
            acc: BTreeMap::new(),
            noise_total: (0.0, 0.0, 0),
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
            let rect = job
                .tiles
                .get(tile)
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
            if batches > job.n_batches || !sums_in_range(&sums) {
                return Err(format!(
                    "tile {tile}: sums out of range for {} spp",
                    job.rec.spp
                ));
            }
            let acc = job.acc.entry(tile).or_default();
            acc.next = batches;
            acc.noise = sums.noise_parts();
            add_noise(&mut job.noise_total, acc.noise, 1.0);
            acc.sums = Some(sums);
        }
        for ((tile, batch), bytes) in loaded.pending {
            let rect = job
                .tiles
                .get(tile)
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
            job.acc.entry(tile).or_default().pending.insert(batch, sums);
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
        self.rec.phase != JobPhase::Active
            || self
                .acc
                .get(&u.tile)
                .is_some_and(|a| u.batch < a.next || a.pending.contains_key(&u.batch))
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

    /// A copy of a unit that is out already, for worker `w` to race, among those `w` does not
    /// hold: the one leased longest ago that has exactly one live lease, or else one whose
    /// live leases are all older than `slow` (held by slow or hoarding workers, which renew
    /// their leases but never finish), up to [`MAX_COPIES`] live leases a unit. Near the end of
    /// a job this keeps a slow, stuck or hostile worker from holding everyone up; the first
    /// result is merged and the others are duplicates.
    fn speculative_unit(
        &self,
        w: u64,
        leases: &HashMap<u64, Lease>,
        now: Instant,
        slow: Duration,
    ) -> Option<Unit> {
        let mut best: Option<(u64, Unit)> = None;
        for (u, ids) in &self.issued {
            if self.is_done(*u) {
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
                && (live.len() == 1 || (all_slow && live.len() < MAX_COPIES));
            if eligible && best.is_none_or(|(b, _)| oldest < b) {
                best = Some((oldest, *u));
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
        let n_tiles = (self.tiles.len() as u64).max(1);
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
        if self.rec.phase != JobPhase::Active {
            return self.rec.final_noise;
        }
        let (var, mean, n) = self.noise_total;
        if n == 0 {
            return (0.0, 0.0);
        }
        // The running total adds and takes away: rounding may leave a variance a hair below 0.
        let rms = (var.max(0.0) / n as f64).sqrt();
        let mean = mean / n as f64;
        let rel = if mean > 0.0 { rms / mean } else { 0.0 };
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        (finite(rms), finite(rel))
    }

    /// Checks a result against the unit it claims to be.
    pub fn check_result(&self, u: Unit, r: &TileSums) -> Result<(), String> {
        let rect = self
            .tiles
            .get(u.tile)
            .ok_or_else(|| format!("the job has no tile {}", u.tile))?;
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
            if !pixel_in_range(s, q, r.count[i]) {
                return Err(format!(
                    "pixel {i}'s sums ({s:?}, {q:?}) are larger than {k} samples of at most \
                     f32::MAX each can add up to"
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
    /// Most leases one registration may hold at once.
    pub max_leases_per_worker: usize,
}

/// Most live leases one unit may have: its first holder and a few racers.
pub const MAX_COPIES: usize = 3;

/// Whether one pixel's sums could come from `k` finite samples. The renderer's samples are
/// f32, so each adds at most `f32::MAX` to a sum and `f32::MAX²` to a squared sum: a result
/// inside these bounds cannot overflow an f64 total however many batches are merged, since a
/// pixel has at most `u32::MAX` samples. Forged finite values near `f64::MAX` are refused
/// here, before they can add up to infinity.
pub fn pixel_in_range(sum: &[f64; 3], sum_sq: &[f64; 3], k: u32) -> bool {
    let max = f32::MAX as f64;
    let k = k as f64;
    sum.iter().all(|v| (0.0..=k * max).contains(v))
        && sum_sq.iter().all(|v| (0.0..=k * max * max).contains(v))
}

/// [`pixel_in_range`] for every pixel of a tile's sums.
pub fn sums_in_range(t: &TileSums) -> bool {
    t.sum
        .iter()
        .zip(&t.sum_sq)
        .zip(&t.count)
        .all(|((s, q), k)| pixel_in_range(s, q, *k))
}

/// Adds `sign` × `parts` to a job's running noise total.
fn add_noise(total: &mut (f64, f64, u64), parts: (f64, f64, u64), sign: f64) {
    total.0 += sign * parts.0;
    total.1 += sign * parts.1;
    total.2 = if sign > 0.0 {
        total.2 + parts.2
    } else {
        total.2.saturating_sub(parts.2)
    };
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
            max_leases_per_worker: 8,
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

    /// A worker's public id, as listed: epoch and number.
    pub fn worker_name(&self, n: u64) -> String {
        format!("w{}-{n}", self.epoch)
    }

    /// The id a worker quotes in its calls: the public id and its secret. Only `Register`'s
    /// reply carries it.
    pub fn worker_credential(&self, n: u64) -> Option<String> {
        let w = self.workers.get(&n)?;
        Some(format!("{}.{}", self.worker_name(n), w.secret))
    }

    /// Looks up a worker by the id it quotes (public id and secret) and marks it seen. An id
    /// with a wrong or missing secret is as unknown as one never issued, so guessing reveals
    /// nothing.
    pub fn touch_worker(&mut self, id: &str, now: Instant) -> Result<u64, Refusal> {
        use subtle::ConstantTimeEq;
        let unknown = || {
            Refusal::NotFound(format!(
                "unknown worker {:?} (the coordinator may have restarted): register again",
                truncate(id.split('.').next().unwrap_or_default())
            ))
        };
        let (public, secret) = id.split_once('.').ok_or_else(unknown)?;
        let n = public
            .strip_prefix('w')
            .and_then(|r| r.split_once('-'))
            .and_then(|(e, n)| Some((e.parse::<u64>().ok()?, n.parse::<u64>().ok()?)))
            .filter(|(e, _)| *e == self.epoch)
            .map(|(_, n)| n)
            .ok_or_else(unknown)?;
        let w = self.workers.get_mut(&n).ok_or_else(unknown)?;
        if !bool::from(w.secret.as_bytes().ct_eq(secret.as_bytes())) {
            return Err(unknown());
        }
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
                        job.speculative_unit(w, &self.leases, now, slow)
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
                            issued: now,
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

    /// Fails the jobs of the leases that worker `w` says it can never render, with its
    /// reason; returns the store changes. Handing such a unit out again would only send it
    /// back and forth (with its scene) for ever.
    pub fn cannot_render(&mut self, w: u64, ids: &[String], reason: &str, now_ms: i64) -> Vec<Op> {
        let who = format!(
            "worker {} ({})",
            self.worker_name(w),
            self.workers
                .get(&w)
                .map(|x| x.name.escape_debug().to_string())
                .unwrap_or_default()
        );
        let reason: String = reason.chars().take(500).collect();
        let mut ops = Vec::new();
        for id in ids {
            let Ok(l) = self.parse_lease(id) else {
                continue;
            };
            let Some(lease) = self.leases.get(&l).filter(|x| x.worker == w && x.active) else {
                continue;
            };
            let (job, unit) = (lease.job, lease.unit);
            if !self.jobs.get(&job).is_some_and(|j| j.is_live()) {
                continue;
            }
            let why = format!(
                "{who} cannot render tile {} batch {}: {reason}",
                unit.tile, unit.batch
            );
            tracing::warn!("{}: {why}", job_name(job));
            ops.extend(self.end_job(job, JobPhase::Failed, why, now_ms));
        }
        ops
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
            Some(l) if l.job == job_id && l.unit == unit && l.worker == w => {}
            _ => {
                return Err(Refusal::Precondition(format!(
                    "lease {lease_id} was not issued to this worker for {} tile {} batch {}",
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
        let acc = job.acc.entry(unit.tile).or_default();
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
            let noise = total.noise_parts();
            add_noise(&mut job.noise_total, acc.noise, -1.0);
            add_noise(&mut job.noise_total, noise, 1.0);
            acc.noise = noise;
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
        job.acc = BTreeMap::new();
        job.noise_total = (0.0, 0.0, 0);
        job.requeue.clear();
        for (_, ids) in job.issued.drain() {
            for l in ids {
                self.leases.remove(&l);
            }
        }
        let mut ops = vec![Op::PutJob(job.rec.clone()), Op::DropSums(id)];
        // A scene is kept while a live job needs it; without this every distinct scene ever
        // submitted (cancelled ones too) would stay in the store for good.
        let hash = job.rec.scene_hash.clone();
        if !self
            .jobs
            .values()
            .any(|j| j.rec.phase == JobPhase::Active && j.rec.scene_hash == hash)
        {
            ops.push(Op::DropScene(hash));
        }
        ops
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
        let rect = job.tiles.get(u.tile).expect("tile");
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
        let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
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
        let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
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
        let acc = &core.jobs[&1].acc[&0];
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
        let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
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
        let a = core.register("a".into(), 1, "v".into(), "s".into(), t0);
        let b = core.register("b".into(), 1, "v".into(), "s".into(), t0);
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
        let slow = core.register("slow".into(), 1, "v".into(), "s".into(), now);
        let fast = core.register("fast".into(), 1, "v".into(), "s".into(), now);
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
        let w = core.register("bad".into(), 1, "v".into(), "s".into(), now);
        let id = core.worker_credential(w).expect("registered");
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
        let other = core.register("good".into(), 1, "v".into(), "s".into(), now);
        let mut units: Vec<Unit> = core.lease(other, 2, now).iter().map(|g| g.unit).collect();
        units.sort();
        let mut want = vec![g[0].unit, g[1].unit];
        want.sort();
        assert_eq!(units, want, "its units are handed out again first");
    }

    #[test]
    fn the_tile_grid_matches_pixel_rect_tiles() {
        for (w, h, size) in [
            (1, 1, 4),
            (17, 5, 4),
            (64, 64, 16),
            (100, 3, 7),
            (3, 100, 128),
        ] {
            let grid = TileGrid::new(w, h, size);
            let all = PixelRect::tiles(w, h, size);
            assert_eq!(grid.len(), all.len());
            for (i, r) in all.iter().enumerate() {
                assert_eq!(grid.get(i as u32), Some(*r), "{w}×{h}/{size} tile {i}");
            }
            assert_eq!(grid.get(all.len() as u32), None);
        }
    }

    #[test]
    fn admission_allocates_nothing_per_tile() {
        // 8192² at tile 4: 4M tiles. The job is accepted and leased with no per-tile memory;
        // only the tiles that get results have accumulators.
        let mut rec = record(1, 1);
        rec.width = 8192;
        rec.height = 8192;
        rec.tile_size = 4;
        let job = Job::new(rec);
        assert_eq!(job.units_total(), 4 << 20);
        assert!(job.acc.is_empty());
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, job);
        let now = Instant::now();
        let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
        let g = core.lease(w, 1, now).remove(0);
        let r = result(&core.jobs[&1], g.unit, 1.0);
        let name = core.lease_name(g.lease);
        assert!(matches!(
            core.submit(w, &name, 1, g.unit, r, now),
            Ok(Merged::New { .. })
        ));
        assert_eq!(core.jobs[&1].acc.len(), 1);
        let (rms, _) = core.jobs[&1].noise();
        assert!(rms.is_finite());
    }

    #[test]
    fn forged_finite_sums_that_would_overflow_when_merged_are_refused() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(4, 2)));
        let now = Instant::now();
        let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
        let g = core.lease(w, 8, now);
        // Two results of 1.7e308 each are finite, but their sum is not.
        for unit in [g[0].unit, g[2].unit] {
            let name = core.lease_name(g.iter().find(|x| x.unit == unit).expect("leased").lease);
            let mut r = result(&core.jobs[&1], unit, 1.0);
            r.sum_sq[0] = [1.7e308; 3];
            assert!(
                matches!(core.submit(w, &name, 1, unit, r, now), Err(Refusal::Invalid(m)) if m.contains("f32::MAX")),
            );
            let mut r = result(&core.jobs[&1], unit, 1.0);
            r.sum[1] = [1e300, 0.0, 0.0];
            assert!(matches!(
                core.submit(w, &name, 1, unit, r, now),
                Err(Refusal::Invalid(_))
            ));
        }
        // The largest honest values merge, and stay finite through every batch.
        for unit in [g[0].unit, g[2].unit] {
            let name = core.lease_name(g.iter().find(|x| x.unit == unit).expect("leased").lease);
            let mut r = result(&core.jobs[&1], unit, 1.0);
            let k = r.count[0] as f64;
            let m = f32::MAX as f64;
            r.sum[0] = [k * m; 3];
            r.sum_sq[0] = [k * m * m; 3];
            assert!(matches!(
                core.submit(w, &name, 1, unit, r, now),
                Ok(Merged::New { .. })
            ));
        }
        let sums = core.jobs[&1].acc[&0].sums.as_ref().expect("sums");
        assert!(sums.sum_sq[0].iter().all(|v| v.is_finite()));
        let (rms, rel) = core.jobs[&1].noise();
        assert!(rms.is_finite() && rel.is_finite());
        // What is stored of a job with such noise loads again.
        let ops = core.end_job(1, JobPhase::Done, String::new(), 1);
        let Some(Op::PutJob(rec)) = ops.first() else {
            panic!("no record")
        };
        let mut rec = rec.clone();
        rec.final_noise = (f64::INFINITY, f64::NAN);
        let json = serde_json::to_vec(&rec).expect("json");
        let back: JobRecord = serde_json::from_slice(&json).expect("loads");
        assert_eq!(back.final_noise, (0.0, 0.0));
        let nulls: JobRecord = serde_json::from_slice(
            &String::from_utf8(json)
                .expect("utf8")
                .replace("[0.0,0.0]", "[null,null]")
                .into_bytes(),
        )
        .expect("a null noise loads");
        assert_eq!(nulls.final_noise, (0.0, 0.0));
    }

    #[test]
    fn ids_are_bound_to_the_registration_that_got_them() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(4, 2)));
        let now = Instant::now();
        let honest = core.register("honest".into(), 1, "v".into(), "secret-a".into(), now);
        let thief = core.register("thief".into(), 1, "v".into(), "secret-b".into(), now);
        // The public id alone, or with another secret, is an unknown worker.
        let public = core.worker_name(honest);
        for forged in [
            public.clone(),
            format!("{public}.secret-b"),
            format!("{public}."),
        ] {
            assert!(
                matches!(core.touch_worker(&forged, now), Err(Refusal::NotFound(_))),
                "{forged}"
            );
        }
        let cred = core.worker_credential(honest).expect("registered");
        assert_eq!(core.touch_worker(&cred, now), Ok(honest));
        // A result under another worker's lease is refused, and does not count against it.
        let g = core.lease(honest, 1, now).remove(0);
        let name = core.lease_name(g.lease);
        let r = result(&core.jobs[&1], g.unit, 1.0);
        assert!(matches!(
            core.submit(thief, &name, 1, g.unit, r.clone(), now),
            Err(Refusal::Precondition(_))
        ));
        assert_eq!(core.workers[&honest].bad_results, 0);
        assert_eq!(core.jobs[&1].units_done, 0);
        assert!(matches!(
            core.submit(honest, &name, 1, g.unit, r, now),
            Ok(Merged::New { .. })
        ));
        // Nor can another worker renew, release or refuse the honest worker's leases.
        let g = core.lease(honest, 1, now).remove(0);
        let name = core.lease_name(g.lease);
        assert_eq!(
            core.heartbeat(thief, std::slice::from_ref(&name), now),
            vec![name.clone()]
        );
        assert_eq!(core.release(thief, std::slice::from_ref(&name)), 0);
        assert!(core
            .cannot_render(thief, std::slice::from_ref(&name), "no", 1)
            .is_empty());
        assert!(core.jobs[&1].is_live());
    }

    #[test]
    fn hoarding_registrations_cannot_stall_a_job() {
        let lease = Duration::from_secs(5);
        let mut core = Core::new(1, lease);
        core.max_leases_per_worker = 8;
        core.jobs.insert(1, Job::new(record(8, 2)));
        let t0 = Instant::now();
        let h1 = core.register("h1".into(), 1, "v".into(), "a".into(), t0);
        let h2 = core.register("h2".into(), 1, "v".into(), "b".into(), t0);
        // Each asks for everything and gets its share, no more: h1 all 8 units, h2 a racing
        // copy of each (each had one live lease), so every unit now has two holders.
        let a = core.lease(h1, 64, t0);
        assert_eq!(a.len(), 8);
        assert!(core.lease(h1, 64, t0).is_empty(), "h1 is at its share");
        let b = core.lease(h2, 64, t0);
        assert_eq!(b.len(), 8);
        let honest = core.register("honest".into(), 1, "v".into(), "c".into(), t0);
        assert!(
            core.lease(honest, 4, t0).is_empty(),
            "fresh hoards are not raced yet: the holders may just be busy"
        );
        // The hoarders keep renewing and never send anything.
        let mut t = t0;
        let mut all: Vec<String> = a
            .iter()
            .chain(&b)
            .map(|g| core.lease_name(g.lease))
            .collect();
        all.sort();
        for _ in 0..3 {
            t += lease / 2;
            core.heartbeat(h1, &all, t);
            core.heartbeat(h2, &all, t);
        }
        // Past a lease time since they were issued, the hoarded units are slow: the honest
        // worker gets copies, up to its share, and finishes every unit.
        let mut done = 0;
        let total = core.jobs[&1].units_total() as usize;
        while done < total {
            let got = core.lease(honest, 4, t);
            assert!(
                !got.is_empty(),
                "the honest worker starves after {done} units"
            );
            for g in got {
                let r = result(&core.jobs[&1], g.unit, 1.0);
                let name = core.lease_name(g.lease);
                if let Ok(Merged::New { .. }) = core.submit(honest, &name, 1, g.unit, r, t) {
                    done += 1;
                }
            }
            t += Duration::from_millis(10);
        }
        assert!(
            core.jobs[&1].finishing,
            "the job finished without the hoarders"
        );
    }

    #[test]
    fn a_unit_a_worker_cannot_render_fails_its_job_once_with_the_reason() {
        let mut core = Core::new(1, Duration::from_secs(5));
        core.jobs.insert(1, Job::new(record(4, 2)));
        let now = Instant::now();
        let w = core.register("small".into(), 1, "v".into(), "s".into(), now);
        let g = core.lease(w, 1, now).remove(0);
        let name = core.lease_name(g.lease);
        let ops = core.cannot_render(
            w,
            std::slice::from_ref(&name),
            "scene.toml: film.width 20000 is above 16384",
            5,
        );
        assert!(ops
            .iter()
            .any(|o| matches!(o, Op::PutJob(r) if r.phase == JobPhase::Failed)));
        let job = &core.jobs[&1];
        assert_eq!(job.rec.phase, JobPhase::Failed);
        assert!(
            job.rec.error.contains("cannot render tile"),
            "{}",
            job.rec.error
        );
        assert!(
            job.rec.error.contains("film.width 20000"),
            "{}",
            job.rec.error
        );
        // The unit is not handed out again.
        assert!(core.lease(w, 8, now).is_empty());
        assert!(core.cannot_render(w, &[name], "again", 6).is_empty());
    }
}
