//! What an audited job keeps besides its sums: where each merged result came from, the copies
//! held for an audit, and the kept results a conviction rebuilds tiles from. The decisions are
//! the scheduler's ([`crate::scheduler`]); these are the job's records of them.

use std::collections::{BTreeMap, BTreeSet};

use tessera_render::{PixelRect, TileSums};

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
    /// Each worker's result, in arrival order; one worker at most once.
    pub results: Vec<(u64, TileSums)>,
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
