//! What an audited job keeps besides its sums: where each merged result came from, the copies
//! held for an audit, and the kept results a conviction rebuilds tiles from. The decisions are
//! the scheduler's ([`crate::scheduler`]); these are the job's records of them.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use tessera_render::guide::SdTree;
use tessera_render::{PixelRect, TileSums};

use super::{add_noise, Job, TileAcc, Unit};
use crate::store::{encode_sums, Op};

/// The contributor of a batch no audit can take back: merged before this boot (whose workers
/// are gone), or settled by two workers' agreeing bits.
pub const NOBODY: u64 = 0;

/// Where a merged result of an audited job came from: the worker, and the merge's serial,
/// which its kept copy carries too. A rebuild folds a kept copy only if its serial is the
/// merge's: a copy written by an earlier merge of the same unit (one an audit took back) may
/// still be all the store has while the newer one waits to be committed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Source {
    /// Worker number in this boot, or [`NOBODY`].
    pub worker: u64,
    /// The merge's serial; 0 for one merged before this boot, whose stored copy is the one
    /// the last commit before the stop left, and so the one merged.
    pub serial: u64,
}

impl Source {
    /// A result merged before this boot.
    pub const RESTORED: Source = Source {
        worker: NOBODY,
        serial: 0,
    };

    /// Whether a kept copy of `serial` is this merge's.
    pub(crate) fn matches(&self, serial: u64) -> bool {
        self.serial == 0 || self.serial == serial
    }
}

/// A unit of an audited job held for its audit: a copy from another host must match it, or
/// the coordinator renders the unit itself and decides.
#[derive(Debug, Default)]
pub struct AuditHold {
    /// Each worker's result, in arrival order; one worker at most once: its sums and, in a
    /// guided job's training epoch, its training tree (which must match too).
    pub results: Vec<(u64, TileSums, Option<SdTree>)>,
    /// The hosts those workers registered from (unknown ones left out): a copy from one of
    /// them does not count, so no single host can agree with itself.
    pub hosts: BTreeSet<String>,
    /// Two results disagreed: the coordinator renders the unit and decides (its referee).
    pub disputed: bool,
    /// When the first copy arrived (for the referee of a copy no other host takes).
    pub since: Option<std::time::Instant>,
}

/// A source of the results an audited job kept ([`Op::PutUnit`]): the store, in the
/// coordinator. `()` keeps none, and a tile folded again without them renders every batch
/// again, which is slower and gives the same bits.
pub trait KeptUnits {
    /// Tile `tile`'s kept results of job `job`: batch → (serial, sums).
    fn kept(&self, job: u64, tile: u32, rect: PixelRect) -> BTreeMap<u32, (u64, TileSums)>;
}

impl KeptUnits for () {
    fn kept(&self, _: u64, _: u32, _: PixelRect) -> BTreeMap<u32, (u64, TileSums)> {
        BTreeMap::new()
    }
}

impl KeptUnits for crate::store::Store {
    fn kept(&self, job: u64, tile: u32, rect: PixelRect) -> BTreeMap<u32, (u64, TileSums)> {
        self.kept_units(job, tile, rect).unwrap_or_else(|e| {
            tracing::warn!(
                "job {job} tile {tile}: kept results unreadable ({e}); rendering it again"
            );
            BTreeMap::new()
        })
    }
}

/// Whether two results are the same: their sums bit for bit, and their training trees (a
/// guided job's) equal, what an audit compares.
pub fn same_result(a: (&TileSums, Option<&SdTree>), b: (&TileSums, Option<&SdTree>)) -> bool {
    same_bits(a.0, b.0) && a.1 == b.1
}

/// Whether two results are the same bits: what an audit compares.
pub fn same_bits(a: &TileSums, b: &TileSums) -> bool {
    let px = |x: &[[f64; 3]], y: &[[f64; 3]]| {
        x.len() == y.len()
            && x.iter()
                .zip(y)
                .all(|(p, q)| p.iter().zip(q).all(|(u, v)| u.to_bits() == v.to_bits()))
    };
    a.rect == b.rect
        && a.samples == b.samples
        && a.nonfinite == b.nonfinite
        && a.count == b.count
        && px(&a.sum, &b.sum)
        && px(&a.sum_sq, &b.sum_sq)
}

/// What [`Job::take_back`] took back.
#[derive(Debug, Default)]
pub struct TakenBack {
    /// The store changes.
    pub ops: Vec<Op>,
    /// Units that were done and go back to be rendered again.
    pub units: u64,
    /// Leases the scheduler must drop: a rewound guided job's units of epochs whose guide is
    /// gone, rendered (if at all) against a guide no longer the job's.
    pub stale_leases: Vec<u64>,
}

impl Job {
    /// Takes back every result worker `w` gave this audited, live job. Its early results and
    /// audit copies are dropped. Each tile it gave a merged batch to is folded again, in batch
    /// order from zero, from the kept results of the others, up to the first batch that is
    /// its own or whose kept copy the store cannot give back; later kept batches wait as early
    /// results. Every batch taken back goes to the front of the queue, to be rendered again.
    ///
    /// A guided job whose training `w` contributed to is rewound instead, to the start of the
    /// first epoch it trained ([`super::Guiding::rewind`]): that epoch's guide holds its training,
    /// and every later epoch sampled a guide refined from it, so every tile is folded again
    /// up to that epoch's first batch, the guides from it on are dropped, and the job renders
    /// on from there with the honest farm's guides and bits. The lie costs the job every
    /// sample from that epoch on: epochs double, so a liar caught in a job's last epoch
    /// costs about half of it, one that trained epoch 0 all of it.
    ///
    pub fn take_back(&mut self, w: u64, kept: &dyn KeptUnits) -> TakenBack {
        let rewind = self.rewind_point(w);
        let keep_below = rewind.map_or(u32::MAX, |(_, b)| b);
        let held = self.drop_audit_copies(w, keep_below);
        let mut back = Back::default();
        for t in self.touched_tiles(w, keep_below) {
            self.take_back_tile(t, (w, keep_below), kept, &mut back);
        }
        let Back { mut ops, again } = back;
        let units = again.len() as u64;
        self.uncount(&again);
        let mut stale_leases = Vec::new();
        if let Some((epoch, first)) = rewind {
            ops.extend(self.rewind_to(epoch, first, &mut stale_leases));
        }
        // A rewound job's cursor finds the units past the rewind again, behind the barrier.
        for u in again.into_iter().chain(held) {
            if u.batch < keep_below {
                self.requeue.push_front(u);
            }
        }
        TakenBack {
            ops,
            units,
            stale_leases,
        }
    }

    /// Drops worker `w`'s copies of units held for an audit, and every held unit from batch
    /// `keep_below` on; returns the units that lost a copy but still hold one.
    fn drop_audit_copies(&mut self, w: u64, keep_below: u32) -> Vec<Unit> {
        let mut held = Vec::new();
        self.audits.retain(|u, _| u.batch < keep_below);
        for (u, hold) in &mut self.audits {
            if hold.results.iter().any(|(k, ..)| *k == w) {
                hold.results.retain(|(k, ..)| *k != w);
                held.push(*u);
            }
        }
        self.audits.retain(|_, h| !h.results.is_empty());
        held
    }

    /// The tiles holding something worker `w` gave, or a batch from `keep_below` on.
    fn touched_tiles(&self, w: u64, keep_below: u32) -> Vec<u32> {
        self.acc
            .iter()
            .filter(|(_, a)| {
                a.next > keep_below
                    || a.pending.range(keep_below..).next().is_some()
                    || a.by
                        .iter()
                        .chain(a.pending_by.values())
                        .any(|s| s.worker == w)
            })
            .map(|(t, _)| *t)
            .collect()
    }

    /// Takes back tile `t`'s results from worker `w` and from batch `keep_below` on: its early
    /// ones dropped, its merged ones folded again from the others' kept copies, the job's
    /// totals (non-finite samples, noise, dirty tiles, pilots) kept in step.
    fn take_back_tile(
        &mut self,
        t: u32,
        (w, keep_below): (u64, u32),
        kept: &dyn KeptUnits,
        back: &mut Back,
    ) {
        let id = self.rec.id;
        let Some(rect) = self.tiles.get(t) else {
            return;
        };
        let first = self.first_batches;
        let pixel_bytes = self.pixel_bytes();
        let Some(acc) = self.acc.get_mut(&t) else {
            return;
        };
        let lost = drop_pending(acc, (id, t), (w, keep_below), back);
        if acc.next > keep_below || acc.by.iter().any(|s| s.worker == w) {
            let old = acc.sums.take();
            let old_next = acc.next;
            let gone = |b: u32, s: &Source| s.worker == w || b >= keep_below;
            let (total, next) = refold(acc, kept.kept(id, t, rect), (id, t, rect), &gone, back);
            self.nonfinite = self
                .nonfinite
                .saturating_sub(old.map_or(0, |o| o.nonfinite));
            self.nonfinite += total.as_ref().map_or(0, |s| s.nonfinite);
            self.nonfinite += acc
                .pending
                .iter()
                .filter(|(b, _)| **b < old_next)
                .map(|(_, p)| p.nonfinite)
                .sum::<u64>();
            let noise = total.as_ref().map_or((0.0, 0.0, 0), |s| s.noise_parts());
            add_noise(&mut self.noise_total, acc.noise, -1.0);
            add_noise(&mut self.noise_total, noise, 1.0);
            acc.noise = noise;
            if self.dirty.insert(t) {
                self.dirty_bytes += rect.area() as u64 * pixel_bytes;
            }
            acc.sums = total.map(Arc::new);
            acc.next = next;
            if old_next >= first && next < first {
                self.pilots_in = self.pilots_in.saturating_sub(1);
                self.tiles_closed = self.tiles_closed.saturating_sub(1);
            }
        }
        for p in lost {
            self.nonfinite = self.nonfinite.saturating_sub(p.nonfinite);
        }
    }

    /// Uncounts `again`'s units from the units and samples done.
    fn uncount(&mut self, again: &[Unit]) {
        for u in again {
            let area = self.tiles.get(u.tile).map_or(0, |r| r.area() as u64);
            self.units_done = self.units_done.saturating_sub(1);
            self.samples_done = self
                .samples_done
                .saturating_sub(area * self.batch_range(u.batch).len() as u64);
        }
    }

    /// Where a guided job must rewind to after worker `w` is convicted: the first epoch that
    /// trains a guide among those `w` gave results to (merged or waiting their turn; a held
    /// copy trained nothing yet), and its first batch. `None` for an unguided job, or one `w`
    /// gave only results of the last epoch, which trains nothing.
    fn rewind_point(&self, w: u64) -> Option<(usize, u32)> {
        let g = self.guiding.as_ref()?;
        let k = (self.acc.values())
            .flat_map(|a| {
                let merged = (a.by.iter().enumerate())
                    .filter(|(_, s)| s.worker == w)
                    .map(|(b, _)| b as u32);
                let waiting = (a.pending_by.iter())
                    .filter(|(_, s)| s.worker == w)
                    .map(|(b, _)| *b);
                merged.chain(waiting).collect::<Vec<_>>()
            })
            .map(|b| g.epoch_of(b))
            .min()?;
        g.trains(k).then(|| (k, g.first_batch(k)))
    }

    /// Rewinds the epochs to `epoch` (first batch `first`), with the tiles already folded back
    /// to it: the guides from it on are dropped, the cursor goes back to it, and the leases of
    /// units past the new barrier go into `stale` (their guides are gone). Returns the store
    /// changes.
    fn rewind_to(&mut self, epoch: usize, first: u32, stale: &mut Vec<u64>) -> Vec<Op> {
        let id = self.rec.id;
        let Some(g) = &mut self.guiding else {
            return Vec::new();
        };
        let mut ops = match g.rewind(id, epoch) {
            Ok(ops) => ops,
            Err(e) => {
                // Guides are this coordinator's own encodings: they decode.
                tracing::error!("job {id}: rewinding to epoch {epoch}: {e}");
                Vec::new()
            }
        };
        let released = g.released();
        self.note_guides();
        ops.push(Op::PutJob(self.rec.clone()));
        let n_tiles = self.tiles.len() as u64;
        self.cursor = self.cursor.min(first as u64 * n_tiles);
        self.requeue.retain(|u| u.batch < first);
        self.issued.retain(|u, ids| {
            let keep = u.batch < released;
            if !keep {
                stale.append(ids);
            }
            keep
        });
        ops
    }
}

/// What taking back a worker's results gives: store operations, and units to render again.
#[derive(Default)]
struct Back {
    ops: Vec<Op>,
    again: Vec<Unit>,
}

/// Drops tile `t`'s early results from worker `w` and from batch `keep_below` on; returns
/// them (their non-finite samples are uncounted by the caller).
fn drop_pending(
    acc: &mut TileAcc,
    (id, t): (u64, u32),
    (w, keep_below): (u64, u32),
    back: &mut Back,
) -> Vec<TileSums> {
    let mine: Vec<u32> = acc
        .pending
        .keys()
        .filter(|b| **b >= keep_below || acc.pending_by.get(b).is_some_and(|s| s.worker == w))
        .copied()
        .collect();
    let mut lost = Vec::new();
    for b in mine {
        acc.pending_by.remove(&b);
        if let Some(p) = acc.pending.remove(&b) {
            lost.push(p);
        }
        back.ops.push(Op::DelPending(id, t, b));
        back.again.push(Unit { tile: t, batch: b });
    }
    lost
}

/// Folds tile `t`'s merged batches again, in batch order from zero, from the kept `copies`
/// of those not `gone`, up to the first that is gone or has no copy; later kept batches wait
/// as early results, the rest go back. Returns the sums and the first batch not folded.
fn refold(
    acc: &mut TileAcc,
    mut copies: BTreeMap<u32, (u64, TileSums)>,
    (id, t, rect): (u64, u32, PixelRect),
    gone: &dyn Fn(u32, &Source) -> bool,
    back: &mut Back,
) -> (Option<TileSums>, u32) {
    let by = std::mem::take(&mut acc.by);
    let mut total: Option<TileSums> = None;
    let mut next = 0u32;
    for (b, src) in (0..acc.next).zip(by) {
        let copy = copies
            .remove(&b)
            .filter(|(serial, _)| !gone(b, &src) && src.matches(*serial));
        match copy {
            Some((_, s)) if next == b => {
                // Kept copies were checked when they were merged.
                let sum = total.get_or_insert_with(|| TileSums::empty(rect, 0));
                if sum.merge(&s).is_err() {
                    back.again.push(Unit { tile: t, batch: b });
                    continue;
                }
                acc.by.push(src);
                next += 1;
            }
            Some((_, s)) => {
                back.ops.push(Op::PutPending(id, t, b, encode_sums(&s)));
                acc.pending.insert(b, s);
                acc.pending_by.insert(b, src);
            }
            None => back.again.push(Unit { tile: t, batch: b }),
        }
    }
    (total, next)
}
