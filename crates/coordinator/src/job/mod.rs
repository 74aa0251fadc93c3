//! A job in memory: its tiles as arithmetic, its per-tile accumulators, and the merge that
//! folds results into them in batch order. Scheduling (which unit goes to whom) is the
//! [`scheduler`](crate::scheduler)'s; this file knows nothing of workers or leases.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::ops::Range;
use std::sync::Arc;
use std::time::Instant;

use tessera_proto::ids::JobId;
use tessera_proto::view::JobState;
use tessera_render::adaptive::{min_batches, neyman_scale, tile_wants_more, wants_more};
use tessera_render::{Adaptive, Aovs, RenderSettings, TileSums};

use crate::error::Refusal;

mod audit;
mod guide_epochs;
mod preview;
mod rate;
mod resident;
mod restore;
mod tiles;

use crate::store::{encode_sums, JobPhase, JobRecord, Op};
pub use audit::{same_bits, same_result, AuditHold, KeptUnits, Source, TakenBack, NOBODY};
pub use guide_epochs::{Guide, Guiding};
pub use preview::{PreviewSource, TileMeans};
pub use rate::Rate;
pub use resident::{
    aov_means, preview_step, FrameTile, Snapshot, Thumb, MAX_DIRTY_BYTES, PREVIEW_EDGE,
};
pub use tiles::{check_aov_sums, pixel_in_range, sums_in_range, TileGrid};

/// One work unit: a tile and a batch of sample indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Unit {
    /// Tile index (row-major).
    pub tile: u32,
    /// Batch index.
    pub batch: u32,
}

/// Most tiles a finished job keeps its per-tile noise for ([`Job::final_tile_noise`]): 256 KiB.
pub const MAX_KEPT_TILE_NOISE: usize = 1 << 16;

/// The relative noise of sums whose [`TileSums::noise_parts`] are `parts`: the RMS standard
/// error of the pixel means over their mean; NaN where there are no samples (or no signal).
pub fn relative_noise(parts: (f64, f64, u64)) -> f32 {
    let (var, mean, n) = parts;
    if n > 0 && mean > 0.0 {
        ((var.max(0.0) / n as f64).sqrt() / (mean / n as f64)) as f32
    } else {
        f32::NAN
    }
}

/// Merged sums of one tile: batches `0..next` folded in order, plus results that arrived early.
#[derive(Debug, Default)]
pub struct TileAcc {
    /// Sums of batches `0..next` (allocated at the first merge). Shared with a checkpoint
    /// being encoded, which takes a snapshot under the lock and encodes it outside; a merge
    /// meanwhile copies the tile first (copy on write), so the snapshot stays the moment's.
    pub sums: Option<Arc<TileSums>>,
    /// First batch not yet folded in.
    pub next: u32,
    /// Results for batches after `next`, waiting for their turn.
    pub pending: BTreeMap<u32, TileSums>,
    /// [`TileSums::noise_parts`] of `sums`.
    pub noise: (f64, f64, u64),
    /// Audited jobs only: where each batch in `0..next` came from.
    pub by: Vec<Source>,
    /// Audited jobs only: where each early result came from.
    pub pending_by: BTreeMap<u32, Source>,
    /// Set when `sums` were dropped from memory because the store holds them and no result
    /// will change them ([`Job::evict`]): the preview's means of the tile, at its resolution.
    pub thumb: Option<Thumb>,
}

/// A job in memory.
#[derive(Debug)]
pub struct Job {
    /// What is stored.
    pub rec: JobRecord,
    /// Its tiles, row-major.
    pub tiles: TileGrid,
    /// Batches per tile (the most, with a noise target).
    pub n_batches: u32,
    /// Batches every tile takes before its first noise decision ([`n_batches`](Self::n_batches)
    /// without a noise target): the cursor hands these out, decisions the rest.
    pub first_batches: u32,
    /// Batches that tiles' noise decisions released, lowest batch first: `(batch, tile)`.
    pub ready: BTreeSet<(u32, u32)>,
    /// Tiles that need no more batches.
    pub tiles_closed: u64,
    /// Tiles whose first batches (the adaptive pilot) are all merged: decisions wait until
    /// every tile's are, which fixes the image's scale.
    pub pilots_in: u64,
    /// Units the job will take at least: every tile's first batches, and one more for each
    /// decision to go on. The job's whole count without a noise target.
    pub units_planned: u64,
    /// Accumulators of the tiles that have results, made at a tile's first result (none
    /// once the job has ended).
    pub acc: BTreeMap<u32, TileAcc>,
    /// The sum of every accumulator's `noise`, kept as results merge so that a status does
    /// not walk every tile under the lock.
    pub noise_total: (f64, f64, u64),
    /// Tiles whose sums changed since the last checkpoint ([`Job::checkpoint`]).
    pub dirty: BTreeSet<u32>,
    /// Bytes of those tiles' accumulators.
    pub dirty_bytes: u64,
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
    /// Merged samples over the last seconds.
    pub rate: Rate,
    /// A unit has been leased.
    pub started: bool,
    /// Every unit is in; the EXR is being written.
    pub finishing: bool,
    /// Audited jobs: units rendered more than once and not yet settled (kept in memory only:
    /// after a restart such a unit is rendered again).
    pub audits: HashMap<Unit, AuditHold>,
    /// A finished job's per-tile relative noise, kept (in memory only) for the dashboard's
    /// noise view once the sums are gone; none for a job of more than [`MAX_KEPT_TILE_NOISE`]
    /// tiles, or one that ended before this boot.
    pub final_tile_noise: Option<Vec<f32>>,
    /// The noise of the finished image, as `tessera render` computes it from the EXR's pixels
    /// ([`tessera_render::Image::noise`]), set when the EXR is written: what a done job
    /// reports, so the farm and `render` print the same figure for the same bits.
    pub image_noise: Option<(f64, f64)>,
    /// A guided job's epochs and guides ([`Guiding`]).
    pub guiding: Option<Guiding>,
    /// Failed, and its scene still kept for `tessera retry` (in memory: set when it fails, and
    /// at a restart from the record's end time and the stored scenes).
    pub retryable: bool,
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

impl Job {
    /// A job from its record, with the stored sums folded back in.
    pub fn new(rec: JobRecord) -> Self {
        let tiles = TileGrid::new(rec.width, rec.height, rec.tile_size);
        let guiding = rec
            .guiding
            .as_ref()
            .map(|g| Guiding::new(rec.spp, rec.batch, g.bounds));
        let n_batches = guiding.as_ref().map_or_else(
            || rec.spp.div_ceil(rec.batch.max(1)),
            |g| g.ranges().len() as u32,
        );
        let first_batches = if rec.noise_target > 0.0 {
            min_batches(rec.batch).min(n_batches)
        } else {
            n_batches
        };
        Self {
            rec,
            tiles,
            n_batches,
            first_batches,
            ready: BTreeSet::new(),
            tiles_closed: 0,
            pilots_in: 0,
            units_planned: tiles.len() as u64 * first_batches as u64,
            acc: BTreeMap::new(),
            noise_total: (0.0, 0.0, 0),
            dirty: BTreeSet::new(),
            dirty_bytes: 0,
            cursor: 0,
            requeue: VecDeque::new(),
            issued: HashMap::new(),
            units_done: 0,
            samples_done: 0,
            nonfinite: 0,
            rate: Rate::default(),
            started: false,
            finishing: false,
            audits: HashMap::new(),
            final_tile_noise: None,
            image_noise: None,
            guiding,
            retryable: false,
        }
    }

    /// Copies the guides' hashes into the record.
    fn note_guides(&mut self) {
        if let (Some(g), Some(r)) = (&self.guiding, &mut self.rec.guiding) {
            r.guides = g.hashes();
        }
    }

    /// The job's id.
    pub fn id(&self) -> JobId {
        JobId(self.rec.id)
    }

    /// Units in the job: the most it can take (with a noise target, tiles may stop before).
    pub fn units_total(&self) -> u64 {
        self.tiles.len() as u64 * self.n_batches as u64
    }

    /// (units in all, units done, samples in all, samples done) for a status. With a noise
    /// target the totals are what the decisions so far commit the job to, and grow as tiles
    /// decide to go on; once the job is done they are what it took.
    pub fn progress(&self) -> (u64, u64, u64, u64) {
        let rec = &self.rec;
        if rec.phase == JobPhase::Done && rec.final_counts != (0, 0) {
            let (u, s) = rec.final_counts;
            return (u, u, s, s);
        }
        let full = rec.width as u64 * rec.height as u64 * rec.spp as u64;
        if rec.phase == JobPhase::Done || rec.noise_target <= 0.0 {
            let done = if rec.phase == JobPhase::Done {
                (self.units_total(), full)
            } else {
                (self.units_done, self.samples_done)
            };
            return (self.units_total(), done.0, full, done.1);
        }
        let per_unit = (rec.width as u64 * rec.height as u64 * rec.batch as u64)
            .div_ceil(self.tiles.len().max(1) as u64);
        let to_come = self.units_planned.saturating_sub(self.units_done) * per_unit;
        (
            self.units_planned.max(self.units_done),
            self.units_done,
            (self.samples_done + to_come).min(full),
            self.samples_done,
        )
    }

    /// Units handed out by the cursor: every tile's first batches.
    pub fn units_first(&self) -> u64 {
        self.tiles.len() as u64 * self.first_batches as u64
    }

    /// Whether every tile has all the batches it will take, merged.
    pub fn all_closed(&self) -> bool {
        self.tiles_closed == self.tiles.len() as u64
    }

    /// Whether some tile has results past its pilot.
    fn past_pilot(&self) -> bool {
        let first = self.first_batches;
        self.acc
            .values()
            .any(|a| a.next > first || a.pending.keys().any(|&b| b >= first))
    }

    /// An adaptive job with results past its tiles' pilots and no scale: one accepted before
    /// the scale was kept (by an earlier rule), whose decisions cannot be made again.
    pub fn lost_scale(&self) -> bool {
        self.rec.noise_target > 0.0 && self.rec.adaptive_scale.is_none() && self.past_pilot()
    }

    /// The scale decisions are made under: 0 for a job without a noise target (whose tiles
    /// all run to `spp`), the adaptive scale once every tile's pilot is in, else none yet.
    fn scale(&self) -> Option<f64> {
        if self.rec.noise_target <= 0.0 {
            Some(0.0)
        } else {
            self.rec.adaptive_scale
        }
    }

    /// Computes the adaptive scale from every tile's pilot sums, in tile order, and makes
    /// every tile's first decision under it.
    fn fix_scale(&mut self) {
        let pilots = self.acc.values().filter_map(|a| a.sums.as_deref());
        self.rec.adaptive_scale = Some(neyman_scale(self.rec.noise_target, pilots));
        let tiles: Vec<u32> = self.acc.keys().copied().collect();
        for tile in tiles {
            self.decide(tile);
        }
    }

    /// The noise decision for `tile`, whose batches `0..next` are merged and which has had its
    /// first batches: either its next batch is released, or it is closed. Every decision is
    /// made here, from merged sums only, so that the same job stops every tile at the same
    /// batch whatever order results come in, and after a restart.
    fn decide(&mut self, tile: u32) {
        let Some(scale) = self.scale() else {
            return;
        };
        let Some(acc) = self.acc.get(&tile) else {
            return;
        };
        let end = acc.next.saturating_mul(self.rec.batch).min(self.rec.spp);
        let settings = self.settings();
        let more = match &acc.sums {
            Some(sums) => tile_wants_more(&settings, sums, scale),
            None => wants_more(&settings, end, 0.0, scale),
        };
        if more {
            self.ready.insert((acc.next, tile));
            self.units_planned += 1;
        } else {
            self.tiles_closed += 1;
        }
    }

    /// Sample indices of batch `b`.
    pub fn batch_range(&self, b: u32) -> Range<u32> {
        if let Some(g) = &self.guiding {
            let spp = self.rec.spp;
            return g.ranges().get(b as usize).cloned().unwrap_or(spp..spp);
        }
        let s = b.saturating_mul(self.rec.batch).min(self.rec.spp);
        s..s.saturating_add(self.rec.batch).min(self.rec.spp)
    }

    /// The renderer settings of this job.
    pub fn settings(&self) -> RenderSettings {
        RenderSettings {
            seed: self.rec.seed,
            spp: self.rec.spp,
            batch: self.rec.batch,
            strategy: self.rec.strategy,
            adaptive: (self.rec.noise_target > 0.0).then_some(Adaptive {
                noise_target: self.rec.noise_target,
                tile: self.rec.tile_size,
            }),
            frame: self.rec.frame,
            // Written by admission from a list that parsed; a damaged record gives none.
            aovs: Aovs::parse(&self.rec.aovs).unwrap_or_default(),
            guiding: self.guiding.is_some(),
            resolution: self.rec.resolution,
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

    /// Where the job is in its life: the one rule for queued against running (a unit leased).
    pub fn state(&self) -> JobState {
        match self.rec.phase {
            JobPhase::Active if self.started => JobState::Running,
            JobPhase::Active => JobState::Queued,
            JobPhase::Done => JobState::Done,
            JobPhase::Cancelled => JobState::Cancelled,
            JobPhase::Failed => JobState::Failed,
        }
    }

    /// Whether the job still takes leases and results.
    pub fn is_live(&self) -> bool {
        self.rec.phase == JobPhase::Active && !self.finishing
    }

    /// Merged samples per second over the last [`Rate::WINDOW`] before `now`; 0 once the job
    /// has ended.
    pub fn rate(&self, now: Instant) -> f64 {
        if self.rec.phase == JobPhase::Active {
            self.rate.per_second(now)
        } else {
            0.0
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
        match (&r.aov, self.rec.aovs.is_empty()) {
            (None, true) => Ok(()),
            (Some(a), false) => check_aov_sums(a, per_pixel),
            (Some(_), true) => Err("result has AOV sums, and the job renders no AOVs".into()),
            (None, false) => Err(format!(
                "result has no AOV sums, and the job renders {}",
                self.rec.aovs
            )),
        }
    }

    /// Folds a checked result for `unit` into its tile: at once if it is the tile's next batch
    /// (with any early results it lets in after it), or else kept until its turn. Tiles fold
    /// their batches in index order from zero, so the sums are the same bits whatever order
    /// results arrive in. Returns the store changes and whether it was the job's last unit.
    ///
    /// `by` is the worker it came from: an audited job keeps each result and its source, so
    /// that an audit can take back a worker's results later ([`Job::take_back`]).
    pub fn merge(
        &mut self,
        unit: Unit,
        sums: TileSums,
        by: Source,
        now: Instant,
    ) -> Result<(Vec<Op>, bool), Refusal> {
        let id = self.rec.id;
        let audited = self.rec.audited;
        let samples = sums.rect.area() as u64 * sums.samples.len() as u64;
        self.units_done += 1;
        self.samples_done += samples;
        self.nonfinite += sums.nonfinite;
        self.rate.record(now, self.samples_done);
        let mut ops = Vec::new();
        if audited {
            ops.push(Op::PutUnit(
                id,
                unit.tile,
                unit.batch,
                by.serial,
                encode_sums(&sums),
            ));
        }
        let rect = sums.rect;
        let acc = self.acc.entry(unit.tile).or_default();
        let before = acc.next;
        let mut advanced = false;
        if unit.batch == acc.next {
            advanced = true;
            let total = Arc::make_mut(
                acc.sums
                    .get_or_insert_with(|| Arc::new(TileSums::empty(rect, 0))),
            );
            total
                .merge(&sums)
                .map_err(|e| Refusal::Invalid(e.to_string()))?;
            acc.next += 1;
            if audited {
                acc.by.push(by);
            }
            while let Some(p) = acc.pending.remove(&acc.next) {
                total
                    .merge(&p)
                    .map_err(|e| Refusal::Invalid(e.to_string()))?;
                ops.push(Op::DelPending(id, unit.tile, acc.next));
                if audited {
                    let from = acc.pending_by.remove(&acc.next);
                    acc.by.push(from.unwrap_or(Source::RESTORED));
                }
                acc.next += 1;
            }
            let noise = total.noise_parts();
            add_noise(&mut self.noise_total, acc.noise, -1.0);
            add_noise(&mut self.noise_total, noise, 1.0);
            acc.noise = noise;
            // Written at the next checkpoint, once however many merges come before it.
            if self.dirty.insert(unit.tile) {
                self.dirty_bytes += rect.area() as u64 * self.pixel_bytes();
            }
        } else {
            ops.push(Op::PutPending(
                id,
                unit.tile,
                unit.batch,
                encode_sums(&sums),
            ));
            acc.pending.insert(unit.batch, sums);
            if audited {
                acc.pending_by.insert(unit.batch, by);
            }
        }
        if let (true, Some(g)) = (advanced, &mut self.guiding) {
            let after = self.acc[&unit.tile].next;
            let done = g.advanced(id, before, after, self.tiles.len() as u64);
            if !done.is_empty() {
                ops.extend(done);
                self.note_guides();
                ops.push(Op::PutJob(self.rec.clone()));
            }
        }
        if advanced && self.acc[&unit.tile].next >= self.first_batches {
            if before < self.first_batches {
                self.pilots_in += 1;
            }
            if self.scale().is_some() {
                self.decide(unit.tile);
            } else if self.pilots_in == self.tiles.len() as u64 {
                // The last pilot: the scale is kept with the tile's sums, in one commit.
                self.fix_scale();
                ops.push(Op::PutJob(self.rec.clone()));
            }
        }
        let finished = self.all_closed();
        if finished {
            self.finishing = true;
        }
        Ok((ops, finished))
    }

    /// Each tile's relative noise from its merged sums, row-major ([`relative_noise`]).
    pub fn tile_noise(&self) -> Vec<f32> {
        (0..self.tiles.len() as u32)
            .map(|t| relative_noise(self.acc.get(&t).map(|a| a.noise).unwrap_or_default()))
            .collect()
    }

    /// Forgets the job's units, sums and early results (it has ended): what is left is its
    /// record. Returns the unit leases that were out, for the scheduler to drop.
    pub fn clear(&mut self) -> Vec<u64> {
        self.acc = BTreeMap::new();
        self.dirty.clear();
        self.dirty_bytes = 0;
        self.noise_total = (0.0, 0.0, 0);
        self.requeue.clear();
        self.audits.clear();
        self.issued.drain().flat_map(|(_, ids)| ids).collect()
    }
}
