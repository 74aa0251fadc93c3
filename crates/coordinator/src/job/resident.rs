//! Which tiles' sums are in memory. A tile's accumulator is needed in memory while results
//! still merge into it; once it is closed (every batch merged) and a checkpoint has written it,
//! the store holds the same bits and nothing will change them, so it is dropped from memory
//! ([`Job::evict`]) and read back once, tile by tile, when the frame is written
//! ([`FrameTile::Stored`]). What stays is the tile's means at the dashboard preview's
//! resolution ([`Thumb`]), so a preview of a large frame still shows every tile.
//!
//! A job whose whole frame of sums is larger than the policy's bound
//! ([`Policy::evict_open_over`](crate::scheduler::Policy::evict_open_over)) also lets its open
//! tiles go once stored, between their batches: units go out batch-major, so every tile of
//! such a job is open for most of its life, and keeping them would hold the whole frame. The
//! next batch's result reads the tile back first ([`Job::reload`]), at the cost of one tile
//! read per merge, which is why small jobs keep theirs. A job's resident sums are then the
//! tiles merged since the last checkpoint and results that wait for an earlier batch, and the
//! coordinator asks for a checkpoint early once the former reach [`MAX_DIRTY_BYTES`].
//!
//! A tile read back is the one that left only if the store still holds what memory dropped:
//! an evicted tile is never dirty, so no checkpoint writes it until it is read back and merged
//! into, and [`Job::reload`] checks the read's sample count against the tile's merged batches,
//! which refuses a read that raced a later checkpoint's copy.
//!
//! Audited jobs keep every tile (an audit folds a tile again from its sums) and so do adaptive
//! ones (their decisions read the sums); so does a job in the last moments before its frame is
//! written.

use std::sync::Arc;

use tessera_render::guide::SdTree;
use tessera_render::{PixelRect, TileSums};

use super::{Job, TileGrid, Unit};
use crate::store::{encode_sums, JobPhase, Op, AOV_BYTES, PIXEL_BYTES};

/// Longest edge of a dashboard preview, in pixels: larger frames are averaged down to it, so a
/// preview of a huge frame costs what one of a large frame does. Here rather than with the
/// preview because the tiles' kept means are made at its resolution.
pub const PREVIEW_EDGE: u32 = 1600;

/// Bytes of tiles merged since the last checkpoint (their accumulators, which cannot leave
/// memory before it) at which the coordinator asks for a checkpoint before the interval is up.
pub const MAX_DIRTY_BYTES: u64 = 256 << 20;

/// The full-resolution pixels a preview pixel of a `width` × `height` frame averages, along
/// each axis.
pub fn preview_step(width: u32, height: u32) -> u32 {
    width.max(height).div_ceil(PREVIEW_EDGE).max(1)
}

/// A tile's means at a preview's resolution: for each preview pixel the tile overlaps, the sum
/// of the means of its full-resolution pixels inside the tile, and how many there are. Adding
/// them to a preview gives what adding the pixels one by one would (up to f32 rounding).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Thumb {
    /// The first preview pixel's column and row.
    pub origin: (u32, u32),
    /// Preview pixels across.
    pub width: u32,
    /// Sums of means, row-major.
    pub sum: Vec<[f32; 3]>,
    /// Full-resolution pixels in each sum.
    pub count: Vec<u32>,
    /// Sums of the albedo and normal AOVs' means, as `sum` (empty for a job without them):
    /// what a denoised preview of a running job is filtered with.
    pub aux: Vec<[[f32; 3]; 2]>,
}

impl Thumb {
    /// `sums`' means, `step` pixels to a preview pixel along each axis. A mean is the EXR's
    /// (f64 division, then f32); a pixel without samples is black.
    pub fn of(sums: &TileSums, step: u32) -> Self {
        let r = sums.rect;
        let step = step.max(1);
        let origin = (r.x0 / step, r.y0 / step);
        let width = (r.x0 + r.width.max(1) - 1) / step - origin.0 + 1;
        let height = (r.y0 + r.height.max(1) - 1) / step - origin.1 + 1;
        let n = width as usize * height as usize;
        let mut thumb = Self {
            origin,
            width,
            sum: vec![[0.0; 3]; n],
            count: vec![0; n],
            aux: if sums.aov.is_some() {
                vec![[[0.0; 3]; 2]; n]
            } else {
                Vec::new()
            },
        };
        for (i, (s, &k)) in sums.sum.iter().zip(&sums.count).enumerate() {
            let x = r.x0 + i as u32 % r.width;
            let y = r.y0 + i as u32 / r.width;
            let j =
                (y / step - origin.1) as usize * width as usize + (x / step - origin.0) as usize;
            if k > 0 {
                for (t, v) in thumb.sum[j].iter_mut().zip(s) {
                    *t += (v / k as f64) as f32;
                }
            }
            thumb.count[j] += 1;
            if let (Some(aov), Some(t)) = (&sums.aov, thumb.aux.get_mut(j)) {
                let m = aov_means(aov, i);
                for (a, b) in t.iter_mut().zip(m) {
                    for c in 0..3 {
                        a[c] += b[c];
                    }
                }
            }
        }
        thumb
    }
}

/// Pixel `i`'s mean albedo and mean normal from AOV sums (black where no sample was summed).
pub fn aov_means(aov: &tessera_render::film::AovSums, i: usize) -> [[f32; 3]; 2] {
    let k = aov.count.get(i).copied().unwrap_or(0);
    if k == 0 {
        return [[0.0; 3]; 2];
    }
    let mean = |v: Option<&[f64; 3]>| v.map_or([0.0; 3], |s| s.map(|c| (c / f64::from(k)) as f32));
    [mean(aov.albedo.get(i)), mean(aov.normal.get(i))]
}

/// Dirty tiles' sums as they were at a checkpoint: (job, tile, sums), none for a tile whose
/// sums an audit took back. Shared with the live accumulators until encoded.
#[derive(Debug, Default)]
pub struct Snapshot(
    pub Vec<(u64, u32, Option<Arc<TileSums>>)>,
    /// Guided jobs' training trees as merged at the moment: (job, epoch, tree).
    pub Vec<(u64, u32, Arc<SdTree>)>,
);

impl Snapshot {
    /// Adds another job's snapshot.
    pub fn extend(&mut self, other: Snapshot) {
        self.0.extend(other.0);
        self.1.extend(other.1);
    }

    /// The store changes: each tile's sums encoded, or its deletion, and each training tree
    /// encoded. Made outside the scheduler's lock.
    pub fn ops(self) -> Vec<Op> {
        let trees = self
            .1
            .into_iter()
            .map(|(id, e, t)| Op::PutGuide(id, e, t.encode()));
        self.0
            .into_iter()
            .map(|(id, t, sums)| match sums {
                Some(s) => Op::PutTile(id, t, encode_sums(&s)),
                None => Op::DelTile(id, t),
            })
            .chain(trees)
            .collect()
    }
}

/// A tile of a frame to be written: its sums, or where the store keeps them.
#[derive(Debug)]
pub enum FrameTile {
    /// In memory.
    Here(TileSums),
    /// In the store, under the job's id and this tile index.
    Stored(u32, PixelRect),
}

/// A frame's tiles, row-major, from `sums` of each tile index. A tile without any (which would
/// be a bug once every unit is in) is black rather than left out of the frame.
fn frame_of(tiles: TileGrid, mut sums: impl FnMut(u32) -> Option<TileSums>) -> Vec<TileSums> {
    (0..tiles.len() as u32)
        .filter_map(|t| {
            let rect = tiles.get(t)?;
            Some(sums(t).unwrap_or_else(|| TileSums::empty(rect, 0)))
        })
        .collect()
}

impl Job {
    /// What brings the store's copy of the tiles merged since the last checkpoint up to date:
    /// each dirty tile's sums as they are now (a shared snapshot, encoded by [`Snapshot::ops`]
    /// outside the scheduler's lock), or its deletion where an audit took every batch back.
    /// Encoding at checkpoints rather than at each merge writes and copies a tile once per
    /// checkpoint, however many results it took.
    pub fn checkpoint(&mut self) -> Snapshot {
        let id = self.rec.id;
        self.dirty_bytes = 0;
        let tiles = std::mem::take(&mut self.dirty)
            .into_iter()
            .map(|t| (id, t, self.acc.get(&t).and_then(|a| a.sums.clone())))
            .collect();
        let trees = self
            .guiding
            .as_mut()
            .and_then(|g| g.take_dirty())
            .map(|(e, t)| (id, e, t))
            .into_iter()
            .collect();
        Snapshot(tiles, trees)
    }

    /// Whether tiles of this job may leave memory once stored (see the module's doc).
    fn evicts(&self) -> bool {
        !self.rec.audited
            && self.rec.noise_target == 0.0
            && self.rec.phase == JobPhase::Active
            && !self.finishing
    }

    /// Drops from memory the sums of those of `tiles` (just written by a checkpoint) that are
    /// not merged into since and have no result waiting, keeping their preview means: closed
    /// tiles only, unless `open` (see the module's doc). Returns the bytes freed.
    pub fn evict(&mut self, tiles: impl IntoIterator<Item = u32>, open: bool) -> u64 {
        if !self.evicts() {
            return 0;
        }
        let step = preview_step(self.rec.width, self.rec.height);
        let mut freed = 0;
        for t in tiles {
            if self.dirty.contains(&t) {
                continue;
            }
            let n_batches = self.n_batches;
            let Some(acc) = self.acc.get_mut(&t) else {
                continue;
            };
            if (acc.next < n_batches && !open) || !acc.pending.is_empty() {
                continue;
            }
            if let Some(sums) = acc.sums.take() {
                // The checkpoint's snapshot has been encoded: this is the last reference.
                acc.thumb = Some(Thumb::of(&sums, step));
                freed += sums.rect.area() as u64 * self.pixel_bytes();
            }
        }
        freed
    }

    /// Bytes of this job's sums were every tile in memory: what
    /// [`Policy::evict_open_over`](crate::scheduler::Policy::evict_open_over) is compared with.
    pub fn frame_bytes(&self) -> u64 {
        self.rec.width as u64 * self.rec.height as u64 * self.pixel_bytes()
    }

    /// What a pixel's sums take as stored, which memory is counted in: the beauty's, and the
    /// AOVs' where the job asks for them.
    pub fn pixel_bytes(&self) -> u64 {
        let aov = if self.rec.aovs.is_empty() {
            0
        } else {
            AOV_BYTES
        };
        (PIXEL_BYTES + aov) as u64
    }

    /// Where `unit`'s result must read its tile back from the store before it merges: the
    /// tile's sums left memory and the result is its next batch (an early one waits without
    /// them). Returns the tile's rectangle.
    pub fn needs_reload(&self, unit: Unit) -> Option<PixelRect> {
        let acc = self.acc.get(&unit.tile)?;
        (acc.sums.is_none() && acc.thumb.is_some() && acc.next == unit.batch && self.is_live())
            .then(|| self.tiles.get(unit.tile))
            .flatten()
    }

    /// Puts back the sums of `tile` read from the store, if they are still out of memory and
    /// are what left it (they cover every merged batch: a read that raced a later checkpoint
    /// holds more, and is dropped). Returns whether they went back.
    pub fn reload(&mut self, tile: u32, sums: TileSums) -> bool {
        let Some(acc) = self.acc.get(&tile) else {
            return false;
        };
        if acc.sums.is_some() || acc.thumb.is_none() || acc.next == 0 {
            return false;
        }
        let want = self.batch_range(acc.next - 1).end;
        if sums.samples != (0..want) || Some(sums.rect) != self.tiles.get(tile) {
            return false;
        }
        let Some(acc) = self.acc.get_mut(&tile) else {
            return false;
        };
        acc.sums = Some(Arc::new(sums));
        acc.thumb = None;
        true
    }

    /// Every tile's sums, row-major, copied (what tests compare frames by; writing the frame
    /// takes them instead, [`take_frame_tiles`](Self::take_frame_tiles)). A tile whose sums
    /// are only in the store is black here.
    pub fn frame_tiles(&self) -> Vec<TileSums> {
        frame_of(self.tiles, |t| {
            self.acc.get(&t).and_then(|a| a.sums.as_deref().cloned())
        })
    }

    /// Every tile, row-major, for writing the frame: the sums in memory moved out of the job
    /// (once every unit is in, the frame is written and the job ends, so a copy would double
    /// the memory a large frame takes at its peak; a restart before the end reads them from the
    /// store), and where the store holds the rest.
    pub fn take_frame_tiles(&mut self) -> Vec<FrameTile> {
        let tiles = self.tiles;
        let step = preview_step(self.rec.width, self.rec.height);
        (0..tiles.len() as u32)
            .filter_map(|t| {
                let rect = tiles.get(t)?;
                let acc = self.acc.get_mut(&t);
                Some(match acc {
                    Some(a) if a.sums.is_none() && a.thumb.is_some() => FrameTile::Stored(t, rect),
                    Some(a) => {
                        let sums = a
                            .sums
                            .take()
                            .map_or_else(|| TileSums::empty(rect, 0), Arc::unwrap_or_clone);
                        // The preview keeps showing the frame while it is written, or while
                        // it waits for a worker to denoise it.
                        a.thumb = Some(Thumb::of(&sums, step));
                        FrameTile::Here(sums)
                    }
                    None => FrameTile::Here(TileSums::empty(rect, 0)),
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thumb_sums_the_means_of_the_pixels_of_each_preview_pixel() {
        let rect = PixelRect {
            x0: 5,
            y0: 2,
            width: 4,
            height: 3,
        };
        let mut t = TileSums::empty(rect, 0);
        for (i, (s, k)) in t.sum.iter_mut().zip(&mut t.count).enumerate() {
            *k = 2;
            *s = [2.0 * i as f64, 0.0, 1.0];
        }
        t.count[0] = 0;
        // Step 1: the means themselves.
        let one = Thumb::of(&t, 1);
        assert_eq!((one.origin, one.width, one.count.len()), ((5, 2), 4, 12));
        assert_eq!(one.sum[5], [5.0, 0.0, 0.5]);
        assert_eq!(one.sum[0], [0.0; 3], "no samples: black");
        // Step 3: columns 5 | 6 7 8 → preview columns 1, 2; rows 2 | 3 4 → rows 0, 1.
        let three = Thumb::of(&t, 3);
        assert_eq!((three.origin, three.width), ((1, 0), 2));
        assert_eq!(three.count, vec![1, 3, 2, 6]);
        let total: f32 = three.sum.iter().map(|s| s[0]).sum();
        let want: f32 = (1..12).map(|i| i as f32).sum();
        assert_eq!(total, want);
    }
}
